//! The fault soak: one dry-run campaign through the real drivers and engine (`engine::run_campaign` on a `Rig`
//! with the in-process simulator, on a paused tokio clock so that instrument time costs no wall time) while
//! the simulator garbles, drops and delays replies, stalls moves and pulls the cables every few minutes.
//!
//! Checked afterwards:
//! - the campaign completed, with one row per planned point;
//! - every point is either valid (its BRDF within 5 standard uncertainties, plus the optics' 1e-6 integration
//!   floor, of the simulator's aperture-averaged ground truth stored with it; on an imperfect instrument plus
//!   what the imperfections explain, from the point's own attribution: [`crate::truth_check`]) or recorded
//!   without a value and with its reason (`failed: <the device's reason>`, or a measurement flag); a value
//!   outside that band is silently wrong, a point with neither value nor reason is unexplained;
//! - every fault the simulator counted is in the log (its own "fault injected" report), and the host's side of
//!   it: driver warnings, the engine's fault events (the campaign's event stream), reconnections.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_campaign};
use gonio_instrument::{Faults, InstrumentFile};
use gonio_simulator::FaultCounts;
use tracing_subscriber::Layer as _;
use tracing_subscriber::layer::SubscriberExt as _;

use crate::SoakError;
use crate::logcap::{LogCapture, LogCounts, runtime_logging_to};
use crate::rows::RowSummary;
use crate::setup::{SoakCampaign, SoakInstrument, build_campaign, instrument_with_faults};
use crate::truth_check::Tolerance;

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultSoakConfig {
    /// Planned points.
    pub points: u64,
    /// Seed of the geometries and of every fault draw.
    pub seed: u64,
    /// The fault settings (`seed` is replaced by [`FaultSoakConfig::seed`]).
    pub faults: Faults,
    /// An empty directory for the store.
    pub data_dir: PathBuf,
    /// Where to write the warnings log, if anywhere.
    pub log_file: Option<PathBuf>,
    /// How many times the soak, acting as the operator, resumes a campaign that paused (each is reported).
    pub max_resumes: u32,
    /// The instrument file the faults are written into.
    pub instrument: SoakInstrument,
}

/// Move commands per measured point in a fault-free run of the soak campaign (about 4, counted from the
/// drivers' "move absolute"/"move abs" logs, backlash approaches included): converts "one stalled move per N points" into a stall rate.
pub const MOVES_PER_POINT: f64 = 4.0;

impl FaultSoakConfig {
    /// The rates of issue 8: 1 % garbled replies, 0.5 % dropped, random extra latency (1 ms plus up to 40 ms, the
    /// drivers' reply deadlines are 300 ms and more), about one stalled move per 300 points, and the devices
    /// vanishing every 4 minutes of instrument time for 5 s.
    pub fn issue_8(points: u64, seed: u64, data_dir: PathBuf) -> FaultSoakConfig {
        FaultSoakConfig {
            points,
            seed,
            faults: Faults {
                seed,
                garble_rate: 0.01,
                drop_rate: 0.005,
                delay_ms: 1.0,
                delay_jitter_ms: 40.0,
                stall_rate: 1.0 / (300.0 * MOVES_PER_POINT),
                disconnect_after_s: Some(120.0),
                reconnect_after_s: Some(5.0),
                disconnect_every_s: Some(240.0),
                saturate: false,
            },
            data_dir,
            log_file: None,
            max_resumes: 5,
            instrument: SoakInstrument::simulated(),
        }
    }

    /// Higher rates for a short CI run: every kind of fault shows up within a few hundred points.
    pub fn stressed(points: u64, seed: u64, data_dir: PathBuf) -> FaultSoakConfig {
        FaultSoakConfig {
            faults: Faults {
                seed,
                garble_rate: 0.03,
                drop_rate: 0.015,
                delay_ms: 1.0,
                delay_jitter_ms: 40.0,
                stall_rate: 1.0 / (30.0 * MOVES_PER_POINT),
                disconnect_after_s: Some(40.0),
                reconnect_after_s: Some(5.0),
                disconnect_every_s: Some(60.0),
                saturate: false,
            },
            ..FaultSoakConfig::issue_8(points, seed, data_dir)
        }
    }
}

/// The kind of a device error, from its message (the driver error's `Display`, which the engine forwards).
pub fn error_class(message: &str) -> &'static str {
    if message.contains("no reply to") || message.contains("did not answer") {
        "timeout"
    } else if message.contains("connection is lost") || message.contains("cannot open") {
        "disconnected"
    } else if message.contains("bad reply to") {
        "bad reply"
    } else if message.contains("is not referenced") {
        "not referenced"
    } else if message.contains(" failed: ") && message.contains("move to") {
        "motion fault"
    } else if message.contains("was rejected") {
        "rejected"
    } else if message.contains("is outside") {
        "out of range"
    } else {
        "other"
    }
}

/// What the campaign's event stream said.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EventTally {
    /// `Event::Fault`, by [`error_class`].
    pub faults: BTreeMap<String, u64>,
    /// Of those, the engine's reconnection attempts that failed (`reconnect: ...`).
    pub failed_reconnects: u64,
    /// Of the motion faults, the Zaber stage's stalls (`FS (stalled and stopped)`).
    pub zaber_stall_faults: u64,
    /// State changes with their messages.
    pub states: Vec<(CampaignState, Option<String>)>,
    /// Points reported.
    pub points: u64,
    /// Events lost because the listener lagged (must be 0 for the counts to be complete).
    pub lagged: u64,
}

impl EventTally {
    pub fn fault_total(&self) -> u64 {
        self.faults.values().sum()
    }

    fn observe(&mut self, event: Event) {
        match event {
            Event::Fault { message, .. } => {
                if message.starts_with("reconnect:") {
                    self.failed_reconnects += 1;
                }
                if error_class(&message) == "motion fault" && message.contains("FS (stalled") {
                    self.zaber_stall_faults += 1;
                }
                *self.faults.entry(error_class(&message).to_string()).or_default() += 1;
            }
            Event::State { state, message, .. } => self.states.push((state, message)),
            Event::Point { .. } => self.points += 1,
            _ => {}
        }
    }
}

/// Everything the fault soak measured.
#[derive(Debug, Clone)]
pub struct FaultSoakReport {
    pub config: FaultSoakConfig,
    pub campaign: SoakCampaign,
    /// The `[simulator.faults]` keys in force.
    pub faults_toml: String,
    /// The `[simulator.quirks]` in force (the recorded real-device variants).
    pub quirks_toml: String,
    /// Command lines the simulated devices lost to their input pacing (the SMC100 after a set command), by
    /// command code: the stops the drivers send at once on purpose, and lines caught by one.
    pub lost_to_pacing: std::collections::BTreeMap<String, u64>,
    pub final_state: CampaignState,
    pub last_error: Option<String>,
    /// Why the campaign paused each time the soak resumed it.
    pub pauses: Vec<String>,
    /// The campaign did not end within its instrument-time budget (five times the prediction, at least an
    /// hour): a hang.
    pub hung: bool,
    /// The final points against the plan and the simulator's ground truth.
    pub committed: RowSummary,
    /// The simulator's own counters.
    pub injected: FaultCounts,
    /// What the log said.
    pub log: LogCounts,
    /// What the campaign's event stream said.
    pub events: EventTally,
    /// Campaign instrument time (s): the last point or calibration.
    pub instrument_s: f64,
    /// The simulator's clock at the end (s): instrument time including start-up and homing.
    pub sim_clock_s: f64,
    pub wall_s: f64,
}

/// The simulator's log messages ("fault injected: <kind>") for each counter.
pub const INJECTED_LOG_KINDS: [(&str, &str); 7] = [
    ("garbled", "reply byte garbled"),
    ("dropped", "reply dropped"),
    ("delayed", "reply delayed"),
    ("stalls", "move will stall"),
    ("disconnects", "device disconnected, connection closed"),
    ("refused_opens", "open refused, device is disconnected"),
    ("saturated_readings", "detector overload"),
];

/// A counter of [`FaultCounts`] by its field name.
pub fn counter(c: &FaultCounts, name: &str) -> u64 {
    match name {
        "garbled" => c.garbled,
        "dropped" => c.dropped,
        "delayed" => c.delayed,
        "stalls" => c.stalls,
        "disconnects" => c.disconnects,
        "outages" => c.outages,
        "refused_opens" => c.refused_opens,
        "saturated_readings" => c.saturated_readings,
        _ => 0,
    }
}

/// The Zaber driver's warning when a move starts with a fault flag (FS: stalled) still set.
pub const STALL_FLAG_MESSAGE: &str = "fault flag active at move start";

impl FaultSoakReport {
    /// Stall flags the drivers logged at the start of a move (a stall the engine did not see as a motion fault).
    pub fn stall_flags_logged(&self) -> u64 {
        self.log
            .driver_warnings_by_message
            .get(STALL_FLAG_MESSAGE)
            .copied()
            .unwrap_or(0)
    }

    /// Zaber stalls the host saw: the engine's motion faults with the FS flag, plus the flags the driver found
    /// at the start of the next move.
    pub fn zaber_stalls_seen(&self) -> u64 {
        self.events.zaber_stall_faults + self.stall_flags_logged()
    }

    /// SMC100 stalls the host saw: each leaves its controller in DISABLE until the driver re-enables it, after
    /// the engine saw the move fail or when a reconnection's re-verification found it.
    pub fn smc100_stalls_seen(&self) -> u64 {
        self.log.smc100_stalls_reenabled
    }

    /// Stalls the host saw, both kinds of controller.
    pub fn stalls_seen(&self) -> u64 {
        self.zaber_stalls_seen() + self.smc100_stalls_seen()
    }

    /// Every broken invariant, in words; empty when the soak passed.
    pub fn violations(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.hung {
            v.push(
                "the campaign did not end within five times its predicted instrument time (hang)".to_string(),
            );
        }
        if self.final_state != CampaignState::Completed {
            v.push(format!(
                "the campaign ended {} ({})",
                self.final_state,
                self.last_error.clone().unwrap_or_default()
            ));
        }
        if !self.pauses.is_empty() {
            v.push(format!(
                "the campaign paused {} times and needed the operator: {:?}",
                self.pauses.len(),
                self.pauses
            ));
        }
        v.extend(self.committed.violations());
        // Every injected fault is in the log, one report each.
        for (name, message) in INJECTED_LOG_KINDS {
            let counted = counter(&self.injected, name);
            let logged = self.log.injected.get(message).copied().unwrap_or(0);
            if counted != logged {
                v.push(format!(
                    "{name}: the simulator counted {counted} but the log reports {logged} (\"fault injected: {message}\")"
                ));
            }
        }
        // Every configured kind of fault was exercised.
        let f = &self.config.faults;
        for (name, on) in [
            ("garbled", f.garble_rate > 0.0),
            ("dropped", f.drop_rate > 0.0),
            ("delayed", f.delay_ms > 0.0 || f.delay_jitter_ms > 0.0),
            ("stalls", f.stall_rate > 0.0),
            ("outages", f.disconnect_after_s.is_some()),
        ] {
            if on && counter(&self.injected, name) == 0 {
                v.push(format!(
                    "{name}: configured but never injected (the soak is too short)"
                ));
            }
        }
        // The host's side: each stall ends in a motion fault the engine reports (or, for a move command sent
        // again after a lost reply, whose first copy stalled too, in the stall flag the driver finds at the start
        // of the next move); each outage in a lost connection the engine reports (and recovers from).
        let engine = |k: &str| self.events.faults.get(k).copied().unwrap_or(0);
        let smc100 = self.log.smc100_stalls_manifested;
        let zaber = self.log.stalls_manifested - smc100;
        if self.zaber_stalls_seen() < zaber || self.smc100_stalls_seen() < smc100 {
            v.push(format!(
                "{} stalls took effect ({} drawn: {zaber} Zaber, {smc100} SMC100) but the host saw {} Zaber stalls \
                 ({} motion faults with FS in the campaign's events, {} stall flags logged by the drivers) and {} \
                 SMC100 stalls (controllers re-enabled after a following error; {} motion faults in all)",
                self.log.stalls_manifested,
                self.injected.stalls,
                self.zaber_stalls_seen(),
                self.events.zaber_stall_faults,
                self.stall_flags_logged(),
                self.smc100_stalls_seen(),
                engine("motion fault"),
            ));
        }
        if engine("disconnected") < self.injected.outages {
            v.push(format!(
                "{} outages injected but the campaign's events report {} lost connections",
                self.injected.outages,
                engine("disconnected")
            ));
        }
        if self.events.lagged > 0 {
            v.push(format!("the event listener lost {} events", self.events.lagged));
        }
        v
    }
}

/// Run the fault soak.
pub fn run_fault_soak(cfg: &FaultSoakConfig) -> Result<FaultSoakReport, SoakError> {
    let wall = Instant::now();
    let mut faults = cfg.faults.clone();
    faults.seed = cfg.seed;
    let (file, instrument_text) = instrument_with_faults(&cfg.instrument, &faults)?;
    let campaign = build_campaign("fault-soak", cfg.points, cfg.seed, &file)?;
    let mut store = Store::open(&cfg.data_dir)?;
    if !store.campaigns()?.is_empty() {
        return Err(SoakError::Setup(format!(
            "{} already holds a store with campaigns: give the fault soak an empty directory",
            cfg.data_dir.display()
        )));
    }
    let prepared = prepare_campaign(&campaign.text, "fault-soak.toml", Path::new("."), &file)?;
    let id = store.create_campaign(&prepared.new_campaign(&campaign.text, &instrument_text))?;
    let store = Arc::new(Mutex::new(store));

    let capture = LogCapture::new(cfg.log_file.as_deref())?;
    let dispatch = tracing::Dispatch::new(
        tracing_subscriber::registry().with(capture.clone().with_filter(LogCapture::filter())),
    );
    let runtime = runtime_logging_to(&dispatch, true)?;
    let driven = tracing::dispatcher::with_default(&dispatch, || {
        runtime.block_on(drive(
            Arc::clone(&store),
            id,
            &file,
            cfg.max_resumes,
            Duration::from_secs_f64((campaign.predicted_s * 5.0).max(3600.0)),
        ))
    })?;
    drop(runtime);

    let s = store.lock().unwrap_or_else(|e| e.into_inner());
    let record = s.campaign(id)?;
    let points = s.points(id)?;
    let calibrations = s.calibrations(id)?;
    drop(s);
    let instrument_s = points
        .iter()
        .map(|p| p.t_s)
        .chain(calibrations.iter().map(|c| c.t_s))
        .fold(0.0f64, f64::max);
    let committed = RowSummary::of(campaign.total_points, &points, &Tolerance::of(&file));
    Ok(FaultSoakReport {
        config: cfg.clone(),
        faults_toml: crate::setup::faults_toml(&faults),
        quirks_toml: crate::setup::quirks_toml(&file.simulator.quirks),
        lost_to_pacing: driven.lost_to_pacing,
        campaign,
        committed,
        final_state: record.state,
        last_error: record.last_error,
        pauses: driven.pauses,
        hung: driven.hung,
        injected: driven.injected,
        log: capture.counts(),
        events: driven.events,
        instrument_s,
        sim_clock_s: driven.sim_clock_s,
        wall_s: wall.elapsed().as_secs_f64(),
    })
}

struct Driven {
    lost_to_pacing: std::collections::BTreeMap<String, u64>,
    pauses: Vec<String>,
    hung: bool,
    injected: FaultCounts,
    events: EventTally,
    sim_clock_s: f64,
}

async fn drive(
    store: Arc<Mutex<Store>>,
    id: gonio_engine::store::CampaignId,
    file: &InstrumentFile,
    max_resumes: u32,
    budget: Duration,
) -> Result<Driven, SoakError> {
    // Simulated time at scale 1 on the paused clock: the instrument takes its real time, the wall clock none.
    let rig = Rig::connect_with_time_scale(file, None, 1.0).await?;
    let control = Control::new();
    let mut rx = control.subscribe();
    let tally = Arc::new(Mutex::new(EventTally::default()));
    let t2 = Arc::clone(&tally);
    let listener = tokio::spawn(async move {
        loop {
            let event = rx.recv().await;
            let mut t = t2.lock().unwrap_or_else(|e| e.into_inner());
            match event {
                Ok(e) => t.observe(e),
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => t.lagged += n,
                Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
            }
        }
    });
    let mut pauses = Vec::new();
    // Simulated time at scale 1: a hang would let the paused clock run on forever, so the run has a budget.
    let deadline = tokio::time::Instant::now() + budget;
    let mut hung = false;
    loop {
        let run = run_campaign(Arc::clone(&store), id, &rig, control.clone());
        let Ok(state) = tokio::time::timeout_at(deadline, run).await else {
            hung = true;
            break;
        };
        let state = state?;
        if state != CampaignState::Paused || pauses.len() >= max_resumes as usize {
            break;
        }
        // Acting as the operator: note why, then resume (running the campaign again is the resume).
        let why = store
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .campaign(id)?
            .last_error
            .unwrap_or_default();
        tracing::warn!(campaign = %id, reason = %why, "soak: the campaign paused; resuming it as the operator");
        pauses.push(why);
    }
    let injected = rig.sim().map(|s| s.fault_counts()).unwrap_or_default();
    let sim_clock_s = rig.sim().map(|s| s.now_s()).unwrap_or(f64::NAN);
    let lost_to_pacing = rig.sim().map(|s| s.lost_input_by_command()).unwrap_or_default();
    // The listener ends when the last sender (the control) is gone; the queued events are delivered first.
    drop(control);
    let _ = tokio::time::timeout(Duration::from_secs(3600), listener).await;
    let events = tally.lock().unwrap_or_else(|e| e.into_inner()).clone();
    Ok(Driven {
        lost_to_pacing,
        pauses,
        hung,
        injected,
        events,
        sim_clock_s,
    })
}

#[cfg(test)]
mod tests;
