//! The daemon process the crash soak kills: `gonio-soak worker`.
//!
//! It is `gonio daemon` minus its command line: the store in a data directory, the rig on the simulated
//! instrument, the daemon's [`Service`] (campaign queue, interrupted campaigns resumed first) and its HTTP API on
//! a loopback port, run by [`api::run_daemon`]. It submits the soak campaign when the store does not hold it yet,
//! and stops once the campaign is final (or paused). Like `gonio run`'s dry-runs it runs on a paused tokio clock,
//! so that instrument time costs no wall time.
//!
//! It reports on stdout, one line per event, flushed at once (the parent reads them up to the kill):
//! `ready`, `point <index>` after each commit, `sweep <segment>` after each sweep segment's commit, `move <axis>
//! <target_deg>` per move command, `die <moment>: ...` just before a self-inflicted kill, `final <state>` at the
//! end. Points and sweep segments are the campaign's units of progress: the kills are armed by their count.
//!
//! Self-inflicted kills put the SIGKILL at an exact moment, which a kill from outside can only hit by chance:
//! - mid-move: a `tracing` layer sees the driver's move command and, at the next reply read on a port (the
//!   controller has taken the move and the axis is travelling), raises SIGKILL;
//! - mid-sweep: the same layer sees the engine start a sweep (`sweep started`: the arm is moving and the meter is
//!   read back to back) and raises SIGKILL at the given reply (the meter's or a controller's) read while sweeps
//!   run, inside the reading loop;
//! - mid-commit: SQLite's commit hook ([`Store::on_commit`]), armed once enough units are committed, raises
//!   SIGKILL inside the next commit: the record's writes are made, the commit is not (a point, a sweep segment
//!   with its readings, a calibration reading or a state change, whichever the engine writes next).
//!
//! SIGKILL cannot be caught: the process ends there, every thread at once, exactly as under `kill -9`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use gonio_campaign::CampaignFile;
use gonio_daemon::api::{self, ApiConfig};
use gonio_daemon::service::{CampaignRunner, EngineRunner, RunFuture, Service, Submission};
use gonio_engine::PreparedCampaign;
use gonio_engine::control::{Control, Event};
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignId, CampaignRecord, CampaignState, Store};
use gonio_instrument::InstrumentFile;
use tracing::field::{Field, Visit};
use tracing::{Level, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::{Context, SubscriberExt as _};

use crate::SoakError;

/// Exit code of a worker whose campaign completed.
pub const EXIT_COMPLETED: i32 = 0;
/// Exit code of a worker whose campaign ended in another state (paused, failed, aborted).
pub const EXIT_NOT_COMPLETED: i32 = 3;
/// Exit code of a worker that could not run.
pub const EXIT_ERROR: i32 = 2;

/// Where the worker kills itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DieAt {
    MidMove,
    MidCommit,
    /// At this reply read (1 = the first) after a sweep started.
    MidSweep {
        reads: u32,
    },
}

impl DieAt {
    /// The argument of `--die` (a sweep's reply count after a colon: `mid-sweep:120`).
    pub fn to_arg(self) -> String {
        match self {
            DieAt::MidMove => "mid-move".into(),
            DieAt::MidCommit => "mid-commit".into(),
            DieAt::MidSweep { reads } => format!("mid-sweep:{reads}"),
        }
    }
    pub fn parse(s: &str) -> Option<DieAt> {
        match s.split_once(':') {
            None if s == "mid-move" => Some(DieAt::MidMove),
            None if s == "mid-commit" => Some(DieAt::MidCommit),
            Some(("mid-sweep", n)) => n
                .parse()
                .ok()
                .filter(|n| *n > 0)
                .map(|reads| DieAt::MidSweep { reads }),
            _ => None,
        }
    }
}

/// What the worker runs.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerArgs {
    pub data: PathBuf,
    pub campaign: PathBuf,
    pub instrument: PathBuf,
    /// Kill itself at the first such moment after this many units (points and sweep segments) committed by this
    /// process.
    pub die: Option<(DieAt, u64)>,
}

impl WorkerArgs {
    /// The command-line arguments after `worker`.
    pub fn to_args(&self) -> Vec<String> {
        let mut v = vec![
            "--data".into(),
            self.data.display().to_string(),
            "--campaign".into(),
            self.campaign.display().to_string(),
            "--instrument".into(),
            self.instrument.display().to_string(),
        ];
        if let Some((at, after)) = self.die {
            v.extend(["--die".into(), at.to_arg(), "--after".into(), after.to_string()]);
        }
        v
    }
}

/// One line on stdout, flushed (the parent may kill us right after).
fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = out.write_all(line.as_bytes());
    let _ = out.write_all(b"\n");
    let _ = out.flush();
}

fn die(line: &str) -> ! {
    say(line);
    let _ = nix::sys::signal::raise(nix::sys::signal::Signal::SIGKILL);
    // Unreachable in practice; never return from a kill.
    std::process::abort()
}

/// Run the worker; returns the process exit code.
pub fn run_worker(args: &WorkerArgs) -> i32 {
    match run(args) {
        Ok(CampaignState::Completed) => EXIT_COMPLETED,
        Ok(_) => EXIT_NOT_COMPLETED,
        Err(e) => {
            eprintln!("gonio-soak worker: {e}");
            say(&format!("error {e}"));
            EXIT_ERROR
        }
    }
}

fn run(args: &WorkerArgs) -> Result<CampaignState, SoakError> {
    let units = Arc::new(AtomicU64::new(0));
    let probe = MoveProbe {
        units: Arc::clone(&units),
        die_after: match args.die {
            Some((at @ (DieAt::MidMove | DieAt::MidSweep { .. }), n)) => Some((at, n)),
            _ => None,
        },
        pending: Mutex::new(None),
    };
    let subscriber = tracing_subscriber::registry()
        .with(
            probe.with_filter(
                Targets::new()
                    .with_target("gonio_driver", Level::DEBUG)
                    .with_target("gonio_engine::runner", Level::INFO),
            ),
        )
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_filter(LevelFilter::WARN),
        );
    tracing::subscriber::set_global_default(subscriber)
        .map_err(|e| SoakError::Worker(format!("cannot install the log: {e}")))?;

    let read =
        |p: &Path| std::fs::read_to_string(p).map_err(SoakError::io(format!("cannot read {}", p.display())));
    let instrument_text = read(&args.instrument)?;
    let campaign_text = read(&args.campaign)?;
    let file = InstrumentFile::parse(&instrument_text, &args.instrument.display().to_string())
        .map_err(|e| SoakError::Setup(e.to_string()))?;
    let commit_killer = match args.die {
        Some((DieAt::MidCommit, after)) => Some(CommitKiller {
            units: Arc::clone(&units),
            after,
        }),
        _ => None,
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(SoakError::io("cannot start the async runtime"))?;
    runtime.block_on(async move {
        let store = Store::open(&args.data)?;
        let rig = Rig::connect_with_time_scale(&file, None, 1.0).await?;
        let base_dir = args.campaign.parent().map(Path::to_path_buf).unwrap_or_default();
        let runner = Arc::new(ProbeRunner {
            inner: EngineRunner::new(file, instrument_text, base_dir, rig),
            commit_killer,
        });
        let service =
            Service::new(store, runner, Control::new()).map_err(|e| SoakError::Worker(e.to_string()))?;
        let name = campaign_name(&campaign_text)?;
        let mut events = service.subscribe();
        let known = service
            .campaigns()
            .map_err(|e| SoakError::Worker(e.to_string()))?;
        if !known.iter().any(|c| c.name == name) {
            service
                .submit(&campaign_text, &args.campaign.display().to_string())
                .map_err(|e| SoakError::Worker(e.to_string()))?;
        }
        say("ready");
        let end: Arc<Mutex<Option<CampaignState>>> = Arc::new(Mutex::new(None));
        let end2 = Arc::clone(&end);
        let stop = async move {
            loop {
                match events.recv().await {
                    Ok(Event::Point { point, .. }) => {
                        units.fetch_add(1, Ordering::SeqCst);
                        say(&format!("point {}", point.index));
                    }
                    Ok(Event::Sweep { segment, .. }) => {
                        units.fetch_add(1, Ordering::SeqCst);
                        say(&format!("sweep {segment}"));
                    }
                    Ok(Event::State { state, .. }) if state.is_final() || state == CampaignState::Paused => {
                        *end2.lock().unwrap_or_else(|e| e.into_inner()) = Some(state);
                        break;
                    }
                    Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
                }
            }
        };
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(SoakError::io("cannot listen on loopback"))?;
        api::run_daemon(listener, service.clone(), &ApiConfig::default(), stop).await;
        let state = service
            .campaigns()
            .map_err(|e| SoakError::Worker(e.to_string()))?
            .into_iter()
            .find(|c| c.name == name)
            .map(|c| c.state)
            .or(*end.lock().unwrap_or_else(|e| e.into_inner()))
            .ok_or_else(|| SoakError::Worker("the campaign is not in the store".into()))?;
        say(&format!("final {state}"));
        Ok(state)
    })
}

/// `[campaign] id` of a campaign file.
fn campaign_name(text: &str) -> Result<String, SoakError> {
    let file = CampaignFile::parse(text).map_err(|e| SoakError::Setup(format!("campaign file: {e}")))?;
    file.id()
        .map(str::to_string)
        .ok_or_else(|| SoakError::Setup("campaign file: no [campaign] id".into()))
}

/// The engine runner, arming the mid-commit kill on the store the service hands it.
struct ProbeRunner {
    inner: EngineRunner,
    commit_killer: Option<CommitKiller>,
}

impl CampaignRunner for ProbeRunner {
    fn prepare(
        &self,
        campaign_toml: &str,
        origin: &str,
    ) -> Result<Submission, gonio_daemon::service::ServiceError> {
        self.inner.prepare(campaign_toml, origin)
    }

    fn run(
        &self,
        store: Arc<Mutex<Store>>,
        id: CampaignId,
        control: Control,
        prepared: Option<Arc<PreparedCampaign>>,
    ) -> RunFuture {
        if let Some(killer) = &self.commit_killer {
            killer.arm(&store);
        }
        self.inner.run(store, id, control, prepared)
    }

    fn points_csv(
        &self,
        store: &Store,
        record: &CampaignRecord,
    ) -> Result<String, gonio_engine::store::StoreError> {
        self.inner.points_csv(store, record)
    }
}

/// SIGKILL inside the first commit once `after` units are committed by this process.
struct CommitKiller {
    units: Arc<AtomicU64>,
    after: u64,
}

impl CommitKiller {
    fn arm(&self, store: &Arc<Mutex<Store>>) {
        let (units, after) = (Arc::clone(&self.units), self.after);
        let hook = move || {
            let done = units.load(Ordering::SeqCst);
            if done >= after {
                die(&format!(
                    "die mid-commit: inside the commit of a store write, {done} units committed by this process"
                ));
            }
            false
        };
        let armed = store
            .lock()
            .map_err(|_| "poisoned".to_string())
            .and_then(|mut s| s.on_commit(hook).map_err(|e| e.to_string()));
        if let Err(e) = armed {
            die(&format!("die: cannot arm the mid-commit kill: {e}"));
        }
    }
}

/// Sees the drivers' move commands and the engine's sweeps: reports each move, and kills the process mid-move or
/// mid-sweep when armed.
struct MoveProbe {
    units: Arc<AtomicU64>,
    die_after: Option<(DieAt, u64)>,
    pending: Mutex<Option<Pending>>,
}

/// A kill waiting for its reply.
enum Pending {
    /// A move commanded while armed: the first line read back on its port.
    Move { port: String, what: String },
    /// A sweep started while armed: the `left`-th reply read back from any device while sweeps run (the count
    /// holds between a sweep's end and the next one's start).
    Sweep { left: u32, what: String, running: bool },
}

#[derive(Default)]
struct Fields {
    message: String,
    axis: String,
    target: String,
    rx: String,
    port: String,
    segment: Option<u64>,
}

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        let slot = match field.name() {
            "message" => &mut self.message,
            "axis" => &mut self.axis,
            "target_deg" => &mut self.target,
            "rx" => &mut self.rx,
            "port" => &mut self.port,
            _ => return,
        };
        *slot = format!("{value:?}");
    }
    fn record_f64(&mut self, field: &Field, value: f64) {
        if field.name() == "target_deg" {
            self.target = format!("{value}");
        }
    }
    fn record_u64(&mut self, field: &Field, value: u64) {
        if field.name() == "segment" {
            self.segment = Some(value);
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        match field.name() {
            "message" => self.message = value.to_string(),
            "port" => self.port = value.to_string(),
            "axis" => self.axis = value.to_string(),
            _ => {}
        }
    }
}

impl MoveProbe {
    /// Armed for `kind` now: its kind matches and enough units are committed.
    fn armed(&self, kind: fn(&DieAt) -> bool) -> Option<DieAt> {
        self.die_after
            .filter(|(at, n)| kind(at) && self.units.load(Ordering::SeqCst) >= *n)
            .map(|(at, _)| at)
    }
}

impl<S: Subscriber> Layer<S> for MoveProbe {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: Context<'_, S>) {
        let mut f = Fields::default();
        event.record(&mut f);
        let target = event.metadata().target();
        if f.message == "move absolute" || f.message == "move abs" {
            say(&format!("move {} {}", f.axis, f.target));
            if self.armed(|a| *a == DieAt::MidMove).is_some() {
                // The axis is named "light (arms/1)": its port is the device before the slash.
                let port = f
                    .axis
                    .split_once('(')
                    .and_then(|(_, rest)| rest.split('/').next())
                    .unwrap_or_default()
                    .to_string();
                *self.pending.lock().unwrap_or_else(|e| e.into_inner()) = Some(Pending::Move {
                    port,
                    what: format!("{} commanded to {} deg", f.axis, f.target),
                });
            }
        } else if f.message == "sweep started" && target.starts_with("gonio_engine") {
            if let Some(DieAt::MidSweep { reads }) = self.armed(|a| matches!(a, DieAt::MidSweep { .. })) {
                let segment = f.segment.map_or_else(|| "?".to_string(), |s| s.to_string());
                let what = format!("sweep segment {segment} of {} under way", f.axis);
                let mut pending = self.pending.lock().unwrap_or_else(|e| e.into_inner());
                match pending.as_mut() {
                    Some(Pending::Sweep { what: w, running, .. }) => (*w, *running) = (what, true),
                    _ => {
                        *pending = Some(Pending::Sweep {
                            left: reads,
                            what,
                            running: true,
                        })
                    }
                }
            }
        } else if f.message == "sweep ended" && target.starts_with("gonio_engine") {
            if let Some(Pending::Sweep { running, .. }) =
                self.pending.lock().unwrap_or_else(|e| e.into_inner()).as_mut()
            {
                *running = false;
            }
        } else if (f.message == "read" && target.contains("transport")) || f.message == "USBTMC reply" {
            let serial = f.message == "read";
            let mut pending = self.pending.lock().unwrap_or_else(|e| e.into_inner());
            let kill = match pending.as_mut() {
                // The first line read back on that port after the move command: the controller has taken it.
                Some(Pending::Move { port, what }) if serial && *port == f.port => {
                    Some(format!("die mid-move: {what}"))
                }
                Some(Pending::Sweep {
                    left,
                    what,
                    running: true,
                }) => {
                    *left = left.saturating_sub(1);
                    (*left == 0).then(|| format!("die mid-sweep: {what}"))
                }
                _ => None,
            };
            if let Some(kill) = kill {
                pending.take();
                die(&format!(
                    "{kill}, reply {} read, {} units committed by this process",
                    f.rx,
                    self.units.load(Ordering::SeqCst)
                ));
            }
        }
    }
}
