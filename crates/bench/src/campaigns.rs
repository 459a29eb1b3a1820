//! Benchmark (item 2): plan strategies per seed material -> predicted instrument time against BRDF error versus
//! ground truth on a dense validation set.
//!
//! - Ground truth and "measurements": the material's pointwise BRDF (`Brdf::eval` at 550 nm), noise-free. The
//!   simulator's reading differs from it by the aperture average (0.01 rad, far narrower than any seed lobe; item
//!   1 measures that) and by detector noise, which would blur the comparison between strategies.
//! - Reconstruction: the interpolation the product has for scattered points, [`Adaptive::reconstruct_all`]
//!   (inverse-distance weighting of ln(1 + f) over the 8 nearest measured points in the (wi, wo) embedding),
//!   the same for every strategy. (The measured model of crates/brdf is a MERL table lookup; filling a table from
//!   scattered points needs such an interpolation first.)
//! - Validation set: quasi-random (R-sequence) pairs, uniform in solid angle for wi and wo (cos theta uniform),
//!   delta phi uniform, in the isotropic canonical domain theta_i <= theta_o, kept when the simulated instrument
//!   can measure them (the constraints and kinematics with a 12.5 mm sample): the error is over what a campaign
//!   can measure.
//! - Metrics (shared/reference/radiometry-and-materials.md, "Error metrics"): cosine-weighted relative RMS
//!   `sqrt(sum ((f - f_ref) cos theta_i)^2 / sum (f_ref cos theta_i)^2)` and the log error
//!   `sqrt(mean (ln(1 + f cos theta_i) - ln(1 + f_ref cos theta_i))^2)`.
//! - Strategies: a uniform full grid (anisotropic treatment: theta_i, phi_i, theta_o, phi_o, no reductions), an
//!   isotropic grid with reciprocity (theta_i, theta_o, delta phi; the planner's reductions), and adaptive
//!   campaigns at several point budgets, run by the product's engine as `gonio run` runs them (an in-process
//!   dry-run: each pass placed from the simulator's readings); their geometries are then valued with the same
//!   ground truth as the grids'.
//! - Time: for grids, the scheduler's time model on the ordered schedule (one band, no calibration steps); for
//!   adaptive campaigns, the simulated instrument time the engine's run took (its start-up darks and direct-beam
//!   readings included; the time model agrees with dry-runs within 1 %).

use gonio_brdf::{Brdf, Direction, Material, Wavelength};
use gonio_campaign::{AcquisitionSection, CampaignFile};
use gonio_instrument::Instrument;
use gonio_scheduler::adaptive::{Adaptive, Measured};
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_scheduler::plan::AdaptiveSpec;
use gonio_scheduler::plan::{self, BuildContext, Plan, PlanSpec, SampleTraits};
use gonio_scheduler::schedule;
use gonio_scheduler::timing::TimeModel;

pub const SAMPLE_RADIUS_MM: f64 = 12.5;
pub const BAND_NM: f64 = 550.0;

/// One strategy at one size.
#[derive(Debug, Clone)]
pub struct CampaignPoint {
    pub material: &'static str,
    pub strategy: Strategy,
    /// "step 10 deg", "budget 400".
    pub label: String,
    pub points: usize,
    pub predicted_s: f64,
    /// None when the reference is 0 everywhere (the mirror: a delta BRDF has no pointwise values).
    pub rel_rms: Option<f64>,
    pub log_rms: f64,
    /// Adaptive plans: batch geometries the planner refused (dropped while scheduling).
    pub dropped: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Strategy {
    FullGrid,
    IsotropicGrid,
    Adaptive,
    /// Adaptive after a first pass of sweeps (`first_pass_sweeps` at [`FIRST_PASS_SWEEP_DEG_S`]).
    AdaptiveSwept,
}

impl Strategy {
    pub fn name(&self) -> &'static str {
        match self {
            Strategy::FullGrid => "uniform full grid",
            Strategy::IsotropicGrid => "isotropic + reciprocity grid",
            Strategy::Adaptive => "adaptive",
            Strategy::AdaptiveSwept => "adaptive, first pass swept",
        }
    }
}

/// The detector's speed in the swept first pass (deg/s): a reading every 0.013 deg at the meter's one sample a
/// reading.
pub const FIRST_PASS_SWEEP_DEG_S: f64 = 20.0;

/// What the runs share.
pub struct Setup<'a> {
    pub instrument: &'a Instrument,
    pub validation: Vec<Geometry>,
    pub time: TimeModel,
}

/// Sizes of each strategy.
pub struct Sizes {
    pub full_steps_deg: Vec<f64>,
    pub iso_steps_deg: Vec<f64>,
    pub budgets: Vec<u32>,
    pub validation_points: usize,
}

impl Sizes {
    pub fn new(quick: bool) -> Sizes {
        if quick {
            Sizes {
                full_steps_deg: vec![30.0, 20.0],
                iso_steps_deg: vec![15.0, 10.0, 7.5, 5.0],
                budgets: vec![50, 100, 200, 400],
                validation_points: 10_000,
            }
        } else {
            Sizes {
                full_steps_deg: vec![30.0, 22.5, 15.0],
                iso_steps_deg: vec![15.0, 10.0, 7.5, 5.0, 3.75, 3.0],
                budgets: vec![50, 100, 200, 400, 800, 1600, 3200],
                validation_points: 40_000,
            }
        }
    }
}

fn ctx(instrument: &Instrument, isotropic: bool) -> BuildContext<'_> {
    BuildContext {
        instrument,
        traits: SampleTraits {
            isotropic,
            spectrally_flat: false,
        },
        sample_radius_mm: Some(SAMPLE_RADIUS_MM),
        start: None,
    }
}

impl<'a> Setup<'a> {
    pub fn new(instrument: &'a Instrument, validation_points: usize) -> Setup<'a> {
        let constraints = Constraints::new(instrument, Some(SAMPLE_RADIUS_MM));
        let kin = Kinematics::new(instrument);
        let hint = Pose::new(0.0, 0.0, 0.0, 0.0);
        let mut validation = Vec::with_capacity(validation_points);
        // R3 sequence (plastic-number generalisation of the golden ratio): low discrepancy in 3 dimensions.
        let g = 1.220_744_084_605_759_5f64;
        let (a1, a2, a3) = (1.0 / g, 1.0 / (g * g), 1.0 / (g * g * g));
        let mut k = 0u64;
        while validation.len() < validation_points && k < 50 * validation_points as u64 {
            k += 1;
            let kf = k as f64;
            let (u1, u2, u3) = (
                (0.5 + kf * a1).fract(),
                (0.5 + kf * a2).fract(),
                (0.5 + kf * a3).fract(),
            );
            let ti = u1.acos().to_degrees();
            let to = u2.acos().to_degrees();
            let geometry = Geometry::new(ti.min(to), 0.0, ti.max(to), 180.0 * u3);
            let (wi, wo) = geometry.directions();
            if constraints.check_directions(&wi, &wo).is_ok()
                && kin.isotropic_solutions(&wi, &wo, 0.0, &hint).is_ok()
            {
                validation.push(geometry);
            }
        }
        Setup {
            instrument,
            validation,
            time: TimeModel::new(instrument),
        }
    }
}

/// The material at the benchmark band, as a closure over geometries.
pub fn truth_fn(material: &str) -> impl Fn(&Geometry) -> f64 {
    let wl = Wavelength::from_nm(BAND_NM).expect("550 nm");
    let m = Material::preset(material)
        .expect("seed preset")
        .at_wavelength(wl)
        .expect("550 nm is in every seed table");
    move |g: &Geometry| {
        let (wi, wo): (Direction, Direction) = g.directions();
        m.eval(&wi, &wo, wl).unwrap_or(0.0)
    }
}

/// (relative RMS, log RMS) of `rec` against `truth` at `at` (module doc).
pub fn errors(at: &[Geometry], rec: &[f64], truth: &[f64]) -> (Option<f64>, f64) {
    let (mut num, mut den, mut log) = (0.0, 0.0, 0.0);
    for ((g, r), t) in at.iter().zip(rec).zip(truth) {
        let c = g.theta_i_deg.to_radians().cos();
        num += ((r - t) * c).powi(2);
        den += (t * c).powi(2);
        log += ((r.max(0.0) * c).ln_1p() - (t * c).ln_1p()).powi(2);
    }
    let rel = (den > 0.0).then(|| (num / den).sqrt());
    (rel, (log / at.len().max(1) as f64).sqrt())
}

fn grid_text(full: bool, step: f64) -> String {
    let theta = format!("{{ from = 0.0, to = 85.0, step = {step} }}");
    if full {
        let phi = format!(
            "{{ from = 0.0, to = {}, step = {} }}",
            360.0 - 2.0 * step,
            2.0 * step
        );
        format!(
            "[plan]\nbands_nm = [{BAND_NM}]\nreciprocity = false\n[plan.grid]\nkind = \"full\"\n\
             theta_i_deg = {theta}\nphi_i_deg = {phi}\ntheta_o_deg = {theta}\nphi_o_deg = {phi}\n"
        )
    } else {
        format!(
            "[plan]\nbands_nm = [{BAND_NM}]\nreciprocity = true\n[plan.grid]\nkind = \"isotropic\"\n\
             theta_i_deg = {theta}\ntheta_o_deg = {theta}\ndelta_phi_deg = {{ from = 0.0, to = 180.0, step = {} }}\n",
            2.0 * step
        )
    }
}

/// The geometries a plan measures (the geometry at each kept pose).
fn measured_geometries(plan: &Plan) -> Vec<Geometry> {
    plan.geometries
        .iter()
        .filter_map(|g| g.candidates.first().map(|c| c.1))
        .collect()
}

/// A grid strategy: (points, predicted s, measured geometries).
pub fn grid_plan(setup: &Setup, full: bool, step: f64) -> Result<(usize, f64, Vec<Geometry>), String> {
    let spec = PlanSpec::from_toml(&grid_text(full, step), "bench").map_err(|e| e.to_string())?;
    let plan = plan::build(&spec, &ctx(setup.instrument, !full)).map_err(|e| e.to_string())?;
    let sched = schedule::schedule(&plan, &setup.time, None);
    let geometries = measured_geometries(&plan);
    Ok((geometries.len(), sched.breakdown.total_s(), geometries))
}

/// The campaign file of an adaptive campaign on `material` to `budget` points (one band, no calibration steps
/// beyond the engine's own at start); `swept`: its first pass swept.
pub fn adaptive_campaign_text(material: &str, budget: u32, swept: bool) -> String {
    let adaptive = AdaptiveSpec {
        batch_points: 40,
        target_error: 0.0,
        first_pass_step_deg: 10.0,
        resolution_deg: 2.5,
        first_pass_sweeps: swept.then_some(gonio_scheduler::plan::FirstPassSweeps {
            speed_deg_s: FIRST_PASS_SWEEP_DEG_S,
            averaging: 1,
        }),
        ..AdaptiveSpec::with_budget(budget)
    };
    let plan = PlanSpec {
        bands_nm: Some(vec![BAND_NM]),
        reciprocity: true,
        adaptive: Some(adaptive),
        ..PlanSpec::default()
    };
    CampaignFile::new(
        &format!("bench-adaptive-{material}-{budget}"),
        SAMPLE_RADIUS_MM,
        plan,
    )
    .with_material_preset(material)
    .with_acquisition(AcquisitionSection {
        averaging: Some(10),
        ..AcquisitionSection::default()
    })
    .to_toml()
    .expect("a campaign of numbers and names serialises")
}

/// An adaptive campaign to `budget` points, run by the product's engine (`gonio run`'s in-process dry-run: the
/// planner places each pass from the simulator's readings). Returns the measured geometries with their ground
/// truth (the reconstruction compares strategies on noise-free values, module doc), the instrument time the run
/// took (simulated, the engine's own start-up calibration included), and the budget points not measured.
///
/// `swept`: the first pass is swept; the sweep readings join the points as the planner takes them (one value a
/// bin along every arc, `gonio_campaign::passes::swept_values`), valued at the ground truth like the points.
pub fn adaptive_run(
    budget: u32,
    material: &str,
    swept: bool,
    truth: &dyn Fn(&Geometry) -> f64,
) -> Result<(Vec<Measured>, f64, usize), String> {
    let text = adaptive_campaign_text(material, budget, swept);
    let points = crate::throughput::in_process_points(&text)?;
    // The points follow the sweeps: the last point ends the run.
    let instrument_s = points.iter().map(|p| p.t_s).fold(0.0f64, f64::max);
    let mut values: Vec<(Geometry, Option<f64>)> = points
        .iter()
        .map(|p| {
            let g = Geometry::new(p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg);
            (g, Some(truth(&g)))
        })
        .collect();
    let short = (budget as usize).saturating_sub(values.len());
    if swept {
        values.extend(swept_bins(&text)?.into_iter().map(|g| (g, Some(truth(&g)))));
    }
    Ok((gonio_campaign::measured_geometries(values), instrument_s, short))
}

/// The bins a first pass of sweeps fills (every bin along every arc the path check kept).
fn swept_bins(text: &str) -> Result<Vec<Geometry>, String> {
    let file = gonio_instrument::InstrumentFile::simulated();
    let sources = gonio_campaign::Sources::Local(std::env::temp_dir());
    let p =
        gonio_campaign::load_and_prepare(text, "bench.toml", &sources, &file).map_err(|e| e.to_string())?;
    let (Some(adaptive), Some(sweeps)) = (&p.adaptive, &p.sweeps) else {
        return Err("the first pass is not swept".into());
    };
    let step = adaptive.planner().sweep_bin_deg();
    let mut out = Vec::new();
    for arc in &sweeps.plan.arcs {
        out.extend(
            arc.geometries_every(step)
                .map(|g| adaptive.planner().sweep_bin(&g)),
        );
    }
    Ok(out)
}

/// Every strategy at every size for one material.
pub fn run_material(
    setup: &Setup,
    sizes: &Sizes,
    material: &'static str,
    reconstructor: &Adaptive,
) -> Vec<CampaignPoint> {
    let truth = truth_fn(material);
    let reference: Vec<f64> = setup.validation.iter().map(&truth).collect();
    let mut out = Vec::new();
    let evaluate = |geoms: &[Geometry]| -> Vec<Measured> {
        geoms
            .iter()
            .map(|g| Measured {
                geometry: *g,
                value: truth(g),
            })
            .collect()
    };
    for (full, steps) in [(true, &sizes.full_steps_deg), (false, &sizes.iso_steps_deg)] {
        for &step in steps {
            match grid_plan(setup, full, step) {
                Ok((points, predicted_s, geoms)) => {
                    let measured = evaluate(&geoms);
                    let rec = reconstructor.reconstruct_all(&measured, &setup.validation);
                    let (rel, log) = errors(&setup.validation, &rec, &reference);
                    out.push(CampaignPoint {
                        material,
                        strategy: if full {
                            Strategy::FullGrid
                        } else {
                            Strategy::IsotropicGrid
                        },
                        label: format!("step {step} deg"),
                        points,
                        predicted_s,
                        rel_rms: rel,
                        log_rms: log,
                        dropped: 0,
                    });
                }
                Err(e) => eprintln!("{material}: grid step {step}: {e}"),
            }
        }
    }
    for strategy in [Strategy::Adaptive, Strategy::AdaptiveSwept] {
        for &budget in &sizes.budgets {
            let run = AdaptiveRow {
                setup,
                material,
                reconstructor,
                truth: &truth,
                reference: &reference,
            };
            out.extend(run.row(budget, strategy));
        }
    }
    out
}

/// What an adaptive run's row is measured with.
struct AdaptiveRow<'a> {
    setup: &'a Setup<'a>,
    material: &'static str,
    reconstructor: &'a Adaptive,
    truth: &'a dyn Fn(&Geometry) -> f64,
    reference: &'a [f64],
}

impl AdaptiveRow<'_> {
    /// One run's row; a run that fails is reported, not fatal (the other rows still count). Points: the points
    /// measured (a swept first pass's readings besides them).
    fn row(&self, budget: u32, strategy: Strategy) -> Option<CampaignPoint> {
        let swept = strategy == Strategy::AdaptiveSwept;
        match adaptive_run(budget, self.material, swept, self.truth) {
            Ok((measured, predicted_s, dropped)) => {
                let rec = self
                    .reconstructor
                    .reconstruct_all(&measured, &self.setup.validation);
                let (rel, log) = errors(&self.setup.validation, &rec, self.reference);
                Some(CampaignPoint {
                    material: self.material,
                    strategy,
                    label: format!("budget {budget}"),
                    points: budget as usize - dropped,
                    predicted_s,
                    rel_rms: rel,
                    log_rms: log,
                    dropped,
                })
            }
            Err(e) => {
                eprintln!("{}: {} budget {budget}: {e}", self.material, strategy.name());
                None
            }
        }
    }
}

/// A reconstructor (any Adaptive: reconstruction does not depend on its spec).
pub fn reconstructor(instrument: &Instrument) -> Adaptive {
    let spec = AdaptiveSpec {
        budget_points: 1,
        budget_s: None,
        batch_points: 1,
        target_error: 0.0,
        first_pass_step_deg: 10.0,
        first_pass_theta_i_deg: None,
        resolution_deg: 45.0,
        first_pass_sweeps: None,
    };
    Adaptive::new(&spec, &ctx(instrument, true)).expect("reconstructor")
}

/// Points the adaptive plan needs to reach `error` (log-log interpolation along its measured curve), if it does.
pub fn adaptive_points_for(curve: &[(usize, f64)], error: f64) -> Option<f64> {
    let mut prev: Option<(usize, f64)> = None;
    for &(n, e) in curve {
        if e <= error {
            return Some(match prev {
                Some((n0, e0)) if e0 > e && e > 0.0 => {
                    let t = (e0.ln() - error.ln()) / (e0.ln() - e.ln());
                    ((n0 as f64).ln() + t * ((n as f64).ln() - (n0 as f64).ln())).exp()
                }
                _ => n as f64,
            });
        }
        prev = Some((n, e));
    }
    None
}

/// The target comparison for one material and metric: for each uniform isotropic grid, the adaptive points
/// reaching its error and the ratio.
#[derive(Debug, Clone)]
pub struct Parity {
    pub uniform_points: usize,
    pub uniform_error: f64,
    /// None when no adaptive budget reached it.
    pub adaptive_points: Option<f64>,
}

impl Parity {
    pub fn ratio(&self) -> Option<f64> {
        self.adaptive_points.map(|a| self.uniform_points as f64 / a)
    }
}

/// [`Parity`] rows for `material` on the relative RMS (`log = false`) or the log error.
pub fn parity(points: &[CampaignPoint], material: &str, log: bool) -> Vec<Parity> {
    let metric = |p: &CampaignPoint| if log { Some(p.log_rms) } else { p.rel_rms };
    let curve: Vec<(usize, f64)> = points
        .iter()
        .filter(|p| p.material == material && p.strategy == Strategy::Adaptive)
        .filter_map(|p| metric(p).map(|e| (p.points, e)))
        .collect();
    points
        .iter()
        .filter(|p| p.material == material && p.strategy == Strategy::IsotropicGrid)
        .filter_map(|p| {
            metric(p).map(|e| Parity {
                uniform_points: p.points,
                uniform_error: e,
                adaptive_points: adaptive_points_for(&curve, e),
            })
        })
        .collect()
}

/// Markdown for the campaign section.
pub fn markdown(points: &[CampaignPoint], sizes: &Sizes, validation: usize, elapsed_s: f64) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Validation set: {validation} reachable geometries. Budgets {:?} (adaptive: batches of 40, candidate grid \
         2.5 deg, first pass 10 deg; first pass swept: the same incidences swept by the detector from grazing to \
         grazing at {FIRST_PASS_SWEEP_DEG_S} deg/s before any point, its readings binned at 1.25 deg and valued \
         like the points, the budget in points after them, the sweeps' time in the run's); isotropic grids theta \
         step {:?} deg (delta phi twice that, theta 0-85); full grids step {:?} deg (phi twice that). Section run \
         time {elapsed_s:.0} s.\n",
        sizes.budgets, sizes.iso_steps_deg, sizes.full_steps_deg
    );
    let mut materials: Vec<&str> = Vec::new();
    for p in points {
        if !materials.contains(&p.material) {
            materials.push(p.material);
        }
    }
    for m in &materials {
        let _ = writeln!(s, "#### {m}\n");
        let _ = writeln!(
            s,
            "| strategy | size | points | predicted time (s) | cos-weighted rel. RMS | log error |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for p in points.iter().filter(|p| p.material == *m) {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.0} | {} | {:.4} |",
                p.strategy.name(),
                p.label,
                p.points,
                p.predicted_s,
                p.rel_rms.map_or("n/a".into(), |r| format!("{r:.4}")),
                p.log_rms
            );
        }
        if points.iter().any(|p| p.material == *m && p.rel_rms.is_none()) {
            let _ = writeln!(
                s,
                "\n{m} is a delta reflector: its pointwise BRDF is 0 everywhere off the mirror direction (the delta \
                 lobe has no point value), so every strategy reconstructs it exactly, the relative RMS is undefined \
                 (0/0) and the log error is 0. What a campaign learns about a mirror is the delta's reflectance, \
                 measured through the aperture on the specular geometries (section 1); these rows only show the plans' \
                 sizes and times."
            );
        }
        let file = format!("campaign_{m}.svg");
        let _ = writeln!(s, "\n![{m}](docs/bench/{file})\n");
    }
    s
}
