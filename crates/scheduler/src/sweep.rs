//! Sweeps: one arm turns over an arc at a set speed while every other axis holds and the meter reads
//! continuously. This module plans them: which arcs (the whole swept path checked against every constraint),
//! in what order, and how long they take.
//!
//! # Schema (`[[plan.sweeps]]`, any number of entries; see `config/campaigns/plan-examples.toml`)
//! ```toml
//! [[plan.sweeps]]
//! arm = "detector"                          # the arm that sweeps: "detector" (default) or "light"
//! theta_i_deg = [0.0, 30.0, 60.0]           # detector sweeps: incidences held, one arc each (list or range)
//! theta_o_deg = { from = -80.0, to = 80.0 } # detector sweeps: the swept arc, signed as in in-plane grids
//! plane_phi_deg = [0.0]                     # planes of incidence (sample azimuths); default [0.0]
//! speed_deg_s = 2.0                         # the swept arm's speed at cruise
//! averaging = 1                             # meter samples per sweep reading; default 1
//! follow = { first_pass = "out/first", tolerance_rel = 2e-3 }  # optional: speed that follows the BRDF
//! isotropic = true                          # optional: the sample is isotropic (below); default false
//! # arm = "light": theta_o_deg holds the detector (list or range, at phi_o = plane + 180) and theta_i_deg is
//! # the swept arc { from, to }: > 0 with the source opposite the detector (phi_i = plane), < 0 on its side.
//! ```
//! A plan may hold sweeps beside a `[plan.grid]` or `[plan.adaptive]` (the sweeps follow the points), or
//! sweeps alone.
//!
//! # The path
//! Every arc is checked along its whole length (`path`): the static rules of `crate::constraints` (horizon,
//! grazing limit, overfill, the retro-reflection block, the arm separation), the swept axis's limits, and the
//! side of the arms the plan keeps (the arms never pass each other). What fails is cut out; an arc crossing the
//! retro-reflection block becomes two pieces, the one beyond the source swept with the mirror axis solution
//! (the arms keep their order): on an in-plane arc, the sample turned half a turn and the light arm on the other
//! side. With `isotropic = true` (the lab declares that the sample's BRDF depends on the azimuths through their
//! difference only) such a stretch is measured on the arc turned about the normal instead (plane + 180 deg:
//! every swept angle keeps theta_i, theta_o and the azimuths' difference), the sample held: only the light arm
//! changes sides between the stretches. Its readings carry the geometry measured. The degrees cut are reported by
//! rule.
//!
//! # The time model of a sweep step
//! A step moves to the piece's start (`TimeModel::plan_move`, settle included), turns the wheel to its band
//! when it is not there, then sweeps: the swept axis's speed set (`LegTiming::set_velocity_s`; with its
//! acceleration on the axis's first sweep, `set_speed_s`: the driver writes what the device is not known to
//! hold), one plain move to the piece's other end at the entry's speed (`speed_deg_s` at cruise, the axis's own
//! acceleration, no backlash approach: the pose of a reading comes from the controller's position reports, not
//! from the direction of approach), then what the engine waits for after the motion (`walk::sweep_tail_s`: no
//! reading is asked for that would run more than half its integration past the predicted end, the arm being
//! within half a reading of its stop; then the stop seen and checked with the swept axis's read-back, no other
//! axis having moved), as the engine does it (`crates/engine/src/motion/sweep.rs`). The axis's own speed is restored (`set_velocity_s`) before anything
//! else moves (a move, a calibration, another axis's sweep) and when the sweeps end, not between the pieces of a
//! chain (below): the next sets its own. When no point precedes the sweeps, the calibration that opens
//! a session comes first (`crate::schedule::calibration_preamble`). The meter reads back to back while the arm
//! moves: one reading every [`sweep_reading_period_s`] (`averaging` x the detector's sample time, and one
//! exchange), so a piece of motion time `T` gives `floor(T / period)` readings (at least one), each smeared over
//! `speed x averaging x sample time` degrees at cruise. The bands of one piece are swept back and forth (the
//! wheel's shortest covering walk), so consecutive bands need no move. A chain of pieces (consecutive pieces each
//! ending where the next starts: a speed profile's) is swept one way, piece after piece, entered at its end
//! nearer the arm; chains are visited nearest end first. (Visiting the pieces nearest first, a profile whose arm
//! stood mid-arc swept the near half, came back through it and swept the rest.)
//!
//! Calibrations (darks, then the normalisation readings, as the session's opening one) fall due between arcs
//! every `Calibration::sweep_every_s` of instrument time, and close the sweeps when the plan asks for references.
//!
//! # Speed that follows the BRDF
//! An entry with `follow = { first_pass = "out/first/sweeps.csv", tolerance_rel = 2e-3 }` sweeps its arcs in
//! pieces of constant speed, each as fast as the BRDF allows for that smearing tolerance (`speed_deg_s` is the
//! top speed): [`follow`] turns samples of the BRDF along an arc into the pieces and their predicted smearing,
//! [`profile`] makes the samples from a first pass (an earlier sweep of the same arcs, read by the campaign
//! loader) and cuts the path's pieces where the speed changes. Each piece is an arc of its own to the walk and
//! the engine (a move from rest to rest at its speed), so its time is predicted like any sweep's.

pub mod follow;
mod path;
pub mod profile;
mod spec;
mod walk;

use std::collections::BTreeMap;

use gonio_instrument::Instrument;

pub use crate::plan::{FollowSpec, SweepSpec, SweptArm};
pub use path::{EDGE_TOLERANCE_DEG, PathContext, PathVerdict, Piece, SCAN_STEP_DEG, swept_role};
pub use profile::{ArcProfile, PassReading, ProfileError, arc_profile};
pub use spec::{MAX_SWEEP_SPEED_DEG_S, MAX_SWEEPS, MIN_PIECE_DEG, SweepRequest, requests};
pub use walk::{SweepBreakdown, SweepCalibration, SweepSchedule, SweepStep, schedule_sweeps};

use crate::constraints::{Constraints, Reason};
use crate::kinematics::{Geometry, Kinematics};
use crate::plan::PlanError;
use crate::timing::{DETECTOR_SAMPLE_S, EXCHANGE_S, TimeModel};

/// Time between two sweep readings with `averaging` samples each: the meter's integration and one exchange.
pub fn sweep_reading_period_s(averaging: u32) -> f64 {
    f64::from(averaging) * DETECTOR_SAMPLE_S + EXCHANGE_S
}

/// One sweepable arc: a piece of a requested arc.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepArc {
    /// The arc the piece measures: its request, or the request turned about the normal when the piece is
    /// (`Piece::turned`: an isotropic sample's stretch swept without turning the sample).
    pub request: SweepRequest,
    pub piece: Piece,
}

impl SweepArc {
    pub fn length_deg(&self) -> f64 {
        self.piece.to_deg - self.piece.from_deg
    }

    /// The geometries every `step_deg` along the arc from its start (none for a step that is not a positive
    /// number): where a sweep's readings fall, or a bin's worth of them.
    pub fn geometries_every(&self, step_deg: f64) -> impl Iterator<Item = Geometry> + '_ {
        let n = if step_deg.is_finite() && step_deg > 0.0 {
            (self.length_deg() / step_deg).floor() as usize + 1
        } else {
            0
        };
        (0..n).map(move |k| {
            self.request
                .geometry_at(self.piece.from_deg + k as f64 * step_deg)
        })
    }
}

/// The sweeps of a plan, before ordering.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Sweepable arcs, in request order (each request's pieces by increasing angle).
    pub arcs: Vec<SweepArc>,
    /// Requested arcs (entries x held angles x planes).
    pub requested: usize,
    /// Degrees requested, over all arcs (one band).
    pub requested_deg: f64,
    /// Degrees cut by the path check, by rule.
    pub skipped_deg: BTreeMap<Reason, f64>,
    /// Bands each arc is swept in.
    pub bands_nm: Vec<f64>,
}

impl SweepPlan {
    /// Degrees swept per band.
    pub fn swept_deg(&self) -> f64 {
        self.arcs.iter().map(SweepArc::length_deg).sum()
    }
}

/// Validate `[[plan.sweeps]]` and check every arc's path on `instrument`. `light_below_detector`: the side of
/// the arms a point plan already chose; `None` keeps the side that sweeps more. `profiles`: the speed profile
/// of every arc whose entry follows the BRDF (`profile::arc_profile`); those arcs are swept in pieces of one
/// speed each.
pub fn build_sweeps(
    specs: &[SweepSpec],
    instrument: &Instrument,
    time: &TimeModel,
    sample_radius_mm: Option<f64>,
    bands_nm: &[f64],
    light_below_detector: Option<bool>,
    profiles: &[ArcProfile],
) -> Result<SweepPlan, PlanError> {
    let reqs = requests(specs, |arm| {
        instrument.axis(swept_role(arm)).map(|a| a.max_speed_deg_s)
    })?;
    let kinematics = Kinematics::new(instrument);
    let constraints = Constraints::new(instrument, sample_radius_mm);
    let on_side = |side: bool| -> Vec<(SweepRequest, PathVerdict)> {
        let ctx = PathContext {
            instrument,
            kinematics: &kinematics,
            constraints: &constraints,
            time,
            light_below_detector: side,
        };
        reqs.iter().map(|r| (*r, ctx.verdict(r))).collect()
    };
    let swept = |v: &[(SweepRequest, PathVerdict)]| -> f64 {
        v.iter()
            .flat_map(|(_, p)| &p.pieces)
            .map(|p| p.to_deg - p.from_deg)
            .sum()
    };
    let verdicts = match light_below_detector {
        Some(side) => on_side(side),
        None => {
            let (below, above) = (on_side(true), on_side(false));
            if swept(&below) >= swept(&above) {
                below
            } else {
                above
            }
        }
    };
    let mut plan = SweepPlan {
        arcs: Vec::new(),
        requested: reqs.len(),
        requested_deg: reqs.iter().map(SweepRequest::length_deg).sum(),
        skipped_deg: BTreeMap::new(),
        bands_nm: bands_nm.to_vec(),
    };
    for (request, verdict) in verdicts {
        for (reason, deg) in verdict.skipped_deg {
            *plan.skipped_deg.entry(reason).or_default() += deg;
        }
        let follows = specs.get(request.entry).is_some_and(|s| s.follow.is_some());
        let profile = profiles.iter().find(|p| p.matches(&request));
        match (follows, profile) {
            (true, Some(profile)) => plan.arcs.extend(verdict.pieces.iter().flat_map(|piece| {
                profile::split_piece(&request, piece, profile)
                    .into_iter()
                    .map(|(piece, speed_deg_s)| SweepArc {
                        request: SweepRequest {
                            speed_deg_s,
                            ..request.turned_if(piece.turned)
                        },
                        piece,
                    })
            })),
            (true, None) => {
                return Err(PlanError::Invalid {
                    table: format!(".sweeps #{}", request.entry + 1),
                    key: "follow".to_string(),
                    message: format!(
                        "no speed profile for the arc at {} deg in the plane at {} deg (the first pass was not read)",
                        request.held_deg, request.plane_phi_deg
                    ),
                });
            }
            (false, _) => plan.arcs.extend(verdict.pieces.into_iter().map(|piece| SweepArc {
                request: request.turned_if(piece.turned),
                piece,
            })),
        }
    }
    Ok(plan)
}
