//! From a built [`Plan`] to the ordered list of steps the daemon executes, with the predicted duration.
//!
//! - Geometries are ordered by `crate::order` on their representative poses (the candidate cheapest to reach
//!   from the anchor); then, walking the order, each geometry takes the candidate pose cheapest to reach from
//!   the previous pose (the branch choice of the kinematics).
//! - Bands: either all bands at each geometry, the wheel taking the shortest covering walk from where it is
//!   ([`BandMode::PerGeometry`]), or one tour per band, alternately forwards and backwards so that consecutive
//!   tours join without a move ([`BandMode::PerBand`]). Both are computed and the quicker kept: a slow wheel
//!   groups the bands.
//! - Repeats: each further pass runs the previous one backwards.
//! - Calibration: a dark step (wheel on the blank, one reading per band's wavelength setting) and a reference step (move to the reference pose,
//!   one reading per band, the wheel on the blank before and after while the operator handles the sample)
//!   at the start, whenever `every_points` measured points or `every_s` seconds have
//!   passed since the last one, and at the end.
//! - The raster time is the same walk over the plan's request order, bands in their listed order at each
//!   geometry, passes repeated as they are. The ordered schedule is never longer: if it were, raster order would
//!   be used.
//! - No start pose: the instrument is assumed to be at the first step's pose, and the wheel on its first band.

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

/// Walks a sequence of visits, choosing poses, inserting calibration steps and adding up the time.
struct Walker<'a> {
    plan: &'a Plan,
    time: &'a TimeModel,
    pose: Option<Pose>,
    wheel: Option<u8>,
    t: f64,
    steps: Vec<Step>,
    breakdown: Breakdown,
    points_since_dark: u32,
    points_since_reference: u32,
    last_dark_s: f64,
    last_reference_s: f64,
    pass: u32,
    dropped: usize,
    representative: &'a [Pose],
}

impl<'a> Walker<'a> {
    fn new(
        plan: &'a Plan,
        time: &'a TimeModel,
        start: Option<&Pose>,
        representative: &'a [Pose],
        from: Option<Cadence>,
    ) -> Walker<'a> {
        let c = from.unwrap_or_default();
        Walker {
            plan,
            time,
            pose: start.copied(),
            wheel: c.wheel,
            t: 0.0,
            steps: Vec::new(),
            breakdown: Breakdown::default(),
            points_since_dark: c.points_since_dark,
            points_since_reference: c.points_since_reference,
            last_dark_s: -c.since_dark_s,
            last_reference_s: -c.since_reference_s,
            pass: 0,
            dropped: 0,
            representative,
        }
    }

    fn band_position(&self, band_nm: f64) -> Option<u8> {
        self.time.wheel.as_ref().and_then(|w| w.position_of(band_nm))
    }

    fn push(&mut self, mut step: Step) {
        step.start_s = self.t;
        step.pass = self.pass;
        let total = step.movement.total_s() + step.wheel_s + step.reading_s;
        match step.kind {
            StepKind::Measure => {
                self.breakdown.motion_s += step.movement.motion_s;
                self.breakdown.settle_s += step.movement.settle_s;
                self.breakdown.wheel_s += step.wheel_s;
                self.breakdown.integration_s += step.reading_s;
            }
            StepKind::Dark | StepKind::Reference => self.breakdown.calibration_s += total,
        }
        self.t += total;
        self.pose = Some(step.pose);
        if step.wheel_position.is_some() {
            self.wheel = step.wheel_position;
        }
        self.steps.push(step);
    }

    fn wheel_to(&mut self, to: Option<u8>) -> f64 {
        match self.wheel {
            None => 0.0,
            from => self.time.wheel_time_s(from, to),
        }
    }

    fn dark(&mut self, at: Pose) {
        let blank = self.time.wheel.as_ref().and_then(|w| w.blank);
        let wheel_s = self.wheel_to(blank);
        let pose = self.pose.unwrap_or(at);
        self.push(Step {
            kind: StepKind::Dark,
            geometry_index: None,
            geometry: None,
            band_nm: None,
            wheel_position: blank,
            pose,
            controller_deg: self.time.controller_deg(&pose),
            movement: Move {
                phases: Vec::new(),
                motion_s: 0.0,
                settle_s: 0.0,
            },
            wheel_s,
            // One dark reading at each band's wavelength setting: the meter converts current to watts with the
            // responsivity at the wavelength it is set to, so each band needs its own dark (the daemon reads
            // them all).
            reading_s: self.time.reading_s * self.plan.bands_nm.len().max(1) as f64,
            pass: 0,
            start_s: 0.0,
        });
        self.points_since_dark = 0;
        self.last_dark_s = self.t;
    }

    fn reference(&mut self, at: Pose) {
        let from = self.pose.unwrap_or(at);
        let target = self.plan.calibration.reference_pose(&from);
        let Ok(mut movement) = self.time.plan_move(&from, &target) else {
            // Unreachable reference pose (arms would cross): skip it rather than risk the arms.
            self.points_since_reference = 0;
            self.last_reference_s = self.t;
            return;
        };
        // The daemon closes the beam (wheel on the blank) while the operator removes the sample, and again while
        // they mount it back: a turn to the blank before the bands' walk and one after it.
        let blank = self.time.wheel.as_ref().and_then(|w| w.blank);
        let mut blank_before_s = 0.0;
        if blank.is_some() {
            blank_before_s = self.wheel_to(blank);
            self.wheel = blank;
        }
        let bands = self.plan.bands_nm.clone();
        let positions: Vec<u8> = bands.iter().filter_map(|b| self.band_position(*b)).collect();
        let order: Vec<(f64, Option<u8>)> = match &self.time.wheel {
            Some(w) if positions.len() == bands.len() => cover_walk(w, self.wheel, &positions)
                .into_iter()
                .filter_map(|p| w.bands.iter().find(|(_, q)| *q == p).map(|(b, _)| (*b, Some(p))))
                .filter(|(b, _)| bands.iter().any(|x| (x - b).abs() <= 1e-6))
                .collect(),
            _ => bands.iter().map(|b| (*b, None)).collect(),
        };
        for (band, pos) in order {
            let wheel_s = self.wheel_to(pos) + std::mem::take(&mut blank_before_s);
            self.push(Step {
                kind: StepKind::Reference,
                geometry_index: None,
                geometry: None,
                band_nm: Some(band),
                wheel_position: pos,
                pose: target,
                controller_deg: self.time.controller_deg(&target),
                movement: std::mem::replace(
                    &mut movement,
                    Move {
                        phases: Vec::new(),
                        motion_s: 0.0,
                        settle_s: 0.0,
                    },
                ),
                wheel_s,
                reading_s: self.time.reading_s,
                pass: 0,
                start_s: 0.0,
            });
        }
        if blank.is_some() {
            let back_s = self.wheel_to(blank);
            if let Some(last) = self.steps.last_mut().filter(|s| s.kind == StepKind::Reference) {
                last.wheel_s += back_s;
                self.t += back_s;
                self.breakdown.calibration_s += back_s;
            }
            self.wheel = blank;
        }
        self.points_since_reference = 0;
        self.last_reference_s = self.t;
    }

    fn calibrate_if_due(&mut self, at: Pose) {
        let c = &self.plan.calibration;
        let due = |every_points: Option<u32>, every_s: Option<f64>, since: u32, last: f64, t: f64| {
            every_points.is_some_and(|n| since >= n) || every_s.is_some_and(|s| t - last >= s)
        };
        if c.darks()
            && due(
                c.dark_every_points,
                c.dark_every_s,
                self.points_since_dark,
                self.last_dark_s,
                self.t,
            )
        {
            self.dark(at);
        }
        let c = &self.plan.calibration;
        if c.references()
            && due(
                c.reference_every_points,
                c.reference_every_s,
                self.points_since_reference,
                self.last_reference_s,
                self.t,
            )
        {
            self.reference(at);
        }
    }

    /// Measure geometry `g` at the given bands (in the given order, or the wheel's covering walk if `smart`).
    fn visit(&mut self, g: usize, bands: &[f64], smart: bool) {
        let candidates = &self.plan.geometries[g].candidates;
        let rep = self.representative[g];
        let (pose, geometry, movement) = match self.pose {
            None => (
                rep,
                candidates
                    .iter()
                    .find(|(p, _)| *p == rep)
                    .map_or(candidates[0].1, |c| c.1),
                empty(),
            ),
            Some(cur) => {
                let mut best: Option<(f64, Pose, Geometry, Move)> = None;
                for (p, geom) in candidates {
                    if let Ok(m) = self.time.plan_move(&cur, p)
                        && best.as_ref().is_none_or(|b| m.total_s() < b.0)
                    {
                        best = Some((m.total_s(), *p, *geom, m));
                    }
                }
                match best {
                    Some((_, p, geom, m)) => (p, geom, m),
                    None => {
                        self.dropped += bands.len();
                        return;
                    }
                }
            }
        };
        let order: Vec<f64> = match (&self.time.wheel, smart) {
            (Some(w), true) => {
                let pos: Vec<u8> = bands.iter().filter_map(|b| w.position_of(*b)).collect();
                if pos.len() == bands.len() {
                    cover_walk(w, self.wheel, &pos)
                        .into_iter()
                        .filter_map(|p| bands.iter().copied().find(|b| w.position_of(*b) == Some(p)))
                        .collect()
                } else {
                    bands.to_vec()
                }
            }
            _ => bands.to_vec(),
        };
        let mut movement = Some(movement);
        for band in order {
            self.calibrate_if_due(pose);
            let wheel_position = self.band_position(band);
            let wheel_s = self.wheel_to(wheel_position);
            // After a calibration step the move starts from wherever that left the arms.
            let m = match (movement.take(), self.pose) {
                (Some(m), Some(cur))
                    if cur != pose && self.steps.last().is_some_and(|s| s.kind != StepKind::Measure) =>
                {
                    let _ = m;
                    self.time.plan_move(&cur, &pose).unwrap_or_else(|_| empty())
                }
                (Some(m), _) => m,
                (None, _) => empty(),
            };
            self.push(Step {
                kind: StepKind::Measure,
                geometry_index: Some(g),
                geometry: Some(geometry),
                band_nm: Some(band),
                wheel_position,
                pose,
                controller_deg: self.time.controller_deg(&pose),
                movement: m,
                wheel_s,
                reading_s: self.time.reading_s,
                pass: 0,
                start_s: 0.0,
            });
            self.points_since_dark += 1;
            self.points_since_reference += 1;
        }
    }

    fn begin(&mut self, first: Pose) {
        if self.plan.calibration.darks() {
            self.dark(first);
        }
        if self.plan.calibration.references() {
            self.reference(first);
        }
    }

    fn finish(mut self, first: Pose, close: bool) -> Walked {
        if close && self.plan.calibration.darks() {
            self.dark(first);
        }
        if close && self.plan.calibration.references() {
            self.reference(first);
        }
        let end = Cadence {
            points_since_dark: self.points_since_dark,
            points_since_reference: self.points_since_reference,
            since_dark_s: self.t - self.last_dark_s,
            since_reference_s: self.t - self.last_reference_s,
            wheel: self.wheel,
        };
        (self.steps, self.breakdown, self.dropped, end)
    }
}

fn empty() -> Move {
    Move {
        phases: Vec::new(),
        motion_s: 0.0,
        settle_s: 0.0,
    }
}

/// How a walk visits the geometries.
enum Visits<'a> {
    PerGeometry {
        tour: &'a [usize],
        smart: bool,
        reverse_passes: bool,
    },
    PerBand {
        tour: &'a [usize],
    },
}

/// Steps, their time, readings dropped, and the cadence at the end.
type Walked = (Vec<Step>, Breakdown, usize, Cadence);

fn walk(
    plan: &Plan,
    time: &TimeModel,
    start: Option<&Pose>,
    representative: &[Pose],
    visits: Visits,
    frame: Frame,
) -> Walked {
    let from = match frame {
        Frame::Complete => None,
        Frame::Open { from } => from,
    };
    let mut w = Walker::new(plan, time, start, representative, from);
    let first_node = match &visits {
        Visits::PerGeometry { tour, .. } | Visits::PerBand { tour } => tour.first().copied(),
    };
    let Some(first_node) = first_node else {
        return (Vec::new(), Breakdown::default(), 0, from.unwrap_or_default());
    };
    let first = start.copied().unwrap_or(representative[first_node]);
    // A continued schedule's cadence comes from the one before it: only a schedule that starts a campaign
    // opens with darks and normalisation readings.
    if from.is_none() {
        w.begin(first);
    }
    for pass in 0..plan.repeats {
        w.pass = pass;
        match &visits {
            Visits::PerGeometry {
                tour,
                smart,
                reverse_passes,
            } => {
                let forward = !*reverse_passes || pass % 2 == 0;
                let mut seq: Vec<usize> = tour.to_vec();
                if !forward {
                    seq.reverse();
                }
                for g in seq {
                    w.visit(g, &plan.bands_nm, *smart);
                }
            }
            Visits::PerBand { tour } => {
                let mut bands = plan.bands_nm.clone();
                if let Some(wh) = &time.wheel {
                    let pos: Vec<u8> = bands.iter().filter_map(|b| wh.position_of(*b)).collect();
                    if pos.len() == bands.len() {
                        bands = cover_walk(wh, w.wheel, &pos)
                            .into_iter()
                            .filter_map(|p| {
                                plan.bands_nm
                                    .iter()
                                    .copied()
                                    .find(|b| wh.position_of(*b) == Some(p))
                            })
                            .collect();
                    }
                }
                let mut forward = pass % 2 == 0;
                for band in bands {
                    let mut seq: Vec<usize> = tour.to_vec();
                    if !forward {
                        seq.reverse();
                    }
                    for g in seq {
                        w.visit(g, &[band], false);
                    }
                    forward = !forward;
                }
            }
        }
    }
    w.finish(first, frame == Frame::Complete)
}

/// Order a plan and predict its duration. `start`: the instrument's current pose, if known.
pub fn schedule(plan: &Plan, time: &TimeModel, start: Option<&Pose>) -> Schedule {
    schedule_framed(plan, time, start, Frame::Complete)
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
    schedule_framed(plan, time, start, Frame::Open { from })
}

fn schedule_framed(plan: &Plan, time: &TimeModel, start: Option<&Pose>, frame: Frame) -> Schedule {
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
    let tour = order::order(&representative, start, time);
    let mut best = {
        let (s, b, d, e) = walk(
            plan,
            time,
            start,
            &representative,
            Visits::PerGeometry {
                tour: &tour,
                smart: true,
                reverse_passes: true,
            },
            frame,
        );
        (s, b, d, e, BandMode::PerGeometry)
    };
    if plan.bands_nm.len() > 1 && time.wheel.is_some() {
        let (s, b, d, e) = walk(
            plan,
            time,
            start,
            &representative,
            Visits::PerBand { tour: &tour },
            frame,
        );
        if b.total_s() < best.1.total_s() {
            best = (s, b, d, e, BandMode::PerBand);
        }
    }
    if raster.total_s() < best.1.total_s() {
        best = (raster_steps, raster, raster_dropped, raster_end, BandMode::Raster);
    }
    let (steps, breakdown, dropped, end, mode) = best;

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
        calibration_lb += forced(plan.calibration.dark_every_points) as f64 * time.reading_s;
    }
    if plan.calibration.references() && readings > 0 {
        calibration_lb += forced(plan.calibration.reference_every_points) as f64
            * plan.bands_nm.len() as f64
            * time.reading_s;
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

/// The reason recorded for readings dropped during the walk.
pub const DROPPED_REASON: Reason = Reason::ArmSeparation;
