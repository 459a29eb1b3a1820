//! The control API's requests: submitting, showing, pausing, resuming, aborting and confirming campaigns, and
//! the emergency stop. Each is routed by the campaign's state: to the engine for the campaign on the instrument,
//! straight to the store for the others.

use super::{CampaignView, KEEP_PREPARED, RunState, Service, ServiceError, Submission, lock};
use gonio_engine::control::Event;
use gonio_engine::store::{CampaignId, CampaignRecord, CampaignState};

impl Service {
    /// Validate and queue a campaign.
    pub fn submit(&self, campaign_toml: &str, origin: &str) -> Result<CampaignId, ServiceError> {
        let Submission {
            campaign: mut new,
            prepared,
        } = self.shared.runner.prepare(campaign_toml, origin)?;
        // The current calibration goes with the campaign (the run loop applies what is stored with it).
        if let Some(c) = self.current_calibration() {
            new.alignment_toml = Some(c.toml);
            new.calibration_id = Some(c.id);
        }
        let id = lock(&self.shared.store).create_campaign(&new)?;
        if let Some(p) = prepared {
            let mut run = lock(&self.shared.run);
            if run.prepared.len() < KEEP_PREPARED {
                run.prepared.insert(id, p);
            }
        }
        tracing::info!(
            campaign = %id,
            name = %new.name,
            points = new.total_points,
            calibration = ?new.calibration_id,
            "campaign queued"
        );
        self.emit_state(id, CampaignState::Queued, None);
        self.shared.wake.notify_one();
        Ok(id)
    }

    pub fn campaigns(&self) -> Result<Vec<CampaignView>, ServiceError> {
        let records = lock(&self.shared.store).campaigns()?;
        let run = lock(&self.shared.run);
        Ok(records.into_iter().map(|r| view(r, &run)).collect())
    }

    pub fn campaign(&self, id: CampaignId) -> Result<CampaignView, ServiceError> {
        let record = lock(&self.shared.store).campaign(id)?;
        Ok(view(record, &lock(&self.shared.run)))
    }

    /// The points of a campaign as CSV.
    pub fn points_csv(&self, id: CampaignId) -> Result<String, ServiceError> {
        let store = lock(&self.shared.store);
        let record = store.campaign(id)?;
        self.shared
            .runner
            .points_csv(&store, &record)
            .map_err(ServiceError::from)
    }

    /// A campaign's measurement report, as `gonio report --data DIR --campaign ID` writes it (every model fitted):
    /// read from the store under its lock, fitted and drawn after it (that takes seconds).
    pub fn report_html(&self, id: CampaignId) -> Result<String, ServiceError> {
        let (run, sweeps) = {
            let store = lock(&self.shared.store);
            let record = store.campaign(id)?;
            (
                gonio_engine::export::run_of(&store, &record, "the daemon's store")?,
                gonio_engine::export::sweep_readings(&store, id)?,
            )
        };
        let now_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let (page, _) =
            gonio_engine::export::report(&run, &sweeps, &gonio_results::fit::FitModel::ALL, now_s, |_| {})
                .map_err(|e| ServiceError::Internal(format!("report of campaign {id}: {e}")))?;
        Ok(page)
    }

    /// Pause: the running campaign at its next safe point; a queued one leaves the queue.
    pub fn pause(&self, id: CampaignId) -> Result<CampaignView, ServiceError> {
        let mut run = lock(&self.shared.run);
        let record = lock(&self.shared.store).campaign(id)?;
        if run.running == Some(id) && !record.state.is_final() {
            if matches!(record.state, CampaignState::Pausing | CampaignState::Paused) {
                return Err(conflict(&record, "pause", "it is already pausing"));
            }
            run.pending_pause = true;
            run.user_paused = true;
            self.shared.control.pause();
            tracing::info!(campaign = %id, "pause requested");
            return Ok(view(record, &run));
        }
        match record.state {
            CampaignState::Queued => {
                drop(run);
                self.set_state(id, CampaignState::Paused, None)
            }
            _ => Err(conflict(
                &record,
                "pause",
                "only a queued or running campaign can be paused",
            )),
        }
    }

    /// Resume: a paused campaign goes back into the queue; a campaign still pausing keeps running.
    pub fn resume(&self, id: CampaignId) -> Result<CampaignView, ServiceError> {
        let mut run = lock(&self.shared.run);
        let record = lock(&self.shared.store).campaign(id)?;
        if run.running == Some(id) && record.state == CampaignState::Pausing {
            run.pending_pause = false;
            run.user_paused = false;
            self.shared.control.resume();
            tracing::info!(campaign = %id, "pause withdrawn");
            return Ok(view(record, &run));
        }
        match record.state {
            CampaignState::Paused if run.running != Some(id) => {
                drop(run);
                let v = self.set_state(id, CampaignState::Queued, None)?;
                self.shared.wake.notify_one();
                Ok(v)
            }
            CampaignState::Paused => Err(conflict(
                &record,
                "resume",
                "it is still stopping; retry in a moment",
            )),
            _ => Err(conflict(
                &record,
                "resume",
                "only a paused campaign can be resumed",
            )),
        }
    }

    /// Abort: the running campaign at its next safe point; a queued or paused one at once.
    pub fn abort(&self, id: CampaignId) -> Result<CampaignView, ServiceError> {
        let mut run = lock(&self.shared.run);
        let record = lock(&self.shared.store).campaign(id)?;
        if record.state.is_final() {
            return Err(conflict(&record, "abort", "it has already ended"));
        }
        if run.running == Some(id) {
            run.pending_abort = true;
            self.shared.control.abort();
            tracing::info!(campaign = %id, "abort requested");
            return Ok(view(record, &run));
        }
        drop(run);
        self.set_state(id, CampaignState::Aborted, None)
    }

    /// The operator did what the `waiting-operator` message asked.
    pub fn confirm(&self, id: CampaignId) -> Result<CampaignView, ServiceError> {
        let run = lock(&self.shared.run);
        let record = lock(&self.shared.store).campaign(id)?;
        if run.running == Some(id) && record.state == CampaignState::WaitingOperator {
            self.shared.control.confirm();
            tracing::info!(campaign = %id, "operator confirmed");
            return Ok(view(record, &run));
        }
        Err(conflict(
            &record,
            "confirm",
            "only a campaign waiting for the operator can be confirmed",
        ))
    }

    /// Emergency stop: halt the instrument now and hold the queue (every queued campaign is paused).
    pub fn estop(&self) -> Result<(), ServiceError> {
        tracing::warn!("emergency stop");
        // Hold the run lock throughout, so that the queue loop cannot start the next campaign between the stop
        // and the holding of the queue. Taking it never waits on the instrument.
        let run = lock(&self.shared.run);
        self.shared.control.estop();
        let message = "emergency stop: resume to put it back in the queue";
        let mut held = Vec::new();
        {
            let mut store = lock(&self.shared.store);
            let queued: Vec<CampaignId> = store
                .campaigns()?
                .into_iter()
                .filter(|c| c.state == CampaignState::Queued && run.running != Some(c.id))
                .map(|c| c.id)
                .collect();
            for id in queued {
                store.set_state(id, CampaignState::Paused, Some(message))?;
                held.push(id);
            }
        }
        drop(run);
        for id in held {
            self.emit_state(id, CampaignState::Paused, Some(message.to_string()));
        }
        Ok(())
    }

    pub(super) fn set_state(
        &self,
        id: CampaignId,
        state: CampaignState,
        message: Option<&str>,
    ) -> Result<CampaignView, ServiceError> {
        let record = {
            let mut store = lock(&self.shared.store);
            store.set_state(id, state, message)?;
            store.campaign(id)?
        };
        tracing::info!(campaign = %id, %state, "campaign state set");
        self.emit_state(id, state, message.map(str::to_string));
        Ok(view(record, &lock(&self.shared.run)))
    }

    fn emit_state(&self, campaign: CampaignId, state: CampaignState, message: Option<String>) {
        self.shared.control.emit(Event::State {
            campaign,
            state,
            message,
        });
    }
}

fn view(r: CampaignRecord, run: &RunState) -> CampaignView {
    let on_instrument = run.running == Some(r.id) && !r.state.is_final();
    CampaignView {
        eta_s: if on_instrument {
            run.eta_s.get(&r.id).copied()
        } else {
            None
        },
        id: r.id,
        name: r.name,
        state: r.state,
        points_done: r.points_done,
        total_points: r.total_points,
        last_error: r.last_error,
        operator_message: r.operator_message,
        dry_run: r.dry_run,
        created_unix_s: r.created_unix_s,
        software_version: r.software_version,
        calibration_id: r.calibration_id,
    }
}

fn conflict(record: &CampaignRecord, action: &str, why: &str) -> ServiceError {
    ServiceError::Conflict(format!(
        "cannot {action} campaign {} ({}): {why}",
        record.id, record.state
    ))
}
