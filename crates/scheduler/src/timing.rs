//! The time model: how long a move, a filter change and a reading take. The daemon executes moves exactly as
//! [`Move`] describes them (phases, waypoints), so that this prediction and the run agree.
//!
//! - One axis, distance `d`, top speed `v`, acceleration `a`: a trapezoidal (or, when short, triangular) profile,
//!   `t = d/v + v/a` if `d >= v^2/a`, else `t = 2 sqrt(d/a)`.
//! - Backlash: an axis with `backlash_deg > 0` always makes its final approach upwards in CONTROLLER
//!   coordinates. A move that ends downwards first goes [`BACKLASH_OVERSHOOT`] x backlash below the target,
//!   stops, and comes back up: two profiles back to back.
//! - All axes of a phase start together; the phase ends when the last one arrives. Normally a move is one phase.
//!   Moving both arms at once keeps [`TimeModel::arm_stopping_margin_deg`] more than that separation at every
//!   instant (if one arm stops dead, a stall, the other runs on until the engine sees it and stops it), unless
//!   the ranges the two arms sweep stay that separation apart: no stall can bring them closer then.
//!   When the simultaneous move would bring the arms closer than `min_arm_separation_deg` at some instant, the
//!   move is split into two phases: one arm (with tilt and rotation) first, then the other arm. One of the two
//!   orders is always safe when both end poses are (proof at [`TimeModel::plan_move`]).
//! - Settle: each axis that moved waits its `settle_s` after its own arrival; the move is over when the last
//!   axis has settled. `motion_s` is the time until the last arrival, `settle_s` the remainder.
//! - Filter wheel: `seconds_per_position` per step, the shortest way round. The wheel has 6 slots when no
//!   configured position exceeds 6, else 12 (the FW102C's two models).
//! - Reading: `averaging x` [`DETECTOR_SAMPLE_S`], plus the driver's range query ([`reading_time_s`]).
//! - Driver overheads the daemon really pays: each leg's exchanges before its motion starts and until its end is
//!   seen, by protocol and line speed (`legs`: the SMC100's pause after a move command, the status question at
//!   the predicted end, the read-back; none before the motion, the driver knowing where the axis came to rest);
//!   about [`EXCHANGE_S`] per request/reply of the meter and the wheel (a filter change is five).
//! - The wheel and the axes do not move at the same time (the daemon changes the filter once the axes have
//!   settled), so the parts of the breakdown add up.

//!
//! The single-axis and wheel models are in `profile`, the drivers' exchanges around a leg in `legs`; the whole
//! instrument's model and the move planner here.

mod legs;
mod profile;
mod trapezoid;

pub use legs::{ARRIVAL_MARGIN_S, LegTiming, SMC100_SET_GAP_S, exchange_s};
pub use profile::{AxisModel, WheelModel};
pub use trapezoid::{Trapezoid, trapezoid_time_s};

use gonio_instrument::{AxisRole, Instrument};

use crate::constraints::{ANGLE_TOLERANCE_DEG, Reason};
use crate::kinematics::{Pose, ROLES};

/// Time for one detector sample: the PM100 takes about 3 ms per averaged sample.
pub const DETECTOR_SAMPLE_S: f64 = 0.003;

/// Longest time the engine takes to see that an arm stopped short: while a move is predicted to run, the motion
/// drivers ask the controller's status at least every 50 ms.
pub const STALL_DETECTION_S: f64 = 0.05;

/// One request/reply round trip with a device: a USB transaction with the meter, or a short line and its echo
/// and prompt at 115200 baud on the wheel (about 1 ms).
pub const EXCHANGE_S: f64 = 0.001;

/// Exchanges of one reading beyond the measurement itself (the range query after `MEAS:POW?`).
const READING_EXCHANGES: f64 = 1.0;

/// Exchanges of one filter change: the driver asks the position count and the position, commands `pos=N`, and
/// checks the position after the prompt twice (a garbled digit must not confirm a wheel that did not turn).
const WHEEL_EXCHANGES: f64 = 5.0;

/// Duration of one detector reading with `averaging` samples, as the daemon takes it.
pub fn reading_time_s(averaging: u32) -> f64 {
    f64::from(averaging) * DETECTOR_SAMPLE_S + READING_EXCHANGES * EXCHANGE_S
}

/// A backlash approach starts this many backlash widths below the target.
pub const BACKLASH_OVERSHOOT: f64 = 2.0;

/// Displacements smaller than this (degrees) are not moves: no command, no settle.
const STILL_DEG: f64 = 1e-9;

/// One axis's motion within a move phase.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisMotion {
    pub role: AxisRole,
    /// Index of the axis in the instrument file's `[[instrument.axes]]` list.
    pub axis_index: usize,
    /// Controller positions (degrees) to command in turn: the target, preceded by the backlash overshoot point
    /// when the approach would otherwise end downwards.
    pub waypoints_deg: Vec<f64>,
    /// Duration of this axis's motion (all waypoints).
    pub duration_s: f64,
}

/// A move from one pose to the next, as the daemon must execute it.
#[derive(Debug, Clone, PartialEq)]
pub struct Move {
    /// Phases run one after the other; within a phase all axes start together and the phase ends when the last
    /// arrives. Axes that do not move are absent. Empty when nothing moves.
    pub phases: Vec<Vec<AxisMotion>>,
    /// Until the last arrival.
    pub motion_s: f64,
    /// After the last arrival until every moved axis has settled.
    pub settle_s: f64,
}

impl Move {
    pub fn total_s(&self) -> f64 {
        self.motion_s + self.settle_s
    }
}

/// The whole instrument's timing.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeModel {
    /// Per role, in [`ROLES`] order; `None` for the missing tilt of an in-plane instrument.
    pub axes: [Option<AxisModel>; 4],
    /// Number of axes in the instrument file.
    pub axis_count: usize,
    pub min_arm_separation_deg: f64,
    pub wheel: Option<WheelModel>,
    /// One detector reading at a point.
    pub reading_s: f64,
    /// One dark or normalisation reading: they may average more samples than a point's (the campaign's
    /// `[acquisition] calibration_averaging`).
    pub calibration_reading_s: f64,
}

/// Breakdown of an instrument time.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Breakdown {
    pub motion_s: f64,
    pub settle_s: f64,
    pub wheel_s: f64,
    pub integration_s: f64,
    /// Everything spent in dark and reference steps (their moves, wheel changes and readings).
    pub calibration_s: f64,
    /// The wheel's last turn to its blank when the run ends (the daemon closes the beam): no step's.
    pub closing_s: f64,
}

impl Breakdown {
    pub fn total_s(&self) -> f64 {
        self.motion_s
            + self.settle_s
            + self.wheel_s
            + self.integration_s
            + self.calibration_s
            + self.closing_s
    }
}

impl TimeModel {
    pub fn new(instrument: &Instrument) -> TimeModel {
        let mut axes: [Option<AxisModel>; 4] = Default::default();
        for (index, axis) in instrument.axes.iter().enumerate() {
            if let Some(k) = ROLES.iter().position(|r| *r == axis.role) {
                axes[k] = Some(AxisModel {
                    name: axis.name.clone(),
                    role: axis.role,
                    axis_index: index,
                    max_speed_deg_s: axis.max_speed_deg_s,
                    accel_deg_s2: axis.accel_deg_s2,
                    backlash_deg: axis.backlash_deg,
                    settle_s: axis.settle_s,
                    zero_offset_deg: axis.zero_offset_deg,
                    direction: f64::from(axis.direction),
                    leg: LegTiming::of_axis(instrument, index),
                });
            }
        }
        let wheel = instrument.filter_wheel.as_ref().map(|w| {
            let max = w.positions.iter().map(|p| p.position).max().unwrap_or(1);
            WheelModel {
                seconds_per_position: w.seconds_per_position,
                slots: if max <= 6 { 6 } else { 12 },
                bands: w
                    .positions
                    .iter()
                    .filter_map(|p| p.band_nm.map(|b| (b, p.position)))
                    .collect(),
                blank: w.positions.iter().find(|p| p.blank).map(|p| p.position),
            }
        });
        TimeModel {
            axes,
            axis_count: instrument.axes.len(),
            min_arm_separation_deg: instrument.safety.min_arm_separation_deg,
            wheel,
            reading_s: reading_time_s(instrument.detector.averaging),
            calibration_reading_s: reading_time_s(instrument.detector.averaging),
        }
    }

    /// How much closer than their end positions the arms can come during a move because of backlash
    /// overshoots: the plan keeps end poses at least this much above `min_arm_separation_deg`, so that a safe
    /// move between any two poses with the arms on the same side always exists.
    pub fn arm_overshoot_margin_deg(&self) -> f64 {
        self.axes[..2]
            .iter()
            .flatten()
            .map(|m| BACKLASH_OVERSHOOT * m.backlash_deg)
            .fold(0.0, f64::max)
    }

    /// When both arms move at once and one stops dead (a stall), the other runs on at up to full speed until the
    /// engine sees it ([`STALL_DETECTION_S`]) and stops it, then brakes: `v t + v^2 / 2a` at most, for the faster
    /// arm. Simultaneous arm moves keep this much more than `min_arm_separation_deg` at every instant (an
    /// emergency stop brakes both arms and needs less).
    pub fn arm_stopping_margin_deg(&self) -> f64 {
        self.axes[..2]
            .iter()
            .flatten()
            .filter(|m| m.max_speed_deg_s.is_finite() && m.accel_deg_s2 > 0.0)
            .map(|m| {
                m.max_speed_deg_s * STALL_DETECTION_S
                    + m.max_speed_deg_s * m.max_speed_deg_s / (2.0 * m.accel_deg_s2)
            })
            .fold(0.0, f64::max)
    }

    /// Controller positions (degrees) of every axis, in instrument-file order.
    pub fn controller_deg(&self, pose: &Pose) -> Vec<f64> {
        let mut out = vec![0.0; self.axis_count];
        for m in self.axes.iter().flatten() {
            if let Some(slot) = out.get_mut(m.axis_index) {
                *slot = m.controller_deg(pose.get(m.role));
            }
        }
        out
    }

    /// Axis names in instrument-file order.
    pub fn axis_names(&self) -> Vec<String> {
        let mut out = vec![String::new(); self.axis_count];
        for m in self.axes.iter().flatten() {
            if let Some(slot) = out.get_mut(m.axis_index) {
                slot.clone_from(&m.name);
            }
        }
        out
    }

    /// A provable lower bound on the duration of any move from `from` to `to`: every axis that must move takes
    /// at least its direct trapezoidal time (backlash overshoots and phases only add) plus its settle time.
    pub fn lower_bound_s(&self, from: &Pose, to: &Pose) -> f64 {
        let mut t = 0.0f64;
        for m in self.axes.iter().flatten() {
            let d = to.get(m.role) - from.get(m.role);
            if d.abs() > STILL_DEG {
                t = t.max(trapezoid_time_s(d, m.max_speed_deg_s, m.accel_deg_s2) + m.settle_s);
            }
        }
        t
    }

    /// The motions of one phase moving `roles` from `from` to `to`, starting at time 0 of the phase. Each axis's
    /// duration is as the daemon drives it ([`AxisModel::driven_time_s`]), after the opening exchanges of the axes
    /// before it on the same controller chain (the engine starts a phase's axes in [`ROLES`] order).
    fn phase(&self, from: &Pose, to: &Pose, roles: &[AxisRole]) -> Vec<(AxisMotion, Vec<Trapezoid>)> {
        let mut moving = Vec::new();
        for m in self.axes.iter().flatten() {
            if !roles.contains(&m.role) {
                continue;
            }
            let a = m.controller_deg(from.get(m.role));
            let b = m.controller_deg(to.get(m.role));
            let waypoints = m.waypoints(a, b);
            if !waypoints.is_empty() {
                moving.push((m, a, waypoints));
            }
        }
        let mut out = Vec::with_capacity(moving.len());
        for (m, a, waypoints) in &moving {
            let segments = m.segments(*a, waypoints, 0.0);
            let duration_s = m.driven_time_s(*a, waypoints);
            out.push((
                AxisMotion {
                    role: m.role,
                    axis_index: m.axis_index,
                    waypoints_deg: waypoints.clone(),
                    duration_s,
                },
                segments,
            ));
        }
        out
    }

    /// True when the arms keep `min_arm_separation_deg` throughout a phase.
    fn phase_is_safe(&self, from: &Pose, motions: &[(AxisMotion, Vec<Trapezoid>)]) -> bool {
        let path = |role: AxisRole| -> (f64, Vec<Trapezoid>) {
            let start = from.get(role);
            let segs = motions
                .iter()
                .find(|(m, _)| m.role == role)
                .map(|(_, s)| s.clone())
                .unwrap_or_default();
            (start, segs)
        };
        let (l0, ls) = path(AxisRole::LightArm);
        let (d0, ds) = path(AxisRole::DetectorArm);
        let both_move = !ls.is_empty() && !ds.is_empty();
        let apart = self.min_arm_separation_deg - ANGLE_TOLERANCE_DEG;
        // Sufficient whether one arm moves or both: the whole ranges swept by the two arms stay apart. An arm
        // never leaves the range of its own commanded path, whatever befalls the other (a stalled arm stops on
        // it, one stopped by the engine brakes no harder than its profile's own deceleration), so no stall can
        // bring them closer than the ranges' gap, and no stopping margin is needed: arms moving apart from the
        // closest pose allowed (a sweep ended beside the light arm) move together.
        let range = |p0: f64, segs: &[Trapezoid]| {
            segs.iter().fold((p0, p0), |(lo, hi), s| {
                (lo.min(s.to_deg).min(s.from_deg), hi.max(s.to_deg).max(s.from_deg))
            })
        };
        let (llo, lhi) = range(l0, &ls);
        let (dlo, dhi) = range(d0, &ds);
        if !approaches_multiple_of_360(llo - dhi, lhi - dlo, apart) {
            return true;
        }
        // Ranges that overlap: the arms' positions at each instant, with the stopping margin when both move.
        let sep = apart
            + if both_move {
                self.arm_stopping_margin_deg()
            } else {
                0.0
            };
        // Exact test: between consecutive profile breakpoints both arms are quadratic in time, so their
        // difference is too; its extremes on each interval are at the ends or at the vertex.
        let mut breaks = vec![0.0];
        for s in ls.iter().chain(ds.iter()) {
            let (t0, ramp, total) = (s.t0_s, s.ramp_s(), s.duration_s());
            breaks.extend([t0, t0 + ramp, t0 + total - ramp, t0 + total]);
        }
        breaks.sort_by(f64::total_cmp);
        breaks.dedup();
        let pos = |p0: f64, segs: &[Trapezoid], t: f64| -> f64 {
            let mut p = p0;
            for s in segs {
                if t >= s.t0_s {
                    p = s.position(t);
                }
            }
            p
        };
        let diff = |t: f64| pos(l0, &ls, t) - pos(d0, &ds, t);
        if breaks.len() == 1 {
            let d = diff(0.0);
            return !approaches_multiple_of_360(d, d, sep);
        }
        for w in breaks.windows(2) {
            let (ta, tb) = (w[0], w[1]);
            let (fa, fb) = (diff(ta), diff(tb));
            let (mut lo, mut hi) = (fa.min(fb), fa.max(fb));
            if tb > ta {
                // Quadratic through the three values; vertex inside the interval?
                let fm = diff(0.5 * (ta + tb));
                let c2 = 2.0 * (fa + fb - 2.0 * fm); // in units of the interval parameter u in [0, 1]
                let c1 = fb - fa - c2;
                if c2.abs() > 0.0 {
                    let u = -c1 / (2.0 * c2);
                    if (0.0..=1.0).contains(&u) {
                        let fv = fa + c1 * u + c2 * u * u;
                        lo = lo.min(fv);
                        hi = hi.max(fv);
                    }
                }
            }
            if approaches_multiple_of_360(lo, hi, sep) {
                return false;
            }
        }
        true
    }

    fn assemble(&self, from: &Pose, phases: Vec<Vec<(AxisMotion, Vec<Trapezoid>)>>) -> Move {
        let mut start = 0.0;
        let mut settled: f64 = 0.0;
        let mut out = Vec::new();
        let _ = from;
        for phase in phases {
            if phase.is_empty() {
                continue;
            }
            let duration = phase.iter().map(|(m, _)| m.duration_s).fold(0.0, f64::max);
            for (m, _) in &phase {
                let settle = self
                    .axes
                    .iter()
                    .flatten()
                    .find(|a| a.role == m.role)
                    .map_or(0.0, |a| a.settle_s);
                settled = settled.max(start + m.duration_s + settle);
            }
            start += duration;
            out.push(phase.into_iter().map(|(m, _)| m).collect());
        }
        Move {
            phases: out,
            motion_s: start,
            settle_s: (settled - start).max(0.0),
        }
    }

    /// The move from `from` to `to`: simultaneous when the arms stay apart throughout, else in two phases.
    ///
    /// Why two phases always suffice when both end poses keep the separation `s` and the arms do not change
    /// sides (l - d keeps its sign, say l > d): moving one arm alone changes the separation monotonically, so a
    /// two-phase move is safe iff its intermediate pose is. If both intermediates failed, `l1 - d0 < s` and
    /// `l0 - d1 < s`; adding, `(l0 - d0) + (l1 - d1) < 2 s`, contradicting `l0 - d0 >= s` and `l1 - d1 >= s`.
    /// (Backlash overshoots can still make both fail by a hair; then the move is refused.)
    /// `Err(ArmSeparation)` when no safe move exists, e.g. when the arms would have to pass each other.
    pub fn plan_move(&self, from: &Pose, to: &Pose) -> Result<Move, Reason> {
        let all = ROLES;
        let direct = self.phase(from, to, &all);
        if self.phase_is_safe(from, &direct) {
            return Ok(self.assemble(from, vec![direct]));
        }
        let mut best: Option<Move> = None;
        for (first, second) in [
            (
                [AxisRole::LightArm, AxisRole::SampleTilt, AxisRole::SampleRotation],
                AxisRole::DetectorArm,
            ),
            (
                [
                    AxisRole::DetectorArm,
                    AxisRole::SampleTilt,
                    AxisRole::SampleRotation,
                ],
                AxisRole::LightArm,
            ),
        ] {
            let p1 = self.phase(from, to, &first);
            if !self.phase_is_safe(from, &p1) {
                continue;
            }
            let mut mid = *from;
            for r in first {
                mid.set(r, to.get(r));
            }
            let p2 = self.phase(&mid, to, &[second]);
            if !self.phase_is_safe(&mid, &p2) {
                continue;
            }
            let m = self.assemble(from, vec![p1, p2]);
            if best.as_ref().is_none_or(|b| m.total_s() < b.total_s()) {
                best = Some(m);
            }
        }
        best.ok_or(Reason::ArmSeparation)
    }

    /// Duration of [`TimeModel::plan_move`], or infinity when no safe move exists.
    pub fn move_cost_s(&self, from: &Pose, to: &Pose) -> f64 {
        self.plan_move(from, to).map_or(f64::INFINITY, |m| m.total_s())
    }

    /// The same duration as [`TimeModel::move_cost_s`], without allocating when the arms' swept ranges are
    /// clearly apart (the common case); the ordering search calls this millions of times.
    pub fn fast_cost_s(&self, from: &Pose, to: &Pose) -> f64 {
        // (controller start, controller end, backlash reach) of each moving axis, in ROLES order.
        let mut legs: [Option<(f64, f64, f64)>; 4] = [None; 4];
        let mut swept = [(0.0, 0.0); 2];
        for (k, m) in self.axes.iter().enumerate() {
            let Some(m) = m else { continue };
            let (p0, p1) = (from.get(m.role), to.get(m.role));
            let (a, b) = (m.controller_deg(p0), m.controller_deg(p1));
            let mut reach = 0.0;
            if (b - a).abs() > STILL_DEG {
                if m.backlash_deg > 0.0 && b < a {
                    reach = BACKLASH_OVERSHOOT * m.backlash_deg;
                }
                legs[k] = Some((a, b, reach));
            }
            if k < 2 {
                swept[k] = (p0.min(p1) - reach, p0.max(p1) + reach);
            }
        }
        // Ranges this far apart pass `phase_is_safe` whether one arm moves or both.
        let sep = self.min_arm_separation_deg - ANGLE_TOLERANCE_DEG;
        let (l, d) = (swept[0], swept[1]);
        if self.axes[0].is_some()
            && self.axes[1].is_some()
            && approaches_multiple_of_360(l.0 - d.1, l.1 - d.0, sep)
        {
            return self.move_cost_s(from, to);
        }
        // The same arithmetic as `phase` over one phase of every moving axis, without the waypoint vectors.
        let mut motion: f64 = 0.0;
        let mut total: f64 = 0.0;
        for (k, m) in self.axes.iter().enumerate() {
            let (Some(m), Some((a, b, reach))) = (m, legs[k]) else {
                continue;
            };
            let t = if reach > 0.0 {
                let via = b - reach;
                m.leg
                    .leg_s(trapezoid_time_s(via - a, m.max_speed_deg_s, m.accel_deg_s2))
                    + m.leg
                        .leg_s(trapezoid_time_s(reach, m.max_speed_deg_s, m.accel_deg_s2))
            } else {
                m.leg
                    .leg_s(trapezoid_time_s(b - a, m.max_speed_deg_s, m.accel_deg_s2))
            };
            motion = motion.max(t);
            total = total.max(t + m.settle_s);
        }
        total.max(motion)
    }

    /// Wheel time between two positions (0 without a wheel).
    pub fn wheel_time_s(&self, from: Option<u8>, to: Option<u8>) -> f64 {
        match (&self.wheel, from, to) {
            (Some(w), Some(a), Some(b)) => w.time_s(a, b),
            _ => 0.0,
        }
    }
}

/// True when some value in [lo, hi] lies within `sep` of a multiple of 360 (the arms would be too close).
fn approaches_multiple_of_360(lo: f64, hi: f64, sep: f64) -> bool {
    let k_min = ((lo - sep) / 360.0).ceil();
    let k_max = ((hi + sep) / 360.0).floor();
    let mut k = k_min;
    while k <= k_max {
        let m = 360.0 * k;
        if m > lo - sep && m < hi + sep {
            return true;
        }
        k += 1.0;
    }
    false
}
