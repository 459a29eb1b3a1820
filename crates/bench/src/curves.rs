//! Issue 41's curves: instrument time against error for four strategies on one validation set, per seed material,
//! on both instrument files. Every run goes through the release binary (`gonio run`), one band (550 nm), at the
//! incidences [`INCIDENCES_DEG`] in the plane of incidence (what sweeps measure: an arm turns in that plane):
//!
//! - stop-and-go grids (`[plan.grid] kind = "in-plane"`, theta_o from -80 to 80 deg at [`GRID_STEPS_DEG`]);
//! - on an instrument whose filters leak (realistic.toml) and a sample that is not grey, the same grids in three
//!   bands at
//!   [`GRID_THREE_BANDS_STEPS_DEG`]: a campaign in one band has no spectrum to correct the leak with, and one
//!   in three bands does (its 550 nm values are compared); likewise sweeps in three bands at
//!   [`THREE_BAND_SWEEP_SETTINGS`];
//! - adaptive stop-and-go plans (`[plan.adaptive]`, first pass at the same incidences, [`ADAPTIVE_BUDGETS`] points);
//! - constant-speed sweeps of the same arcs at the speeds and averaging of [`SWEEP_SETTINGS`];
//! - sweeps whose speed follows the BRDF (top speed 20 deg/s, [`FOLLOW_AVERAGING`] samples a reading, the 4 deg/s
//!   sweeps as the first pass, tolerances [`FOLLOW_TOLERANCES`] of the peak).
//!
//! On an instrument whose filters leak and a sample that is not grey, every sweep run measures beside its sweeps the probe a lab would (`gonio
//! plan` asks for it): the in-plane points at [`PROBE_THETA_O_DEG`] in three bands, which lend the 550 nm sweeps
//! their spectrum (`[plan] sweep_bands_nm`); their instrument time is the sweep run's.
//!
//! Validation set: the plane of incidence at the same incidences, theta_o every 0.25 deg from -80 to 80 where the
//! instrument can measure (the rules and the kinematics, a 12.5 mm sample). Truth: the material's point BRDF at
//! 550 nm (crate::campaigns::truth_fn). Every run's valid values (points or sweep readings) are interpolated to
//! the validation set by the product's reconstruction for scattered values (`Adaptive::reconstruct_all`), the same
//! for every strategy; error: the cosine-weighted relative RMS (crate::campaigns::errors). Time: the run's
//! instrument time (run.json), and its measuring time (its first value to its last: the opening calibration is
//! the same for every strategy).
//!
//! Target: below the error the best stop-and-go run reaches within an hour of instrument time (the grids go to
//! about an hour), sweeps reach it within a tenth of that hour: some sweep run of at most 360 s has an error at
//! most the hour's.

use std::fmt::Write as _;
use std::path::Path;

use gonio_brdf::Brdf as _;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::adaptive::Measured;
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};

use crate::campaigns::{errors, reconstructor, truth_fn};
use crate::gonio_run::{GonioRun, gonio_run};
use crate::readings::MATERIALS;

const INCIDENCES_DEG: [f64; 4] = [15.0, 30.0, 45.0, 60.0];
const GRID_STEPS_DEG: [f64; 9] = [10.0, 5.0, 2.5, 1.25, 0.625, 0.3125, 0.15625, 0.078125, 0.0390625];
const ADAPTIVE_BUDGETS: [u32; 3] = [100, 400, 1600];
const GRID_THREE_BANDS_STEPS_DEG: [f64; 4] = [10.0, 5.0, 2.5, 1.25];
/// Sweeps in three bands (each arc swept in each), as [`SWEEP_SETTINGS`].
const THREE_BAND_SWEEP_SETTINGS: [(f64, u32); 2] = [(20.0, 1), (10.0, 1)];
/// The probe's exitances at each incidence (signed as in-plane grids: > 0 on the specular side).
const PROBE_THETA_O_DEG: [f64; 5] = [-60.0, -30.0, 0.0, 30.0, 60.0];
const BAND_NM: f64 = 550.0;
const THREE_BANDS_NM: &str = "[450.0, 550.0, 650.0]";
/// (speed, meter samples a reading): fast and noisy to slow and quiet (the reconstruction averages a few
/// neighbours only, so a reading's own noise sets the error floor on smooth samples).
const SWEEP_SETTINGS: [(f64, u32); 5] = [(20.0, 1), (4.0, 1), (1.0, 1), (4.0, 10), (2.0, 30)];
const FOLLOW_AVERAGING: u32 = 10;
const FOLLOW_TOLERANCES: [f64; 2] = [1e-4, 1e-5];
const RATIO_TARGET: f64 = 0.1;
const HOUR_S: f64 = 3600.0;

/// What a strategy is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Grid,
    GridThreeBands,
    Adaptive,
    Constant,
    ConstantThreeBands,
    Follow,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Grid => "grid",
            Kind::GridThreeBands => "grid in three bands",
            Kind::Adaptive => "adaptive",
            Kind::Constant => "constant-speed sweeps",
            Kind::ConstantThreeBands => "constant-speed sweeps in three bands",
            Kind::Follow => "sweeps following the BRDF",
        }
    }

    fn sweeps(self) -> bool {
        matches!(self, Kind::Constant | Kind::ConstantThreeBands | Kind::Follow)
    }
}

/// One run's place on the curves.
struct Run {
    kind: Kind,
    setting: String,
    values: usize,
    instrument_s: f64,
    measuring_s: f64,
    error: Option<f64>,
}

fn incidences() -> String {
    let list: Vec<String> = INCIDENCES_DEG.iter().map(|t| format!("{t:.1}")).collect();
    format!("[{}]", list.join(", "))
}

/// A campaign: `bands` the `[plan]` keys that choose the bands, `plan` its tables.
fn campaign(material: &str, bands: &str, plan: &str) -> String {
    format!(
        "[campaign]\nid = \"curve\"\n[sample]\nradius_mm = 12.5\n[plan]\n{bands}\n{plan}\n\
         [calibration]\nmethod = \"absolute\"\nsimulate_operator = true\n[material]\npreset = \"{material}\"\n"
    )
}

/// Whether `file`'s 550 nm filter leaks light from outside its band (gonio_instrument::leakage).
fn leaks(file: &InstrumentFile) -> bool {
    gonio_instrument::leakage::band_leakage(&file.instrument, BAND_NM).is_some_and(|l| l > 0.0)
}

/// The probe beside the sweeps (module doc): its bands keys and its grid.
fn probe() -> (String, String) {
    let list: Vec<String> = PROBE_THETA_O_DEG.iter().map(|t| format!("{t:.1}")).collect();
    (
        format!("bands_nm = {THREE_BANDS_NM}\nsweep_bands_nm = [{BAND_NM:.1}]"),
        format!(
            "[plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = {}\ntheta_o_deg = [{}]\n",
            incidences(),
            list.join(", ")
        ),
    )
}

fn grid(step_deg: f64) -> String {
    format!(
        "[plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = {}\ntheta_o_deg = {{ from = -80.0, to = 80.0, step = \
         {step_deg} }}\n",
        incidences()
    )
}

fn adaptive(budget: u32) -> String {
    format!(
        "[plan.adaptive]\nbudget_points = {budget}\ntarget_error = 0.0\nfirst_pass_theta_i_deg = {}\n",
        incidences()
    )
}

fn sweeps(speed_deg_s: f64, averaging: u32, follow: &str) -> String {
    format!(
        "[[plan.sweeps]]\ntheta_i_deg = {}\ntheta_o_deg = {{ from = -80.0, to = 80.0 }}\nspeed_deg_s = \
         {speed_deg_s}\naveraging = {averaging}\n{follow}\n",
        incidences()
    )
}

/// The validation set (module doc).
fn validation(file: &InstrumentFile) -> Vec<Geometry> {
    let inst = &file.instrument;
    let constraints = Constraints::new(inst, Some(crate::campaigns::SAMPLE_RADIUS_MM));
    let kin = Kinematics::new(inst);
    let hint = Pose::new(0.0, 0.0, 0.0, 0.0);
    let mut out = Vec::new();
    for ti in INCIDENCES_DEG {
        for k in 0..=640 {
            let s = -80.0 + 0.25 * f64::from(k);
            let g = if s >= 0.0 {
                Geometry::new(ti, 0.0, s, 180.0)
            } else {
                Geometry::new(ti, 0.0, -s, 0.0)
            };
            let (wi, wo) = g.directions();
            if constraints.check_directions(&wi, &wo).is_ok()
                && kin.isotropic_solutions(&wi, &wo, 0.0, &hint).is_ok()
            {
                out.push(g);
            }
        }
    }
    out
}

/// A run's valid values and their times.
fn values(run: &GonioRun, kind: Kind) -> Result<Vec<(Measured, f64)>, String> {
    if kind.sweeps() {
        Ok(run
            .sweeps()?
            .into_iter()
            .filter(|r| r.flags.is_empty() && (r.band_nm - BAND_NM).abs() < 1e-6)
            .filter_map(|r| {
                let value = r.brdf_sr?;
                let geometry = Geometry::new(r.theta_i_deg, r.phi_i_deg, r.theta_o_deg, r.phi_o_deg);
                Some((Measured { geometry, value }, r.t_s))
            })
            .collect())
    } else {
        let path = run.out.join("points.csv");
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let table =
            gonio_results::points::parse_points_csv(&text, "points.csv").map_err(|e| e.to_string())?;
        Ok(table
            .points
            .into_iter()
            .filter(|p| p.flags.is_empty() && (p.band_nm - BAND_NM).abs() < 1e-6)
            .filter_map(|p| {
                let value = p.brdf_sr?;
                let geometry = Geometry::new(p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg);
                Some((Measured { geometry, value }, p.t_s?))
            })
            .collect())
    }
}

/// Everything measured for one material on one instrument, and the first pass the following sweeps use.
fn runs(binary: &Path, material: &str, instrument: &Path, quick: bool) -> Vec<Result<Run, String>> {
    let file = match InstrumentFile::load(instrument) {
        Ok(f) => f,
        Err(e) => return vec![Err(e.to_string())],
    };
    let at = validation(&file);
    let truth_at = truth_fn(material);
    let truth: Vec<f64> = at.iter().map(truth_at).collect();
    let rec = reconstructor(&file.instrument);
    let first_pass =
        std::env::temp_dir().join(format!("gonio-bench-curves-{}-first.csv", std::process::id()));
    let one_band = format!("bands_nm = [{BAND_NM:.1}]");
    let three_bands = format!("bands_nm = {THREE_BANDS_NM}");
    // A grey sample cancels the leak (and is measured in one band whatever the campaign asks): no probe.
    let flat = gonio_brdf::Material::preset(material).is_ok_and(|m| m.is_spectrally_flat());
    let leaky = leaks(&file) && !flat;
    let measure = |kind: Kind, setting: String, plan: String| -> Result<Run, String> {
        let text = match kind {
            Kind::GridThreeBands | Kind::ConstantThreeBands => campaign(material, &three_bands, &plan),
            Kind::Constant | Kind::Follow if leaky => {
                let (bands, grid) = probe();
                campaign(material, &bands, &format!("{grid}{plan}"))
            }
            _ => campaign(material, &one_band, &plan),
        };
        let run = gonio_run(binary, &text, Some(instrument))?;
        let values = values(&run, kind)?;
        if kind == Kind::Constant && setting == "4 deg/s, 1 samples" {
            let text = std::fs::read_to_string(run.out.join("sweeps.csv")).map_err(|e| e.to_string())?;
            std::fs::write(&first_pass, text).map_err(|e| e.to_string())?;
        }
        let measured: Vec<Measured> = values.iter().map(|(m, _)| *m).collect();
        let (lo, hi) = values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, t)| {
                (lo.min(*t), hi.max(*t))
            });
        let error = if measured.is_empty() {
            None
        } else {
            errors(&at, &rec.reconstruct_all(&measured, &at), &truth).0
        };
        Ok(Run {
            kind,
            setting,
            values: values.len(),
            instrument_s: run.instrument_s()?,
            measuring_s: (hi - lo).max(0.0),
            error,
        })
    };
    let take = |n: usize, all: usize| if quick { n.min(all) } else { all };
    let mut out = Vec::new();
    for step in &GRID_STEPS_DEG[..take(3, GRID_STEPS_DEG.len())] {
        out.push(measure(Kind::Grid, format!("{step} deg"), grid(*step)));
    }
    if leaky {
        for step in &GRID_THREE_BANDS_STEPS_DEG[..take(1, GRID_THREE_BANDS_STEPS_DEG.len())] {
            out.push(measure(Kind::GridThreeBands, format!("{step} deg"), grid(*step)));
        }
    }
    for budget in &ADAPTIVE_BUDGETS[..take(1, ADAPTIVE_BUDGETS.len())] {
        out.push(measure(
            Kind::Adaptive,
            format!("{budget} points"),
            adaptive(*budget),
        ));
    }
    for (speed, averaging) in SWEEP_SETTINGS {
        out.push(measure(
            Kind::Constant,
            format!("{speed} deg/s, {averaging} samples"),
            sweeps(speed, averaging, ""),
        ));
    }
    if leaky {
        for (speed, averaging) in &THREE_BAND_SWEEP_SETTINGS[..take(1, THREE_BAND_SWEEP_SETTINGS.len())] {
            out.push(measure(
                Kind::ConstantThreeBands,
                format!("{speed} deg/s, {averaging} samples"),
                sweeps(*speed, *averaging, ""),
            ));
        }
    }
    for tolerance in &FOLLOW_TOLERANCES[..take(1, FOLLOW_TOLERANCES.len())] {
        let follow = format!(
            "follow = {{ first_pass = \"{}\", tolerance_rel = {tolerance:e}, relative_to = \"peak\" }}",
            first_pass.display()
        );
        out.push(measure(
            Kind::Follow,
            format!("{tolerance:e} of the peak"),
            sweeps(20.0, FOLLOW_AVERAGING, &follow),
        ));
    }
    let _ = std::fs::remove_file(&first_pass);
    out
}

/// The target over one material and instrument (module doc): the best stop-and-go error within an hour, the
/// best sweep error within a tenth of it, and the shortest sweep run that reaches the hour's error (s).
struct Verdict {
    hour_error: f64,
    sweep_error: Option<f64>,
    sweep_s: Option<f64>,
}

impl Verdict {
    fn of(runs: &[Run]) -> Result<Verdict, String> {
        let best = |sweeps: bool, within_s: f64| {
            runs.iter()
                .filter(|r| r.kind.sweeps() == sweeps && r.instrument_s <= within_s)
                .filter_map(|r| r.error)
                .fold(None, |b: Option<f64>, e| Some(b.map_or(e, |b| b.min(e))))
        };
        let hour_error =
            best(false, HOUR_S).ok_or("no stop-and-go error (the point BRDF is 0 on the validation set)")?;
        let sweep_s = runs
            .iter()
            .filter(|r| r.kind.sweeps() && r.error.is_some_and(|e| e <= hour_error))
            .map(|r| r.instrument_s)
            .fold(None, |b: Option<f64>, t| Some(b.map_or(t, |b| b.min(t))));
        Ok(Verdict {
            hour_error,
            sweep_error: best(true, RATIO_TARGET * HOUR_S),
            sweep_s,
        })
    }

    fn met(&self) -> bool {
        self.sweep_s.is_some_and(|t| t <= RATIO_TARGET * HOUR_S)
    }
}

/// Section 7's time against error (module doc).
pub fn section(root: &Path, binary: &Path, quick: bool) -> String {
    let mut s = String::from("\n### Instrument time against error\n\n");
    let _ = writeln!(
        s,
        "Per seed material and instrument file (crates/bench/src/curves.rs): in-plane grids, adaptive plans, \
         constant-speed sweeps and sweeps following the BRDF at {:?} deg incidence, one band (550 nm), each through \
         `gonio run`; on realistic.toml, whose filters leak, for samples that are not grey, also grids and sweeps \
         in three bands (their 550 nm values), \
         and every sweep run with a probe beside it (in-plane points at {:?} deg in three bands, which lend the \
         sweeps their spectrum: `[plan] sweep_bands_nm`; its time counted in the run's); \
         error: cosine-weighted relative RMS against the point BRDF on one validation set (the plane of incidence at \
         those incidences, every 0.25 deg the instrument can measure), every run's values interpolated by the same \
         reconstruction. Time: instrument time, and measuring time (first value to last). Target: sweeps reach the \
         error the best stop-and-go run reaches within an hour in at most a tenth of the hour ({:.0} s). Figures: \
         docs/bench/time_vs_error_<material>.svg.\n",
        INCIDENCES_DEG,
        PROBE_THETA_O_DEG,
        RATIO_TARGET * HOUR_S
    );
    s.push_str(
        "| material | instrument | strategy | setting | values | instrument s | measuring s | error |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    let mut targets = String::from(
        "\n| material | instrument | best stop-and-go error within an hour | best sweep error within 360 s | \
         shortest sweep run reaching the hour's error | target |\n|---|---|---|---|---|---|\n",
    );
    let materials: &[&str] = if quick { &MATERIALS[3..4] } else { &MATERIALS };
    for material in materials {
        let mut panels: Vec<crate::plot::Panel> = Vec::new();
        for (label, instrument) in [
            ("ideal", root.join("config/instruments/simulated.toml")),
            ("realistic", root.join("config/instruments/realistic.toml")),
        ] {
            eprintln!("    time against error: {material}, {label}...");
            let mut ok = Vec::new();
            for r in runs(binary, material, &instrument, quick) {
                match r {
                    Ok(r) => {
                        let _ = writeln!(
                            s,
                            "| {material} | {label} | {} | {} | {} | {:.0} | {:.0} | {} |",
                            r.kind.name(),
                            r.setting,
                            r.values,
                            r.instrument_s,
                            r.measuring_s,
                            r.error.map_or("-".into(), |e| format!("{e:.2e}"))
                        );
                        ok.push(r);
                    }
                    Err(e) => {
                        let _ = writeln!(s, "| {material} | {label} | FAILED: {e} | | | | | |");
                    }
                }
            }
            match Verdict::of(&ok) {
                Ok(v) => {
                    let _ = writeln!(
                        targets,
                        "| {material} | {label} | {:.2e} | {} | {} | {} |",
                        v.hour_error,
                        v.sweep_error.map_or("-".into(), |e| format!("{e:.2e}")),
                        v.sweep_s.map_or("never".into(), |t| format!("{t:.0} s")),
                        if v.met() { "met" } else { "NOT met" }
                    );
                }
                Err(e) => {
                    let _ = writeln!(targets, "| {material} | {label} | {e} | | | not measured |");
                }
            }
            let series = [
                Kind::Grid,
                Kind::GridThreeBands,
                Kind::Adaptive,
                Kind::Constant,
                Kind::ConstantThreeBands,
                Kind::Follow,
            ]
            .iter()
            .map(|k| {
                let line: Vec<(f64, f64)> = ok
                    .iter()
                    .filter(|r| r.kind == *k)
                    .filter_map(|r| Some((r.instrument_s, r.error?)))
                    .collect();
                (k.name().to_string(), line)
            })
            .filter(|(_, line)| !line.is_empty())
            .collect();
            panels.push((label.to_string(), series));
        }
        let path = root.join(format!("docs/bench/time_vs_error_{material}.svg"));
        if let Err(e) = crate::plot::time_vs_error(&path, material, &panels) {
            eprintln!("    plot {}: {e}", path.display());
        }
    }
    s.push_str(&targets);
    s
}
