//! Issue 29's accuracy table (ACCURACY.md): does each value's stated standard uncertainty cover the BRDF at the
//! nominal geometry? Over random geometries per material (a third near the specular direction), on the ideal
//! instrument and on realistic.toml, each at several seeds, without and after bring-up (`gonio align` with the
//! characterisation and the sample's own alignment, its calibration applied), through the release binary as a
//! lab runs it. What every value of an instrument shares (the solid angle, a range's gain, a filter's centre,
//! a band's direct-beam reading) is one draw per instrument: on one seed it is either inside its interval or
//! not for all of them at once, so the geometries are spread over [`SEEDS`] instruments and coverage is a
//! statement about them all. Per material and angular class (gonio_results::angular_class): how often the
//! k = 2 interval holds the point truth, the rms of (value - truth) / u (1 for an honest budget), the median and 95th
//! percentile of |value / truth - 1|, the median k = 2 relative uncertainty, and the three largest budget
//! components (median u / value). The targets are checked at the top and a missed one is said so.

use std::collections::BTreeMap;
use std::path::Path;

use gonio_brdf::Direction;
use gonio_results::aperture::FLAG_NARROW_LOBE;
use gonio_results::points::{Point, parse_points_csv};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::bring_up::run as gonio;

mod chance;
mod fits;
mod report;
use crate::error_budget::variant_text;
pub use report::markdown;

pub const COMMAND: &str =
    "cargo build --release -p gonio && cargo run --release -p gonio-bench -- --accuracy";

/// The materials: every preset (the five seed materials and spectralon).
pub const MATERIALS: &[&str] = gonio_brdf::presets::NAMES;
/// The instruments: each file's seed set to realistic.toml's own and fifteen more, on realistic.toml each a
/// different draw of every hidden imperfection, on both different noise.
pub const SEEDS: [u64; 16] = [16, 3, 5, 7, 11, 21, 29, 42, 2, 13, 17, 23, 31, 37, 53, 61];
/// More instruments for `--seeds N` (up to 64 with [`SEEDS`]): with 16, an honest k = 2 interval is within on
/// 14 of 16 or fewer about one time in six, so a fit parameter's row says little on its own.
const MORE_SEEDS: [u64; 48] = [
    67, 71, 73, 79, 83, 89, 97, 101, 103, 107, 109, 113, 127, 131, 137, 139, 149, 151, 157, 163, 167, 173,
    179, 181, 191, 193, 197, 199, 211, 223, 227, 229, 233, 239, 241, 251, 257, 263, 269, 271, 277, 281, 283,
    293, 307, 311, 313, 317,
];
/// Random geometries per material and set-up (each measured in every band of the run), spread evenly over its
/// seeds.
pub const GEOMETRIES: usize = 2000;
/// The bands every geometry is measured in, unless `--bands` says otherwise (nm).
pub const BANDS_NM: [f64; 3] = [450.0, 550.0, 650.0];

/// What one accuracy run covers: the table in ACCURACY.md takes the defaults; `--bands`, `--materials`,
/// `--setups` and `--seeds` narrow or change it for working on one part (the five-band experiment in
/// gonio_results::band_component's notes, the 48-instrument run in docs/reference/uncertainty.md), written
/// elsewhere (`--out`), never over ACCURACY.md.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Bands in nm, ascending.
    pub bands_nm: Vec<f64>,
    pub materials: Vec<&'static str>,
    /// Which of [`setups`] by kind: `ideal`, `realistic`, `bring-up`.
    pub setups: Vec<String>,
    /// The instruments (simulator seeds) of every set-up: [`SEEDS`], or the first `--seeds N` of them and
    /// [`MORE_SEEDS`].
    pub seeds: Vec<u64>,
}

/// The set-up kinds `--setups` takes, in [`setups`]' order.
pub const SETUP_KINDS: [&str; 3] = ["ideal", "realistic", "bring-up"];

impl Default for Options {
    fn default() -> Options {
        Options {
            bands_nm: BANDS_NM.to_vec(),
            materials: MATERIALS.to_vec(),
            setups: SETUP_KINDS.iter().map(|k| k.to_string()).collect(),
            seeds: SEEDS.to_vec(),
        }
    }
}

impl Options {
    /// From the bench's arguments after `--accuracy`: `--bands 450,500,550`, `--materials gold,mirror`,
    /// `--setups ideal,bring-up` (each a comma-separated list), `--seeds 48` (how many instruments, at most
    /// 64); an error names what is wrong.
    pub fn parse(args: &[String]) -> Result<Options, String> {
        let mut o = Options::default();
        let value = |flag: &str| -> Result<Option<Vec<String>>, String> {
            match args.iter().position(|a| a == flag) {
                None => Ok(None),
                Some(i) => args
                    .get(i + 1)
                    .filter(|v| !v.starts_with("--"))
                    .map(|v| Some(v.split(',').map(|x| x.trim().to_string()).collect()))
                    .ok_or_else(|| format!("{flag} needs a comma-separated list")),
            }
        };
        if let Some(bands) = value("--bands")? {
            let mut nm = bands
                .iter()
                .map(|b| {
                    b.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite() && *v > 0.0)
                        .ok_or_else(|| format!("--bands: {b:?} is not a wavelength in nm"))
                })
                .collect::<Result<Vec<f64>, String>>()?;
            nm.sort_by(f64::total_cmp);
            nm.dedup();
            o.bands_nm = nm;
        }
        if let Some(materials) = value("--materials")? {
            o.materials = materials
                .iter()
                .map(|m| {
                    MATERIALS.iter().copied().find(|k| k == m).ok_or_else(|| {
                        format!(
                            "--materials: {m:?} is not a preset (one of {})",
                            MATERIALS.join(", ")
                        )
                    })
                })
                .collect::<Result<Vec<&'static str>, String>>()?;
        }
        if let Some(n) = value("--seeds")? {
            let all: Vec<u64> = SEEDS.iter().chain(&MORE_SEEDS).copied().collect();
            let n = match n.as_slice() {
                [one] => one.parse::<usize>().ok(),
                _ => None,
            }
            .filter(|n| (1..=all.len()).contains(n))
            .ok_or_else(|| {
                format!(
                    "--seeds: {:?} is not a count from 1 to {}",
                    n.join(","),
                    all.len()
                )
            })?;
            o.seeds = all[..n].to_vec();
        }
        if let Some(kinds) = value("--setups")? {
            for k in &kinds {
                if !SETUP_KINDS.contains(&k.as_str()) {
                    return Err(format!(
                        "--setups: {k:?} is not one of {}",
                        SETUP_KINDS.join(", ")
                    ));
                }
            }
            o.setups = kinds;
        }
        Ok(o)
    }

    /// Whether this is the table ACCURACY.md keeps.
    pub fn is_default(&self) -> bool {
        *self == Options::default()
    }

    /// The bands as the campaign file writes them: `[450.0, 550.0, 650.0]`.
    pub fn bands_toml(&self) -> String {
        let nm: Vec<String> = self.bands_nm.iter().map(|b| format!("{b:.1}")).collect();
        format!("[{}]", nm.join(", "))
    }

    /// The set-ups chosen, in [`setups`]' order.
    pub fn setups(&self) -> Vec<Setup> {
        setups(&self.seeds)
            .into_iter()
            .zip(SETUP_KINDS)
            .filter(|(_, kind)| self.setups.iter().any(|k| k == kind))
            .map(|(s, _)| s)
            .collect()
    }
}

/// An instrument set-up the table covers.
#[derive(Debug, Clone, PartialEq)]
pub struct Setup {
    pub name: String,
    /// The simulator's seeds the geometries are spread over, each a different instrument.
    pub seeds: Vec<u64>,
    pub bring_up: bool,
    /// realistic.toml (every imperfection); else the ideal simulated.toml.
    pub realistic: bool,
}

/// The set-ups, each over the instruments `seeds`.
pub fn setups(seeds: &[u64]) -> Vec<Setup> {
    let mut s = vec![Setup {
        name: format!("ideal (simulated.toml), {} seeds", seeds.len()),
        seeds: seeds.to_vec(),
        bring_up: false,
        realistic: false,
    }];
    for bring_up in [false, true] {
        s.push(Setup {
            name: format!(
                "realistic.toml, {} seeds{}",
                seeds.len(),
                if bring_up { ", after bring-up" } else { "" }
            ),
            seeds: seeds.to_vec(),
            bring_up,
            realistic: true,
        });
    }
    s
}

/// An instrument file's text with its `[simulator] seed` set to `seed` (no other table's `seed`).
fn with_seed(text: &str, seed: u64) -> String {
    let mut table = String::new();
    text.lines()
        .map(|l| {
            let t = l.trim();
            if t.starts_with('[') {
                table = t.to_string();
            }
            if table == "[simulator]" && t.starts_with("seed =") {
                format!("seed = {seed}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// `n` random geometries [theta_i, phi_i, theta_o, phi_o] (degrees): theta_i uniform in [0, 75], phi_i = 0; a
/// sixth within 2 deg of the specular direction, a sixth 2-15 deg from it, the rest uniform in solid angle up
/// to theta_o = 80 deg.
pub fn geometries(n: usize, seed: u64) -> Vec<[f64; 4]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let k = out.len();
        let ti: f64 = rng.random_range(0.0..75.0);
        let wo = if k % 3 == 0 {
            let off_deg: f64 = if k % 6 == 0 {
                rng.random_range(0.0..2.0)
            } else {
                rng.random_range(2.0..15.0)
            };
            let psi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            about_specular(ti, off_deg, psi)
        } else {
            let cos_max = 80f64.to_radians().cos();
            let c: f64 = rng.random_range(cos_max..1.0);
            let phi: f64 = rng.random_range(0.0..360.0);
            Direction::from_spherical_deg(c.acos().to_degrees(), phi)
        };
        let (to, po) = wo.to_spherical_deg();
        if to <= 82.0 {
            out.push([ti, 0.0, to, po.rem_euclid(360.0)]);
        }
    }
    out
}

/// The direction `off_deg` from the mirror direction of incidence (ti, 0), at angle `psi` around it.
fn about_specular(ti_deg: f64, off_deg: f64, psi: f64) -> Direction {
    let s = Direction::from_spherical_deg(ti_deg, 180.0);
    // Two unit vectors perpendicular to s: u in the plane of incidence, v = s x u.
    let (st, ct) = ti_deg.to_radians().sin_cos();
    let u = [ct, 0.0, st];
    let sv = [s.x(), s.y(), s.z()];
    let v = [
        sv[1] * u[2] - sv[2] * u[1],
        sv[2] * u[0] - sv[0] * u[2],
        sv[0] * u[1] - sv[1] * u[0],
    ];
    let (sd, cd) = off_deg.to_radians().sin_cos();
    let (sp, cp) = psi.sin_cos();
    let d: Vec<f64> = (0..3)
        .map(|i| cd * sv[i] + sd * (cp * u[i] + sp * v[i]))
        .collect();
    Direction::new(d[0], d[1], d[2]).unwrap_or(s)
}

fn campaign_text(material: &str, geometries: &[[f64; 4]], bands_toml: &str) -> String {
    let points: Vec<String> = geometries
        .iter()
        .map(|g| format!("[{:.4}, {:.4}, {:.4}, {:.4}]", g[0], g[1], g[2], g[3]))
        .collect();
    format!(
        "[campaign]\nid = \"accuracy-{material}\"\n\n[sample]\nradius_mm = 12.5\n\n[plan]\nbands_nm = {bands_toml}\n\
         repeats = 1\nreciprocity = false\n\n[plan.grid]\nkind = \"points\"\npoints = [{}]\n\n\
         [plan.calibration]\ndark_every_points = 100\nreference_every_s = 600.0\n\
         reference_pose_deg = {{ light = -90.0, detector = 90.0 }}\n\n[calibration]\nmethod = \"absolute\"\n\
         simulate_operator = true\n\n[acquisition]\naveraging = 10\n\n[material]\npreset = \"{material}\"\n",
        points.join(", ")
    )
}

/// One class's figures.
#[derive(Debug, Clone, Default)]
pub struct ClassRow {
    pub n: usize,
    pub coverage_k2: f64,
    pub rms_z: f64,
    /// The mean of (value - truth) / u: what errors shared by the points move them all by.
    pub mean_z: f64,
    pub median_err: f64,
    pub p95_err: f64,
    pub median_u_k2: f64,
    /// The largest components: name and median u / value (k = 1).
    pub top: Vec<(String, f64)>,
}

/// The nearest-rank quantile of `v` (sorted here), as the error budget's tables take it.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    crate::error_budget::quantile(v, q)
}

/// The value the table holds to the truth: a valid point's, or a `narrow-lobe` point's aperture average
/// (flagged because no honest correction exists, with an uncertainty meant to cover the bias: held to that).
pub(crate) fn checked_value(p: &Point) -> Option<f64> {
    p.value().or_else(|| {
        let narrow_only = p.flags.len() == 1 && p.flags[0] == FLAG_NARROW_LOBE;
        p.brdf_sr.filter(|v| narrow_only && v.is_finite())
    })
}

/// The figures of `points` (valid or narrow-lobe ones with a truth and an uncertainty).
pub fn class_row(points: &[&Point]) -> ClassRow {
    let (mut z, mut err, mut u) = (Vec::new(), Vec::new(), Vec::new());
    let mut components: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for p in points {
        let (Some(f), Some(t), Some(s)) = (checked_value(p), p.truth_point_sr, p.brdf_u_sr) else {
            continue;
        };
        // A truth of zero (a mirror away from its specular direction) still tests the interval; the
        // relative figures need a value.
        if !(t >= 0.0 && t.is_finite() && s > 0.0 && f.is_finite()) {
            continue;
        }
        z.push((f - t) / s);
        if t > 0.0 {
            err.push((f / t - 1.0).abs());
        }
        if f != 0.0 {
            u.push(2.0 * s / f.abs());
            for (name, u) in p.budget.by_component() {
                components.entry(name.to_string()).or_default().push(u / f.abs());
            }
        }
    }
    let n = z.len();
    let mut top: Vec<(String, f64)> = components
        .into_iter()
        .map(|(name, mut v)| (name, quantile(&mut v, 0.5)))
        .collect();
    top.sort_by(|a, b| b.1.total_cmp(&a.1));
    top.truncate(3);
    let nan_if_empty = |v: f64| if n == 0 { f64::NAN } else { v };
    ClassRow {
        n,
        coverage_k2: nan_if_empty(z.iter().filter(|z| z.abs() <= 2.0).count() as f64 / n.max(1) as f64),
        rms_z: nan_if_empty((z.iter().map(|z| z * z).sum::<f64>() / n.max(1) as f64).sqrt()),
        mean_z: nan_if_empty(z.iter().sum::<f64>() / n.max(1) as f64),
        median_err: quantile(&mut err, 0.5),
        p95_err: quantile(&mut err, 0.95),
        median_u_k2: quantile(&mut u, 0.5),
        top,
    }
}

/// One material on one instrument of a set-up: its points.
#[derive(Debug, Clone)]
pub struct Run {
    pub setup: String,
    /// The simulator's seed.
    pub seed: u64,
    pub material: &'static str,
    /// Geometries asked for (each in every band).
    pub planned: usize,
    pub points: Vec<Point>,
    /// Why the run stopped before its end (the last line of gonio's error), when it did.
    pub stopped: Option<String>,
    /// `gonio fit` with the material's own model (crate::accuracy::fits); `None` for the mirror (its delta
    /// lobe is no model gonio fits).
    pub fit: Option<Result<fits::FitOutcome, String>>,
}

/// Every set-up and material, through the release binary `binary`.
pub fn run(
    root: &Path,
    binary: &Path,
    geometries_per_material: usize,
    options: &Options,
) -> Result<Vec<Run>, String> {
    if !binary.exists() {
        return Err(format!(
            "{} not found: build it with `cargo build --release -p gonio`",
            binary.display()
        ));
    }
    let realistic = std::fs::read_to_string(root.join("config/instruments/realistic.toml"))
        .map_err(|e| format!("config/instruments/realistic.toml: {e}"))?;
    let dir = std::env::temp_dir().join(format!("gonio-bench-accuracy-{}", std::process::id()));
    let mut out = Vec::new();
    for (k, setup) in options.setups().into_iter().enumerate() {
        // The geometries spread over the instruments: each its own, the same count.
        let per_instrument = geometries_per_material.div_ceil(setup.seeds.len().max(1));
        for (j, &seed) in setup.seeds.iter().enumerate() {
            let here = dir.join(format!("setup-{k}-{j}"));
            std::fs::create_dir_all(&here).map_err(|e| format!("{}: {e}", here.display()))?;
            let instrument = here.join("instrument.toml");
            let text = if setup.realistic {
                with_seed(&variant_text(&realistic, &crate::error_budget::GROUPS)?, seed)
            } else {
                with_seed(gonio_instrument::SIMULATED_INSTRUMENT_TOML, seed)
            };
            std::fs::write(&instrument, &text).map_err(|e| format!("{}: {e}", instrument.display()))?;
            let label = format!("{}: seed {seed}", setup.name);
            let cal = here.join("cal.toml");
            if setup.bring_up {
                eprintln!("    {label}: gonio align...");
                crate::bring_up::align(binary, &instrument, &cal)?;
            }
            for &material in &options.materials {
                // The material's place among all of them, so that a narrowed run measures the same geometries.
                let m = MATERIALS.iter().position(|k| *k == material).unwrap_or(0);
                eprintln!("    {label}: {material}...");
                let campaign = here.join(format!("{material}.toml"));
                let geoms = geometries(per_instrument, 1000 + m as u64 + 100 * j as u64);
                std::fs::write(&campaign, campaign_text(material, &geoms, &options.bands_toml()))
                    .map_err(|e| format!("{}: {e}", campaign.display()))?;
                let out_dir = here.join(material);
                let mut args: Vec<&std::ffi::OsStr> = vec![
                    "run".as_ref(),
                    campaign.as_os_str(),
                    "--quiet".as_ref(),
                    "--instrument".as_ref(),
                    instrument.as_os_str(),
                    "--out".as_ref(),
                    out_dir.as_os_str(),
                ];
                if setup.bring_up {
                    args.extend(["--calibration".as_ref(), cal.as_os_str()]);
                }
                // A run that stops early (a paused campaign) still wrote the points it committed: they are
                // measured, and the table says why the rest are missing.
                let stopped = gonio(binary, &args).err();
                if let Some(e) = &stopped {
                    eprintln!("      stopped early: {e}");
                }
                let csv_path = out_dir.join("points.csv");
                let csv =
                    std::fs::read_to_string(&csv_path).map_err(|e| format!("{}: {e}", csv_path.display()))?;
                let table =
                    parse_points_csv(&csv, &csv_path.display().to_string()).map_err(|e| e.to_string())?;
                let fit = (material != "mirror").then(|| fits::fit(binary, &out_dir, material));
                out.push(Run {
                    setup: setup.name.clone(),
                    seed,
                    material,
                    planned: geoms.len(),
                    points: table.points,
                    stopped,
                    fit,
                });
            }
        }
    }
    // GONIO_BENCH_KEEP=1 keeps every run (instrument, campaign, store, points.csv, run.json) to look into.
    if std::env::var_os("GONIO_BENCH_KEEP").is_some() {
        eprintln!("    kept {}", dir.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_brdf::Direction;

    #[test]
    fn geometries_put_a_third_near_the_specular_direction() {
        let g = geometries(600, 1);
        assert_eq!(g.len(), 600);
        let off = |g: &[f64; 4]| {
            Direction::from_spherical_deg(g[0], g[1])
                .reflect_about_normal()
                .angle_to(&Direction::from_spherical_deg(g[2], g[3]))
                .to_degrees()
        };
        let within_2 = g.iter().filter(|g| off(g) <= 2.0 + 1e-9).count();
        let within_15 = g.iter().filter(|g| off(g) <= 15.0 + 1e-9).count();
        assert!((100..=140).contains(&within_2), "{within_2}");
        assert!((200..=260).contains(&within_15), "{within_15}");
        assert!(g.iter().all(|g| g[2] <= 82.0 && g[0] < 75.0));
        // Deterministic for a seed.
        assert_eq!(geometries(10, 7), geometries(10, 7));
    }

    fn args(a: &[&str]) -> Vec<String> {
        a.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn options_default_to_the_table_accuracy_md_keeps() {
        let o = Options::parse(&args(&["gonio-bench", "--accuracy"])).expect("no options");
        assert!(o.is_default());
        assert_eq!(o.bands_toml(), "[450.0, 550.0, 650.0]");
        assert_eq!(o.setups().len(), 3);
        assert_eq!(o.materials, MATERIALS);
    }

    #[test]
    fn options_narrow_the_bands_materials_and_setups() {
        let o = Options::parse(&args(&[
            "--accuracy",
            "--bands",
            "650,450,500,550,600",
            "--materials",
            "construction-paper,gold",
            "--setups",
            "bring-up,ideal",
        ]))
        .expect("valid options");
        assert!(!o.is_default());
        assert_eq!(o.bands_toml(), "[450.0, 500.0, 550.0, 600.0, 650.0]");
        assert_eq!(o.materials, ["construction-paper", "gold"]);
        let setups = o.setups();
        assert_eq!(setups.len(), 2);
        assert!(
            !setups[0].realistic,
            "the ideal instrument first, in the table's order"
        );
        assert!(setups[1].realistic && setups[1].bring_up);
        // More instruments: the sixteen first, then others, every one different.
        let o48 = Options::parse(&args(&["--seeds", "48"])).expect("48 seeds");
        assert!(!o48.is_default());
        assert_eq!(&o48.seeds[..16], &SEEDS[..]);
        let mut distinct = o48.seeds.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), 48);
        assert!(
            o48.setups()
                .iter()
                .all(|s| s.seeds == o48.seeds && s.name.contains("48 seeds"))
        );
        // The campaign asks for the bands given.
        let text = campaign_text("gold", &geometries(3, 1), &o.bands_toml());
        assert!(
            text.contains("bands_nm = [450.0, 500.0, 550.0, 600.0, 650.0]"),
            "{text}"
        );
    }

    #[test]
    fn options_refuse_what_they_do_not_know() {
        for bad in [
            &["--bands", "blue"][..],
            &["--bands", "-5"],
            &["--bands"],
            &["--bands", "--materials"],
            &["--materials", "velvet"],
            &["--setups", "perfect"],
            &["--seeds", "0"],
            &["--seeds", "65"],
            &["--seeds", "many"],
        ] {
            let e = Options::parse(&args(bad)).expect_err("refused");
            assert!(e.starts_with(bad[0]), "the message names the option: {e}");
        }
    }

    #[test]
    fn each_instrument_takes_its_own_seed() {
        for text in [
            gonio_instrument::SIMULATED_INSTRUMENT_TOML,
            include_str!("../../../config/instruments/realistic.toml"),
        ] {
            let t = with_seed(text, 29);
            let seeds: Vec<&str> = t
                .lines()
                .filter(|l| l.trim_start().starts_with("seed ="))
                .collect();
            assert_eq!(seeds, ["seed = 29"]);
            let file =
                gonio_instrument::InstrumentFile::parse(&t, "with_seed").expect("still an instrument file");
            assert_eq!(file.simulator.seed, 29);
        }
    }
}
