//! The control seam between a running campaign and whoever drives it (`gonio run`, the daemon's HTTP API):
//! [`Control`] carries requests in (pause, resume, abort, operator confirmation, emergency stop) and
//! [`Event`]s out (state changes, points, progress, faults) on a broadcast channel.
//!
//! One `Control` serves one instrument: at most one campaign runs on it at a time. Requests are flags the engine
//! reads at its safe points (between points), except the emergency stop, which halts every axis of the attached
//! [`Rig`] at once.
//!
//! Semantics (what the service can rely on):
//! - `pause()`: the running campaign goes `pausing` now (recorded in the store and announced by a `State`
//!   event as soon as the engine's task runs, even in the middle of a move or a settle) and `paused` at the next
//!   safe point, where [`run_campaign`](crate::runner::run_campaign) returns `Ok(Paused)`. While waiting for the
//!   operator it goes `paused` directly. To continue, call `resume()` and `run_campaign` again: it continues
//!   from the first uncommitted point.
//! - `resume()`: clears a pending pause (also one requested while nothing ran); a campaign still `pausing` goes
//!   back to `running` and carries on. Starting `run_campaign` clears a stale pause, abort, estop or
//!   confirmation too: starting a run is itself the resume.
//! - `abort()`: the campaign ends `aborted` at the next safe point (also while waiting for the operator).
//! - `confirm()`: the operator did what the `waiting-operator` message asked; ignored at other times.
//! - `estop()`: halts all axes now (and the simulator's, in dry-runs); the point in progress is not committed;
//!   the campaign ends `paused` with the message "emergency stop", resumable like any pause.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};
use tokio::sync::{Notify, broadcast};

use crate::rig::Rig;
use crate::store::{CampaignId, CampaignState, PointRecord};

/// Capacity of the event channel; a subscriber that lags further behind loses the oldest events
/// (`RecvError::Lagged`), never blocks the engine.
pub const EVENT_CAPACITY: usize = 4096;

/// What the engine reports while it runs. Serialised with a `type` tag: `{"type":"state",...}`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case")]
pub enum Event {
    /// The campaign changed state; `message` says why (operator instructions, the pause reason, the error).
    State {
        campaign: CampaignId,
        state: CampaignState,
        message: Option<String>,
    },
    /// A point was committed to the store.
    Point {
        campaign: CampaignId,
        /// Boxed: a point with its budget is ten times the size of the other events.
        point: Box<PointRecord>,
    },
    /// Points done out of total, and the predicted remaining instrument time (s).
    Progress {
        campaign: CampaignId,
        done: u64,
        total: u64,
        eta_s: Option<f64>,
    },
    /// A device fault, retried or not: for the operator's log.
    Fault { campaign: CampaignId, message: String },
    /// A sweep was committed with its readings (crate::store::sweeps): `segment` of `segments`, in run order.
    Sweep {
        campaign: CampaignId,
        segment: u32,
        segments: u32,
        readings: u32,
    },
}

/// Requests to the engine, shared by every clone.
#[derive(Clone, Debug)]
pub struct Control {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    events: broadcast::Sender<Event>,
    pause: AtomicBool,
    abort: AtomicBool,
    estop: AtomicBool,
    confirm: AtomicBool,
    /// Woken on every request, so waits (operator, settle) can react at once.
    wake: Notify,
    /// The instrument an emergency stop halts.
    rig: Mutex<Option<Rig>>,
}

impl Default for Control {
    fn default() -> Self {
        Control::new()
    }
}

impl Control {
    pub fn new() -> Control {
        let (events, _) = broadcast::channel(EVENT_CAPACITY);
        Control {
            inner: Arc::new(Inner {
                events,
                pause: AtomicBool::new(false),
                abort: AtomicBool::new(false),
                estop: AtomicBool::new(false),
                confirm: AtomicBool::new(false),
                wake: Notify::new(),
                rig: Mutex::new(None),
            }),
        }
    }

    /// Attach the instrument that [`Control::estop`] halts (`run_campaign` does this itself).
    pub fn attach_rig(&self, rig: &Rig) {
        *self.inner.rig.lock().unwrap_or_else(|e| e.into_inner()) = Some(rig.clone());
    }

    /// Pause at the next safe point.
    pub fn pause(&self) {
        self.inner.pause.store(true, Ordering::SeqCst);
        self.inner.wake.notify_waiters();
    }

    /// Withdraw a pause request.
    pub fn resume(&self) {
        self.inner.pause.store(false, Ordering::SeqCst);
        self.inner.estop.store(false, Ordering::SeqCst);
        self.inner.wake.notify_waiters();
    }

    /// End the campaign (`aborted`) at the next safe point.
    pub fn abort(&self) {
        self.inner.abort.store(true, Ordering::SeqCst);
        self.inner.wake.notify_waiters();
    }

    /// The operator did what was asked.
    pub fn confirm(&self) {
        self.inner.confirm.store(true, Ordering::SeqCst);
        self.inner.wake.notify_waiters();
    }

    /// Emergency stop: halt every axis now.
    pub fn estop(&self) {
        self.inner.estop.store(true, Ordering::SeqCst);
        self.inner.wake.notify_waiters();
        let rig = self.inner.rig.lock().unwrap_or_else(|e| e.into_inner()).clone();
        if let Some(rig) = rig {
            match tokio::runtime::Handle::try_current() {
                Ok(handle) => {
                    handle.spawn(async move { rig.estop().await });
                }
                Err(_) => {
                    tracing::error!("emergency stop requested outside a tokio runtime: axes not halted")
                }
            }
        }
    }

    /// Receive every event from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.inner.events.subscribe()
    }

    // ---- the runner's side: the engine, or any other runner of campaigns the service queues on this control ----

    /// Send `event` to every subscriber.
    pub fn emit(&self, event: Event) {
        // No subscriber is not an error.
        let _ = self.inner.events.send(event);
    }

    pub fn pause_requested(&self) -> bool {
        self.inner.pause.load(Ordering::SeqCst)
    }

    pub fn abort_requested(&self) -> bool {
        self.inner.abort.load(Ordering::SeqCst)
    }

    pub fn estop_requested(&self) -> bool {
        self.inner.estop.load(Ordering::SeqCst)
    }

    /// Take a pending confirmation (true once per `confirm()`).
    pub fn take_confirm(&self) -> bool {
        self.inner.confirm.swap(false, Ordering::SeqCst)
    }

    /// Forget requests left over from an earlier run.
    pub fn clear_requests(&self) {
        for flag in [
            &self.inner.pause,
            &self.inner.abort,
            &self.inner.estop,
            &self.inner.confirm,
        ] {
            flag.store(false, Ordering::SeqCst);
        }
    }

    /// The `Notify` future, created before a check so that a request between check and wait is not lost.
    pub(crate) fn notified(&self) -> tokio::sync::futures::Notified<'_> {
        self.inner.wake.notified()
    }
}
