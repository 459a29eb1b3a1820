//! One owner of the instrument at a time: the campaign queue, or a person (a console for manual control and
//! alignment drives the same motion layer as a campaign, [`gonio_engine::motion`]).
//!
//! [`Service::take_instrument`] hands the instrument to a person when no campaign runs on it: the queue starts
//! nothing while the lease is held (submitted campaigns stay queued), and the lease is refused while a campaign
//! runs (pause it first). Dropping the [`InstrumentLease`] gives the instrument back to the queue, which starts
//! the next campaign at once. The emergency stop reaches whoever holds the instrument: the lease's motion layer
//! listens to the service's own [`Control`](gonio_engine::control::Control).

use gonio_scheduler::timing::TimeModel;

use super::{Service, ServiceError, lock};
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;

/// The instrument, held by a person until dropped (module doc).
#[derive(Debug)]
pub struct InstrumentLease {
    service: Service,
    holder: String,
    rig: Option<Rig>,
}

impl InstrumentLease {
    /// Who holds the instrument, as they named themselves.
    pub fn holder(&self) -> &str {
        &self.holder
    }

    /// The connected instrument (None when the service's runner has no instrument of its own: queue tests).
    pub fn rig(&self) -> Option<&Rig> {
        self.rig.as_ref()
    }

    /// The motion layer on the held instrument, planning with the instrument's own time model and retrying
    /// each device operation `retries` times; the service's emergency stop halts it.
    pub fn motion(&self, retries: u32) -> Option<Motion<'_>> {
        let rig = self.rig.as_ref()?;
        let time = TimeModel::new(&rig.file().instrument);
        Some(Motion::new(
            rig,
            time,
            retries,
            self.service.shared.control.clone(),
        ))
    }
}

impl Drop for InstrumentLease {
    fn drop(&mut self) {
        let mut run = lock(&self.service.shared.run);
        if run.held_by.as_deref() == Some(self.holder.as_str()) {
            run.held_by = None;
        }
        drop(run);
        tracing::info!(holder = %self.holder, "instrument handed back to the campaign queue");
        self.service.shared.wake.notify_one();
    }
}

impl Service {
    /// Hand the instrument to `holder` (module doc). Refused (`Conflict`) while a campaign runs on it or while
    /// someone else holds it.
    pub fn take_instrument(&self, holder: &str) -> Result<InstrumentLease, ServiceError> {
        let mut run = lock(&self.shared.run);
        if let Some(id) = run.running {
            let what = match lock(&self.shared.store).campaign(id) {
                Ok(c) => format!("campaign {id} ({:?}, {})", c.name, c.state.as_str()),
                Err(_) => format!("campaign {id}"),
            };
            return Err(ServiceError::Conflict(format!(
                "{what} owns the instrument: pause it first, then take the instrument"
            )));
        }
        if let Some(other) = &run.held_by {
            return Err(ServiceError::Conflict(format!(
                "the instrument is held by {other}"
            )));
        }
        run.held_by = Some(holder.to_string());
        // Taking the instrument starts afresh, as starting a run does: an old stop request must not stop the
        // person's first move (nothing is moving: no campaign runs).
        self.shared.control.clear_requests();
        drop(run);
        tracing::info!(%holder, "instrument handed to a person; the campaign queue waits");
        Ok(InstrumentLease {
            service: self.clone(),
            holder: holder.to_string(),
            rig: self.shared.runner.rig(),
        })
    }

    /// Who holds the instrument, when a person does.
    pub fn instrument_holder(&self) -> Option<String> {
        lock(&self.shared.run).held_by.clone()
    }
}
