//! How a run ends: the beam closed, the state it ended in recorded and announced, and for a completed
//! campaign the values' and budgets' parts that need every point (crate::budget's completion).

use super::{Interrupt, Run, lock};
use crate::error::EngineError;
use crate::store::{CampaignState, StoreError};

impl Run<'_> {
    /// The campaign's completion (crate::budget::complete): the points read and the result written under the
    /// store's lock, the model fitted between without it (seconds on a large campaign; status requests go on).
    fn complete_points(&self) -> Result<usize, StoreError> {
        let (record, committed, calibrations) = {
            let s = lock(&self.store);
            (
                s.campaign(self.id)?,
                s.committed_points(self.id)?,
                s.calibrations(self.id)?,
            )
        };
        let dark_sensitivity = |d: &crate::budget::Darkened| self.dark_per_w(d);
        let context = crate::budget::RunContext {
            relative: self.reference.is_some(),
            dark_sensitivity: &dark_sensitivity,
            floor: self.detector.as_ref().map(|detector| crate::budget::NoiseFloor {
                detector,
                averaging: self.c.campaign.acquisition.averaging,
            }),
            sample: crate::budget::SampleSpec {
                radius_mm: self.c.campaign.sample_radius_mm,
                non_uniformity: self.c.campaign.sample_non_uniformity,
            },
        };
        let updates = crate::budget::completions(
            &record,
            &committed,
            &calibrations,
            &self.file.instrument,
            &context,
        );
        lock(&self.store).update_completions(self.id, &updates)?;
        // The sweep readings likewise (crate::budget::sweeps), when there are any.
        let readings = lock(&self.store).committed_sweep_readings(self.id)?;
        if !readings.is_empty() {
            let segments = lock(&self.store).sweep_segments(self.id)?;
            // The points lend their spectra to sweeps swept in fewer bands (the leak's correction).
            let probes = crate::export::points_table(&record, &committed).points;
            let sweeps = crate::budget::sweep_completions(
                &record,
                &readings,
                &probes,
                &segments,
                &calibrations,
                &self.file.instrument,
                &context,
            );
            lock(&self.store).update_sweep_completions(self.id, &sweeps)?;
        }
        Ok(updates.len())
    }

    /// Leave the run in a consistent state and say how it ended.
    pub(super) async fn finish(
        mut self,
        outcome: Result<(), Interrupt>,
    ) -> Result<CampaignState, EngineError> {
        // Close the beam whatever happened (best effort: the wheel may be the device that failed).
        if let Some(blank) = self.blank_position()
            && let Some(w) = self.rig.wheel()
            && self.wheel_at != Some(blank)
        {
            match tokio::time::timeout(std::time::Duration::from_secs(10), w.go_to(blank)).await {
                Ok(Ok(())) => self.wheel_at = Some(blank),
                Ok(Err(e)) => tracing::warn!("closing the beam: {e}"),
                Err(_) => tracing::warn!("closing the beam: the filter wheel did not answer in 10 s"),
            }
        }
        // The instrument is free from here (what follows is computation).
        let ended_s = self.t();
        // What a person asked for (an abort, a pause) is news, not a warning; everything else, the emergency stop
        // included, is for an operator to look at.
        let requested = matches!(outcome, Err(Interrupt::Abort | Interrupt::PauseRequested(_)));
        let (state, message) = match outcome {
            Ok(()) => (CampaignState::Completed, None),
            Err(Interrupt::Abort) => (CampaignState::Aborted, Some("aborted by request".to_string())),
            Err(Interrupt::Estop) => (CampaignState::Paused, Some("emergency stop".to_string())),
            Err(Interrupt::Pause(reason)) => (CampaignState::Paused, Some(reason)),
            Err(Interrupt::PauseRequested(m)) => (CampaignState::Paused, Some(m.to_string())),
            Err(Interrupt::StoreWrite(reason)) => (
                CampaignState::Paused,
                Some(format!(
                    "{reason}: the campaign paused before moving on. Every committed point is kept; free space or \
                     make the store writable, then resume (it continues from the first point not committed)"
                )),
            ),
            Err(Interrupt::Fatal(EngineError::Device(reason))) => (CampaignState::Paused, Some(reason)),
            Err(Interrupt::Fatal(e)) => {
                let msg = e.to_string();
                let _ = lock(&self.store).set_state(self.id, CampaignState::Failed, Some(&msg));
                self.emit_state(CampaignState::Failed, Some(msg));
                return Err(e);
            }
        };
        if let Some(m) = &message {
            if requested {
                tracing::info!(campaign = %self.id, state = %state, "{m}");
            } else {
                tracing::warn!(campaign = %self.id, state = %state, "{m}");
            }
        }
        // The values' and budgets' parts that need every point (crate::budget::complete), before the campaign
        // reads as completed: an export of a completed campaign always has them.
        if state == CampaignState::Completed
            && let Err(e) = self.complete_points()
        {
            tracing::warn!(campaign = %self.id, "cannot complete the points' values and budgets: {e}");
        }
        {
            let mut s = lock(&self.store);
            let _ = s.set_operator_message(self.id, None);
            // How long the instrument was held, the closing wheel turn and operator step included (no reading
            // records them): what the time model predicts.
            if let Err(e) = s.set_ended_instrument_s(self.id, ended_s) {
                tracing::warn!("cannot record when the run ended: {e}");
            }
            if let Err(e) = s.set_state(self.id, state, message.as_deref()) {
                // A store that cannot be written cannot record the pause: the store shows it from memory (status
                // requests see it), and the file still says "running", which a restart resumes.
                tracing::warn!("cannot record the campaign state {state}: {e}");
            }
        }
        self.emit_state(state, message);
        Ok(state)
    }
}
