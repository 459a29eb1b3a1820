//! The realistic instrument's error budget (issue 16): the demo campaign (config/campaigns/demo.toml) dry-run on
//! config/instruments/realistic.toml with each group of imperfections alone and all together, and how far each
//! pushes the measured BRDF from the simulator's point truth, by angular class. Also the in-process throughput
//! on the realistic instrument beside the ideal one.
//!
//! Variants are the realistic file with every other `[simulator.imperfections.*]` table removed (same seed, so
//! "geometry alone" is exactly the geometry of "all"); "ideal" is the same file with none of them.
//!
//! Classes (exclusive, in this order): grazing (theta_i or theta_o >= 70 deg); within 2 deg of the specular
//! direction; 2-15 deg; beyond 15 deg. Error: |BRDF - point truth| / point truth over the points that have both
//! (flagged points have no BRDF and are counted apart).

use std::path::Path;

use gonio_engine::store::PointRecord;
use gonio_instrument::InstrumentFile;
use gonio_results::angular_class::AngularClass;

use crate::throughput::{self, Throughput};

/// The groups of `[simulator.imperfections]` realistic.toml has, in report order.
pub const GROUPS: [&str; 6] = ["geometry", "detector", "source", "sample", "filters", "beam"];

/// Angular classes, in report order.
pub const CLASSES: [&str; 4] = [
    "within 2 deg of specular",
    "2-15 deg",
    "beyond 15 deg",
    "grazing (>= 70 deg)",
];

/// One variant's result.
#[derive(Debug, Clone)]
pub struct Variant {
    pub name: String,
    /// Per class: (points with a BRDF, median, p95, max relative error).
    pub classes: Vec<ClassErrors>,
    /// Points without a BRDF (flagged).
    pub flagged: usize,
    pub points: usize,
}

#[derive(Debug, Clone, Default)]
pub struct ClassErrors {
    pub n: usize,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

/// The realistic instrument's text with only `keep` of its imperfection groups (none: `&[]`).
pub fn variant_text(realistic: &str, keep: &[&str]) -> Result<String, String> {
    gonio_instrument::imperfections::keep_only_groups(realistic, keep)
        .map_err(|e| format!("realistic.toml: {e}"))
}

/// The class of a nominal geometry (degrees; index into [`CLASSES`]): gonio_results' angular classes.
pub fn class_of(theta_i_deg: f64, phi_i_deg: f64, theta_o_deg: f64, phi_o_deg: f64) -> usize {
    match AngularClass::of_geometry(theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg) {
        AngularClass::Specular => 0,
        AngularClass::NearSpecular => 1,
        AngularClass::OffSpecular => 2,
        AngularClass::Grazing => 3,
    }
}

/// The nearest-rank quantile `q` of ascending `sorted`; NaN for none.
pub(crate) fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    // Nearest rank.
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// One point as the classes see it: the nominal geometry (deg), the BRDF and the point truth (1/sr).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassPoint {
    pub geometry_deg: [f64; 4],
    pub brdf_sr: Option<f64>,
    pub truth_sr: Option<f64>,
}

impl From<&PointRecord> for ClassPoint {
    fn from(p: &PointRecord) -> ClassPoint {
        ClassPoint {
            geometry_deg: [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg],
            brdf_sr: p.brdf_sr,
            truth_sr: p.truth_point_sr,
        }
    }
}

/// The errors of a run's points by class.
pub fn errors_by_class(name: &str, points: &[PointRecord]) -> Variant {
    let points: Vec<ClassPoint> = points.iter().map(ClassPoint::from).collect();
    errors_of(name, &points)
}

/// The errors of `points` by class, and over all of them as a fifth class.
pub fn errors_of(name: &str, points: &[ClassPoint]) -> Variant {
    let mut per: Vec<Vec<f64>> = vec![Vec::new(); CLASSES.len() + 1];
    let mut flagged = 0;
    for p in points {
        match (p.brdf_sr, p.truth_sr) {
            (Some(b), Some(t)) if t > 0.0 && b.is_finite() => {
                let [ti, pi, to, po] = p.geometry_deg;
                let e = ((b - t) / t).abs();
                per[class_of(ti, pi, to, po)].push(e);
                per[CLASSES.len()].push(e);
            }
            _ => flagged += 1,
        }
    }
    let classes = per
        .into_iter()
        .map(|mut e| {
            e.sort_by(f64::total_cmp);
            ClassErrors {
                n: e.len(),
                median: quantile(&e, 0.5),
                p95: quantile(&e, 0.95),
                max: e.last().copied().unwrap_or(f64::NAN),
            }
        })
        .collect();
    Variant {
        name: name.to_string(),
        classes,
        flagged,
        points: points.len(),
    }
}

/// Run `campaign` on the realistic file reduced to `keep`.
fn run_variant(
    campaign: &str,
    realistic: &str,
    keep: &[&str],
    base: &Path,
) -> Result<(Vec<PointRecord>, Throughput), String> {
    let text = variant_text(realistic, keep)?;
    let file = InstrumentFile::parse(&text, "realistic.toml (variant)").map_err(|e| e.to_string())?;
    throughput::in_process_on(campaign, &file, &text, base)
}

/// Every variant of the error budget: ideal, each group alone, all.
pub fn budget(root: &Path) -> Result<Vec<Variant>, String> {
    let realistic = std::fs::read_to_string(root.join("config/instruments/realistic.toml"))
        .map_err(|e| format!("config/instruments/realistic.toml: {e}"))?;
    let campaign = std::fs::read_to_string(root.join("config/campaigns/demo.toml"))
        .map_err(|e| format!("config/campaigns/demo.toml: {e}"))?;
    let base = std::env::temp_dir();
    let mut variants = Vec::new();
    let mut runs: Vec<(String, Vec<&str>)> = vec![("ideal (none)".to_string(), Vec::new())];
    runs.extend(GROUPS.iter().map(|g| (format!("{g} alone"), vec![*g])));
    runs.push(("all (realistic.toml)".to_string(), GROUPS.to_vec()));
    for (name, keep) in runs {
        let (points, _) = run_variant(&campaign, &realistic, &keep, &base)?;
        variants.push(errors_by_class(&name, &points));
    }
    Ok(variants)
}

/// Rounds of the throughput runs: each instrument's figure is its median run.
pub const THROUGHPUT_ROUNDS: usize = 5;

/// In-process throughput of the throughput campaign: on config/instruments/simulated.toml (section 3's
/// instrument), on realistic.toml without its imperfections, and on realistic.toml; each the median (by points
/// per second) of [`THROUGHPUT_ROUNDS`] runs, the three instruments taking turns, so that a busy moment of a
/// shared machine does not pass for a difference between instruments (one run takes about a second).
pub fn throughput_runs(root: &Path, campaign: &str) -> Result<Vec<(&'static str, Throughput)>, String> {
    let realistic = std::fs::read_to_string(root.join("config/instruments/realistic.toml"))
        .map_err(|e| format!("config/instruments/realistic.toml: {e}"))?;
    let base = std::env::temp_dir();
    let simulated = InstrumentFile::simulated();
    let mut runs: [Vec<Throughput>; 3] = Default::default();
    for _ in 0..THROUGHPUT_ROUNDS {
        let (_, sim) = throughput::in_process_on(
            campaign,
            &simulated,
            gonio_instrument::SIMULATED_INSTRUMENT_TOML,
            &base,
        )?;
        runs[0].push(sim);
        runs[1].push(run_variant(campaign, &realistic, &[], &base)?.1);
        runs[2].push(run_variant(campaign, &realistic, &GROUPS, &base)?.1);
    }
    let [sim, ideal, real] = runs.map(median_run);
    Ok(vec![
        ("simulated.toml (ideal, section 3)", sim),
        ("realistic.toml without its imperfections", ideal),
        ("realistic.toml", real),
    ])
}

/// The run of median points per second (the upper one of an even count).
fn median_run(mut runs: Vec<Throughput>) -> Throughput {
    runs.sort_by(|a, b| a.points_per_s().total_cmp(&b.points_per_s()));
    let mid = runs.len() / 2;
    runs.swap_remove(mid)
}

pub fn pct(x: f64) -> String {
    if x.is_nan() {
        "-".to_string()
    } else if x < 1e-4 {
        format!("{:.1e} %", 100.0 * x)
    } else {
        format!("{:.3} %", 100.0 * x)
    }
}

/// The report's section.
pub fn markdown(variants: &[Variant], throughput: &[(&str, Throughput)], target_pps: f64) -> String {
    let mut s = String::new();
    s.push_str(
        "## 5. The realistic instrument: error budget before alignment and calibration\n\n\
         The demo campaign (config/campaigns/demo.toml: coloured plastic, 3 bands, absolute method) dry-run in \
         process on config/instruments/realistic.toml (seed 16) with each group of `[simulator.imperfections]` \
         alone and all together. Error: |measured BRDF - the simulator's point truth| / point truth at the \
         nominal geometry. Classes: grazing (theta_i or theta_o >= 70 deg) first, then by the angle between the \
         outgoing direction and the mirror of the incident one. The ideal row is the same campaign on the ideal \
         instrument: what the measurement equation, the finite aperture and the meter's noise cost by \
         themselves. Details: crates/bench/src/error_budget.rs.\n\n\
         How to read the filters' row: the direct-beam calibration passes the same filter, so what remains is \
         the band's mean of the sample's spectrum against its value at the band's centre (its curvature over \
         the band and the drawn centre offsets, times its slope), and the leakage's share of the sample's \
         spectrum far from the band, which the completion corrects from the bands measured \
         (gonio_results::band_component) up to the spectrum beyond the outermost band. Coloured plastic's \
         spectrum is a 50 nm table read as a monotone cubic (crates/brdf/src/spectrum.rs).\n\n",
    );
    s.push_str("| imperfections | class | points | median | p95 | max |\n|---|---|---|---|---|---|\n");
    for v in variants {
        for (k, c) in v.classes.iter().enumerate().take(CLASSES.len()) {
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} |\n",
                if k == 0 { v.name.as_str() } else { "" },
                CLASSES[k],
                c.n,
                pct(c.median),
                pct(c.p95),
                pct(c.max)
            ));
        }
        if v.flagged > 0 {
            s.push_str(&format!(
                "| | flagged (no BRDF) | {} of {} | | | |\n",
                v.flagged, v.points
            ));
        }
    }
    if !throughput.is_empty() {
        s.push_str(&format!(
            "\n### Throughput on the realistic instrument\n\n\
             The end-to-end campaign of section 3, in process on the paused clock, store on disk, on three \
             instrument files (the realistic one computes every imperfection per reading); each row is the median \
             of {THROUGHPUT_ROUNDS} runs, the three files taking turns. The first two do the same work per point \
             (the files differ only in the seed, the wheel's time per position and keys left at their defaults, \
             none of which this one-band campaign's work depends on): their difference is the machine's noise. \
             Target: >= {target_pps:.0} points/s on the realistic instrument.\n\n\
             | instrument | points | wall (s) | points/s overall | steady points/s | instrument time (s) | target | result |\n\
             |---|---|---|---|---|---|---|---|\n"
        ));
        for (k, (name, t)) in throughput.iter().enumerate() {
            let last = k + 1 == throughput.len();
            s.push_str(&format!(
                "| {name} | {} | {:.2} | {:.0} | {:.0} | {:.0} | {} | {} |\n",
                t.points,
                t.wall_s,
                t.points_per_s(),
                t.steady_points_per_s(),
                t.instrument_s,
                if last {
                    format!(">= {target_pps:.0} points/s")
                } else {
                    "-".into()
                },
                if !last {
                    "-"
                } else if t.points_per_s() >= target_pps {
                    "met"
                } else {
                    "NOT met"
                }
            ));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_run_is_the_middle_one_by_points_per_second() {
        // 100 points in 0.5, 0.04, 0.1, 0.2 and 0.05 s: 200, 2500, 1000, 500 and 2000 points/s.
        let runs: Vec<Throughput> = [0.5, 0.04, 0.1, 0.2, 0.05]
            .iter()
            .map(|&wall_s| Throughput {
                points: 100,
                wall_s,
                instrument_s: 1.0,
                steady_wall_s: wall_s,
            })
            .collect();
        assert_eq!(median_run(runs).wall_s, 0.1);
    }

    #[test]
    fn variants_keep_only_the_named_groups_and_classes_split_as_documented() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let realistic =
            std::fs::read_to_string(root.join("config/instruments/realistic.toml")).expect("read");
        let only = variant_text(&realistic, &["detector"]).expect("variant");
        let file = InstrumentFile::parse(&only, "v").expect("parses");
        let i = &file.simulator.imperfections;
        assert!(i.geometry.is_ideal() && i.source.is_ideal() && !i.detector.is_ideal());
        let none =
            InstrumentFile::parse(&variant_text(&realistic, &[]).expect("variant"), "v").expect("parses");
        assert!(none.simulator.imperfections.is_ideal());
        assert_eq!(none.simulator.seed, 16);
        assert_eq!(class_of(30.0, 0.0, 30.0, 180.0), 0, "the mirror direction");
        assert_eq!(class_of(30.0, 0.0, 31.5, 180.0), 0);
        assert_eq!(class_of(30.0, 0.0, 40.0, 180.0), 1);
        assert_eq!(class_of(30.0, 0.0, 0.0, 0.0), 2);
        assert_eq!(class_of(30.0, 0.0, 75.0, 0.0), 3);
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0], 0.5), 2.0);
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0], 0.95), 4.0);
    }
}
