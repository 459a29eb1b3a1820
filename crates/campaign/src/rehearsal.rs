//! What an adaptive campaign will take, known before it runs: its passes rehearsed on a stand-in sample.
//!
//! The planner places each later pass from the values measured. Where the BRDF varies little, which candidates
//! come first turns on differences as small as a reading's noise, so two runs of one campaign on one sample
//! place different passes and take different times. A rehearsal on exact values is one such outcome, and not
//! necessarily a middle one. So the passes are rehearsed [`DRAWS`] times, every stand-in value perturbed by a
//! reading's noise as the instrument file states it ([`reading_noise`]), and the prediction is the draws' mean,
//! their spread beside it for the prediction's band.
//!
//! Measured on the 150-point adaptive styrofoam campaign of BENCHMARKS.md section 6, ideal instrument
//! (crates/engine/tests/it/timing.rs, `an_adaptive_campaign_on_a_diffuser_is_predicted_as_the_mean_of_its_runs`,
//! prints it): at simulator seeds 1-4 the runs took 192.6, 190.2, 195.5 and 195.0 s against 192.9 s predicted
//! by eight rehearsals with a reading's noise (spread 1.7 s), the runs' mean 193.3 s. When this was built (the
//! calibration readings then at the points' averaging), one rehearsal on exact values gave 189.0 s where runs
//! at seeds 1-6 took 186.7 to 194.2 s, and the time model's prediction for the passes each run itself placed
//! was within 0.3 % of that run: the error is in where the passes fall, not in what they take. The draws' size
//! mattered little (relative 1e-4 to 1e-2 gave eight-draw means of 189.0 to 190.4 s), only that there are draws.
//!
//! The stand-in is read as the detector reads it during the run, averaged over its aperture (the aperture
//! correction comes after the passes): on gold with a first pass of sweeps, the point values made the prediction
//! of the 20 deg/s campaign in crates/engine/tests/it/timing.rs 1.5 % short when this was built, the aperture's
//! mean 1.1 % (what that test prints; the rest is where the real passes fall).
//!
//! The draws are deterministic (seeded by their index): the same campaign and instrument file give the same
//! prediction every time, which `gonio plan`, `gonio run` and a resumed run rely on to agree.

use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Wavelength};
use gonio_scheduler::adaptive::BatchMemo;
use gonio_scheduler::kinematics::Geometry;
use gonio_scheduler::schedule::{Schedule, Step};
use gonio_scheduler::sweep::{SweepPlan, SweepSchedule, sweep_reading_period_s};
use rand::{Rng, SeedableRng};

use crate::passes::{AdaptivePlan, After, NextPass, planner_input, swept_values};

/// The stand-in sample of a rehearsal when the campaign names none: a glossy dielectric (a lobe the planner
/// refines and a diffuse floor), the commonest kind of sample.
const STAND_IN_PRESET: &str = "coloured-plastic";

/// Rehearsals per prediction: their mean is within a third of a spread of the mean of many (module doc), and
/// they run side by side on the machine's cores.
pub const DRAWS: usize = 8;

/// An adaptive campaign rehearsed [`DRAWS`] times.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rehearsal {
    /// The predicted instrument time of every pass, the first included: the draws' mean (s).
    pub mean_s: f64,
    /// The draws' sample standard deviation (s): how much the passes' placement alone moves the duration.
    pub spread_s: f64,
    /// Points the passes measure, the draws' mean rounded (the budget, unless the planner stops at its target).
    pub points: u64,
    /// Rehearsals that ran.
    pub draws: usize,
}

/// A prepared campaign's rehearsal, made when first asked for ([`crate::Prepared::rehearsal`]): a second or two
/// of work that exports and status requests, which prepare a campaign for other reasons, do not need.
#[derive(Clone, Default)]
pub(crate) struct Deferred {
    /// The relative noise the draws perturb each value by ([`reading_noise`]).
    pub(crate) noise: f64,
    pub(crate) made: std::sync::OnceLock<Option<Rehearsal>>,
}

impl Deferred {
    pub(crate) fn new(noise: f64) -> Deferred {
        Deferred {
            noise,
            made: std::sync::OnceLock::new(),
        }
    }
}

/// What the rehearsal depends on, not whether it was made yet: two preparations of one campaign print alike.
impl std::fmt::Debug for Deferred {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deferred").field("noise", &self.noise).finish()
    }
}

/// The relative noise of one reading the instrument file states: the source's relative noise over the square
/// root of the samples a reading averages. What the rehearsals perturb each stand-in value by (module doc).
pub fn reading_noise(instrument: &gonio_instrument::Instrument, averaging: u32) -> f64 {
    let n = f64::from(averaging.max(1));
    let noise = instrument.source.relative_noise / n.sqrt();
    if noise.is_finite() && noise > 0.0 {
        noise
    } else {
        0.0
    }
}

/// What an adaptive campaign's passes will take, planned before it runs: its passes placed in turn, each from
/// the values a stand-in sample gives at the points before it, exactly as the run places them from the values it
/// measures, [`DRAWS`] times with each value perturbed by `noise` (relative, standard deviation; module doc).
/// The stand-in is the campaign's `[material]` (a dry-run's simulated sample; for a real sample, what the lab
/// declared) or, without one, a glossy plastic. How far the real passes differ depends on how far the sample
/// differs from its stand-in: the planner refines where the sample's BRDF varies.
///
/// `swept`: a first pass of sweeps (`first_pass_sweeps`), whose readings the stand-in gives along every arc
/// at the planner's binning; their time is in the total.
pub fn rehearse(
    adaptive: &AdaptivePlan,
    first: &Schedule,
    swept: Option<(&SweepPlan, &SweepSchedule)>,
    material: Option<&Material>,
    noise: f64,
) -> Rehearsal {
    // Without a stand-in, or should every draw fail: the first pass (and its sweeps) alone.
    let first_alone = || Rehearsal {
        mean_s: first.breakdown.total_s() + swept.map_or(0.0, |(_, s)| s.breakdown.total_s()),
        spread_s: 0.0,
        points: first.measure_steps().count() as u64,
        draws: 0,
    };
    let fallback = Material::preset(STAND_IN_PRESET).ok();
    let Some(sample) = material.or(fallback.as_ref()) else {
        return first_alone();
    };
    // Without noise every draw would place the same passes: one is enough.
    let draws = if noise > 0.0 { DRAWS } else { 1 };
    let outcomes: Vec<(f64, u64)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..draws)
            .map(|draw| {
                scope.spawn(move || rehearse_once(adaptive, first, swept, sample, noise, draw as u64))
            })
            .collect();
        // A draw that panicked is left out; the others still make a prediction.
        handles.into_iter().filter_map(|h| h.join().ok()).collect()
    });
    let n = outcomes.len();
    if n == 0 {
        return first_alone();
    }
    let mean_s = outcomes.iter().map(|o| o.0).sum::<f64>() / n as f64;
    let points = outcomes.iter().map(|o| o.1 as f64).sum::<f64>() / n as f64;
    let spread_s = if n > 1 {
        (outcomes.iter().map(|o| (o.0 - mean_s).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    Rehearsal {
        mean_s,
        spread_s,
        points: points.round() as u64,
        draws: n,
    }
}

/// One rehearsal: the predicted instrument time of every pass and the points they measure. Draw 0 with `noise`
/// 0 is the rehearsal on exact values.
fn rehearse_once(
    adaptive: &AdaptivePlan,
    first: &Schedule,
    swept: Option<(&SweepPlan, &SweepSchedule)>,
    sample: &Material,
    noise: f64,
    draw: u64,
) -> (f64, u64) {
    let swept_s = swept.map_or(0.0, |(_, s)| s.breakdown.total_s());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(draw);
    // Uniform with the standard deviation `noise`: the draws' size matters little, their presence does.
    let half_width = noise * 3f64.sqrt();
    let det = &adaptive.instrument.detector;
    let half_angle = gonio_brdf::radiometry::aperture_half_angle_rad(det.aperture_radius_mm, det.distance_mm);
    let mut eval = |g: Geometry, band_nm: Option<f64>| -> Option<f64> {
        let (wi, wo) = g.directions();
        let value = band_nm
            .and_then(|nm| Wavelength::from_nm(nm).ok())
            .or_else(|| Wavelength::from_nm(550.0).ok())
            .and_then(|wl| aperture_mean(sample, &wi, &wo, wl, half_angle))?;
        let factor = if half_width > 0.0 {
            1.0 + rng.random_range(-half_width..=half_width)
        } else {
            1.0
        };
        Some(value * factor)
    };
    // The sweeps' readings, one every reading period at cruise along every arc in every band, binned as the
    // planner takes them: a bin's mean over a lobe is not its value at the bin's centre, and the passes the
    // planner places from it are what is timed.
    let mut readings: Vec<(Geometry, Option<f64>)> = Vec::new();
    if let Some((plan, _)) = swept {
        let bands: Vec<Option<f64>> = if plan.bands_nm.is_empty() {
            vec![None]
        } else {
            plan.bands_nm.iter().map(|b| Some(*b)).collect()
        };
        for arc in &plan.arcs {
            let step_deg = arc.request.speed_deg_s * sweep_reading_period_s(arc.request.averaging);
            for g in arc.geometries_every(step_deg) {
                readings.extend(bands.iter().map(|b| (g, eval(g, *b))));
            }
        }
    }
    let swept_values = swept_values(adaptive, readings);
    let mut value = |step: &Step| -> (Geometry, Option<f64>) {
        let g = step.geometry.unwrap_or_else(|| Geometry::new(0.0, 0.0, 0.0, 0.0));
        (g, eval(g, step.band_nm))
    };
    let mut points: Vec<(Geometry, Option<f64>)> = first.measure_steps().map(&mut value).collect();
    let mut elapsed_s = first.breakdown.total_s() + swept_s;
    let mut after = match swept {
        Some((_, s)) => After::sweeps(s),
        None => After::schedule(first),
    };
    let mut memo = BatchMemo::new();
    // Every pass measures at least one point and the budget is finite; the bound is a guard, not a limit.
    for _ in 0..adaptive.budget_points() {
        let (measured, counted) = planner_input(&swept_values, &points);
        match adaptive.next_pass(&measured, counted, elapsed_s, after, &mut memo) {
            NextPass::Pass { schedule, .. } => {
                elapsed_s += schedule.breakdown.total_s();
                points.extend(schedule.measure_steps().map(&mut value));
                after = After::schedule(&schedule);
            }
            NextPass::Done { .. } => break,
        }
    }
    // The calibration the run closes with once the planner stops, and the daemon's last turn of the wheel to
    // its blank.
    elapsed_s += adaptive.closing(after).map_or(0.0, |c| c.breakdown.total_s());
    (elapsed_s, points.len() as u64)
}

/// The stand-in's BRDF averaged over the detector's aperture around `wo` (cone of `half_angle` rad), as the
/// instrument reads it during a run (the aperture correction comes after the passes): a seven-point rule on the
/// disk (the centre with weight 1/4, six points at sqrt(2/3) of the radius with 1/8 each; exact for cubics).
fn aperture_mean(
    sample: &Material,
    wi: &gonio_brdf::geometry::Direction,
    wo: &gonio_brdf::geometry::Direction,
    wl: Wavelength,
    half_angle: f64,
) -> Option<f64> {
    use gonio_brdf::geometry::Direction;
    let centre = sample.eval(wi, wo, wl).ok()?;
    if !(half_angle.is_finite() && half_angle > 0.0) {
        return Some(centre);
    }
    let (x, y, z) = (wo.x(), wo.y(), wo.z());
    // A unit vector perpendicular to wo, then the third by the cross product.
    let (ax, ay, az) = if z.abs() < 0.9 {
        (0.0, 0.0, 1.0)
    } else {
        (1.0, 0.0, 0.0)
    };
    let u = Direction::new(ay * z - az * y, az * x - ax * z, ax * y - ay * x)?;
    let v = Direction::new(
        y * u.z() - z * u.y(),
        z * u.x() - x * u.z(),
        x * u.y() - y * u.x(),
    )?;
    let r = (2.0f64 / 3.0).sqrt() * half_angle.tan();
    let mut sum = 0.25 * centre;
    for k in 0..6 {
        let a = f64::from(k) * std::f64::consts::PI / 3.0;
        let (c, s) = (r * a.cos(), r * a.sin());
        let d = Direction::new(
            x + c * u.x() + s * v.x(),
            y + c * u.y() + s * v.y(),
            z + c * u.z() + s * v.z(),
        )?;
        if !d.is_above_horizon() {
            return Some(centre);
        }
        sum += 0.125 * sample.eval(wi, &d, wl).ok()?;
    }
    Some(sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_brdf::geometry::Direction;

    /// The mean over the cone by brute force: a polar grid on the tangent plane's disk, each cell weighted by its
    /// area (independent of the seven-point rule).
    fn dense_mean(sample: &Material, wi: &Direction, wo: &Direction, wl: Wavelength, half: f64) -> f64 {
        let (x, y, z) = (wo.x(), wo.y(), wo.z());
        let u = Direction::new(-y, x, 0.0).expect("wo not along z");
        let v = Direction::new(
            y * u.z() - z * u.y(),
            z * u.x() - x * u.z(),
            x * u.y() - y * u.x(),
        )
        .expect("v");
        let (rings, spokes) = (60, 90);
        let (mut sum, mut area) = (0.0, 0.0);
        for i in 0..rings {
            let r = half.tan() * (f64::from(i) + 0.5) / f64::from(rings);
            for j in 0..spokes {
                let a = std::f64::consts::TAU * f64::from(j) / f64::from(spokes);
                let (c, s) = (r * a.cos(), r * a.sin());
                let d = Direction::new(
                    x + c * u.x() + s * v.x(),
                    y + c * u.y() + s * v.y(),
                    z + c * u.z() + s * v.z(),
                )
                .expect("direction");
                sum += r * sample.eval(wi, &d, wl).expect("eval");
                area += r;
            }
        }
        sum / area
    }

    #[test]
    fn the_stand_in_is_read_as_the_detector_reads_it_averaged_over_its_aperture() {
        let gold = Material::preset("gold").expect("preset");
        let wl = Wavelength::from_nm(550.0).expect("wavelength");
        // The simulated instrument's aperture: 2.5 mm at 250 mm, 0.57 degrees.
        let half = gonio_brdf::radiometry::aperture_half_angle_rad(2.5, 250.0);
        let wi = Direction::from_spherical_deg(30.0, 0.0);
        for off_deg in [0.0, 0.5, 1.0, 3.0] {
            let wo = Direction::from_spherical_deg(30.0 + off_deg, 180.0);
            let centre = gold.eval(&wi, &wo, wl).expect("eval");
            let mean = aperture_mean(&gold, &wi, &wo, wl, half).expect("mean");
            let dense = dense_mean(&gold, &wi, &wo, wl, half);
            assert!(
                (mean / dense - 1.0).abs() < 2e-3,
                "{off_deg} deg: {mean} against {dense}"
            );
            if off_deg == 0.0 {
                // The lobe's peak reads low through the aperture.
                assert!(mean < centre * 0.999, "{mean} against the peak {centre}");
            }
        }
        // No aperture: the value itself.
        let wo = Direction::from_spherical_deg(30.0, 180.0);
        assert_eq!(
            aperture_mean(&gold, &wi, &wo, wl, 0.0),
            gold.eval(&wi, &wo, wl).ok()
        );
    }
}
