//! The self-test: each device identified and exercised, and what the instrument file claims about the hardware
//! measured on it (each axis's top speed, acceleration, settle time and backlash, the wheel's time per position,
//! each device's reply latency, when the arms' controllers take their reported positions, the meter's dark and
//! noise per range), every figure against the file's value with a verdict.
//!
//! How each figure is measured (the fits are pure: `fit`):
//! - An axis's top speed and acceleration: a long move of that axis alone (the arms parked apart, in the order
//!   they have after homing), its read-back sampled as fast as the controller answers. The slope of position
//!   against time over the middle of the move is the top speed; the first ramp, where `|p - p0| = a t^2 / 2`,
//!   gives the acceleration. The move is commanded at the file's own speed and acceleration: hardware slower
//!   than the file shows, hardware faster does not (the file's value is then what it runs at, and passes).
//! - The wheel's time per position: one step against half a turn, timed from command to verified arrival (the
//!   fixed cost of each turn cancels), after a full turn through every position.
//! - Reply latency: ten position queries of each device, timed; a motion controller's time beyond its reply's
//!   time on the line is its `reply_latency_ms`, which the time model adds to each exchange (`measure_latency`).
//! - Dark and noise: the blank in the beam, the meter fixed on each of its ranges in turn, readings' mean and
//!   spread; the head's dark current (`detector.dark_current_a`) from the smallest range's, its amplifier's
//!   current noise (`detector.amplifier_noise_a_per_rthz`) from that range's scatter at averaging 1, and the source's
//!   white relative noise (`source.relative_noise`) from readings of the direct beam at averaging 1 while the
//!   holder is empty for the settle times (`noise`: how, and what ambient light does to a dark).
//!
//! - When each swept arm's controller takes the positions it reports (`position_sampled_ms`): the direct beam
//!   swept both ways at two speeds, last while the holder is empty (`sweep_timing`).
//! - Settle time and backlash: the meter on a sharp edge in the beam, the direct beam's for the arms and a
//!   mirror's reflection for the tilt (`settle`, the fit in `ringdown`); the rotation's are not observable that
//!   way, and the report says so. The settle time fails only when the hardware needs longer than the file
//!   waits (a shorter one is not wrong); the backlash fails either way.

mod amplifier;
mod fit;
mod noise;
mod report;
mod ringdown;
mod settle;
mod sweep_timing;

pub use noise::{AMBIENT_ALLOWANCE, FLICKER_ALLOWANCE, FLICKER_WINDOW_S, MAX_FILL, NOISE_READINGS};
pub use report::{Check, SelftestReport, Verdict, against, at_most, info, within};
pub use settle::{SETTLE_REPEATS, STEP_DEG};

use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::timing::exchange_s;

use crate::align::Placement;
use crate::motion::{Device, Motion, MotionError};
use crate::rig::RigAxis;
use fit::{Sample, cruise_speed, mean_std, ramp_acceleration};

/// Relative tolerance of a measured figure against the file's, unless told otherwise.
pub const DEFAULT_TOLERANCE: f64 = 0.10;
/// Position queries per device for its latency.
const LATENCY_QUERIES: usize = 10;
/// A motion controller's reply latency passes within this of the file's (ms): the host sees replies at whole
/// milliseconds (a USB-serial adapter's latency timer).
pub const LATENCY_ALLOWED_MS: f64 = 1.0;
/// The measured moves stay this far (deg) inside each axis's travel and beyond the arms' safety separation.
const MARGIN_DEG: f64 = 5.0;

/// Run the self-test on the instrument under `motion` (module doc). `tolerance`: relative, e.g. 0.1.
/// `operator` is asked to empty the sample holder, then to mount the alignment mirror, and returns when done.
pub async fn run_selftest(
    motion: &mut Motion<'_>,
    tolerance: f64,
    operator: &dyn Fn(Placement) -> Result<(), String>,
) -> Result<SelftestReport, MotionError> {
    let rig = motion.rig();
    let clock = motion.clock();
    let t0 = clock.now_s();
    let file = rig.file().clone();
    let devices = rig.identities().await;
    tracing::info!("self-test: referencing the axes");
    motion.reference_all().await?;
    let mut checks = Vec::new();
    let mut not_measured = Vec::new();
    let mut accelerations = std::collections::BTreeMap::new();

    for a in rig.axes() {
        match measure_axis(motion, a).await? {
            Some((speed, accel)) => {
                accelerations.insert(a.config.name.clone(), accel);
                let key = |k: &str| format!("axes.{}.{k}", a.config.name);
                checks.push(against(
                    key("max_speed_deg_s"),
                    "top speed",
                    "deg/s",
                    a.config.max_speed_deg_s,
                    speed,
                    tolerance,
                ));
                checks.push(against(
                    key("accel_deg_s2"),
                    "acceleration",
                    "deg/s^2",
                    a.config.accel_deg_s2,
                    accel,
                    tolerance,
                ));
            }
            None => not_measured.push(format!(
                "axes.{}: its travel leaves no room for a move long enough to cruise",
                a.config.name
            )),
        }
    }
    if let Some(sps) = measure_wheel(motion).await? {
        if let Some(w) = &file.instrument.filter_wheel {
            checks.push(against(
                "filter_wheel.seconds_per_position".into(),
                "wheel time per position",
                "s",
                w.seconds_per_position,
                sps,
                tolerance,
            ));
        }
    }
    checks.extend(measure_latency(motion, tolerance).await?);
    let meter = noise::measure_meter(motion, tolerance).await?;
    checks.extend(meter.checks);
    not_measured.extend(meter.not_measured);
    if let Some(nm) = meter.blank_at_nm {
        match amplifier::measure(motion, nm, tolerance).await? {
            Ok(check) => checks.push(check),
            Err(e) => not_measured.push(format!("detector.amplifier_noise_a_per_rthz: {e}")),
        }
    }
    let settling = settle::measure_settling(motion, operator, tolerance, &accelerations).await?;
    checks.extend(settling.checks);
    not_measured.extend(settling.not_measured);
    checks.extend(sampling_checks(&file, &settling.sampling));
    Ok(SelftestReport {
        instrument: file.instrument.name.clone(),
        dry_run: rig.is_dry_run(),
        tolerance,
        devices,
        checks,
        not_measured,
        instrument_s: clock.now_s() - t0,
    })
}

/// Each swept controller's sampling instant (`sweep_timing`, its arms' findings together) against the file's
/// `position_sampled_ms`; a file silent on it is held to what a sweep then assumes, the middle of the window
/// between a query's arrival and its reply. Passes within [`LATENCY_ALLOWED_MS`] or three standard
/// uncertainties.
fn sampling_checks(file: &gonio_instrument::InstrumentFile, found: &[sweep_timing::Sampling]) -> Vec<Check> {
    let devices: std::collections::BTreeSet<&str> = found.iter().map(|s| s.device.as_str()).collect();
    devices
        .into_iter()
        .filter_map(|name| {
            let mine: Vec<_> = found.iter().filter(|s| s.device == name).cloned().collect();
            let s = sweep_timing::combined(&mine)?;
            let said = file.instrument.device(name).and_then(|d| d.position_sampled_ms);
            let mut check = within(
                format!("devices.{name}.position_sampled_ms"),
                "position taken after the query is sent (direct beam swept both ways)",
                "ms",
                said.unwrap_or(s.assumed_ms),
                s.after_ms,
                LATENCY_ALLOWED_MS.max(3.0 * s.u_ms),
            );
            check.assumed = said.is_none();
            Some(check)
        })
        .collect()
}

/// The span (deg) an axis's measured move covers, with every other axis parked where the move is safe:
/// (pose at the start, end of the move), or None when the travel is too short.
fn measured_move(motion: &Motion<'_>, a: &RigAxis) -> Option<(Pose, f64)> {
    let file = motion.rig().file();
    let inst = &file.instrument;
    let sep = inst.safety.min_arm_separation_deg + MARGIN_DEG;
    let here = *motion.current();
    // The arms' order as homing left them (detector above the light arm when they are together).
    let order = if here.detector_deg >= here.light_deg {
        1.0
    } else {
        -1.0
    };
    let role_axis = |r: AxisRole| inst.axis(r);
    let mut start = here;
    let (lo, hi) = (a.config.min_deg + MARGIN_DEG, a.config.max_deg - MARGIN_DEG);
    let (from, to) = match a.config.role {
        AxisRole::DetectorArm => {
            // The light arm parked at the end of its travel away from the detector.
            let light = role_axis(AxisRole::LightArm);
            let park = light.map(|l| {
                if order > 0.0 {
                    l.min_deg + MARGIN_DEG
                } else {
                    l.max_deg - MARGIN_DEG
                }
            });
            if let Some(p) = park {
                start.light_deg = p;
            }
            match (park, order > 0.0) {
                (Some(p), true) => ((p + sep).max(lo), hi),
                (Some(p), false) => ((p - sep).min(hi), lo),
                (None, _) => (lo, hi),
            }
        }
        AxisRole::LightArm => {
            let detector = role_axis(AxisRole::DetectorArm);
            let park = detector.map(|d| {
                if order > 0.0 {
                    d.max_deg - MARGIN_DEG
                } else {
                    d.min_deg + MARGIN_DEG
                }
            });
            if let Some(p) = park {
                start.detector_deg = p;
            }
            match (park, order > 0.0) {
                (Some(p), true) => (lo, (p - sep).min(hi)),
                (Some(p), false) => (hi, (p + sep).max(lo)),
                (None, _) => (lo, hi),
            }
        }
        _ => (lo, hi),
    };
    // Long enough to cruise: twice the ramp at the file's speed and acceleration, and a cruise as long again.
    let ramp = a.config.max_speed_deg_s.powi(2) / a.config.accel_deg_s2;
    if !((to - from).abs() > 2.0 * ramp && (to - from).abs() > 10.0) {
        return None;
    }
    start.set(a.config.role, from);
    Some((start, to))
}

/// Top speed and acceleration of one axis (module doc), or None when its travel is too short.
async fn measure_axis(motion: &mut Motion<'_>, a: &RigAxis) -> Result<Option<(f64, f64)>, MotionError> {
    let Some((start, to)) = measured_move(motion, a) else {
        return Ok(None);
    };
    let name = &a.config.name;
    tracing::info!(axis = %name, "self-test: measuring top speed and acceleration");
    motion.move_to(&start).await?;
    let from = start.get(a.config.role);
    let (v, acc) = (a.config.max_speed_deg_s, a.config.accel_deg_s2);
    motion
        .device(Device::Axis(a), &format!("set the speed of {name}"), || {
            a.driver.set_speed(v, acc)
        })
        .await?;
    let samples = sample_move(motion, a, to).await?;
    motion.read_positions().await?;
    // Back to the start the other way, which also exercises the axis in both directions.
    motion.move_to(&start).await?;
    let Some(speed) = cruise_speed(&samples, from, to) else {
        return Ok(None);
    };
    Ok(ramp_acceleration(&samples, from, speed).map(|accel| (speed, accel)))
}

/// Command `a` to `to_deg` and read its position back as fast as it answers until it arrives (within its
/// tolerance), then wait for the controller's verified arrival.
async fn sample_move(motion: &Motion<'_>, a: &RigAxis, to_deg: f64) -> Result<Vec<Sample>, MotionError> {
    let tolerance = a.config.tolerance_deg;
    let samples = start_and_sample(motion, a, to_deg, &|s: &[Sample]| {
        s.last().is_some_and(|(_, p)| (p - to_deg).abs() <= tolerance)
    })
    .await?;
    arrive(motion, a, to_deg).await?;
    Ok(samples)
}

/// Start a plain move of `a` to `to_deg` (no backlash approach: the approach's direction is the caller's).
async fn start(motion: &Motion<'_>, a: &RigAxis, to_deg: f64) -> Result<(), MotionError> {
    let name = &a.config.name;
    motion
        .device(
            Device::Axis(a),
            &format!("start {name} to {to_deg:.4} deg"),
            || a.driver.start_move(to_deg),
        )
        .await
}

/// Wait for the controller's verified arrival of `a` at `to_deg`.
async fn arrive(motion: &Motion<'_>, a: &RigAxis, to_deg: f64) -> Result<(), MotionError> {
    let name = &a.config.name;
    motion
        .device(
            Device::Axis(a),
            &format!("{name} arrives at {to_deg:.4} deg"),
            || a.driver.wait_arrived(to_deg),
        )
        .await
        .map(|_| ())
}

/// Command `a` to `to_deg` (a plain move, no backlash approach) and read its position back as fast as it
/// answers until `done` says so of the samples so far, within a deadline of three times the move's predicted
/// duration and ten seconds more. The caller waits for the verified arrival.
async fn start_and_sample(
    motion: &Motion<'_>,
    a: &RigAxis,
    to_deg: f64,
    done: &dyn Fn(&[Sample]) -> bool,
) -> Result<Vec<Sample>, MotionError> {
    let clock = motion.clock();
    let name = &a.config.name;
    let from = motion.current().get(a.config.role);
    let predicted_s = gonio_driver::motion::trapezoid_time_s(
        (to_deg - from).abs(),
        a.config.max_speed_deg_s,
        a.config.accel_deg_s2,
    );
    start(motion, a, to_deg).await?;
    let deadline_s = clock.now_s() + 3.0 * predicted_s + 10.0;
    let mut samples = Vec::new();
    loop {
        if clock.now_s() > deadline_s {
            let _ = a.driver.stop().await;
            return Err(MotionError::Device(format!(
                "{name} did not reach {to_deg:.3} deg within {:.1} s (predicted {predicted_s:.1} s)",
                3.0 * predicted_s + 10.0
            )));
        }
        let t_before = clock.now_s();
        // One attempt per sample: a lost reply is a missing sample, not a failed test (the deadline bounds it).
        let Ok(p) = a.driver.position_deg().await else {
            continue;
        };
        let t = 0.5 * (t_before + clock.now_s());
        samples.push((t, p));
        if done(&samples) {
            return Ok(samples);
        }
    }
}

/// The wheel's seconds per position (module doc); None without a wheel of at least 4 positions.
async fn measure_wheel(motion: &Motion<'_>) -> Result<Option<f64>, MotionError> {
    let Some(wheel) = motion.rig().wheel() else {
        return Ok(None);
    };
    let n = motion
        .device(Device::Wheel, "wheel position count", || wheel.position_count())
        .await?;
    if n < 4 {
        return Ok(None);
    }
    tracing::info!(
        positions = n,
        "self-test: a full turn of the wheel, then its time per position"
    );
    for p in (1..=n).chain(std::iter::once(1)) {
        motion
            .device(Device::Wheel, &format!("turn the wheel to {p}"), || {
                wheel.go_to(p)
            })
            .await?;
    }
    let clock = motion.clock();
    let half = n / 2;
    let timed = |to: u8| async move {
        let t = clock.now_s();
        motion
            .device(Device::Wheel, &format!("turn the wheel to {to}"), || {
                wheel.go_to(to)
            })
            .await?;
        Ok::<f64, MotionError>(clock.now_s() - t)
    };
    let one = timed(2).await?;
    let back = timed(1).await?;
    let far = timed(1 + half).await?;
    let step = 0.5 * (one + back);
    Ok(Some((far - step) / f64::from(half - 1)))
}

/// Each device's reply latency (ms). A motion controller's is held against the file's `reply_latency_ms` (none
/// when absent), which the time model adds to every exchange with it: the median time of one position query
/// beyond what the model gives an exchange with that reply ([`exchange_s`]: its bytes on the line, seen at the
/// next whole millisecond), so that the file written with it makes the model's exchanges take what they took
/// here. It passes within [`LATENCY_ALLOWED_MS`] or the tolerance of the file's value. The wheel's and the
/// meter's are for the record.
async fn measure_latency(motion: &Motion<'_>, tolerance: f64) -> Result<Vec<Check>, MotionError> {
    let rig = motion.rig();
    let clock = motion.clock();
    let mut out = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for a in rig.axes() {
        if !seen.insert(a.config.device.clone()) {
            continue;
        }
        let Some(device) = rig.file().instrument.device(&a.config.device) else {
            continue;
        };
        let baud = device.line_baud();
        let mut beyond_ms = Vec::new();
        for _ in 0..LATENCY_QUERIES {
            let t = clock.now_s();
            let report = motion
                .device(Device::Axis(a), "position query", || a.driver.position_report())
                .await?;
            let took_s = clock.now_s() - t;
            beyond_ms.push(1e3 * (took_s - exchange_s(report.reply_bytes, baud)).max(0.0));
        }
        beyond_ms.sort_by(f64::total_cmp);
        if let Some(median) = beyond_ms.get(beyond_ms.len() / 2) {
            let configured = device.reply_latency_ms.unwrap_or(0.0);
            out.push(within(
                format!("devices.{}.reply_latency_ms", a.config.device),
                "reply latency beyond the line (position query)",
                "ms",
                configured,
                *median,
                (tolerance * configured).max(LATENCY_ALLOWED_MS),
            ));
        }
    }
    if let Some(w) = rig.wheel() {
        let mut times = Vec::new();
        for _ in 0..LATENCY_QUERIES {
            let t = clock.now_s();
            motion
                .device(Device::Wheel, "wheel position query", || w.position())
                .await?;
            times.push(1e3 * (clock.now_s() - t));
        }
        if let (Some((mean, _)), Some(cfg)) = (mean_std(&times), &rig.file().instrument.filter_wheel) {
            out.push(info(
                format!("latency.{}", cfg.device),
                "reply to a position query",
                "ms",
                mean,
            ));
        }
    }
    let det = rig.detector();
    let mut times = Vec::new();
    for _ in 0..LATENCY_QUERIES {
        let t = clock.now_s();
        motion
            .device(Device::Detector, "meter identification", || det.identify())
            .await?;
        times.push(1e3 * (clock.now_s() - t));
    }
    if let Some((mean, _)) = mean_std(&times) {
        let name = &rig.file().instrument.detector.device;
        out.push(info(format!("latency.{name}"), "reply to *IDN?", "ms", mean));
    }
    Ok(out)
}
