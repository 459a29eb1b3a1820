//! Adaptive plans at run time: each pass after the first is placed by the scheduler's adaptive planner from the
//! points measured so far, until the point budget, the time budget or the target error is reached.
//!
//! Determinism (what resuming relies on): a pass is a pure function of the points committed before it (their
//! geometries and values, read back from the store), the predicted instrument time of the passes before it, and
//! where the pass before it ended (its last pose and calibration cadence). A campaign resumed after any
//! interruption replays the same derivation from the same committed points and so places the same passes as an
//! uninterrupted run that measured the same values.
//!
//! Points and budgets: `budget_points` counts points as everywhere else (one geometry at one band, each repeat
//! counted), so a campaign at B bands with R repeats measures at most `budget_points / (B x R)` geometries. The
//! planner refines on one value per geometry: the mean of that geometry's valid BRDF values over its bands
//! ([`measured_geometries`]); failed and saturated readings carry no value.
//!
//! Time budget: `budget_s` is compared with the predicted instrument time of the passes placed so far (the
//! schedules' own predictions), not with a clock, so that the decision does not depend on when a resume happened.
//!
//! A first pass of sweeps (`first_pass_sweeps`): the campaign's sweeps are the planner's first pass and run
//! before any point; the first pass of points is empty. Every later pass is placed from the sweep readings
//! (binned: `gonio_scheduler::adaptive::Adaptive::sweep_bin`) and the points measured so far, and only the
//! points count against `budget_points` ([`planner_input`]). The sweeps' predicted time counts against
//! `budget_s`.

use gonio_scheduler::adaptive::{Adaptive, BatchMemo, Measured, StopReason};
use gonio_scheduler::kinematics::{Geometry, Pose};
use gonio_scheduler::plan::AdaptiveSpec;
use gonio_scheduler::plan::{self, BuildContext, Plan, PlanError, PlanSpec};
use gonio_scheduler::schedule::{self, Cadence, Schedule};
use gonio_scheduler::sweep::SweepSchedule;

use gonio_scheduler::timing::TimeModel;

/// Where the work before a pass left the instrument: its pose (None: unknown) and the calibration cadence.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct After {
    pub pose: Option<Pose>,
    pub cadence: Cadence,
}

impl After {
    /// After a pass of points.
    pub fn schedule(s: &Schedule) -> After {
        After {
            pose: s.steps.last().map(|s| s.pose),
            cadence: s.end,
        }
    }

    /// After a first pass of sweeps: where they end, the calibration they close with just taken.
    pub fn sweeps(s: &SweepSchedule) -> After {
        let (pose, wheel) = match s.end {
            Some((pose, wheel)) => (Some(pose), wheel),
            None => (None, None),
        };
        After {
            pose,
            cadence: Cadence {
                wheel,
                ..Cadence::default()
            },
        }
    }
}

/// The adaptive planner of one campaign, with what it needs to place and order a pass.
#[derive(Debug, Clone)]
pub struct AdaptivePlan {
    pub(crate) adaptive: Adaptive,
    /// `[plan]` without the grid and the adaptive table: bands, repeats, calibration cadence.
    batch_spec: PlanSpec,
    pub(crate) instrument: gonio_instrument::Instrument,
    traits: gonio_scheduler::plan::SampleTraits,
    sample_radius_mm: Option<f64>,
    pub(crate) time: TimeModel,
    /// Points (measure steps) per geometry: bands x repeats.
    points_per_geometry: u64,
    budget_points: u64,
}

/// What comes after a pass.
#[derive(Debug, Clone)]
pub enum NextPass {
    /// Measure this schedule next.
    Pass {
        schedule: Schedule,
        /// The planner's largest local error estimate before this pass (ln(1 + f) units).
        error_estimate: f64,
    },
    /// The campaign is complete.
    Done { reason: StopReason, error_estimate: f64 },
}

impl AdaptivePlan {
    pub(crate) fn new(
        spec: &AdaptiveSpec,
        plan_spec: &PlanSpec,
        ctx: &BuildContext,
        time: TimeModel,
    ) -> Result<AdaptivePlan, PlanError> {
        let mut batch_spec = plan_spec.clone();
        batch_spec.adaptive = None;
        batch_spec.grid = None;
        // The bands the plan measures (validated by the plan builder on the first pass).
        let bands = plan_spec.bands_nm.as_ref().map_or(1, |b| b.len().max(1)) as u64;
        let points_per_geometry = bands * u64::from(plan_spec.repeats.max(1));
        let budget_points = u64::from(spec.budget_points);
        let geometries = (budget_points / points_per_geometry).max(1);
        let mut geometry_spec = spec.clone();
        geometry_spec.budget_points = u32::try_from(geometries).unwrap_or(u32::MAX);
        let adaptive = Adaptive::new(&geometry_spec, ctx)?;
        Ok(AdaptivePlan {
            adaptive,
            batch_spec,
            instrument: ctx.instrument.clone(),
            traits: ctx.traits,
            sample_radius_mm: ctx.sample_radius_mm,
            time,
            points_per_geometry,
            budget_points: geometries * points_per_geometry,
        })
    }

    /// The most points the campaign measures (the budget, rounded down to whole geometries).
    pub fn budget_points(&self) -> u64 {
        self.budget_points
    }

    /// Points (measure steps) per geometry: bands x repeats.
    pub fn points_per_geometry(&self) -> u64 {
        self.points_per_geometry
    }

    /// The planner itself (its interpolation, for reconstructing the BRDF from the points measured).
    pub fn planner(&self) -> &Adaptive {
        &self.adaptive
    }

    /// True when the first pass sweeps (`first_pass_sweeps`): the campaign's sweeps run before any point.
    pub fn sweeps_first(&self) -> bool {
        self.adaptive.first_pass_sweeps().is_some()
    }

    /// The first pass as a plan: of no point when the first pass sweeps.
    pub(crate) fn first_plan(&self, ctx: &BuildContext) -> Result<Plan, PlanError> {
        let first = if self.sweeps_first() {
            Vec::new()
        } else {
            self.adaptive.first_pass()
        };
        plan::build_from_geometries(&self.batch_spec, ctx, &first, true)
    }

    /// The pass after the work `after` left the instrument in, from every geometry measured so far (of which
    /// `points` count against the budget: [`planner_input`]) and the predicted instrument time of all the work
    /// so far (`elapsed_s`). Deterministic (module doc). `memo`: the planner's memory of the passes before
    /// (one per run; a fresh one places the same pass, only slower).
    pub fn next_pass(
        &self,
        measured: &[Measured],
        points: usize,
        elapsed_s: f64,
        after: After,
        memo: &mut BatchMemo,
    ) -> NextPass {
        let batch = self
            .adaptive
            .next_batch_remembering(measured, points, elapsed_s, memo);
        let error_estimate = batch.error_estimate;
        if let Some(reason) = batch.done {
            return NextPass::Done {
                reason,
                error_estimate,
            };
        }
        let start = after.pose;
        let ctx = BuildContext {
            instrument: &self.instrument,
            traits: self.traits,
            sample_radius_mm: self.sample_radius_mm,
            start,
        };
        // A batch that fills the budget is the last pass: ordered towards the closing that follows it.
        let last = (points + batch.geometries.len()) as u64 * self.points_per_geometry >= self.budget_points;
        let schedule = plan::build_from_geometries(&self.batch_spec, &ctx, &batch.geometries, true)
            .ok()
            .map(|p| {
                let continuing = if last {
                    schedule::schedule_last
                } else {
                    schedule::schedule_continuing
                };
                continuing(&p, &self.time, start.as_ref(), Some(after.cadence))
            });
        match schedule {
            // Nothing of the batch can be measured: the planner would only propose it again.
            Some(s) if s.measure_steps().next().is_some() => NextPass::Pass {
                schedule: s,
                error_estimate,
            },
            _ => NextPass::Done {
                reason: StopReason::NoCandidates,
                error_estimate,
            },
        }
    }

    /// The calibration that closes the campaign once the planner stops, after the work `after` left the
    /// instrument in ([`schedule::schedule_closing`]): the run takes these steps and its rehearsal counts them.
    /// None when nothing was measured (no pose to close at: the run ends as it began).
    pub fn closing(&self, after: After) -> Option<Schedule> {
        let at = after.pose?;
        let ctx = BuildContext {
            instrument: &self.instrument,
            traits: self.traits,
            sample_radius_mm: self.sample_radius_mm,
            start: Some(at),
        };
        let plan = plan::build_from_geometries(&self.batch_spec, &ctx, &[], true).ok()?;
        Some(schedule::schedule_closing(&plan, &self.time, at, after.cadence))
    }
}

/// A first pass of sweeps as the planner takes it: each reading `(geometry at its arc's centre, BRDF in 1/sr or
/// None)` at its bin's geometry (`Adaptive::sweep_bin`); [`planner_input`] averages each bin.
pub fn swept_values(
    adaptive: &AdaptivePlan,
    readings: impl IntoIterator<Item = (Geometry, Option<f64>)>,
) -> Vec<(Geometry, Option<f64>)> {
    readings
        .into_iter()
        .map(|(g, v)| (adaptive.adaptive.sweep_bin(&g), v))
        .collect()
}

/// What the planner places a pass from: one value per geometry over the binned sweep readings (`swept`, from
/// [`swept_values`]; empty without a first pass of sweeps) and the points measured so far, and how many of
/// those geometries are points (what the budget counts).
pub fn planner_input(
    swept: &[(Geometry, Option<f64>)],
    points: &[(Geometry, Option<f64>)],
) -> (Vec<Measured>, usize) {
    if swept.is_empty() {
        let measured = measured_geometries(points.iter().copied());
        let n = measured.len();
        return (measured, n);
    }
    let counted = measured_geometries(points.iter().copied()).len();
    let measured = measured_geometries(swept.iter().chain(points).copied());
    (measured, counted)
}

/// One value per geometry for the planner, from points in measurement order: `(geometry, BRDF in 1/sr or None
/// for a failed or saturated reading)`. A geometry's value is the mean of its valid values (over bands and
/// repeats); geometries without one are left out. Order: each geometry's first appearance.
pub fn measured_geometries(points: impl IntoIterator<Item = (Geometry, Option<f64>)>) -> Vec<Measured> {
    let key = |g: &Geometry| {
        [
            g.theta_i_deg.to_bits(),
            g.phi_i_deg.to_bits(),
            g.theta_o_deg.to_bits(),
            g.phi_o_deg.to_bits(),
        ]
    };
    let mut order: Vec<(Geometry, f64, u32)> = Vec::new();
    let mut index: std::collections::HashMap<[u64; 4], usize> = std::collections::HashMap::new();
    for (g, value) in points {
        let slot = *index.entry(key(&g)).or_insert_with(|| {
            order.push((g, 0.0, 0));
            order.len() - 1
        });
        if let Some(v) = value.filter(|v| v.is_finite())
            && let Some(entry) = order.get_mut(slot)
        {
            entry.1 += v;
            entry.2 += 1;
        }
    }
    order
        .into_iter()
        .filter(|(_, _, n)| *n > 0)
        .map(|(geometry, sum, n)| Measured {
            geometry,
            value: sum / f64::from(n),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_value_per_geometry_the_mean_of_its_valid_bands_in_first_appearance_order() {
        let a = Geometry::new(0.0, 0.0, 30.0, 180.0);
        let b = Geometry::new(30.0, 0.0, 30.0, 180.0);
        let c = Geometry::new(60.0, 0.0, 10.0, 180.0);
        let m = measured_geometries([
            (b, Some(2.0)),
            (a, Some(1.0)),
            (b, Some(4.0)),
            (c, None),
            (a, None),
            (a, Some(f64::NAN)),
            (a, Some(3.0)),
        ]);
        assert_eq!(m.len(), 2, "c has no valid value: {m:?}");
        assert_eq!(m[0].geometry, b);
        assert_eq!(m[0].value, 3.0);
        assert_eq!(m[1].geometry, a);
        assert_eq!(m[1].value, 2.0);
    }
}
