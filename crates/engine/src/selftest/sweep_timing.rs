//! When a motion controller takes the positions it reports while its axis moves (`position_sampled_ms`), from
//! the direct beam swept across the detector both ways at two speeds: what a sweep needs to place its readings
//! where the arm was, and what no exchange on the line shows (the controller answers a query some milliseconds
//! after it arrives; whether it took the position at once, as it answers, or in between, the timing alone
//! cannot tell).
//!
//! Each pass is a sweep as a campaign makes one (crate::motion::sweep): the meter read back to back at no
//! averaging on a fixed range, position reports beside the readings, each reading placed on the commanded
//! trapezoid shifted by the arm's lag taken from the reports, and the reports dated as if taken when the query
//! was sent. Taken `s` later than that, every report is dated `s` early, the lag comes out `s` short and every
//! reading is placed `v s` ahead of the arm at speed `v`: the beam's centre (its centroid, `pass_centre`)
//! appears `v s` further along the sweep. Swept up and then down, the two centres differ by `2 v s`, plus
//! whatever the file's backlash leaves (the load's play, which does not scale with the speed): the difference
//! at two speeds gives `s`. The meter's own timing is in it too: a meter that starts integrating `d` after a
//! reading's request makes every reading `v d` later than placed, which reads as `s - d`. That difference is
//! what placing the readings needs, and below zero when the meter's delay is the longer.

use gonio_driver::{DetectorConfig, PowerRange};
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::sweep::sweep_reading_period_s;
use gonio_scheduler::timing::DETECTOR_SAMPLE_S;

use super::fit::mean_std;
use crate::align::centre::sorted;
use crate::align::scan::Profile;
use crate::motion::sweep::{Reader, ReportDating, load_offset_deg, restore_speed, sweep_axis};
use crate::motion::{Device, Motion, MotionError};
use crate::rig::RigAxis;

/// A position report beside every this many readings (as a campaign's sweep: the readings' cadence mostly the
/// meter's).
const REPORT_EVERY: usize = 4;
/// One speed's passes: the speed (deg/s), the centres seen sweeping up and down (deg, each with its standard
/// uncertainty).
pub(super) type SpeedRuns = (f64, Vec<(f64, f64)>, Vec<(f64, f64)>);

/// Passes per speed and direction.
const SAMPLING_REPEATS: usize = 3;
/// Readings across each edge (15 % to 85 % of the way up) at the faster speed, at least.
const EDGE_READINGS: f64 = 8.0;
/// The slower speed is this fraction of the faster.
const SLOW_FRACTION: f64 = 0.25;
/// A pass's first reading comes at most this long (s) after its start: the move command's reply (an SMC100
/// pauses after a command that sets something).
const UNREAD_START_S: f64 = 0.2;
/// A pass starts and ends this far (deg) beyond the beam's window, the ramp and what passes unread.
const PASS_MARGIN_DEG: f64 = 0.2;

/// What one axis's passes gave.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Sampling {
    /// The controller (the instrument file's device) of the axis.
    pub device: String,
    /// When the controller took its reported positions after a query was sent (ms), and its standard
    /// uncertainty (ms).
    pub after_ms: f64,
    pub u_ms: f64,
    /// When a sweep dates a report after its query was sent when the file says nothing of it (ms, the latest
    /// over the passes): the middle of the window between the query's arrival and the reply's start.
    pub assumed_ms: f64,
}

/// The meter at no averaging on a fixed range: a reading's power (W), or why it is none.
struct FastMeter<'m, 'r> {
    motion: &'m Motion<'r>,
}

impl Reader for FastMeter<'_, '_> {
    type Reading = Result<f64, String>;
    fn integration_s(&self) -> f64 {
        DETECTOR_SAMPLE_S
    }
    async fn read(&mut self) -> Self::Reading {
        let det = self.motion.rig().detector();
        match self
            .motion
            .device(Device::Detector, "read the meter", || det.read_power())
            .await
        {
            Ok(r) if r.overload => Err(format!("the meter is over its {:e} W range", r.range_w)),
            Ok(r) => Ok(r.power_w),
            Err(e) => Err(e.to_string()),
        }
    }
}

/// How far beyond the static scan's half-height edges (deg) the beam is taken to reach in a pass.
fn window_margin_deg(profile: &Profile) -> f64 {
    2.0 * profile.edge_width_deg + 0.5 * PASS_MARGIN_DEG
}

/// The centre (deg) of the beam profile seen by one pass from its placed readings `(deg, W)`, with its standard
/// uncertainty: the profile's centroid above the baseline within the static scan's edges and a margin (each
/// reading weighed by the arc it stands for, half the way to each neighbour). A centroid rather than the
/// half-height edges: an ideal beam's edge is sharper than the readings' spacing even at a slow sweep, and the
/// centroid takes every reading's share of it. Its uncertainty comes from the readings' scatter outside that
/// window (the baseline's).
pub(super) fn pass_centre(readings: &[(f64, f64)], profile: &Profile) -> Result<(f64, f64), String> {
    let margin = window_margin_deg(profile);
    let (lo, hi) = (profile.low.value - margin, profile.high.value + margin);
    let sorted = sorted(readings);
    if !(sorted.first().is_some_and(|p| p.0 < lo) && sorted.last().is_some_and(|p| p.0 > hi)) {
        return Err("the pass did not cross the whole beam".into());
    }
    let base: Vec<f64> = sorted
        .iter()
        .filter(|(x, _)| *x < lo || *x > hi)
        .map(|p| p.1)
        .collect();
    let sigma = mean_std(&base).map_or(0.0, |(_, sd)| sd);
    let (mut sum_w, mut sum_xw) = (0.0, 0.0);
    let mut inside = Vec::new();
    for k in 1..sorted.len().saturating_sub(1) {
        let (x, w) = sorted[k];
        if x < lo || x > hi {
            continue;
        }
        let arc = 0.5 * (sorted[k + 1].0 - sorted[k - 1].0);
        let f = w - profile.base_w;
        sum_w += f * arc;
        sum_xw += x * f * arc;
        inside.push((x, arc));
    }
    if sum_w.is_nan() || sum_w <= 0.0 || inside.len() < 3 {
        return Err(format!(
            "{} readings above the baseline across the beam",
            inside.len()
        ));
    }
    let c = sum_xw / sum_w;
    let u = sigma
        * inside
            .iter()
            .map(|(x, arc)| ((x - c) * arc).powi(2))
            .sum::<f64>()
            .sqrt()
        / sum_w;
    Ok((c, u))
}

/// `s` (s) and its standard uncertainty from the centres seen sweeping up and down at each speed: `(speed
/// deg/s, centres up, centres down)`, two speeds. The difference of the means at each speed is `2 v s + b`.
pub(super) fn sampling_from_centres(runs: &[SpeedRuns]) -> Result<(f64, f64), String> {
    let mean_u = |c: &[(f64, f64)]| -> Option<(f64, f64)> {
        let values: Vec<f64> = c.iter().map(|p| p.0).collect();
        let own = c.iter().map(|p| p.1 * p.1).sum::<f64>().sqrt() / c.len().max(1) as f64;
        match mean_std(&values) {
            Some((m, sd)) => Some((m, (sd / (values.len() as f64).sqrt()).max(own))),
            None => values.first().map(|m| (*m, own)),
        }
    };
    let mut diffs = Vec::new();
    for (v, up, down) in runs {
        let (Some((u_m, u_u)), Some((d_m, d_u))) = (mean_u(up), mean_u(down)) else {
            return Err(format!("no centre swept both ways at {v} deg/s"));
        };
        diffs.push((*v, u_m - d_m, u_u.hypot(d_u)));
    }
    let [(v1, d1, u1), (v2, d2, u2)] = diffs[..] else {
        return Err("two speeds are needed".into());
    };
    let dv = v1 - v2;
    if dv == 0.0 || dv.is_nan() {
        return Err("the two speeds are the same".into());
    }
    let s = (d1 - d2) / (2.0 * dv);
    let u = u1.hypot(u2) / (2.0 * dv.abs());
    if s.is_finite() && u.is_finite() {
        Ok((s, u))
    } else {
        Err("the swept centres give no number".into())
    }
}

/// The sampling instant of `a`'s controller (module doc), with the beam's static `profile` found along `a` and
/// the other axes where `at` puts them; the meter is set to no averaging on `full_scale_w` for the passes and
/// left so. Or why not.
pub(super) async fn measure_sampling(
    motion: &mut Motion<'_>,
    a: &RigAxis,
    profile: &Profile,
    at: &(dyn Fn(f64) -> Pose + Sync),
    band_nm: f64,
    full_scale_w: f64,
) -> Result<Result<Sampling, String>, MotionError> {
    let cfg = &a.config;
    let period_s = sweep_reading_period_s(1);
    let fast = (profile.edge_width_deg / (EDGE_READINGS * period_s)).min(0.8 * cfg.max_speed_deg_s);
    let speeds = [fast, SLOW_FRACTION * fast];
    if !(fast.is_finite() && fast > 0.0 && cfg.accel_deg_s2 > 0.0) {
        return Ok(Err(format!(
            "no sweep speed for an edge {:.4} deg wide",
            profile.edge_width_deg
        )));
    }
    // Beyond the window, the ramp, what passes before the first reading (the command's reply) and a margin.
    let reach = window_margin_deg(profile)
        + fast * fast / (2.0 * cfg.accel_deg_s2)
        + fast * UNREAD_START_S
        + PASS_MARGIN_DEG;
    let (lowest, highest) = (profile.low.value - reach, profile.high.value + reach);
    if lowest < cfg.min_deg || highest > cfg.max_deg {
        return Ok(Err(
            "the beam is too near the end of the travel to sweep across".into()
        ));
    }
    let det = motion.rig().detector();
    let config = DetectorConfig {
        wavelength_nm: band_nm,
        averaging: 1,
        range: PowerRange::Fixed { full_scale_w },
    };
    motion
        .device(Device::Detector, "configure the meter", || det.configure(config))
        .await?;
    let file_dating = ReportDating::of(motion.rig().file(), cfg);
    let on_sending = ReportDating {
        sampled_after_s: Some(0.0),
        ..file_dating
    };
    tracing::info!(axis = %cfg.name, speeds_deg_s = ?speeds, "self-test: the direct beam swept both ways");
    let integration_s = DETECTOR_SAMPLE_S;
    let mut runs = Vec::new();
    let mut assumed_s = 0.0_f64;
    for v in speeds {
        let (mut up, mut down) = (Vec::new(), Vec::new());
        for _ in 0..SAMPLING_REPEATS {
            for (from, to) in [(lowest, highest), (highest, lowest)] {
                motion.move_to(&at(from)).await?;
                let mut meter = FastMeter { motion };
                let pass = sweep_axis(motion, a, (from, to), v, REPORT_EVERY, on_sending, &mut meter).await?;
                restore_speed(motion, a).await?;
                motion.read_positions().await?;
                assumed_s = assumed_s.max(pass.assumed_after_s);
                let Some((lag, _)) = pass.lag_s() else {
                    return Ok(Err(format!("no position report while {} cruised", cfg.name)));
                };
                let offset = load_offset_deg(cfg, to - from);
                let mut placed = Vec::with_capacity(pass.taken.len());
                for (t, reading) in &pass.taken {
                    match reading {
                        Ok(w) => placed.push((
                            pass.profile.mean_over(t - lag, t + integration_s - lag) + offset,
                            *w,
                        )),
                        Err(why) => return Ok(Err(why.clone())),
                    }
                }
                match pass_centre(&placed, profile) {
                    Ok(c) if to > from => up.push(c),
                    Ok(c) => down.push(c),
                    Err(why) => return Ok(Err(why)),
                }
            }
        }
        runs.push((v, up, down));
    }
    Ok(sampling_from_centres(&runs).map(|(s, u)| Sampling {
        device: cfg.device.clone(),
        after_ms: 1e3 * s,
        u_ms: 1e3 * u,
        assumed_ms: 1e3 * assumed_s,
    }))
}

/// The axes' findings on one controller in one: their mean weighted by their uncertainties, the larger of the
/// combined uncertainty and their scatter.
pub(super) fn combined(found: &[Sampling]) -> Option<Sampling> {
    let first = found.first()?;
    let weights: Vec<f64> = found.iter().map(|s| 1.0 / s.u_ms.max(1e-6).powi(2)).collect();
    let total: f64 = weights.iter().sum();
    let mean = found
        .iter()
        .zip(&weights)
        .map(|(s, w)| s.after_ms * w)
        .sum::<f64>()
        / total;
    let scatter = found
        .iter()
        .map(|s| (s.after_ms - mean).abs())
        .fold(0.0, f64::max);
    Some(Sampling {
        device: first.device.clone(),
        after_ms: mean,
        u_ms: (1.0 / total.sqrt()).max(scatter),
        assumed_ms: found.iter().map(|s| s.assumed_ms).fold(0.0, f64::max),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::align::centre::Located;

    fn profile() -> Profile {
        Profile {
            centre: Located { value: 180.0, u: 0.0 },
            low: Located { value: 179.4, u: 0.0 },
            high: Located { value: 180.6, u: 0.0 },
            plateau_w: 1.0,
            base_w: 0.0,
            edge_width_deg: 0.2,
            readings: 0,
        }
    }

    /// A beam 1.2 deg wide with edges 0.2 deg from 15 % to 85 % (an error function), centred on `c`.
    fn beam(x: f64, c: f64) -> f64 {
        let edge = |d: f64| 0.5 * (1.0 + libm_erf(d / 0.0985));
        edge(x - (c - 0.6)) * edge((c + 0.6) - x)
    }

    fn libm_erf(x: f64) -> f64 {
        // Abramowitz and Stegun 7.1.26 (1.5e-7): enough for a test's edge.
        let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
        let y = 1.0
            - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
                + 0.254_829_592)
                * t
                * (-x * x).exp();
        y.copysign(x)
    }

    #[test]
    fn a_pass_finds_the_beams_centroid() {
        let readings: Vec<(f64, f64)> = (0..450)
            .map(|k| {
                let x = 178.5 + 0.0067 * f64::from(k);
                (x, beam(x, 180.013))
            })
            .collect();
        let (c, u) = pass_centre(&readings, &profile()).expect("centre");
        assert!((c - 180.013).abs() < 1e-4, "{c}");
        assert!(u < 1e-12, "no scatter on the baseline: {u}");
        assert!(pass_centre(&readings[..200], &profile()).is_err());
        // A step-sharp beam read every 0.01 deg, each reading the share of its arc the beam covers: still its
        // centre within a small part of the spacing.
        let step = |x: f64| {
            let (a, b) = (x - 0.005, x + 0.005);
            ((b.min(180.6037) - a.max(179.4037)).max(0.0)) / 0.01
        };
        let readings: Vec<(f64, f64)> = (0..300)
            .map(|k| {
                let x = 178.5 + 0.01 * f64::from(k);
                (x, step(x))
            })
            .collect();
        let (c, _) = pass_centre(&readings, &profile()).expect("centre");
        assert!((c - 180.0037).abs() < 2e-4, "{c}");
    }

    #[test]
    fn the_sampling_instant_comes_from_the_speeds_difference() {
        // Taken 4 ms after the query was sent, with a play of 0.01 deg the file does not know of: seen up at c + v s + b/2,
        // down at c - v s - b/2.
        let (s, b) = (0.004, 0.01);
        let runs: Vec<SpeedRuns> = [8.0, 2.0]
            .iter()
            .map(|&v| {
                let seen = |sign: f64, k: f64| (180.0 + sign * (v * s + 0.5 * b) + 1e-4 * k, 1e-4);
                (
                    v,
                    (0..3).map(|k| seen(1.0, f64::from(k))).collect(),
                    (0..3).map(|k| seen(-1.0, f64::from(k))).collect(),
                )
            })
            .collect();
        let (got, u) = sampling_from_centres(&runs).expect("s");
        assert!((got - s).abs() < 1e-9, "{got}");
        assert!(u > 0.0 && u < 2e-5, "{u}");
        assert!(sampling_from_centres(&runs[..1]).is_err());
    }

    #[test]
    fn two_arms_on_one_controller_are_weighed_together() {
        let one = |after_ms: f64, u_ms: f64| Sampling {
            device: "arms".into(),
            after_ms,
            u_ms,
            assumed_ms: 5.0,
        };
        let c = combined(&[one(1.0, 0.1), one(1.2, 0.2)]).expect("combined");
        assert!((c.after_ms - 1.04).abs() < 1e-9, "{c:?}");
        // The scatter (0.16 ms from the mean) is larger than the combined 0.089 ms.
        assert!((c.u_ms - 0.16).abs() < 1e-9, "{c:?}");
        assert_eq!(combined(&[]), None);
    }
}
