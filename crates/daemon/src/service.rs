//! The daemon's core: one instrument, a FIFO queue of campaigns, and the requests of the control API.
//!
//! - Campaigns run ONE AT A TIME on the instrument, in submission order (the lowest-id `queued` campaign next).
//!   Campaigns found interrupted at start-up (`running`, `pausing`, `waiting-operator` in the store: the daemon
//!   stopped under them) are resumed first, from their first uncommitted point.
//! - Requests are routed by the campaign's state: to the engine's [`Control`] for the campaign on the instrument
//!   (it acts at its next safe point), or straight to the store for a campaign that is not running (pausing a
//!   queued campaign takes it out of the queue; resuming a paused one puts it back in).
//! - The emergency stop halts the instrument at once and pauses every queued campaign, so that nothing moves again
//!   until a person resumes a campaign.
//! - Shutdown (SIGINT/SIGTERM) in the mini-redis style: a [`Shutdown`] signal every task watches, and a
//!   completion channel the caller waits on. The running campaign is asked to pause at its next safe point within a
//!   grace period (else it is emergency-stopped); it is then left `running` in the store, which is what an
//!   interrupted campaign looks like, so the next start resumes it first. Every point is committed in its own
//!   transaction, so the store is consistent whatever moment the stop comes.

//!
//! - One owner at a time: a person may take the instrument from the queue between campaigns
//!   ([`Service::take_instrument`], `ownership`); the queue starts nothing until it is handed back.
//!
//! - The console ([`Service::console`], `console`): a person's moves, homing, wheel and meter readings, each
//!   taking the instrument for its duration under the same rule.
//!
//! - Calibrations (`calibration`): the instrument's calibrations kept in the store, and the current one, applied
//!   to every campaign submitted and to the console's moves by geometry: `gonio daemon --calibration FILE` if
//!   given, else the store's latest made for this instrument file; the alignment action (`align`,
//!   [`Service::start_alignment`]) runs `gonio align`'s procedure on the instrument under the one-owner rule and
//!   makes its result the current calibration.
//!
//! Parts: this file holds the types, the shared state and construction; `requests` the API's requests;
//! `console` the console's; `calibration` the calibrations; `align` the alignment action;
//! `queue` the queue loop and shutdown of the running campaign; `ownership` the instrument's one owner; `shutdown` the signal; `engine_runner` the
//! runner that drives the real engine.

mod align;
mod calibration;
mod console;
mod engine_runner;
mod ownership;
mod queue;
mod requests;
mod shutdown;

pub use align::{
    AlignPhase, AlignProcedures, AlignStatus, DEFAULT_ALIGNMENT_MIRROR, DEFAULT_ALIGNMENT_SAMPLE,
};
pub use calibration::{CalibrationView, CurrentCalibration};
pub use console::{CONSOLE_RETRIES, ConsoleAction, FilterMoved, MAX_CONSOLE_READINGS};
pub use engine_runner::EngineRunner;
pub use ownership::InstrumentLease;
pub use shutdown::{Shutdown, ShutdownTrigger};

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::{Notify, broadcast};

use gonio_engine::PreparedCampaign;
use gonio_engine::control::{Control, Event};
use gonio_engine::store::{
    CampaignId, CampaignRecord, CampaignState, InstrumentCalibrationId, NewCampaign, Store, StoreError,
};

/// How long a running campaign is given to reach a safe point when the daemon shuts down, by default.
pub const DEFAULT_SHUTDOWN_GRACE: Duration = Duration::from_secs(20);

/// After an emergency stop at shutdown, how long the engine is given to return before its task is dropped.
const ESTOP_GRACE: Duration = Duration::from_secs(5);

/// Why a request was refused. The HTTP layer maps each kind to a status code.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// No campaign with this id (404).
    #[error("no campaign with id {0}")]
    NotFound(CampaignId),
    /// No stored calibration with this id (404).
    #[error("no calibration with id {0}")]
    NoCalibration(InstrumentCalibrationId),
    /// The submitted campaign file is invalid; the message names the line and key (400).
    #[error("{0}")]
    Invalid(String),
    /// The campaign's state does not allow the request (409).
    #[error("{0}")]
    Conflict(String),
    /// The store failed (500).
    #[error("store: {0}")]
    Store(StoreError),
    /// Building the export failed (500).
    #[error("{0}")]
    Internal(String),
}

impl From<StoreError> for ServiceError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::NoSuchCampaign(id) => ServiceError::NotFound(id),
            StoreError::NoSuchCalibration(id) => ServiceError::NoCalibration(id),
            other => ServiceError::Store(other),
        }
    }
}

/// A future the runner returns, boxed so that [`CampaignRunner`] stays object-safe.
pub type RunFuture = Pin<Box<dyn Future<Output = Result<CampaignState, gonio_engine::EngineError>> + Send>>;

/// A validated submission: the record the store keeps, and the campaign as the engine prepared it, which the
/// queue keeps with its entry for the campaign's first run (so that it is not planned and ordered twice).
#[derive(Debug, Clone)]
pub struct Submission {
    pub campaign: NewCampaign,
    pub prepared: Option<Arc<PreparedCampaign>>,
}

/// What the service needs from the campaign engine: validate a submission, run a stored campaign, export its
/// points. The daemon uses [`EngineRunner`]; tests of the queue logic use a fake.
pub trait CampaignRunner: Send + Sync + 'static {
    /// Validate a submitted campaign file and resolve it into what the store keeps. A refusal is
    /// [`ServiceError::Invalid`] with the message a person reads (file, line, key, what was expected).
    /// `origin` names the file in messages (the client's file name, or "submitted campaign").
    fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<Submission, ServiceError>;

    /// Run (or resume from its first uncommitted point) a stored campaign until it is final or paused. The
    /// engine keeps the store's state up to date and reports through `control`. `prepared`: what
    /// [`CampaignRunner::prepare`] gave for it, on its first run.
    fn run(
        &self,
        store: Arc<Mutex<Store>>,
        id: CampaignId,
        control: Control,
        prepared: Option<Arc<PreparedCampaign>>,
    ) -> RunFuture;

    /// The campaign's points as CSV (the columns of `gonio run`).
    fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, StoreError>;

    /// The connected instrument, for a person who takes it ([`Service::take_instrument`]); None for a runner
    /// without one (the queue tests' fake).
    fn rig(&self) -> Option<gonio_engine::rig::Rig> {
        None
    }

    /// The text of the instrument file in force (what calibrations are made for and checked against); None for
    /// a runner without an instrument of its own (the queue tests' fake).
    fn instrument_toml(&self) -> Option<&str> {
        None
    }

    /// The pose correction of the alignment calibration `alignment_toml` (a `gonio align` file already checked
    /// against this instrument file) on this instrument, for the console's moves by geometry; None when it
    /// cannot be read or the runner has no instrument.
    fn pose_correction(
        &self,
        _alignment_toml: &str,
    ) -> Option<gonio_engine::align::correction::PoseCorrection> {
        None
    }
}

/// A campaign as the API shows it: the stored record without the (long) configuration texts, plus the ETA.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignView {
    pub id: CampaignId,
    pub name: String,
    pub state: CampaignState,
    pub points_done: u64,
    pub total_points: u64,
    /// Predicted remaining instrument time (s) from the engine's last progress report; `None` when not known
    /// or the campaign is not on the instrument.
    pub eta_s: Option<f64>,
    pub last_error: Option<String>,
    pub operator_message: Option<String>,
    pub dry_run: bool,
    pub created_unix_s: f64,
    pub software_version: String,
    /// The stored instrument calibration applied to the campaign (`GET /api/calibrations/{id}`); None when none
    /// was.
    pub calibration_id: Option<InstrumentCalibrationId>,
}

/// What the service knows about the campaign on the instrument, guarded by one lock so that a request and the
/// start of a run cannot interleave.
#[derive(Debug, Default)]
struct RunState {
    /// The campaign whose run is in progress.
    running: Option<CampaignId>,
    /// Requests made for the running campaign, re-applied when the engine reports it started (starting a run
    /// clears the engine's stale requests, which would otherwise swallow a request made at that instant).
    pending_pause: bool,
    pending_abort: bool,
    /// A person paused the running campaign (so a pause seen at shutdown is theirs, not the shutdown's).
    user_paused: bool,
    /// Interrupted campaigns found at start-up, resumed before the queue.
    resume_first: VecDeque<CampaignId>,
    /// A person holds the instrument (named as they asked for it): the queue starts nothing meanwhile.
    held_by: Option<String>,
    /// Last predicted remaining time per campaign (s).
    eta_s: HashMap<CampaignId, f64>,
    /// Queued campaigns as the engine prepared them, for their first run (at most [`KEEP_PREPARED`]: the
    /// others are planned again from their stored text when they start, as a resumed one always is).
    prepared: HashMap<CampaignId, Arc<PreparedCampaign>>,
}

/// How many prepared campaigns the queue keeps: a schedule is a few hundred bytes per point.
const KEEP_PREPARED: usize = 8;

struct Shared {
    store: Arc<Mutex<Store>>,
    control: Control,
    runner: Arc<dyn CampaignRunner>,
    run: Mutex<RunState>,
    /// Wakes the queue loop when a campaign becomes runnable.
    wake: Notify,
    /// Console actions, one at a time (`console`).
    console: tokio::sync::Mutex<()>,
    /// The calibration applied to campaigns submitted from now on and to the console's moves by geometry.
    calibration: Mutex<Option<CurrentCalibration>>,
    /// The alignment action's progress, or how the last one ended (`align`).
    align: Mutex<AlignStatus>,
    shutdown_grace: Duration,
}

/// The daemon's core, cheap to clone (one per HTTP handler).
#[derive(Clone)]
pub struct Service {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Service {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Service")
            .field("run", &self.shared.run)
            .finish_non_exhaustive()
    }
}

/// Lock a mutex, recovering from a poisoned one: the data it guards (a store connection, flags) stays valid
/// when a holder panicked, and a daemon must not stop serving because of it.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Service {
    /// A service on an opened store. Campaigns the store shows as interrupted are resumed first once
    /// [`Service::run_queue`] runs.
    pub fn new(
        store: Store,
        runner: Arc<dyn CampaignRunner>,
        control: Control,
    ) -> Result<Service, ServiceError> {
        let resume_first: VecDeque<CampaignId> = store.interrupted_campaigns()?.into_iter().collect();
        if !resume_first.is_empty() {
            tracing::info!(campaigns = ?resume_first, "interrupted campaigns will be resumed first");
        }
        let calibration = calibration::latest_for_instrument(&store, runner.as_ref())?;
        Ok(Service {
            shared: Arc::new(Shared {
                store: Arc::new(Mutex::new(store)),
                control,
                runner,
                run: Mutex::new(RunState {
                    resume_first,
                    ..RunState::default()
                }),
                wake: Notify::new(),
                console: tokio::sync::Mutex::new(()),
                calibration: Mutex::new(calibration),
                align: Mutex::new(AlignStatus::default()),
                shutdown_grace: DEFAULT_SHUTDOWN_GRACE,
            }),
        })
    }

    /// Set how long a running campaign is given to reach a safe point at shutdown.
    pub fn with_shutdown_grace(self, grace: Duration) -> Service {
        match Arc::try_unwrap(self.shared) {
            Ok(mut shared) => {
                shared.shutdown_grace = grace;
                Service {
                    shared: Arc::new(shared),
                }
            }
            // Already shared (cloned): keep the setting it has.
            Err(shared) => Service { shared },
        }
    }

    /// Every event from now on: the engine's, and the state changes the service makes itself.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.shared.control.subscribe()
    }
}

#[cfg(test)]
mod tests;
