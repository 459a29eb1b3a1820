//! Each axis's settle time and backlash, from the meter on a sharp intensity edge in the beam: what a real
//! instrument has (the engine never asks the simulator).
//!
//! The edges: the direct beam's (the operator empties the holder) for the detector arm and the light arm, the
//! arms facing each other (crate::align's direct-beam poses and its scan); a mirror's reflection (the operator
//! mounts it) for the sample tilt, which turns the reflection twice as fast. Each scan's low half-height edge
//! is where the reading changes fastest with the axis's position.
//! - Backlash: fine readings across the edge approached from below, then from above, each position reached by a
//!   plain move without the drivers' backlash approach. From above the load lags the motor by the play, so the
//!   edge appears that much lower in the commanded positions. The positions are the commanded ones, which the
//!   controllers servo the motor to (a load-side encoder's read-back would hide the play).
//! - Settle time: the axis steps [`STEP_DEG`] away and comes back to the edge; its read-back is sampled as fast
//!   as the controller answers to time the stop (each sample of the last stretch of the deceleration says when
//!   the motor will stop, at the acceleration measured before), then the meter is read as fast as it can be (no
//!   averaging, a fixed range). The readings' difference from their final level over the edge's slope is the
//!   load's displacement, whose settle time within the axis's tolerance `ringdown` finds; the median of
//!   [`SETTLE_REPEATS`] steps.
//! - The sample rotation turns the mirror about its own normal: nothing in the beam moves with it, so its settle
//!   time and backlash are not observable this way; the report says so.

use std::collections::BTreeMap;

use gonio_driver::{DetectorConfig, PowerRange};
use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;

use super::fit::{line, mean_std};
use super::report::{Check, at_most, within};
use super::ringdown::settle_time_s;
use super::sweep_timing::{Sampling, measure_sampling};
use super::{arrive, start, start_and_sample};
use crate::align::centre::edge;
use crate::align::scan::{DETECTOR_HALF_WIDTH_DEG, Profile, meter_ranges_w, scan, tilt_half_width_deg};
use crate::align::{AlignError, Placement, arms_order, direct_beam_light_angles, model, put_band_in_beam};
use crate::motion::{Device, Motion, MotionError};
use crate::rig::RigAxis;

/// The settle time's step away from the edge and back (deg): a typical move between two points of a campaign.
pub const STEP_DEG: f64 = 2.0;
/// Settle-time steps per axis (their median is reported).
pub const SETTLE_REPEATS: usize = 3;
/// Readings on each side's fine scan across the edge.
const FINE_POINTS: i32 = 17;
/// The mirror's incidence for the tilt's edge (deg from the normal).
const TILT_INCIDENCE_DEG: f64 = 45.0;
/// The most readings one settle step takes.
const MAX_FAST_READINGS: usize = 20_000;
/// A fine scan starts this far (deg) beyond its first position, at least: more than any plausible play.
const PLAY_MARGIN_DEG: f64 = 0.05;

/// The lines and the gaps of this part of the self-test.
#[derive(Debug, Default)]
pub(super) struct Findings {
    pub checks: Vec<Check>,
    pub not_measured: Vec<String>,
    /// When each swept arm's controller takes its reported positions (`sweep_timing`).
    pub sampling: Vec<Sampling>,
}

/// What one axis's edge gave.
struct EdgeFigures {
    settle_s: f64,
    backlash_deg: f64,
    backlash_u_deg: f64,
}

/// An alignment error that is the instrument's motion failing stops the self-test; any other (no beam, no
/// pose for it) only leaves the figures unmeasured, with the reason.
fn reason(e: AlignError) -> Result<String, MotionError> {
    match e {
        AlignError::Motion(m) => Err(m),
        other => Ok(other.to_string()),
    }
}

/// Settle time and backlash of every axis (module doc). `operator` is asked to empty the holder and to mount
/// the mirror; `accel_deg_s2` holds the accelerations measured before, by axis name.
pub(super) async fn measure_settling(
    motion: &mut Motion<'_>,
    operator: &dyn Fn(Placement) -> Result<(), String>,
    tolerance: f64,
    accel_deg_s2: &BTreeMap<String, f64>,
) -> Result<Findings, MotionError> {
    let rig = motion.rig();
    let inst = &rig.file().instrument;
    let mut out = Findings::default();
    let unmeasured = |out: &mut Findings, a: &str, why: &str| {
        out.not_measured
            .push(format!("axes.{a}.settle_s and backlash_deg: {why}"));
    };
    for a in rig
        .axes()
        .iter()
        .filter(|a| a.config.role == AxisRole::SampleRotation)
    {
        unmeasured(
            &mut out,
            &a.config.name,
            "not observable (the rotation turns the mirror about its own normal and the direct beam not at \
             all: no edge in the beam moves with it)",
        );
    }
    let (Some(light), Some(detector)) = (
        rig.axes().iter().find(|a| a.config.role == AxisRole::LightArm),
        rig.axes().iter().find(|a| a.config.role == AxisRole::DetectorArm),
    ) else {
        for a in rig
            .axes()
            .iter()
            .filter(|a| a.config.role != AxisRole::SampleRotation)
        {
            unmeasured(
                &mut out,
                &a.config.name,
                "not measured (they need a light arm and a detector arm)",
            );
        }
        return Ok(out);
    };
    let tilt = rig.axes().iter().find(|a| a.config.role == AxisRole::SampleTilt);
    let optical = [Some(detector), Some(light), tilt];
    let skip_all = |out: &mut Findings, why: &str| {
        for a in optical.iter().flatten() {
            unmeasured(out, &a.config.name, &format!("not measured ({why})"));
        }
    };
    let prepared = async {
        let band_nm = put_band_in_beam(motion).await?;
        let light_deg = *direct_beam_light_angles(motion)?.first().unwrap_or(&-90.0);
        Ok::<_, AlignError>((band_nm, light_deg))
    }
    .await;
    let (band_nm, light_deg) = match prepared {
        Ok(v) => v,
        Err(e) => {
            skip_all(&mut out, &reason(e)?);
            return Ok(out);
        }
    };
    let meter = Meter {
        band_nm,
        averaging: inst.detector.averaging,
    };
    meter.auto(motion).await?;
    if let Err(e) = operator(Placement::Empty) {
        skip_all(&mut out, &format!("operator step not done: {e}"));
        return Ok(out);
    }
    let record = |out: &mut Findings, a: &RigAxis, got: Result<EdgeFigures, String>| {
        let key = |k: &str| format!("axes.{}.{k}", a.config.name);
        match got {
            Ok(f) => {
                out.checks.push(at_most(
                    key("settle_s"),
                    "settle time (meter on an edge)",
                    "s",
                    a.config.settle_s,
                    f.settle_s,
                    tolerance,
                ));
                // A claim of 0 allows no relative tolerance: the measurement's own uncertainty and the
                // encoder's resolution are the least that can be told apart.
                let allowed = (tolerance * a.config.backlash_deg)
                    .max(3.0 * f.backlash_u_deg)
                    .max(a.config.encoder_resolution_deg);
                out.checks.push(within(
                    key("backlash_deg"),
                    "backlash (edge from below and from above)",
                    "deg",
                    a.config.backlash_deg,
                    f.backlash_deg,
                    allowed,
                ));
            }
            Err(why) => unmeasured(out, &a.config.name, &format!("not measured ({why})")),
        }
    };
    let accel = |a: &RigAxis| {
        accel_deg_s2
            .get(&a.config.name)
            .copied()
            .unwrap_or(a.config.accel_deg_s2)
    };

    // The detector arm across the direct beam, then the light arm with the detector on the beam.
    let (mut detector_profile, mut light_profile) = (None, None);
    let facing = model::wrap_deg(light_deg + 180.0);
    let at_detector = |x: f64| Pose::new(light_deg, x, 0.0, 0.0);
    let detector_centre = match scan(
        motion,
        "self-test: direct beam, detector arm",
        AxisRole::DetectorArm,
        facing,
        DETECTOR_HALF_WIDTH_DEG,
        &at_detector,
    )
    .await
    {
        Ok(p) => {
            let got = edge_figures(motion, detector, &p, &meter, accel(detector)).await?;
            record(&mut out, detector, got);
            detector_profile = Some(p);
            p.centre.value
        }
        Err(e) => {
            let why = reason(e)?;
            unmeasured(&mut out, &detector.config.name, &format!("not measured ({why})"));
            facing
        }
    };
    let at_light = |x: f64| Pose::new(x, detector_centre, 0.0, 0.0);
    let got = match scan(
        motion,
        "self-test: direct beam, light arm",
        AxisRole::LightArm,
        light_deg,
        DETECTOR_HALF_WIDTH_DEG,
        &at_light,
    )
    .await
    {
        Ok(p) => {
            let got = edge_figures(motion, light, &p, &meter, accel(light)).await?;
            light_profile = Some(p);
            got
        }
        Err(e) => Err(reason(e)?),
    };
    record(&mut out, light, got);
    // The source's relative noise on the direct beam while the holder is still empty (crate::selftest::noise).
    match super::noise::source_noise(motion, &at_detector(detector_centre), band_nm, tolerance).await? {
        Ok((c, (nm, range_w))) => {
            out.checks.push(c);
            match super::noise::source_flicker(motion, nm, range_w).await? {
                Ok(c) => out.checks.push(c),
                Err(why) => out
                    .not_measured
                    .push(format!("source.flicker_rel: not measured ({why})")),
            }
        }
        Err(why) => out.not_measured.push(format!(
            "source.relative_noise, source.flicker_rel: not measured ({why})"
        )),
    }
    meter.auto(motion).await?;
    // When the arms' controllers take their reported positions, the same beam swept: last in the direct beam,
    // so that the figures above are read as they were before this step existed.
    if let Some(p) = detector_profile {
        sampling(motion, &mut out, detector, &p, &at_detector, &meter).await?;
    }
    // One axis per controller: the light arm only when the detector arm's controller is another.
    if let Some(p) = light_profile.filter(|_| !out.sampling.iter().any(|s| s.device == light.config.device)) {
        sampling(motion, &mut out, light, &p, &at_light, &meter).await?;
    }

    // The tilt across the mirror's reflection, the detector where the reflection is.
    if let Some(tilt) = tilt {
        if let Err(e) = operator(Placement::Mirror) {
            unmeasured(
                &mut out,
                &tilt.config.name,
                &format!("not measured (operator step not done: {e})"),
            );
            return Ok(out);
        }
        let light_deg = -arms_order(motion) * TILT_INCIDENCE_DEG;
        let at_reflection = |x: f64| Pose::new(light_deg, x, 0.0, 0.0);
        let found = async {
            let d = scan(
                motion,
                "self-test: mirror, detector arm",
                AxisRole::DetectorArm,
                -light_deg,
                DETECTOR_HALF_WIDTH_DEG,
                &at_reflection,
            )
            .await?;
            let at_tilt = |x: f64| Pose::new(light_deg, d.centre.value, x, 0.0);
            scan(
                motion,
                "self-test: mirror, sample tilt",
                AxisRole::SampleTilt,
                0.0,
                tilt_half_width_deg(TILT_INCIDENCE_DEG),
                &at_tilt,
            )
            .await
        }
        .await;
        let got = match found {
            Ok(p) => edge_figures(motion, tilt, &p, &meter, accel(tilt)).await?,
            Err(e) => Err(reason(e)?),
        };
        record(&mut out, tilt, got);
    }
    motion.read_positions().await?;
    Ok(out)
}

/// When `a`'s controller takes its reported positions, swept across the beam `profile` (`sweep_timing`): into
/// `out`'s findings, or why not into its gaps. The meter is left auto-ranging.
async fn sampling(
    motion: &mut Motion<'_>,
    out: &mut Findings,
    a: &RigAxis,
    profile: &Profile,
    at: &(dyn Fn(f64) -> Pose + Sync),
    meter: &Meter,
) -> Result<(), MotionError> {
    let full_scale_w = fixed_range_w(motion, profile.plateau_w);
    let got = measure_sampling(motion, a, profile, at, meter.band_nm, full_scale_w).await;
    meter.auto(motion).await?;
    match got? {
        Ok(s) => out.sampling.push(s),
        Err(why) => out.not_measured.push(format!(
            "devices.{}.position_sampled_ms from {}: not measured ({why})",
            a.config.device, a.config.name
        )),
    }
    Ok(())
}

/// The meter's settings for the edges.
struct Meter {
    band_nm: f64,
    averaging: u32,
}

impl Meter {
    /// Auto-ranging, the file's averaging (the scans).
    async fn auto(&self, motion: &Motion<'_>) -> Result<(), MotionError> {
        self.set(motion, self.averaging, PowerRange::Auto).await
    }

    /// As fast as the meter reads (no averaging) on a fixed range (the settle time's readings).
    async fn fast(&self, motion: &Motion<'_>, full_scale_w: f64) -> Result<(), MotionError> {
        self.set(motion, 1, PowerRange::Fixed { full_scale_w }).await
    }

    async fn set(&self, motion: &Motion<'_>, averaging: u32, range: PowerRange) -> Result<(), MotionError> {
        let det = motion.rig().detector();
        let config = DetectorConfig {
            wavelength_nm: self.band_nm,
            averaging,
            range,
        };
        motion
            .device(Device::Detector, "configure the meter", || det.configure(config))
            .await
    }
}

/// One reading (W, the time in the middle of its query), or why it is not a measurement.
async fn read_w(motion: &Motion<'_>) -> Result<Result<(f64, f64), String>, MotionError> {
    let det = motion.rig().detector();
    let clock = motion.clock();
    let t = clock.now_s();
    let r = motion
        .device(Device::Detector, "read the meter", || det.read_power())
        .await?;
    let mid = 0.5 * (t + clock.now_s());
    Ok(if r.overload {
        Err(format!(
            "the meter is over its {:e} W range on the edge",
            r.range_w
        ))
    } else {
        Ok((mid, r.power_w))
    })
}

/// The meter's smallest range that holds `plateau_w` with a fifth to spare (else its largest): the fixed range
/// of the fast readings on an edge.
fn fixed_range_w(motion: &Motion<'_>, plateau_w: f64) -> f64 {
    let ranges = meter_ranges_w(motion);
    let fitting = ranges
        .iter()
        .copied()
        .filter(|r| *r >= 1.2 * plateau_w)
        .fold(f64::INFINITY, f64::min);
    if fitting.is_finite() {
        fitting
    } else {
        ranges.iter().copied().fold(0.0, f64::max)
    }
}

/// A plain move of `a` alone to `to_deg` (no backlash approach: the approach's direction is the caller's).
async fn plain_move(motion: &Motion<'_>, a: &RigAxis, to_deg: f64) -> Result<(), MotionError> {
    start(motion, a, to_deg).await?;
    arrive(motion, a, to_deg).await
}

/// Settle time and backlash of `a` on the low edge of `profile` (module doc), or why not.
async fn edge_figures(
    motion: &mut Motion<'_>,
    a: &RigAxis,
    profile: &Profile,
    meter: &Meter,
    accel_deg_s2: f64,
) -> Result<Result<EdgeFigures, String>, MotionError> {
    let cfg = &a.config;
    let clock = motion.clock();
    let x_edge = profile.low.value;
    let step = 1.5 * profile.edge_width_deg / f64::from(FINE_POINTS - 1);
    let half = (FINE_POINTS - 1) / 2;
    let xs: Vec<f64> = (-half..=half).map(|k| x_edge + f64::from(k) * step).collect();
    let play = (4.0 * cfg.backlash_deg).max(PLAY_MARGIN_DEG);
    // Long enough for the vibration of each small step to die down, four times over the file's settle time.
    let wait_s = (6.0 * cfg.settle_s).max(0.3);
    let inside = |x: f64| x >= cfg.min_deg && x <= cfg.max_deg;
    let (Some(&lowest), Some(&highest)) = (xs.first(), xs.last()) else {
        return Ok(Err("no fine positions".into()));
    };
    if !(inside(lowest - play) && inside(highest + play - cfg.backlash_deg)) {
        return Ok(Err("the edge is too near the end of the travel".into()));
    }
    tracing::info!(axis = %cfg.name, edge_deg = x_edge, "self-test: backlash across an edge");
    let mut sides = Vec::with_capacity(2);
    // From above, the positions are shifted down by the claimed play, so that the load stands where it stood
    // from below if the claim is right: the line through the edge's readings then meets the same stretch of
    // the edge's curve, and what remains is the difference from the claim.
    let claimed = cfg.backlash_deg;
    for (start, from_above) in [(lowest - play, false), (highest + play - claimed, true)] {
        plain_move(motion, a, start).await?;
        let mut pts = Vec::with_capacity(xs.len());
        let ordered: Vec<f64> = if from_above {
            xs.iter().rev().map(|x| x - claimed).collect()
        } else {
            xs.clone()
        };
        for x in ordered {
            plain_move(motion, a, x).await?;
            clock.sleep_s(wait_s).await;
            match read_w(motion).await? {
                Ok((_, w)) => pts.push((x, w)),
                Err(why) => return Ok(Err(why)),
            }
        }
        sides.push(pts);
    }
    let (plateau, base) = (profile.plateau_w, profile.base_w);
    let (up, down) = match (
        edge(&sides[0], plateau, base, "low"),
        edge(&sides[1], plateau, base, "low"),
    ) {
        (Ok(u), Ok(d)) => (u, d),
        (Err(e), _) | (_, Err(e)) => return Ok(Err(format!("the edge: {e}"))),
    };
    // The edge's slope (W/deg) from the readings from below between 15 % and 85 % of the way up.
    let span = plateau - base;
    let steep: Vec<(f64, f64)> = sides[0]
        .iter()
        .copied()
        .filter(|(_, w)| (0.15..=0.85).contains(&((w - base) / span)))
        .collect();
    let Some((slope, _)) = line(&steep).filter(|(s, _)| s.is_finite() && *s != 0.0) else {
        return Ok(Err("too few readings on the edge for its slope".into()));
    };

    tracing::info!(axis = %cfg.name, "self-test: settle time on the edge");
    let full_scale_w = fixed_range_w(motion, plateau);
    let from = if inside(x_edge - STEP_DEG) {
        x_edge - STEP_DEG
    } else {
        x_edge + STEP_DEG
    };
    let mut settles = Vec::with_capacity(SETTLE_REPEATS);
    for _ in 0..SETTLE_REPEATS {
        plain_move(motion, a, from).await?;
        clock.sleep_s(wait_s).await;
        meter.fast(motion, full_scale_w).await?;
        let got = settle_once(motion, a, x_edge, slope, accel_deg_s2).await;
        meter.auto(motion).await?;
        match got? {
            Ok(Some(s)) => settles.push(s),
            Ok(None) => {}
            Err(why) => return Ok(Err(why)),
        }
    }
    motion.read_positions().await?;
    settles.sort_by(f64::total_cmp);
    let Some(&settle_s) = settles.get(settles.len() / 2) else {
        return Ok(Err("no readings after the moves".into()));
    };
    Ok(Ok(EdgeFigures {
        settle_s,
        backlash_deg: up.value - down.value,
        backlash_u_deg: up.u.hypot(down.u),
    }))
}

/// One step back to the edge at `x_edge` and the meter read as fast as it answers: the settle time (s), None
/// when the readings say nothing, or why the step could not be made.
async fn settle_once(
    motion: &Motion<'_>,
    a: &RigAxis,
    x_edge: f64,
    slope_w_deg: f64,
    accel_deg_s2: f64,
) -> Result<Result<Option<f64>, String>, MotionError> {
    let cfg = &a.config;
    let clock = motion.clock();
    // The read-back as fast as the controller answers, until the motor is at the target (within half a count)
    // or stands still within the tolerance (a load-side encoder may show the play).
    let resolution = cfg.encoder_resolution_deg.max(1e-6);
    let at_target = |s: &[(f64, f64)]| match s {
        [.., (_, q), (_, p)] => {
            (p - x_edge).abs() <= 0.5 * resolution + 1e-12
                || ((q - p).abs() < 0.5 * resolution && (p - x_edge).abs() <= cfg.tolerance_deg)
        }
        [(_, p)] => (p - x_edge).abs() <= 0.5 * resolution + 1e-12,
        [] => false,
    };
    let approach = start_and_sample(motion, a, x_edge, &at_target).await?;
    let t_stop = stop_time_s(&approach, x_edge, accel_deg_s2, resolution);
    let window_s = (10.0 * cfg.settle_s).max(0.4);
    let mut readings = Vec::new();
    // Bounded by count as well as by time: a meter that answered in no time would not end the window.
    while clock.now_s() < t_stop + window_s && readings.len() < MAX_FAST_READINGS {
        match read_w(motion).await? {
            Ok((t, w)) => readings.push((t - t_stop, w)),
            Err(why) => return Ok(Err(why)),
        }
    }
    arrive(motion, a, x_edge).await?;
    // The final level and one reading's scatter from the last 40 % of the readings, long after the vibration.
    let tail = &readings[readings.len() * 3 / 5..];
    let Some((rest_w, noise_w)) = mean_std(&tail.iter().map(|r| r.1).collect::<Vec<_>>()) else {
        return Ok(Ok(None));
    };
    let displacement: Vec<(f64, f64)> = readings
        .iter()
        .map(|(t, w)| (*t, (w - rest_w) / slope_w_deg))
        .collect();
    Ok(Ok(settle_time_s(
        &displacement,
        cfg.tolerance_deg,
        noise_w / slope_w_deg.abs(),
    )))
}

/// When the motor stopped, from read-back samples `(t, deg)` of its approach to `target_deg`: on the last stretch
/// of the deceleration, `target - p = a (t_stop - t)^2 / 2`, so each sample says `t + sqrt(2 |target - p| / a)`;
/// the median of those a few counts to 0.05 deg short of the target, else the first sample at it.
fn stop_time_s(samples: &[(f64, f64)], target_deg: f64, accel_deg_s2: f64, resolution_deg: f64) -> f64 {
    let mut says: Vec<f64> = samples
        .iter()
        .filter_map(|&(t, p)| {
            let d = (target_deg - p).abs();
            (d >= 4.0 * resolution_deg && d <= 0.05 && accel_deg_s2 > 0.0)
                .then(|| t + (2.0 * d / accel_deg_s2).sqrt())
        })
        .collect();
    says.sort_by(f64::total_cmp);
    match says.get(says.len() / 2) {
        Some(&t) => t,
        None => samples.last().map_or(0.0, |s| s.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stop_is_timed_from_the_deceleration() {
        // A deceleration at 80 deg/s^2 that stops at t = 1.0 on 12.0 deg, sampled every 3 ms, quantised.
        let samples: Vec<(f64, f64)> = (0..60)
            .map(|k| {
                let t = 0.85 + 0.003 * f64::from(k);
                let u = (1.0 - t).max(0.0);
                let p = 12.0 - 40.0 * u * u;
                (t, (p / 0.0005).round() * 0.0005)
            })
            .collect();
        let t = stop_time_s(&samples, 12.0, 80.0, 0.0005);
        assert!((t - 1.0).abs() < 5e-4, "{t}");
        assert_eq!(stop_time_s(&[(2.0, 12.0)], 12.0, 80.0, 0.0005), 2.0);
    }
}
