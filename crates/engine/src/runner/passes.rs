//! Adaptive plans at run time: which pass holds the next point (replayed from the committed points on a
//! resume), the next pass from the planner, and the ETA that follows the pass being measured.

use gonio_campaign::passes::After;
use gonio_scheduler::kinematics::Geometry;

use super::*;

/// One pass of the schedule: a fixed plan's only one, or one of an adaptive plan's.
pub(super) struct Pass {
    pub(super) schedule: gonio_scheduler::schedule::Schedule,
    /// Index of its first point.
    pub(super) first_index: u64,
    /// Predicted instrument time of this pass and every one before it (s).
    pub(super) elapsed_s: f64,
    pub(super) number: u32,
}

impl Pass {
    pub(super) fn end_index(&self) -> u64 {
        self.first_index + self.schedule.measure_steps().count() as u64
    }
}

impl<'a> Run<'a> {
    /// The pass that holds point `self.done`: the schedule of a fixed plan; for an adaptive one, the passes are
    /// derived again from the committed points, exactly as the run that committed them derived them. None when
    /// the adaptive planner stops before that point.
    pub(super) fn locate_pass(&mut self) -> Result<Option<Pass>, Interrupt> {
        let mut pass = Pass {
            schedule: self.c.schedule.clone(),
            first_index: 0,
            elapsed_s: self.c.schedule.breakdown.total_s() + self.first_sweeps_s(),
            number: 0,
        };
        while self.c.adaptive.is_some() && self.done >= pass.end_index() {
            match self.next_pass(&pass)? {
                Some(next) => pass = next,
                None => return Ok(None),
            }
        }
        Ok(Some(pass))
    }

    /// The pass after `pass` (an adaptive plan; a fixed one has one pass), from every point committed up to the
    /// end of `pass`, read back from the store. When the planner stops, a total below the budget becomes the
    /// campaign's total.
    pub(super) fn next_pass(&mut self, pass: &Pass) -> Result<Option<Pass>, Interrupt> {
        if self.c.adaptive.is_none() {
            return Ok(None);
        }
        let end = pass.end_index();
        // Only the points committed since the last pass are read; the earlier ones are kept from then.
        let from = self.measured_to;
        let new = self.st(|s| s.point_values(self.id, from, end))?;
        self.measured.extend(new.iter().map(|p| {
            (
                Geometry::new(p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg),
                p.brdf_sr,
            )
        }));
        self.measured_to = self.measured_to.max(end);
        // A first pass of sweeps: its readings, binned as the planner takes them, read once (they are all
        // committed before the first point: `go`).
        if self.swept.is_none()
            && let Some(adaptive) = self.c.adaptive.as_ref().filter(|_| self.c.sweeps_first())
        {
            let readings = self.st(|s| s.committed_sweep_readings(self.id))?;
            self.swept = Some(gonio_campaign::passes::swept_values(
                adaptive,
                readings.iter().map(|r| {
                    (
                        Geometry::new(r.theta_i_deg, r.phi_i_deg, r.theta_o_deg, r.phi_o_deg),
                        r.brdf_sr,
                    )
                }),
            ));
        }
        let swept = self.swept.as_deref().unwrap_or_default();
        let (measured, counted) = gonio_campaign::passes::planner_input(swept, &self.measured);
        let Some(adaptive) = &self.c.adaptive else {
            return Ok(None);
        };
        let after = self.after(pass);
        match adaptive.next_pass(&measured, counted, pass.elapsed_s, after, &mut self.batch_memo) {
            NextPass::Pass {
                schedule,
                error_estimate,
            } => {
                let points = schedule.measure_steps().count();
                tracing::info!(
                    campaign = %self.id,
                    pass = pass.number + 1,
                    first_point = end,
                    points,
                    error_estimate,
                    "adaptive plan: next pass placed from the points measured"
                );
                Ok(Some(Pass {
                    elapsed_s: pass.elapsed_s + schedule.breakdown.total_s(),
                    schedule,
                    first_index: end,
                    number: pass.number + 1,
                }))
            }
            NextPass::Done {
                reason,
                error_estimate,
            } => {
                // The passes' predicted time beside the instrument time they took: how far the model was off on
                // the passes this run placed (a rehearsal places its own).
                tracing::info!(
                    campaign = %self.id,
                    points = end,
                    ?reason,
                    error_estimate,
                    passes_predicted_s = pass.elapsed_s,
                    instrument_s = self.motion.clock().now_s() - self.t_clock0,
                    "adaptive plan complete"
                );
                if end < self.total {
                    self.st(|s| s.set_total_points(self.id, end))?;
                    self.total = end;
                    // Clients learn the final total now (the last point's report still named the budget).
                    self.progress(None);
                }
                Ok(None)
            }
        }
    }

    /// Where `pass` leaves the instrument. The first pass of points is empty after a first pass of sweeps: what
    /// follows starts where they ended.
    fn after(&self, pass: &Pass) -> After {
        match &self.c.sweeps {
            Some(sweeps) if sweeps.first && pass.number == 0 => After::sweeps(&sweeps.schedule),
            _ => After::schedule(&pass.schedule),
        }
    }

    /// An adaptive plan's closing calibration once its planner has stopped after `pass`
    /// (`AdaptivePlan::closing`: darks, and the normalisation readings under a cadence), as a fixed plan's
    /// schedule closes. Without it the points measured after the last dark were net of that dark held
    /// (the values are net of the dark interpolated between the darks around them). Nothing for a fixed plan:
    /// its schedule holds its own.
    pub(super) async fn close_passes(&mut self, pass: &Pass, bands: &[f64]) -> Result<(), Interrupt> {
        let Some(adaptive) = self.c.adaptive.as_ref() else {
            return Ok(());
        };
        if let Some(closing) = adaptive.closing(self.after(pass)) {
            tracing::info!(
                campaign = %self.id,
                steps = closing.steps.len(),
                predicted_s = closing.breakdown.total_s(),
                "adaptive plan: closing calibration"
            );
            self.run_steps(&closing.steps, 0, bands).await?;
        }
        Ok(())
    }

    /// Progress and ETA follow `pass`: the rest of its predicted time, plus, for an adaptive plan, the rest of
    /// the budget at the predicted time per point of the passes placed so far.
    pub(super) fn follow_pass(&mut self, pass: &Pass) {
        self.pass_total_s = pass.schedule.breakdown.total_s();
        self.pass_start_s = pass.elapsed_s - self.pass_total_s;
        self.pass_end = pass.end_index();
        self.s_per_point = (pass.elapsed_s - self.first_sweeps_s()) / pass.end_index().max(1) as f64;
    }

    /// The predicted time of an adaptive plan's first pass of sweeps (s; 0 without one).
    pub(super) fn first_sweeps_s(&self) -> f64 {
        match &self.c.sweeps {
            Some(s) if s.first => s.schedule.breakdown.total_s(),
            _ => 0.0,
        }
    }
}
