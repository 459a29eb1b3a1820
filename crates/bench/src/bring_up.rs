//! Section 5's "after bring-up" (issue 27): on realistic.toml reduced to some of its imperfection groups, at
//! several seeds, `gonio align` (alignment and characterisation) and then the demo campaign without and with
//! the calibration it wrote, through the release binary as a lab would run them. The same classes and error
//! as the error budget (crate::error_budget).

use std::path::Path;
use std::process::{Command, Stdio};

use crate::error_budget::{CLASSES, ClassPoint, Variant, errors_of, pct, variant_text};

/// The variants: a name and the groups kept.
pub const VARIANTS: [(&str, &[&str]); 3] = [
    ("geometry only", &["geometry"]),
    ("geometry + detector", &["geometry", "detector"]),
    (
        "every effect",
        &["geometry", "detector", "source", "sample", "filters", "beam"],
    ),
];
/// Seeds: realistic.toml's own and four more.
pub const SEEDS: [u64; 5] = [16, 3, 101, 2027, 7];

/// One variant at one seed: the demo's errors without and with the calibration.
#[derive(Debug, Clone)]
pub struct Pair {
    pub variant: &'static str,
    pub seed: u64,
    pub plain: Variant,
    pub aligned: Variant,
}

/// The points of a run's points.csv.
fn read_points(csv: &Path) -> Result<Vec<ClassPoint>, String> {
    let text = std::fs::read_to_string(csv).map_err(|e| format!("{}: {e}", csv.display()))?;
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().ok_or("points.csv is empty")?.split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or(format!("points.csv has no column {name}"))
    };
    let cols = [
        col("theta_i_deg")?,
        col("phi_i_deg")?,
        col("theta_o_deg")?,
        col("phi_o_deg")?,
    ];
    let (brdf, truth) = (col("brdf_sr")?, col("brdf_true_sr")?);
    Ok(lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |k: usize| f.get(k).and_then(|v| v.parse::<f64>().ok());
            ClassPoint {
                geometry_deg: cols.map(|k| num(k).unwrap_or(f64::NAN)),
                brdf_sr: num(brdf),
                truth_sr: num(truth),
            }
        })
        .collect())
}

/// `gonio align` with the bring-up's steps (the alignment, the characterisation and the sample's own alignment)
/// on `instrument`, its calibration written to `out`.
pub fn align(binary: &Path, instrument: &Path, out: &Path) -> Result<(), String> {
    run(
        binary,
        &[
            "align".as_ref(),
            "--instrument".as_ref(),
            instrument.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--steps".as_ref(),
            "alignment,characterisation,sample-alignment".as_ref(),
        ],
    )
}

/// `gonio ARGS...` through `binary`, standard input closed; the last line of its error output on failure.
pub fn run(binary: &Path, args: &[&std::ffi::OsStr]) -> Result<(), String> {
    let out = Command::new(binary)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("{}: {e}", binary.display()))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "gonio {:?}: {}",
            args,
            String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("")
        ))
    }
}

/// Every variant at each of `seeds`.
pub fn bring_up(root: &Path, binary: &Path, seeds: &[u64]) -> Result<Vec<Pair>, String> {
    if !binary.exists() {
        return Err(format!(
            "{} not found: build it with `cargo build --release -p gonio`",
            binary.display()
        ));
    }
    let realistic = std::fs::read_to_string(root.join("config/instruments/realistic.toml"))
        .map_err(|e| format!("config/instruments/realistic.toml: {e}"))?;
    let demo = root.join("config/campaigns/demo.toml");
    let dir = std::env::temp_dir().join(format!("gonio-bench-bring-up-{}", std::process::id()));
    let mut out = Vec::new();
    for (variant, keep) in VARIANTS {
        for &seed in seeds {
            let text = variant_text(&realistic, keep)?.replace("seed = 16", &format!("seed = {seed}"));
            let here = dir.join(format!("{}-{seed}", variant.replace([' ', '+'], "")));
            std::fs::create_dir_all(&here).map_err(|e| format!("{}: {e}", here.display()))?;
            let instrument = here.join("instrument.toml");
            std::fs::write(&instrument, &text).map_err(|e| format!("{}: {e}", instrument.display()))?;
            let cal = here.join("cal.toml");
            align(binary, &instrument, &cal)?;
            let demo_run = |name: &str, calibration: Option<&Path>| -> Result<Variant, String> {
                let out_dir = here.join(name);
                let mut args: Vec<&std::ffi::OsStr> = vec![
                    "run".as_ref(),
                    demo.as_os_str(),
                    "--quiet".as_ref(),
                    "--instrument".as_ref(),
                    instrument.as_os_str(),
                    "--out".as_ref(),
                    out_dir.as_os_str(),
                ];
                if let Some(c) = calibration {
                    args.push("--calibration".as_ref());
                    args.push(c.as_os_str());
                }
                run(binary, &args)?;
                Ok(errors_of(name, &read_points(&out_dir.join("points.csv"))?))
            };
            out.push(Pair {
                variant,
                seed,
                plain: demo_run("plain", None)?,
                aligned: demo_run("aligned", Some(&cal))?,
            });
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(out)
}

/// Issue 27's targets on one pair: the median at least 5x and the p95 at least 3x below the uncorrected run, and
/// in every class at most 3x the ideal instrument's median or 5x below the uncorrected, whichever is larger.
fn verdict(p: &Pair, ideal: &Variant) -> String {
    let all = CLASSES.len();
    let (m0, m1) = (p.plain.classes[all].median, p.aligned.classes[all].median);
    let (p0, p1) = (p.plain.classes[all].p95, p.aligned.classes[all].p95);
    let mut missed = Vec::new();
    if m1 * 5.0 > m0 {
        missed.push(format!("median {:.1}x", m0 / m1));
    }
    if p1 * 3.0 > p0 {
        missed.push(format!("p95 {:.1}x", p0 / p1));
    }
    for (k, name) in CLASSES.iter().enumerate() {
        let limit = (3.0 * ideal.classes[k].median).max(p.plain.classes[k].median / 5.0);
        if p.aligned.classes[k].median > limit {
            missed.push(format!(
                "{name} {} > {}",
                pct(p.aligned.classes[k].median),
                pct(limit)
            ));
        }
    }
    if missed.is_empty() {
        "met".into()
    } else {
        format!("NOT met: {}", missed.join("; "))
    }
}

/// The subsection, with the ideal instrument's classes (`ideal`) for the per-class target.
pub fn markdown(pairs: &Result<Vec<Pair>, String>, ideal: Option<&Variant>) -> String {
    let mut s = String::from(
        "### After bring-up: `gonio align`, then the demo with its calibration\n\n\
         realistic.toml reduced to the groups named, at each seed listed (16 is the file's own), through the release \
         binary: `gonio align --instrument FILE --out CAL.toml --steps alignment,characterisation,sample-alignment` \
         (alignment on a mirror, the characterisation: the meter's ranges, the signature, the source's warm-up, \
         and the alignment on the sample's own specular lobe; the dry-run's sample is the demo's coloured plastic), then `gonio run demo.toml` without and with `--calibration CAL.toml`. Median and p95 of the \
         relative error against the point truth, over all points and per class (median). Targets (issue 27, for \
         geometry + detector): median 5x and p95 3x below the uncorrected run, and per class at most 3x the ideal \
         instrument's median (the error budget's first row) or 5x below the uncorrected, whichever is larger.\n\n\
         | variant | seed | uncorrected median / p95 | calibrated median / p95 | within 2 deg | 2-15 deg | beyond 15 deg | grazing | targets |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    let pairs = match pairs {
        Ok(p) => p,
        Err(e) => {
            s.push_str(&format!("\nFAILED: {e}\n"));
            return s;
        }
    };
    let all = CLASSES.len();
    for p in pairs {
        let class = |k: usize| {
            format!(
                "{} -> {}",
                pct(p.plain.classes[k].median),
                pct(p.aligned.classes[k].median)
            )
        };
        s.push_str(&format!(
            "| {} | {} | {} / {} | {} / {} | {} | {} | {} | {} | {} |\n",
            p.variant,
            p.seed,
            pct(p.plain.classes[all].median),
            pct(p.plain.classes[all].p95),
            pct(p.aligned.classes[all].median),
            pct(p.aligned.classes[all].p95),
            class(0),
            class(1),
            class(2),
            class(3),
            ideal.map_or("-".into(), |i| verdict(p, i)),
        ));
    }
    s.push_str(
        "\nWhat remains after bring-up, and why:\n\
         - **The sample's seating.** The alignment finds the sample's tilt as it sat during the alignment; every \
           mounting sits differently (realistic.toml: 0.01 deg per component), and a campaign remounts the sample \
           after each direct-beam reading. Near the specular direction and at grazing angles that is much of the \
           error left (`cargo test -p gonio --test cli align -- --ignored --nocapture` prints the demo on a sample \
           that seats the same way every time).\n\
         - **The smallest ranges' gains.** Every BRDF is a reading on the smallest ranges over a direct beam on \
           the largest; the gains between them are chained through overlaps, and a top-hat beam's edge gives the \
           middle ranges only a few levels (the sample's reflection reaches the two smallest), so the smallest \
           range's gain relative to the largest is known to about 4e-4: a floor of a few hundredths of a per cent \
           under every diffuse point.\n\
         - **What the scans cannot observe.** The beam's direction against its line through the arms' axis, its \
           elevation, the encoders' cyclic errors and the rotation's zero stay at nominal (crates/engine/src/align/\
           file.rs, `params`); a few hundredths of a degree of incidence or view remain.\n\
         - **The solid angle.** The aperture's radius and its distance from the arms' axis are the lab's measured \
           figures (realistic.toml: to 1 um and 0.1 mm), which no scan observes, and the absolute method divides \
           every value by the solid angle they give: each seed's draw shifts every value alike. Seed 101 draws the \
           aperture 0.21 mm farther than the file says (-0.22 % on every value: its calibrated median), seed 7 a \
           radius 1.7 um smaller (-0.16 %), seeds 16, 3 and 2027 under 0.06 %. The budget carries it as shared \
           by every value (`solid_angle_u`, 0.11 %); the relative method's reference sample takes it out.\n\
         - **Every effect on** adds the finite filter bands on a coloured sample (the error budget's filters \
           row: each filter's centre off its nominal one by up to its tolerance, times the sample's spectral \
           slope, which a calibration through the same filter cannot take out; the light the filters leak from \
           outside their bands is corrected from the bands measured, gonio_results::band_component), the \
           sample's non-uniformity and the source's wander between references; none of these is an instrument \
           error a bring-up can measure (issue 29 puts them in the uncertainty).\n",
    );
    s
}
