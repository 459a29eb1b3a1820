//! A `tracing` layer for the soaks: counts what the simulator says it injected ("fault injected: ..."), what the
//! drivers and the engine logged at warning level (their side of each fault), and the reconnections; and writes
//! warnings (and reconnections) to a log file when asked.
//!
//! Counting from the log is the point: a fault the host handled without a trace in the log would not be
//! "visible in the log", whatever the simulator's own counters say.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{LineWriter, Write as _};
use std::path::Path;
use std::sync::{Arc, Mutex};

use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::Context;

use crate::SoakError;

thread_local! {
    /// The soak's dispatcher on the runtime's own threads (the blocking pool runs device opens).
    static THREAD_DISPATCH: std::cell::RefCell<Option<tracing::dispatcher::DefaultGuard>> =
        const { std::cell::RefCell::new(None) };
}

/// A current-thread runtime (paused clock when `paused`) whose every thread, the blocking pool included, logs to
/// `dispatch`; the caller runs `block_on` inside `tracing::dispatcher::with_default(dispatch, ...)`.
pub fn runtime_logging_to(
    dispatch: &tracing::Dispatch,
    paused: bool,
) -> Result<tokio::runtime::Runtime, SoakError> {
    let d = dispatch.clone();
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(paused)
        .on_thread_start(move || {
            let guard = tracing::dispatcher::set_default(&d);
            THREAD_DISPATCH.with(|g| *g.borrow_mut() = Some(guard));
        })
        .on_thread_stop(|| THREAD_DISPATCH.with(|g| drop(g.borrow_mut().take())))
        .build()
        .map_err(SoakError::io("cannot start the async runtime"))
}

/// What the log said.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LogCounts {
    /// Simulator events "fault injected: <kind>", by kind.
    pub injected: BTreeMap<String, u64>,
    /// Warnings (and errors) of the drivers: the host side of a fault the driver saw (and maybe absorbed).
    pub driver_warnings: u64,
    /// The same, by message.
    pub driver_warnings_by_message: BTreeMap<String, u64>,
    /// Warnings (and errors) of the daemon (the engine's fault reports, pauses).
    pub daemon_warnings: u64,
    /// Errors anywhere.
    pub errors: u64,
    /// Successful reconnections logged by the drivers and the engine.
    pub reconnects: u64,
    /// Move commands the drivers sent ("move absolute", "move abs").
    pub moves: u64,
    /// Stalls that took effect in the simulator (its emulators' reports of a move stopped by a stall). A stall is
    /// drawn when a move starts; a move superseded by a new command before the stall point never stalls.
    pub stalls_manifested: u64,
    /// Of those, the SMC100's (following error: the controller is left in DISABLE).
    pub smc100_stalls_manifested: u64,
    /// The SMC100 driver's re-enables of a controller left in DISABLE by a following error: one per SMC100
    /// stall, whether the engine saw the move fail or a reconnection's re-verification found it.
    pub smc100_stalls_reenabled: u64,
}

#[derive(Debug, Default)]
struct State {
    counts: LogCounts,
}

/// The layer; clone it to read the counts while (or after) it runs.
#[derive(Debug, Clone)]
pub struct LogCapture {
    state: Arc<Mutex<State>>,
    file: Option<Arc<Mutex<LineWriter<File>>>>,
}

/// The drivers' reports of a move command (SMC100, Zaber).
const MOVE_MESSAGES: [&str; 2] = ["move absolute", "move abs"];

/// The emulators' reports of a stall taking effect (Zaber FS flag, SMC100 following error).
const STALL_EFFECT_MESSAGES: [&str; 2] = ["Zaber: stall, FS", "SMC100: following error, DISABLE from MOVING"];

/// The SMC100 driver's warning when it finds a controller in DISABLE after a fault (its reason follows).
const SMC100_REENABLE_MESSAGE: &str = "controller in DISABLE after a fault; re-enabling";

/// Messages that mean a device came back.
const RECONNECT_MESSAGES: [&str; 3] = ["port reconnected", "USB device reopened", "device reconnected"];

impl LogCapture {
    /// A capture; with `log_file`, warnings and reconnections are written there too.
    pub fn new(log_file: Option<&Path>) -> Result<LogCapture, SoakError> {
        let file = match log_file {
            Some(p) => {
                if let Some(dir) = p.parent() {
                    std::fs::create_dir_all(dir)
                        .map_err(SoakError::io(format!("cannot create {}", dir.display())))?;
                }
                let f = File::create(p).map_err(SoakError::io(format!("cannot create {}", p.display())))?;
                Some(Arc::new(Mutex::new(LineWriter::new(f))))
            }
            None => None,
        };
        Ok(LogCapture {
            state: Arc::new(Mutex::new(State::default())),
            file,
        })
    }

    /// What the soak needs to see: the simulator's fault reports (info: delays) and everything of ours at info.
    pub fn filter() -> Targets {
        Targets::new()
            .with_target("gonio_simulator", Level::INFO)
            .with_target("gonio_driver", Level::INFO)
            .with_target("gonio_engine", Level::INFO)
            .with_target("gonio_daemon", Level::INFO)
            .with_default(Level::WARN)
    }

    pub fn counts(&self) -> LogCounts {
        self.state
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .counts
            .clone()
    }
}

/// The message and the other fields of an event, as text.
#[derive(Default)]
struct Fields {
    message: String,
    rest: String,
}

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.message, "{value:?}");
        } else {
            let _ = write!(self.rest, " {}={value:?}", field.name());
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.message.push_str(value);
        } else {
            let _ = write!(self.rest, " {}={value}", field.name());
        }
    }
}

impl<S: Subscriber> Layer<S> for LogCapture {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        let level = *meta.level();
        let target = meta.target();
        let mut f = Fields::default();
        event.record(&mut f);
        let warning = level <= Level::WARN;
        let reconnect = RECONNECT_MESSAGES.contains(&f.message.as_str());
        {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            let c = &mut st.counts;
            if let Some(kind) = f.message.strip_prefix("fault injected: ") {
                *c.injected.entry(kind.to_string()).or_default() += 1;
            } else if warning && target.starts_with("gonio_driver") {
                c.driver_warnings += 1;
                *c.driver_warnings_by_message.entry(f.message.clone()).or_default() += 1;
            } else if warning && (target.starts_with("gonio_engine") || target.starts_with("gonio_daemon")) {
                c.daemon_warnings += 1;
            }
            if level == Level::ERROR {
                c.errors += 1;
            }
            if reconnect {
                c.reconnects += 1;
            }
            if MOVE_MESSAGES.contains(&f.message.as_str()) {
                c.moves += 1;
            }
            if target.starts_with("gonio_simulator") && STALL_EFFECT_MESSAGES.contains(&f.message.as_str()) {
                c.stalls_manifested += 1;
                if f.message == STALL_EFFECT_MESSAGES[1] {
                    c.smc100_stalls_manifested += 1;
                }
            }
            if target.starts_with("gonio_driver")
                && f.message == SMC100_REENABLE_MESSAGE
                && f.rest.contains("following error")
            {
                c.smc100_stalls_reenabled += 1;
            }
        }
        // The log file: warnings and reconnections (the per-reply delay reports are counted, not written).
        if let Some(file) = &self.file
            && (warning || reconnect)
        {
            let mut w = file.lock().unwrap_or_else(|e| e.into_inner());
            let _ = writeln!(w, "{level:>5} {target}: {}{}", f.message, f.rest);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt as _;

    /// An SMC100 stall is seen by the host when its driver re-enables the controller after the following error
    /// (as a reconnection's re-verification does, with no failed move for the engine to report); a re-enable
    /// for another reason is not a stall seen.
    #[test]
    fn stalls_are_counted_by_controller_and_an_smc100_re_enable_is_a_stall_seen() {
        let capture = LogCapture::new(None).expect("capture");
        let subscriber = tracing_subscriber::registry().with(capture.clone());
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!(target: "gonio_simulator::smc100::machine", address = 1, "SMC100: following error, DISABLE from MOVING");
            tracing::warn!(target: "gonio_simulator::zaber::device", axis = "tilt", "Zaber: stall, FS");
            tracing::warn!(target: "gonio_driver::smc100::axis", axis = "light (arms/1)",
                reason = "DISABLE from moving (3D); positioner errors 0020: following error", "controller in DISABLE after a fault; re-enabling");
            tracing::warn!(target: "gonio_driver::smc100::axis", axis = "light (arms/1)",
                reason = "DISABLE from ready (3C)", "controller in DISABLE after a fault; re-enabling");
        });
        let c = capture.counts();
        assert_eq!((c.stalls_manifested, c.smc100_stalls_manifested), (2, 1));
        assert_eq!(c.smc100_stalls_reenabled, 1);
    }
}
