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

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::Serialize;
use tokio::sync::{Notify, broadcast, mpsc, watch};

use gonio_instrument::InstrumentFile;

use crate::control::{Control, Event};
use crate::engine::{prepare_submitted_campaign, run_campaign};
use crate::rig::Rig;
use crate::store::{CampaignId, CampaignRecord, CampaignState, NewCampaign, Store, StoreError};

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
            other => ServiceError::Store(other),
        }
    }
}

/// A future the runner returns, boxed so that [`CampaignRunner`] stays object-safe.
pub type RunFuture = Pin<Box<dyn Future<Output = Result<CampaignState, String>> + Send>>;

/// What the service needs from the campaign engine: validate a submission, run a stored campaign, export its
/// points. The daemon uses [`EngineRunner`]; tests of the queue logic use a fake.
pub trait CampaignRunner: Send + Sync + 'static {
    /// Validate a submitted campaign file and resolve it into what the store keeps. The error is the message a
    /// person reads (file, line, key, what was expected).
    /// `origin` names the file in messages (the client's file name, or "submitted campaign").
    fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<NewCampaign, String>;

    /// Run (or resume from its first uncommitted point) a stored campaign until it is final or paused. The
    /// engine keeps the store's state up to date and reports through `control`.
    fn run(&self, store: Arc<Mutex<Store>>, id: CampaignId, control: Control) -> RunFuture;

    /// The campaign's points as CSV (the columns of `gonio run`).
    fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, String>;
}

/// A campaign as the API shows it: the stored record without the (long) configuration texts, plus the ETA.
#[derive(Debug, Clone, PartialEq, Serialize)]
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
}

/// The shutdown signal: set once, seen by every clone (a `watch` so that tasks started later see it too).
#[derive(Debug, Clone)]
pub struct Shutdown {
    rx: watch::Receiver<bool>,
}

/// Sets the [`Shutdown`] signal.
#[derive(Debug)]
pub struct ShutdownTrigger {
    tx: watch::Sender<bool>,
}

impl ShutdownTrigger {
    pub fn new() -> ShutdownTrigger {
        ShutdownTrigger {
            tx: watch::channel(false).0,
        }
    }

    pub fn subscribe(&self) -> Shutdown {
        Shutdown {
            rx: self.tx.subscribe(),
        }
    }

    /// Tell every task to stop.
    pub fn trigger(&self) {
        self.tx.send_replace(true);
    }
}

impl Default for ShutdownTrigger {
    fn default() -> Self {
        ShutdownTrigger::new()
    }
}

impl Shutdown {
    pub fn is_shutdown(&self) -> bool {
        *self.rx.borrow()
    }

    /// Wait for the signal (returns at once if it was already given, or if the trigger is gone).
    pub async fn recv(&mut self) {
        let _ = self.rx.wait_for(|stop| *stop).await;
    }
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
    /// Last predicted remaining time per campaign (s).
    eta_s: HashMap<CampaignId, f64>,
}

struct Shared {
    store: Arc<Mutex<Store>>,
    control: Control,
    runner: Arc<dyn CampaignRunner>,
    run: Mutex<RunState>,
    /// Wakes the queue loop when a campaign becomes runnable.
    wake: Notify,
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

    /// Validate and queue a campaign.
    pub fn submit(&self, campaign_toml: &str, origin: &str) -> Result<CampaignId, ServiceError> {
        let new = self
            .shared
            .runner
            .prepare(campaign_toml, origin)
            .map_err(ServiceError::Invalid)?;
        let id = lock(&self.shared.store).create_campaign(&new)?;
        tracing::info!(campaign = %id, name = %new.name, points = new.total_points, "campaign queued");
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
            .map_err(ServiceError::Internal)
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

    fn set_state(
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

    /// The next campaign to run: an interrupted one first, else the oldest queued one. Marks it running in the
    /// service (under the same lock the requests take).
    fn take_next(&self) -> Result<Option<CampaignId>, ServiceError> {
        let mut run = lock(&self.shared.run);
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
        let mut run = self
            .shared
            .runner
            .run(self.shared.store.clone(), id, self.shared.control.clone());
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
            Err(message) => {
                // The engine could not even keep the store up to date: record the failure ourselves.
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
    }
}

fn conflict(record: &CampaignRecord, action: &str, why: &str) -> ServiceError {
    ServiceError::Conflict(format!(
        "cannot {action} campaign {} ({}): {why}",
        record.id, record.state
    ))
}

/// The real runner: the campaign engine on one connected instrument.
#[derive(Debug)]
pub struct EngineRunner {
    instrument: InstrumentFile,
    instrument_toml: String,
    /// The daemon's data directory: submitted campaigns may name material presets or files inside it only, and
    /// relative names resolve against it.
    base_dir: PathBuf,
    rig: Rig,
}

impl EngineRunner {
    /// `instrument_toml` is the text of the instrument file in force, stored with every campaign.
    pub fn new(
        instrument: InstrumentFile,
        instrument_toml: String,
        base_dir: PathBuf,
        rig: Rig,
    ) -> EngineRunner {
        EngineRunner {
            instrument,
            instrument_toml,
            base_dir,
            rig,
        }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }
}

impl CampaignRunner for EngineRunner {
    fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<NewCampaign, String> {
        prepare_submitted_campaign(campaign_toml, origin, &self.base_dir, &self.instrument)
            .map(|p| p.new_campaign(campaign_toml, &self.instrument_toml))
            .map_err(|e| e.to_string())
    }

    fn run(&self, store: Arc<Mutex<Store>>, id: CampaignId, control: Control) -> RunFuture {
        let rig = self.rig.clone();
        Box::pin(async move {
            run_campaign(store, id, &rig, control)
                .await
                .map_err(|e| e.to_string())
        })
    }

    fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, String> {
        let points = store.points(record.id).map_err(|e| e.to_string())?;
        Ok(crate::export::points_csv(record, &points))
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;
    use crate::store::PointRecord;

    /// A stand-in engine: one point per simulated second, obeying pause/abort/estop at safe points like the
    /// real one, and recording which campaigns ran and how many at once.
    #[derive(Default)]
    struct FakeRunner {
        active: Arc<AtomicUsize>,
        max_active: Arc<AtomicUsize>,
        started: Arc<Mutex<Vec<CampaignId>>>,
    }

    fn fake_point(index: u64) -> PointRecord {
        PointRecord {
            index,
            band_nm: 550.0,
            theta_i_deg: 10.0,
            phi_i_deg: 0.0,
            theta_o_deg: 20.0,
            phi_o_deg: 180.0,
            signal_w: 1e-6,
            dark_w: 0.0,
            incident_w: 1e-3,
            brdf_sr: Some(0.3),
            brdf_u_sr: Some(0.01),
            flags: vec![],
            t_s: index as f64,
            readback_deg: vec![],
            truth_point_sr: None,
            truth_aperture_sr: None,
        }
    }

    impl CampaignRunner for FakeRunner {
        fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<NewCampaign, String> {
            let points: u64 = campaign_toml
                .strip_prefix("points = ")
                .and_then(|n| n.trim().parse().ok())
                .ok_or_else(|| format!("{origin}:1: key `points`: expected `points = N`"))?;
            Ok(NewCampaign {
                name: format!("fake {points}"),
                campaign_toml: campaign_toml.into(),
                instrument_toml: String::new(),
                total_points: points,
                dry_run: true,
                software_version: "test".into(),
            })
        }

        fn run(&self, store: Arc<Mutex<Store>>, id: CampaignId, control: Control) -> RunFuture {
            let (active, max_active, started) =
                (self.active.clone(), self.max_active.clone(), self.started.clone());
            Box::pin(async move {
                control.clear_requests();
                lock(&started).push(id);
                let now = active.fetch_add(1, Ordering::SeqCst) + 1;
                max_active.fetch_max(now, Ordering::SeqCst);
                let set = |state, msg: Option<&str>| {
                    lock(&store)
                        .set_state(id, state, msg)
                        .map_err(|e| e.to_string())?;
                    control.emit(Event::State {
                        campaign: id,
                        state,
                        message: msg.map(str::to_string),
                    });
                    Ok::<_, String>(state)
                };
                let result = async {
                    set(CampaignState::Running, None)?;
                    let (next, total) = {
                        let s = lock(&store);
                        (
                            s.next_index(id).map_err(|e| e.to_string())?,
                            s.campaign(id).map_err(|e| e.to_string())?.total_points,
                        )
                    };
                    for index in next..total {
                        if control.estop_requested() {
                            return set(CampaignState::Paused, Some("emergency stop"));
                        }
                        if control.abort_requested() {
                            return set(CampaignState::Aborted, None);
                        }
                        if control.pause_requested() {
                            return set(CampaignState::Paused, None);
                        }
                        tokio::time::sleep(Duration::from_secs(1)).await;
                        lock(&store)
                            .commit_point(id, &fake_point(index))
                            .map_err(|e| e.to_string())?;
                        control.emit(Event::Progress {
                            campaign: id,
                            done: index + 1,
                            total,
                            eta_s: Some((total - index - 1) as f64),
                        });
                    }
                    set(CampaignState::Completed, None)
                }
                .await;
                active.fetch_sub(1, Ordering::SeqCst);
                result
            })
        }

        fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, String> {
            let points = store.points(record.id).map_err(|e| e.to_string())?;
            Ok(crate::export::points_csv(record, &points))
        }
    }

    struct Harness {
        service: Service,
        runner: Arc<FakeRunner>,
        trigger: ShutdownTrigger,
        queue: tokio::task::JoinHandle<()>,
        _dir: tempfile::TempDir,
    }

    fn start_with(dir: tempfile::TempDir, setup: impl FnOnce(&mut Store)) -> Harness {
        let mut store = Store::open(dir.path()).expect("store");
        setup(&mut store);
        let runner = Arc::new(FakeRunner::default());
        let service = Service::new(store, runner.clone(), Control::new()).expect("service");
        let trigger = ShutdownTrigger::new();
        let (tx, _rx) = mpsc::channel(1);
        let queue = {
            let (service, shutdown) = (service.clone(), trigger.subscribe());
            tokio::spawn(async move { service.run_queue(shutdown, tx).await })
        };
        Harness {
            service,
            runner,
            trigger,
            queue,
            _dir: dir,
        }
    }

    fn start() -> Harness {
        start_with(tempfile::tempdir().expect("tempdir"), |_| {})
    }

    impl Harness {
        fn state(&self, id: CampaignId) -> CampaignState {
            self.service.campaign(id).expect("campaign").state
        }

        /// Advance (paused) time until `id` is in `state`; at most `limit_s` simulated seconds.
        async fn wait_for(&self, id: CampaignId, state: CampaignState, limit_s: u64) {
            for _ in 0..limit_s * 10 {
                if self.state(id) == state {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            panic!(
                "campaign {id} is {} after {limit_s} s, expected {state}",
                self.state(id)
            );
        }

        fn started(&self) -> Vec<CampaignId> {
            lock(&self.runner.started).clone()
        }
    }

    #[tokio::test(start_paused = true)]
    async fn campaigns_run_one_at_a_time_in_submission_order() {
        let h = start();
        let ids: Vec<_> = [3, 2, 4]
            .iter()
            .map(|n| h.service.submit(&format!("points = {n}"), "t").expect("submit"))
            .collect();
        h.wait_for(ids[2], CampaignState::Completed, 30).await;
        for &id in &ids {
            let c = h.service.campaign(id).expect("c");
            assert_eq!(
                (c.state, c.points_done),
                (CampaignState::Completed, c.total_points)
            );
        }
        assert_eq!(h.started(), ids);
        assert_eq!(h.runner.max_active.load(Ordering::SeqCst), 1);
    }

    #[tokio::test(start_paused = true)]
    async fn invalid_submission_is_refused_with_the_runner_message() {
        let h = start();
        let err = h.service.submit("nonsense", "bad.toml").expect_err("invalid");
        assert!(
            matches!(&err, ServiceError::Invalid(m) if m.contains("bad.toml:1") && m.contains("points")),
            "{err}"
        );
        assert!(h.service.campaigns().expect("list").is_empty());
    }

    #[tokio::test(start_paused = true)]
    async fn pause_at_a_safe_point_then_resume_completes_without_duplicates() {
        let h = start();
        let id = h.service.submit("points = 10", "t").expect("submit");
        h.wait_for(id, CampaignState::Running, 5).await;
        tokio::time::sleep(Duration::from_millis(3500)).await;
        h.service.pause(id).expect("pause");
        h.wait_for(id, CampaignState::Paused, 5).await;
        let done = h.service.campaign(id).expect("c").points_done;
        assert!(done > 0 && done < 10, "{done}");
        // Paused: it does not move on its own.
        tokio::time::sleep(Duration::from_secs(20)).await;
        assert_eq!(h.service.campaign(id).expect("c").points_done, done);
        assert!(matches!(h.service.pause(id), Err(ServiceError::Conflict(_))));
        h.service.resume(id).expect("resume");
        h.wait_for(id, CampaignState::Completed, 30).await;
        let store_points = lock(&h.service.shared.store).points(id).expect("points");
        assert_eq!(
            store_points.iter().map(|p| p.index).collect::<Vec<_>>(),
            (0..10).collect::<Vec<_>>()
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_paused_queued_campaign_is_skipped_and_resume_puts_it_back() {
        let h = start();
        let a = h.service.submit("points = 3", "t").expect("a");
        let b = h.service.submit("points = 2", "t").expect("b");
        let c = h.service.submit("points = 2", "t").expect("c");
        assert_eq!(h.service.pause(b).expect("pause b").state, CampaignState::Paused);
        h.wait_for(c, CampaignState::Completed, 30).await;
        assert_eq!(h.state(b), CampaignState::Paused);
        assert_eq!(h.started(), vec![a, c]);
        assert_eq!(h.service.resume(b).expect("resume").state, CampaignState::Queued);
        h.wait_for(b, CampaignState::Completed, 30).await;
        assert_eq!(h.started(), vec![a, c, b]);
    }

    #[tokio::test(start_paused = true)]
    async fn abort_running_and_queued_and_refuse_wrong_states() {
        let h = start();
        let a = h.service.submit("points = 50", "t").expect("a");
        let b = h.service.submit("points = 2", "t").expect("b");
        h.wait_for(a, CampaignState::Running, 5).await;
        assert_eq!(h.service.abort(b).expect("abort b").state, CampaignState::Aborted);
        h.service.abort(a).expect("abort a");
        h.wait_for(a, CampaignState::Aborted, 5).await;
        assert!(h.service.campaign(a).expect("a").points_done < 50);
        // Final campaigns refuse everything; confirm needs waiting-operator; unknown ids are not found.
        for result in [
            h.service.abort(a),
            h.service.pause(b),
            h.service.resume(a),
            h.service.confirm(a),
        ] {
            assert!(matches!(result, Err(ServiceError::Conflict(_))), "{result:?}");
        }
        assert!(matches!(
            h.service.pause(CampaignId(99)),
            Err(ServiceError::NotFound(CampaignId(99)))
        ));
        tokio::time::sleep(Duration::from_secs(10)).await;
        assert_eq!(h.started(), vec![a]);
    }

    #[tokio::test(start_paused = true)]
    async fn estop_halts_the_running_campaign_and_holds_the_queue() {
        let h = start();
        let a = h.service.submit("points = 50", "t").expect("a");
        let b = h.service.submit("points = 2", "t").expect("b");
        h.wait_for(a, CampaignState::Running, 5).await;
        tokio::time::sleep(Duration::from_millis(2500)).await;
        h.service.estop().expect("estop");
        h.wait_for(a, CampaignState::Paused, 5).await;
        assert_eq!(h.state(b), CampaignState::Paused);
        assert!(
            h.service
                .campaign(b)
                .expect("b")
                .last_error
                .is_some_and(|m| m.contains("emergency stop"))
        );
        tokio::time::sleep(Duration::from_secs(30)).await;
        assert_eq!(h.started(), vec![a], "nothing may start after an emergency stop");
        h.service.resume(a).expect("resume a");
        h.wait_for(a, CampaignState::Completed, 80).await;
        assert_eq!(h.state(b), CampaignState::Paused);
    }

    #[tokio::test(start_paused = true)]
    async fn interrupted_campaigns_are_resumed_first_from_their_first_missing_point() {
        let dir = tempfile::tempdir().expect("tempdir");
        let new = |n| NewCampaign {
            name: "x".into(),
            campaign_toml: String::new(),
            instrument_toml: String::new(),
            total_points: n,
            dry_run: true,
            software_version: "test".into(),
        };
        let mut ids = Vec::new();
        let h = start_with(dir, |store| {
            let queued = store.create_campaign(&new(2)).expect("queued");
            let interrupted = store.create_campaign(&new(5)).expect("interrupted");
            store
                .set_state(interrupted, CampaignState::Running, None)
                .expect("state");
            for i in 0..3 {
                store.commit_point(interrupted, &fake_point(i)).expect("point");
            }
            ids = vec![queued, interrupted];
        });
        h.wait_for(ids[0], CampaignState::Completed, 30).await;
        assert_eq!(h.started(), vec![ids[1], ids[0]]);
        let points = lock(&h.service.shared.store).points(ids[1]).expect("points");
        assert_eq!(
            points.iter().map(|p| p.index).collect::<Vec<_>>(),
            vec![0, 1, 2, 3, 4]
        );
    }

    #[tokio::test(start_paused = true)]
    async fn shutdown_stops_at_a_safe_point_and_leaves_the_campaign_interrupted() {
        let h = start();
        let id = h.service.submit("points = 100", "t").expect("submit");
        h.wait_for(id, CampaignState::Running, 5).await;
        tokio::time::sleep(Duration::from_secs(5)).await;
        h.trigger.trigger();
        tokio::time::timeout(Duration::from_secs(60), h.queue)
            .await
            .expect("queue stops")
            .expect("join");
        let c = h.service.campaign(id).expect("c");
        assert_eq!(c.state, CampaignState::Running, "left as interrupted");
        assert!(c.points_done >= 4 && c.points_done < 100, "{}", c.points_done);
        assert_eq!(
            lock(&h.service.shared.store)
                .interrupted_campaigns()
                .expect("list"),
            vec![id]
        );
    }
}
