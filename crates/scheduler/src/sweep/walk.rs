//! Ordering and timing the sweeps (the model in `crate::sweep`'s module doc).

use super::path::swept_role;
use super::{SweepPlan, sweep_reading_period_s};
use crate::kinematics::Pose;
use crate::plan::Plan;
use crate::schedule::{calibration_preamble, cover_walk};
use crate::timing::{AxisModel, DETECTOR_SAMPLE_S, EXCHANGE_S, Move, TimeModel, trapezoid_time_s};
use gonio_instrument::AxisRole;

/// One sweep of one arc in one band.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepStep {
    /// Index into [`SweepPlan::arcs`].
    pub arc: usize,
    /// None on an instrument without a filter wheel.
    pub band_nm: Option<f64>,
    pub wheel_position: Option<u8>,
    /// True when the arm sweeps from the arc's `from_deg` to its `to_deg`.
    pub forward: bool,
    pub start_pose: Pose,
    pub end_pose: Pose,
    /// The move into `start_pose` (empty when the previous sweep ended there).
    pub movement: Move,
    pub wheel_s: f64,
    /// The swept axis's motion: readings are taken throughout it.
    pub motion_s: f64,
    /// The whole sweep leg: the motion and the driver's exchanges around it.
    pub sweep_s: f64,
    pub readings: u64,
    /// Time between readings.
    pub reading_period_s: f64,
    /// Arc one reading integrates over at cruise speed (degrees).
    pub smear_deg: f64,
    /// Predicted time at which the step begins (its move), from the start of the sweeps.
    pub start_s: f64,
}

impl SweepStep {
    pub fn total_s(&self) -> f64 {
        self.movement.total_s() + self.wheel_s + self.sweep_s
    }
}

/// Where the time of the sweeps goes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SweepBreakdown {
    /// Moves between sweeps.
    pub motion_s: f64,
    pub settle_s: f64,
    pub wheel_s: f64,
    /// The sweeps themselves (their readings run during them), with the exchanges around each (setting and
    /// restoring the axis's speed, seeing it stop and where it stopped).
    pub sweep_s: f64,
    /// The calibration that opens the sweeps when no point precedes them (darks, normalisation readings).
    pub calibration_s: f64,
    /// The wheel's last turn to its blank when the run ends (the engine closes the beam): no step's.
    pub closing_s: f64,
}

impl SweepBreakdown {
    pub fn total_s(&self) -> f64 {
        self.motion_s + self.settle_s + self.wheel_s + self.sweep_s + self.calibration_s + self.closing_s
    }
}

/// The sweeps in run order with their predicted times.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SweepSchedule {
    pub steps: Vec<SweepStep>,
    pub breakdown: SweepBreakdown,
    pub readings: u64,
    /// Arcs no safe move reaches from where the instrument is.
    pub unreachable: usize,
    /// Where the instrument starts: the pose and the wheel position of the calibration that opens the sweeps,
    /// or of the first sweep.
    pub start: Option<(Pose, Option<u8>)>,
    /// Where the sweeps leave the instrument: the pose and the wheel position after the last sweep, or after
    /// the calibration that closes them.
    pub end: Option<(Pose, Option<u8>)>,
}

/// How the sweeps are calibrated: the point plan whose `[plan.calibration]` they follow, and whether the
/// session's calibration opens them (no point precedes them).
#[derive(Debug, Clone, Copy)]
pub struct SweepCalibration<'a> {
    pub plan: &'a Plan,
    pub opening: bool,
    /// The run ends with the sweeps: the wheel's last turn to its blank is theirs (`closing_s`). False when
    /// points follow them (an adaptive plan's first pass of sweeps).
    pub last: bool,
}

/// The time of one sweep on axis `m` whose motion takes `motion_s`, with a reading every `period_s`, besides
/// setting its speed: the move command; the motion; then what the engine (crates/engine/src/motion/sweep.rs)
/// waits for after it ([`sweep_tail_s`]). The speed is the walk's ([`schedule_sweeps`]): set before each sweep
/// (with the acceleration the first time), and the axis's own restored before anything else moves, not between
/// the pieces of a chain.
pub fn sweep_time_s(m: &AxisModel, motion_s: f64, period_s: f64) -> f64 {
    motion_s.max(m.leg.start_return_s) + sweep_tail_s(m, period_s)
}

/// What a sweep waits for after its motion, on average over where the readings fall (s). No reading is asked
/// for that would run more than half its integration `T` past the predicted end, so the last one ends
/// uniformly within `(-T/2, period - T/2]` of it: ended before (a share `T/2 / period`), the arm is asked where
/// it is during the motion and the driver's wait sees the stop a margin and its exchanges after the end
/// (`seen_after_s`); ended after, that wait, then the stop seen and checked with the read-back (`status_s`,
/// `arrived_s`).
pub fn sweep_tail_s(m: &AxisModel, period_s: f64) -> f64 {
    let leg = &m.leg;
    let half = 0.5 * (period_s - EXCHANGE_S).max(0.0);
    if period_s.is_nan() || period_s <= 0.0 {
        return leg.status_s + leg.arrived_s;
    }
    let before = (half / period_s).clamp(0.0, 1.0);
    before * leg.seen_after_s + (1.0 - before) * (0.5 * (period_s - half) + leg.status_s + leg.arrived_s)
}

/// How many of the nearest chain ends the ordering weighs with the move after them.
const LOOK_BEYOND: usize = 8;

/// The chain of each arc, numbered from 0: runs of consecutive arcs of the plan each ending where the next
/// starts (the pieces of a speed profile), swept one after the other, one way, without a move between them.
fn chains(plan: &SweepPlan) -> Vec<usize> {
    let joined = |a: &Pose, b: &Pose| {
        [
            a.light_deg - b.light_deg,
            a.detector_deg - b.detector_deg,
            a.tilt_deg - b.tilt_deg,
            a.rotation_deg - b.rotation_deg,
        ]
        .iter()
        .all(|d| d.abs() < 1e-6)
    };
    let mut chain = 0;
    plan.arcs
        .iter()
        .enumerate()
        .map(|(k, arc)| {
            if k > 0 && !joined(&plan.arcs[k - 1].piece.to_pose, &arc.piece.from_pose) {
                chain += 1;
            }
            chain
        })
        .collect()
}

/// For each chain, its first and last arc left (indices into the plan's arcs; a first of `usize::MAX` for a
/// chain with none left). Arcs are taken from a chain's ends only, so those left are the ones between.
fn chain_ends(chain: &[usize], left: &[usize]) -> Vec<(usize, usize)> {
    let n = chain.last().map_or(0, |m| m + 1);
    let mut ends = vec![(usize::MAX, 0); n];
    for &a in left {
        let (first, last) = &mut ends[chain[a]];
        *first = (*first).min(a);
        *last = (*last).max(a);
    }
    ends
}

/// Order and time the sweeps from `start` (the pose and wheel position the instrument is in; none: at the first
/// arc's start, the wheel on its first band). `calibration`: the session's calibration
/// (`crate::schedule::calibration_preamble`: darks, then the normalisation) opens the sweeps when no point
/// precedes them, falls due between arcs every `Calibration::sweep_every_s` of instrument time, and closes them
/// when the plan asks for references (so that the drift between readings can be interpolated).
pub fn schedule_sweeps(
    plan: &SweepPlan,
    time: &TimeModel,
    start: Option<(Pose, Option<u8>)>,
    calibration: Option<SweepCalibration>,
) -> SweepSchedule {
    let mut out = SweepSchedule::default();
    let Some(first) = plan.arcs.first() else {
        return out;
    };
    let positions: Vec<(Option<f64>, Option<u8>)> = match &time.wheel {
        Some(w) => plan
            .bands_nm
            .iter()
            .filter_map(|b| w.position_of(*b).map(|p| (Some(*b), Some(p))))
            .collect(),
        None => Vec::new(),
    };
    let positions = if positions.is_empty() {
        vec![(plan.bands_nm.first().copied(), None)]
    } else {
        positions
    };
    let (mut pose, mut wheel) = start.unwrap_or((first.piece.from_pose, positions[0].1));
    out.start = Some((pose, wheel));
    let calibrate = |pose: &mut Pose, wheel: &mut Option<u8>, out: &mut SweepSchedule| {
        if let Some(c) = calibration {
            let (_, b, after, wheel_after) = calibration_preamble(c.plan, time, *pose, *wheel);
            out.breakdown.calibration_s += b.total_s();
            *pose = after;
            *wheel = wheel_after;
            return b.total_s();
        }
        0.0
    };
    let mut clock = 0.0;
    if calibration.is_some_and(|c| c.opening) {
        clock += calibrate(&mut pose, &mut wheel, &mut out);
    }
    let every_s = calibration.and_then(|c| c.plan.calibration.sweep_every_s());
    let mut last_calibration = clock;
    // The axis the last sweep left at its sweep speed, with what restoring its own costs: restored (by the
    // engine, crates/engine/src/runner/sweep.rs) before a calibration, a move or another axis's sweep, and when
    // the sweeps end; a chain's next piece sets its own speed from where the last ended. Counted in the sweep
    // that left it so. And the axes whose acceleration the driver has written (their first sweep's).
    let mut slow: Option<(AxisRole, f64)> = None;
    let mut accel_written: Vec<AxisRole> = Vec::new();
    let restore = |slow: &mut Option<(AxisRole, f64)>, clock: &mut f64, out: &mut SweepSchedule| {
        if let Some((_, cost)) = slow.take() {
            *clock += cost;
            out.breakdown.sweep_s += cost;
            if let Some(last) = out.steps.last_mut() {
                last.sweep_s += cost;
            }
        }
    };
    let chain = chains(plan);
    let mut current: Option<(usize, bool)> = None;
    let mut left: Vec<usize> = (0..plan.arcs.len()).collect();
    while !left.is_empty() {
        if every_s.is_some_and(|e| clock - last_calibration >= e) {
            restore(&mut slow, &mut clock, &mut out);
            clock += calibrate(&mut pose, &mut wheel, &mut out);
            last_calibration = clock;
        }
        // A chain is entered at one of its ends and left at the other. The next: the one whose entry from where
        // the arm is, plus the move from its exit to the nearest end of another chain, costs least (chosen by
        // its nearer end alone, the plastic's profile in section 7 of BENCHMARKS.md swept the specular side
        // first and left the detector 100 degrees from the source side's nearer end: 10 s between the two
        // stretches instead of 6.6 s).
        let ends = chain_ends(&chain, &left);
        let onward = |from: &Pose, own: usize| {
            ends.iter()
                .enumerate()
                .filter(|(c, (first, _))| *c != own && *first != usize::MAX)
                .flat_map(|(_, (first, last))| {
                    [
                        time.fast_cost_s(from, &plan.arcs[*first].piece.from_pose),
                        time.fast_cost_s(from, &plan.arcs[*last].piece.to_pose),
                    ]
                })
                .filter(|c| c.is_finite())
                .fold(None, |m: Option<f64>, c| Some(m.map_or(c, |m| m.min(c))))
                .unwrap_or(0.0)
        };
        // The chain being swept and its way, while it has pieces left: only its next piece is a candidate.
        let going = current.filter(|(c, _)| ends[*c].0 != usize::MAX);
        // (entry cost, slot, forward, exit, chain) of every end left.
        let mut entries: Vec<(f64, usize, bool, &Pose, usize)> = Vec::new();
        for (slot, &a) in left.iter().enumerate() {
            let piece = &plan.arcs[a].piece;
            let (first, last) = ends[chain[a]];
            for (forward, entry) in [(true, &piece.from_pose), (false, &piece.to_pose)] {
                let (end, exit) = if forward {
                    (first, &plan.arcs[last].piece.to_pose)
                } else {
                    (last, &plan.arcs[first].piece.from_pose)
                };
                // A chain entered goes on one way to its other end.
                let goes_on = going.is_none_or(|(c, way)| c == chain[a] && way == forward);
                let cost = time.fast_cost_s(&pose, entry);
                if end == a && goes_on && cost.is_finite() {
                    entries.push((cost, slot, forward, exit, chain[a]));
                }
            }
        }
        // The look beyond for the nearest few only: it costs a move per chain left for each.
        entries.sort_by(|a, b| a.0.total_cmp(&b.0));
        let best = entries
            .iter()
            .take(LOOK_BEYOND)
            .map(|&(cost, slot, forward, exit, own)| (cost + onward(exit, own), slot, forward))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let Some((_, slot, mut forward)) = best else {
            out.unreachable += left.len();
            break;
        };
        let a = left.remove(slot);
        current = Some((chain[a], forward));
        let arc = &plan.arcs[a];
        let model = time
            .axes
            .iter()
            .flatten()
            .find(|m| m.role == swept_role(arc.request.arm));
        let targets: Vec<u8> = positions.iter().filter_map(|(_, p)| *p).collect();
        let order: Vec<(Option<f64>, Option<u8>)> = match (&time.wheel, targets.is_empty()) {
            (Some(w), false) => cover_walk(w, wheel, &targets)
                .into_iter()
                .filter_map(|p| positions.iter().find(|(_, q)| *q == Some(p)).copied())
                .collect(),
            _ => positions.clone(),
        };
        let period = sweep_reading_period_s(arc.request.averaging);
        let v = arc.request.speed_deg_s;
        for (band_nm, position) in order {
            let (from, to) = if forward {
                (arc.piece.from_pose, arc.piece.to_pose)
            } else {
                (arc.piece.to_pose, arc.piece.from_pose)
            };
            let Ok(movement) = time.plan_move(&pose, &from) else {
                out.unreachable += 1;
                break;
            };
            let role = swept_role(arc.request.arm);
            if pose != from || slow.is_some_and(|(r, _)| r != role) {
                restore(&mut slow, &mut clock, &mut out);
            }
            let wheel_s = time.wheel_time_s(wheel, position);
            let (motion_s, sweep_s) = match model {
                Some(m) => {
                    let t = trapezoid_time_s(arc.length_deg(), v, m.accel_deg_s2);
                    let set_s = if accel_written.contains(&role) {
                        m.leg.set_velocity_s
                    } else {
                        accel_written.push(role);
                        m.leg.set_speed_s
                    };
                    slow = Some((role, m.leg.set_velocity_s));
                    (t, set_s + sweep_time_s(m, t, period))
                }
                None => (0.0, 0.0),
            };
            let readings = ((motion_s / period).floor() as u64).max(1);
            let step = SweepStep {
                arc: a,
                band_nm,
                wheel_position: position,
                forward,
                start_pose: from,
                end_pose: to,
                movement,
                wheel_s,
                motion_s,
                sweep_s,
                readings,
                reading_period_s: period,
                smear_deg: v * f64::from(arc.request.averaging) * DETECTOR_SAMPLE_S,
                start_s: clock,
            };
            clock += step.total_s();
            out.breakdown.motion_s += step.movement.motion_s;
            out.breakdown.settle_s += step.movement.settle_s;
            out.breakdown.wheel_s += wheel_s;
            out.breakdown.sweep_s += sweep_s;
            out.readings += readings;
            out.steps.push(step);
            pose = to;
            if position.is_some() {
                wheel = position;
            }
            forward = !forward;
        }
    }
    restore(&mut slow, &mut clock, &mut out);
    if calibration.is_some_and(|c| c.plan.calibration.references()) {
        calibrate(&mut pose, &mut wheel, &mut out);
    }
    out.end = Some((pose, wheel));
    if calibration.is_none_or(|c| c.last) {
        out.breakdown.closing_s = time.wheel_time_s(wheel, time.wheel.as_ref().and_then(|w| w.blank));
    }
    out
}
