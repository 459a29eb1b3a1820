//! From a built [`Plan`] to the ordered list of steps the daemon executes, with the predicted duration.
//!
//! - Geometries are ordered by `crate::order` on their representative poses (the candidate cheapest to reach
//!   from the anchor); then, walking the order, each geometry takes the candidate pose cheapest to reach from
//!   the previous pose (the branch choice of the kinematics). A schedule that closes with normalisation
//!   readings (a complete one, or an adaptive campaign's last pass: [`schedule_last`]) is also ordered to end
//!   where the move to their reference pose is shortest (`order::order_towards`), and both orders are walked,
//!   the quicker kept (with the closing counted): the demo 242.8 -> 235.7 s.
//! - Bands: either all bands at each geometry, the wheel taking the shortest covering walk from where it is
//!   ([`BandMode::PerGeometry`]), or one tour per band, alternately forwards and backwards so that consecutive
//!   tours join without a move ([`BandMode::PerBand`]). Both are computed and the quicker kept: a slow wheel
//!   groups the bands.
//! - Repeats: each further pass runs the previous one backwards.
//! - Calibration: a dark step (wheel on the blank, one reading per band's wavelength setting) and a reference step (move to the reference pose,
//!   one reading per band, the wheel on the blank before and after while the operator handles the sample)
//!   at the start of every campaign (the engine opens each start with both, whatever the cadence; a dark only
//!   where the wheel has a blank, and the normalisation where `Calibration::preamble_target` says without a
//!   cadence of references), whenever `every_points` measured points or `every_s` seconds have passed since the
//!   last one, and at the end: darks wherever the wheel has a blank, cadence or not (the values are net of the
//!   dark interpolated between the darks around them), normalisation readings when the plan has a cadence.
//! - The raster time is the same walk over the plan's request order, bands in their listed order at each
//!   geometry, passes repeated as they are. The ordered schedule is never longer: if it were, raster order would
//!   be used.
//! - No start pose: the instrument is assumed to be at the first step's pose, and the wheel on its first band.
//! - A complete schedule ends with the wheel on its blank, as the daemon leaves it (the beam closed): that last
//!   turn is the breakdown's `closing_s`, not a step.

//!
//! The records, the wheel's covering walk and the choice between orders are here; the walk that turns an order
//! into steps and times is in `walk`.

mod walk;

use walk::{Visits, walk};

use crate::constraints::Reason;
use crate::kinematics::{Geometry, Pose};
use crate::order;
use crate::plan::Plan;
use crate::timing::{Breakdown, Move, TimeModel, WheelModel};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepKind {
    /// Read the detector at a plan point.
    Measure,
    /// Wheel on the blank, read the dark signal.
    Dark,
    /// Move to the reference (direct-beam) pose and read one band.
    Reference,
}

impl StepKind {
    pub fn name(&self) -> &'static str {
        match self {
            StepKind::Measure => "measure",
            StepKind::Dark => "dark",
            StepKind::Reference => "reference",
        }
    }
}

/// One step of the run.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub kind: StepKind,
    /// Index into [`Plan::geometries`] (measure steps).
    pub geometry_index: Option<usize>,
    /// The sample-frame geometry measured at this pose (measure steps).
    pub geometry: Option<Geometry>,
    /// None for dark steps and instruments without a wheel band.
    pub band_nm: Option<f64>,
    pub wheel_position: Option<u8>,
    /// Physical axis angles.
    pub pose: Pose,
    /// Controller positions in instrument-file axis order.
    pub controller_deg: Vec<f64>,
    /// The move into `pose` from the previous step's pose.
    pub movement: Move,
    pub wheel_s: f64,
    pub reading_s: f64,
    /// 0-based pass (repeat) number.
    pub pass: u32,
    /// Predicted instrument time at which the step starts (its move begins).
    pub start_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BandMode {
    PerGeometry,
    PerBand,
    /// The ordered walk was no better than raster order, which is used instead.
    Raster,
}

/// An ordered plan and its predicted duration.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    pub steps: Vec<Step>,
    pub mode: BandMode,
    pub breakdown: Breakdown,
    /// The same plan in request order.
    pub raster: Breakdown,
    /// Provable lower bound on the total time of any order (see `crate::order`).
    pub lower_bound_s: f64,
    /// (geometry, band) readings dropped while walking because no safe move reached them.
    pub dropped: usize,
    /// Where the calibration cadence and the wheel stand after the last step: what a schedule that continues
    /// this one starts from ([`schedule_continuing`]).
    pub end: Cadence,
}

/// The state a schedule leaves behind for one that continues it (an adaptive campaign's next pass): the
/// calibration cadence's counters and the wheel, so that a dark or a normalisation falls due across passes as
/// it would within one schedule.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Cadence {
    /// Measure steps since the last dark.
    pub points_since_dark: u32,
    /// Measure steps since the last normalisation (reference) reading.
    pub points_since_reference: u32,
    /// Instrument time since the last dark (s).
    pub since_dark_s: f64,
    /// Instrument time since the last normalisation reading (s).
    pub since_reference_s: f64,
    /// The filter wheel's position (None: unknown).
    pub wheel: Option<u8>,
}

/// How a walk starts and ends: a complete schedule opens and closes with darks and normalisation readings
/// (when the plan asks for them); a continued one carries the cadence of the schedule before it and leaves the
/// closing ones to whoever decides that the campaign ends.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Frame {
    Complete,
    Open { from: Option<Cadence> },
}

/// Plans up to this many geometries walk the order towards the closing beside the free one (ordering twice
/// costs little there, and the closing's move is a larger share of a short campaign: the demo 242.8 -> 235.7 s).
const BOTH_ORDERS_MAX: usize = 1000;

/// Where a schedule's order may end: anywhere, or where the closing normalisation readings that follow its
/// last point are reached soonest (`order::order_towards`).
#[derive(Debug, Clone, Copy, PartialEq)]
enum End {
    Anywhere,
    TowardsClosing,
}

impl Schedule {
    pub fn measure_steps(&self) -> impl Iterator<Item = &Step> {
        self.steps.iter().filter(|s| s.kind == StepKind::Measure)
    }
}

/// The shortest walk of the wheel from `from` covering `targets` (a walk on a circle turns at most once).
pub fn cover_walk(wheel: &WheelModel, from: Option<u8>, targets: &[u8]) -> Vec<u8> {
    let mut uniq: Vec<u8> = targets.to_vec();
    uniq.sort_unstable();
    uniq.dedup();
    let Some(c) = from.or_else(|| uniq.first().copied()) else {
        return Vec::new();
    };
    let slots = i32::from(wheel.slots);
    let off = |p: u8, d: i32| (d * (i32::from(p) - i32::from(c))).rem_euclid(slots);
    let mut best: Option<(i32, Vec<u8>)> = None;
    for d in [1, -1] {
        let mut first: Vec<u8> = uniq.clone();
        first.sort_by_key(|p| off(*p, d));
        for k in 0..=first.len() {
            let (out, back) = first.split_at(k);
            let mut back: Vec<u8> = back.to_vec();
            back.sort_by_key(|p| off(*p, -d));
            let go = out.last().map_or(0, |p| off(*p, d));
            let cost = if back.is_empty() {
                go
            } else {
                2 * go + back.last().map_or(0, |p| off(*p, -d))
            };
            if best.as_ref().is_none_or(|(b, _)| cost < *b) {
                let mut order = out.to_vec();
                order.extend(back);
                best = Some((cost, order));
            }
        }
    }
    best.map(|(_, o)| o).unwrap_or_default()
}

/// Order a plan and predict its duration. `start`: the instrument's current pose, if known.
pub fn schedule(plan: &Plan, time: &TimeModel, start: Option<&Pose>) -> Schedule {
    schedule_framed(plan, time, start, Frame::Complete, End::TowardsClosing)
}

/// Order a plan that a later one may continue (an adaptive campaign's passes): like [`schedule`], but no
/// closing darks or normalisation readings, and, with `from` (the [`Schedule::end`] of the schedule before it),
/// no opening ones either: the calibration cadence carries on from where that schedule left it.
pub fn schedule_continuing(
    plan: &Plan,
    time: &TimeModel,
    start: Option<&Pose>,
    from: Option<Cadence>,
) -> Schedule {
    schedule_framed(plan, time, start, Frame::Open { from }, End::Anywhere)
}

/// [`schedule_continuing`] for the last of the schedules that continue one another (an adaptive campaign's pass
/// that fills its budget): ordered to end where the closing that follows it ([`schedule_closing`]) moves least.
/// A closing with normalisation readings moves the arms to the reference pose, from wherever the last pass
/// happened to end (the test `the_last_pass_is_ordered_towards_its_closing` prints both closings' times).
pub fn schedule_last(plan: &Plan, time: &TimeModel, start: Option<&Pose>, from: Option<Cadence>) -> Schedule {
    schedule_framed(plan, time, start, Frame::Open { from }, End::TowardsClosing)
}

/// What leaving the schedule's order from each representative pose costs (s): the move to the closing
/// normalisation readings' target when the plan closes with them; nothing otherwise (empty: the order ends
/// anywhere). A target the arms cannot reach costs nothing: the walk skips that reading.
fn exit_costs(plan: &Plan, time: &TimeModel, representative: &[Pose], end: End) -> Vec<f64> {
    if end == End::Anywhere || !plan.calibration.references() {
        return Vec::new();
    }
    representative
        .iter()
        .map(|p| {
            plan.calibration
                .reference_target(p, time)
                .map(|target| time.fast_cost_s(p, &target))
                .filter(|c| c.is_finite())
                .unwrap_or(0.0)
        })
        .collect()
}

fn schedule_framed(plan: &Plan, time: &TimeModel, start: Option<&Pose>, frame: Frame, end: End) -> Schedule {
    let anchor = start.copied().or(plan.anchor);
    // Representative pose per geometry: the candidate cheapest to reach from the anchor (else the first).
    let representative: Vec<Pose> = plan
        .geometries
        .iter()
        .map(|g| match anchor {
            Some(a) => g
                .candidates
                .iter()
                .map(|(p, _)| *p)
                .min_by(|x, y| time.fast_cost_s(&a, x).total_cmp(&time.fast_cost_s(&a, y)))
                .unwrap_or(g.candidates[0].0),
            None => g.candidates[0].0,
        })
        .collect();
    let raster_tour: Vec<usize> = (0..plan.geometries.len()).collect();
    let (raster_steps, raster, raster_dropped, raster_end) = walk(
        plan,
        time,
        start,
        &representative,
        Visits::PerGeometry {
            tour: &raster_tour,
            smart: false,
            reverse_passes: false,
        },
        frame,
    );
    // The free order, and the order towards the closing beside it (plans up to BOTH_ORDERS_MAX geometries):
    // each walked, the quickest kept. Towards the closing is not always quicker: with an even number of repeats,
    // or of bands' tours, the walk's last traversal of the tour runs backwards and ends at its other end; and the
    // two searches land in different local optima.
    let free = order::order(&representative, start, time);
    let towards = (representative.len() <= BOTH_ORDERS_MAX)
        .then(|| exit_costs(plan, time, &representative, end))
        .filter(|exit_s| !exit_s.is_empty())
        .map(|exit_s| order::order_towards(&representative, start, &exit_s, time));
    // What a walk is judged by: its time, and for the last of continued schedules, the closing's after it
    // (a complete schedule holds its closing).
    let judged_s = |walked: &walk::Walked| {
        let closing_s = match (frame, end, walked.0.last()) {
            (Frame::Open { .. }, End::TowardsClosing, Some(last)) => {
                walk::close(plan, time, last.pose, walked.3).1.total_s()
            }
            _ => 0.0,
        };
        walked.1.total_s() + closing_s
    };
    // The quickest walk so far: how it was judged, the walk, its band mode.
    let mut best: Option<(f64, walk::Walked, BandMode)> = None;
    let mut keep = |walked: walk::Walked, mode: BandMode| {
        let judged = judged_s(&walked);
        if best.as_ref().is_none_or(|b| judged < b.0) {
            best = Some((judged, walked, mode));
        }
    };
    for tour in std::iter::once(&free).chain(towards.as_ref()) {
        let visits = Visits::PerGeometry {
            tour,
            smart: true,
            reverse_passes: true,
        };
        keep(
            walk(plan, time, start, &representative, visits, frame),
            BandMode::PerGeometry,
        );
        if plan.bands_nm.len() > 1 && time.wheel.is_some() {
            let visits = Visits::PerBand { tour };
            keep(
                walk(plan, time, start, &representative, visits, frame),
                BandMode::PerBand,
            );
        }
    }
    let raster_walk = (raster_steps, raster, raster_dropped, raster_end);
    let ((steps, breakdown, dropped, end), mode) = match best {
        Some((judged, walked, mode)) if judged <= judged_s(&raster_walk) => (walked, mode),
        _ => (raster_walk, BandMode::Raster),
    };

    // Lower bound: moves (crate::order), readings (exact), wheel (each further band needs at least one step),
    // and the calibration readings the point counts force.
    let nodes: Vec<Vec<Pose>> = plan
        .geometries
        .iter()
        .map(|g| g.candidates.iter().map(|c| c.0).collect())
        .collect();
    let reference_arms = plan
        .calibration
        .references()
        .then(|| plan.calibration.reference_pose(&Pose::new(0.0, 0.0, 0.0, 0.0)));
    let moves_lb = order::lower_bound_s(&nodes, start, reference_arms.as_ref(), time);
    let readings = (plan.geometries.len() * plan.bands_nm.len()) as u64 * u64::from(plan.repeats);
    let integration_lb = readings as f64 * time.reading_s;
    let wheel_lb = match &time.wheel {
        Some(w) => {
            let mut pos: Vec<u8> = plan.bands_nm.iter().filter_map(|b| w.position_of(*b)).collect();
            pos.sort_unstable();
            pos.dedup();
            pos.len().saturating_sub(1) as f64 * w.seconds_per_position
        }
        None => 0.0,
    };
    let forced = |every: Option<u32>| -> u64 {
        match every {
            Some(n) if readings > 0 => 2 + (readings - 1) / u64::from(n),
            _ => 2,
        }
    };
    let mut calibration_lb = 0.0;
    // Only a complete schedule is forced to open and close with calibration readings.
    let readings = if frame == Frame::Complete { readings } else { 0 };
    if plan.calibration.darks() && readings > 0 {
        calibration_lb += forced(plan.calibration.dark_every_points) as f64 * time.calibration_reading_s;
    }
    if plan.calibration.references() && readings > 0 {
        calibration_lb += forced(plan.calibration.reference_every_points) as f64
            * plan.bands_nm.len() as f64
            * time.calibration_reading_s;
    }
    let lower_bound_s = if plan.geometries.is_empty() {
        0.0
    } else {
        moves_lb + integration_lb + wheel_lb + calibration_lb
    };
    Schedule {
        steps,
        mode,
        breakdown,
        raster,
        lower_bound_s,
        dropped,
        end,
    }
}

/// The calibration that closes a campaign whose schedules continue one another (an adaptive campaign's, when
/// its planner stops): from `at`, where the last one left the instrument, with the cadence it left (`from`,
/// its [`Schedule::end`]), what a complete schedule closes with: darks where the wheel has a blank, the
/// normalisation readings when the plan has a cadence of them, and the wheel's last turn to its blank
/// (`closing_s`). Without them the values measured after the last dark were net of that dark held, whatever
/// the room's light did since.
pub fn schedule_closing(plan: &Plan, time: &TimeModel, at: Pose, from: Cadence) -> Schedule {
    let (steps, breakdown, dropped, end) = walk::close(plan, time, at, from);
    Schedule {
        steps,
        mode: BandMode::PerGeometry,
        raster: breakdown,
        lower_bound_s: 0.0,
        breakdown,
        dropped,
        end,
    }
}

/// The reason recorded for readings dropped during the walk.
pub const DROPPED_REASON: Reason = Reason::ArmSeparation;

/// The calibration that opens a session where no scheduled step does: darks at `at` (the wheel coming from
/// `wheel`), then the normalisation readings where `Calibration::preamble_target` says. Returns its steps, its
/// time, and the pose and wheel position it leaves.
pub fn calibration_preamble(
    plan: &Plan,
    time: &TimeModel,
    at: Pose,
    wheel: Option<u8>,
) -> (Vec<Step>, Breakdown, Pose, Option<u8>) {
    walk::preamble(plan, time, at, wheel)
}
