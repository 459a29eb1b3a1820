//! The walk: visiting the ordered geometries (all bands per geometry, or one tour per band), choosing each pose,
//! inserting the calibration steps as they fall due, and adding up the predicted time.

use super::{Cadence, Frame, Step, StepKind, cover_walk};
use crate::kinematics::{Geometry, Pose};
use crate::plan::Plan;
use crate::timing::{Breakdown, Move, TimeModel};

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

    /// The wheel's blank position (None: no wheel, or no blank on it: no dark can be taken).
    fn blank(&self) -> Option<u8> {
        self.time.wheel.as_ref().and_then(|w| w.blank)
    }

    fn wheel_to(&mut self, to: Option<u8>) -> f64 {
        match self.wheel {
            None => 0.0,
            from => self.time.wheel_time_s(from, to),
        }
    }

    fn dark(&mut self, at: Pose) {
        let blank = self.blank();
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
            reading_s: self.time.calibration_reading_s * self.plan.bands_nm.len().max(1) as f64,
            pass: 0,
            start_s: 0.0,
        });
        self.points_since_dark = 0;
        self.last_dark_s = self.t;
    }

    /// Normalisation readings of every band: at the plan's reference target, or (`preamble`) where the
    /// calibration that opens a session reads them (`Calibration::preamble_target`).
    fn reference(&mut self, at: Pose, preamble: bool) {
        let from = self.pose.unwrap_or(at);
        let calibration = &self.plan.calibration;
        let target = if preamble {
            calibration.preamble_target(&from, self.time)
        } else {
            calibration.reference_target(&from, self.time)
        };
        let planned = target.map(|target| (target, self.time.plan_move(&from, &target)));
        let Some((target, Ok(mut movement))) = planned else {
            // Unreachable reference pose (arms would cross): skip it rather than risk the arms.
            self.points_since_reference = 0;
            self.last_reference_s = self.t;
            return;
        };
        // The daemon closes the beam (wheel on the blank) while the operator removes the sample, and again while
        // they mount it back: a turn to the blank before the bands' walk and one after it.
        let blank = self.blank();
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
                reading_s: self.time.calibration_reading_s,
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
            self.reference(at, false);
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
            // After a calibration step the move starts from wherever that left the arms, also when the
            // calibration fell between two bands of this geometry (the move into it was already made).
            let after_calibration = self.steps.last().is_some_and(|s| s.kind != StepKind::Measure);
            let m = match (movement.take(), self.pose) {
                (_, Some(cur)) if cur != pose && after_calibration => {
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

    /// The calibration that opens a campaign: darks and the normalisation readings, whether or not the plan asks
    /// for them again later (the engine takes them on every start: a value needs both). Without a cadence of
    /// references they are read where the engine's own preamble reads them (`Calibration::preamble_target`).
    /// Predicting them only when the plan had a cadence left a grid without one 7 % short on the ideal
    /// instrument (the curves bench's in-plane grid in three bands, 338.5 s against 363.2 s) and one band's 17 %.
    fn begin(&mut self, first: Pose) {
        // Without a blank on the wheel the engine has no way to take a dark, and takes none.
        if self.blank().is_some() {
            self.dark(first);
        }
        let cadence = self.plan.calibration.references();
        self.reference(first, !cadence);
    }

    fn finish(mut self, first: Pose, close: bool) -> Walked {
        // A closing dark wherever the wheel has a blank, cadence or not: the values are net of the dark
        // interpolated between the darks around them, and with the opening dark alone a dark that drifts (the
        // room's light) is held from the start. On realistic.toml, construction paper's 550 nm values at 80 deg
        // came 1.7 % lower than at 40 deg after five minutes without one (a grid in three bands, no cadence).
        let blank = self.blank();
        if close && blank.is_some() {
            self.dark(first);
        }
        if close && self.plan.calibration.references() {
            self.reference(first, false);
        }
        if close {
            // The daemon closes the beam when a run ends: a last turn of the wheel to its blank, no step.
            let closing_s = self.wheel_to(blank);
            self.breakdown.closing_s += closing_s;
            self.t += closing_s;
            if blank.is_some() {
                self.wheel = blank;
            }
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
pub(super) enum Visits<'a> {
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
pub(super) type Walked = (Vec<Step>, Breakdown, usize, Cadence);

pub(super) fn walk(
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

/// The calibration that opens a session where no scheduled step does (the engine's own, before sweeps that no
/// point precedes): darks of every band at `at` with the wheel from `wheel`, then the normalisation readings
/// where `Calibration::preamble_target` says. Its steps, their time (all `calibration_s`), and where the
/// instrument and the wheel are after it.
pub(super) fn preamble(
    plan: &Plan,
    time: &TimeModel,
    at: Pose,
    wheel: Option<u8>,
) -> (Vec<Step>, Breakdown, Pose, Option<u8>) {
    let mut w = Walker::new(plan, time, Some(&at), &[], None);
    w.wheel = wheel;
    w.dark(at);
    w.reference(at, true);
    let pose = w.pose.unwrap_or(at);
    (w.steps, w.breakdown, pose, w.wheel)
}

/// The calibration that closes a campaign placed pass by pass (an adaptive one, when its planner stops): what
/// a complete schedule closes with ([`Walker::finish`]), from `at` with the cadence `from` the last pass left.
pub(super) fn close(plan: &Plan, time: &TimeModel, at: Pose, from: Cadence) -> Walked {
    Walker::new(plan, time, Some(&at), &[], Some(from)).finish(at, true)
}
