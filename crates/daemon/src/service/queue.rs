//! The queue loop: picking the next campaign (interrupted ones first, then the oldest queued), running it on the
//! instrument while following its events, and stopping it at a safe point when the daemon shuts down.

use std::time::Duration;

use tokio::sync::{broadcast, mpsc};

use super::{ESTOP_GRACE, RunFuture, Service, ServiceError, Shutdown, lock};
use gonio_engine::control::Event;
use gonio_engine::store::{CampaignId, CampaignState};

impl Service {
    /// The next campaign to run: an interrupted one first, else the oldest queued one. Marks it running in the
    /// service (under the same lock the requests take).
    fn take_next(&self) -> Result<Option<CampaignId>, ServiceError> {
        let mut run = lock(&self.shared.run);
        if run.held_by.is_some() {
            // A person holds the instrument; handing it back wakes the loop.
            return Ok(None);
        }
        let store = lock(&self.shared.store);
        while let Some(id) = run.resume_first.pop_front() {
            match store.campaign(id) {
                // Still interrupted (not aborted meanwhile): resume it.
                Ok(c) if c.state.was_interrupted() => {
                    run.running = Some(id);
                    run.pending_pause = false;
                    run.pending_abort = false;
                    run.user_paused = false;
                    return Ok(Some(id));
                }
                Ok(_) => {}
                Err(e) => tracing::error!(campaign = %id, "cannot resume: {e}"),
            }
        }
        let next = store
            .campaigns()?
            .into_iter()
            .find(|c| c.state == CampaignState::Queued)
            .map(|c| c.id);
        if next.is_some() {
            run.running = next;
            run.pending_pause = false;
            run.pending_abort = false;
            run.user_paused = false;
        }
        Ok(next)
    }

    /// The queue loop: runs campaigns one at a time until shutdown. `_complete` is dropped when the loop has
    /// finished (the campaign on the instrument stopped), which is what the caller waits for.
    pub async fn run_queue(&self, mut shutdown: Shutdown, _complete: mpsc::Sender<()>) {
        let mut events = self.subscribe();
        loop {
            if shutdown.is_shutdown() {
                break;
            }
            // Register for a wake-up before looking, so that a submission in between is not missed.
            let woken = self.shared.wake.notified();
            let next = match self.take_next() {
                Ok(next) => next,
                Err(e) => {
                    tracing::error!("cannot read the queue: {e}");
                    None
                }
            };
            let Some(id) = next else {
                tokio::select! {
                    _ = woken => {}
                    _ = shutdown.recv() => break,
                    // Re-check now and then: a store error above must not stall the queue for good.
                    _ = tokio::time::sleep(Duration::from_secs(5)) => {}
                }
                continue;
            };
            let stopped_by_shutdown = self.run_one(id, &mut shutdown, &mut events).await;
            lock(&self.shared.run).running = None;
            if stopped_by_shutdown {
                break;
            }
        }
        tracing::info!("campaign queue stopped");
    }

    /// Run one campaign to its end or pause, following its events. Returns true when shutdown stopped it.
    async fn run_one(
        &self,
        id: CampaignId,
        shutdown: &mut Shutdown,
        events: &mut broadcast::Receiver<Event>,
    ) -> bool {
        tracing::info!(campaign = %id, "campaign starts");
        let prepared = lock(&self.shared.run).prepared.remove(&id);
        let mut run = self.shared.runner.run(
            self.shared.store.clone(),
            id,
            self.shared.control.clone(),
            prepared,
        );
        let result = loop {
            tokio::select! {
                result = &mut run => break Some(result),
                event = events.recv() => self.observe(event),
                _ = shutdown.recv() => break None,
            }
        };
        let result = match result {
            Some(result) => result,
            None => {
                self.stop_for_shutdown(id, run).await;
                return true;
            }
        };
        match result {
            Ok(state) => tracing::info!(campaign = %id, %state, "campaign run returned"),
            Err(e) => {
                // The engine could not even keep the store up to date: record the failure ourselves.
                let message = e.to_string();
                tracing::error!(campaign = %id, "campaign run failed: {message}");
                let store_state = lock(&self.shared.store).campaign(id).map(|c| c.state);
                if !matches!(store_state, Ok(s) if s.is_final() || s == CampaignState::Paused)
                    && let Err(e) = self.set_state(id, CampaignState::Failed, Some(&message))
                {
                    tracing::error!(campaign = %id, "cannot record the failure: {e}");
                }
            }
        }
        // Progress events for this campaign may still be queued; they carry nothing the store lacks.
        false
    }

    /// Follow the engine's events: ETA, and re-applying requests made as the run started.
    fn observe(&self, event: Result<Event, broadcast::error::RecvError>) {
        let event = match event {
            Ok(e) => e,
            Err(broadcast::error::RecvError::Lagged(n)) => {
                tracing::warn!(missed = n, "service fell behind the engine's events");
                return;
            }
            // The Control (and so the sender) lives as long as the service: cannot close while we run.
            Err(broadcast::error::RecvError::Closed) => return,
        };
        let mut run = lock(&self.shared.run);
        match event {
            Event::Progress { campaign, eta_s, .. } => match eta_s {
                Some(eta) => {
                    run.eta_s.insert(campaign, eta);
                }
                None => {
                    run.eta_s.remove(&campaign);
                }
            },
            Event::State { campaign, state, .. } if run.running == Some(campaign) => {
                if state == CampaignState::Running {
                    if run.pending_pause {
                        self.shared.control.pause();
                    }
                    if run.pending_abort {
                        self.shared.control.abort();
                    }
                }
                if state.is_final() {
                    run.eta_s.remove(&campaign);
                }
            }
            _ => {}
        }
    }

    /// Shutdown while a campaign runs: pause at a safe point within the grace period, else emergency stop; then
    /// leave the campaign `running` in the store (interrupted) unless a person had paused it.
    async fn stop_for_shutdown(&self, id: CampaignId, mut run: RunFuture) {
        tracing::info!(campaign = %id, grace_s = self.shared.shutdown_grace.as_secs_f64(), "shutdown: pausing");
        self.shared.control.pause();
        let mut returned = tokio::time::timeout(self.shared.shutdown_grace, &mut run)
            .await
            .ok();
        if returned.is_none() {
            tracing::warn!(campaign = %id, "no safe point within the grace period: emergency stop");
            self.shared.control.estop();
            returned = tokio::time::timeout(ESTOP_GRACE, &mut run).await.ok();
        }
        drop(run);
        let user_paused = lock(&self.shared.run).user_paused;
        let state = lock(&self.shared.store).campaign(id).map(|c| c.state);
        tracing::info!(campaign = %id, ?returned, ?state, "campaign stopped for shutdown");
        if let Ok(state) = state
            && !state.is_final()
            && !(user_paused && state == CampaignState::Paused)
            && let Err(e) = lock(&self.shared.store).set_state(id, CampaignState::Running, None)
        {
            tracing::error!(campaign = %id, "cannot mark the campaign interrupted: {e}");
        }
    }
}
