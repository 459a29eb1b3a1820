//! The HTTP abuse soak: the daemon runs a campaign while hostile clients press on its control API, and a
//! well-behaved client keeps asking for the campaign's status.
//!
//! The daemon is `gonio daemon` minus its command line, in this process: the store, the simulated instrument (on
//! the real clock, at a time scale), the daemon's `Service` and its API served by `api::run_daemon` on a loopback
//! port, on its own multi-thread runtime (its own threads, as `gonio daemon` has). The clients run on another
//! runtime and reach it over real TCP connections:
//!
//! - slowloris clients trickling request headers one byte at a time, others trickling a request body, and idle
//!   connections that send nothing; together more than the daemon's connection limit. Each reconnects shortly
//!   after the daemon closes it (a persistent attacker);
//! - oversized request bodies, over and over: announced by `Content-Length` (ten times the limit), chunked past
//!   the limit, and streamed past the limit;
//! - the status client: `GET /api/campaigns/{id}` on a new connection at a fixed period, each answer timed.
//!
//! Checked: every status request answered (200) within the deadline, every oversized body refused (413, or the
//! connection closed before the body was taken; never accepted), the slow connections closed by the daemon, and
//! the campaign completed with one valid row per planned point.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gonio_daemon::api::{self, ApiConfig};
use gonio_daemon::service::{EngineRunner, Service};
use gonio_engine::control::Control;
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignState, Store};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::SoakError;
use crate::rows::RowSummary;
use crate::setup::{SoakCampaign, build_campaign};

mod loopback;
mod wire;

use loopback::state_of;
pub use loopback::{LoopbackDaemon, daemon_service};
pub use wire::{Answer, exchange, read_answer, slow_body_bytes};
use wire::{Kind, attacker, oversized};

/// What to run.
#[derive(Debug, Clone)]
pub struct HttpAbuseConfig {
    pub points: u64,
    pub seed: u64,
    /// An empty directory for the daemon's data.
    pub data_dir: PathBuf,
    /// Simulated seconds per wall second of the instrument.
    pub time_scale: f64,
    /// The daemon's API limits (`ApiConfig::default()` is what `gonio daemon` uses).
    pub api: ApiConfig,
    /// Hostile clients of each kind.
    pub header_tricklers: usize,
    pub body_tricklers: usize,
    pub idle: usize,
    /// A trickler sends one byte per period.
    pub trickle_period: Duration,
    /// A hostile client reconnects this long after the daemon closed it.
    pub reconnect_after: Duration,
    /// One oversized request per period.
    pub oversized_period: Duration,
    /// One status request per period.
    pub probe_period: Duration,
    /// A status request (or an oversized request's refusal) must be answered within this.
    pub deadline: Duration,
    /// Longest the whole soak may take (wall).
    pub max_wall: Duration,
}

impl HttpAbuseConfig {
    /// The daemon with its default limits (256 connections, 10 s for headers, 20 s for a body, 1 MiB bodies)
    /// against 1.5 times as many slow connections as it accepts.
    pub fn full(points: u64, seed: u64, data_dir: PathBuf) -> HttpAbuseConfig {
        let api = ApiConfig::default();
        let slow = api.max_connections * 3 / 2;
        HttpAbuseConfig {
            points,
            seed,
            data_dir,
            time_scale: 10.0,
            header_tricklers: slow * 2 / 3,
            body_tricklers: slow / 6,
            idle: slow - slow * 2 / 3 - slow / 6,
            api,
            trickle_period: Duration::from_millis(500),
            reconnect_after: Duration::from_secs(1),
            oversized_period: Duration::from_millis(200),
            probe_period: Duration::from_millis(100),
            deadline: Duration::from_secs(5),
            max_wall: Duration::from_secs(900),
        }
    }

    /// Small limits and a short campaign for a test: the same code path, every limit reached within seconds.
    pub fn quick(points: u64, seed: u64, data_dir: PathBuf) -> HttpAbuseConfig {
        let api = ApiConfig {
            max_connections: 8,
            header_read_timeout: Duration::from_secs(1),
            body_read_timeout: Duration::from_secs(1),
            body_limit_bytes: 64 * 1024,
            ..ApiConfig::default()
        };
        HttpAbuseConfig {
            points,
            seed,
            data_dir,
            time_scale: 20.0,
            header_tricklers: 8,
            body_tricklers: 2,
            idle: 2,
            api,
            trickle_period: Duration::from_millis(200),
            reconnect_after: Duration::from_millis(200),
            oversized_period: Duration::from_millis(100),
            probe_period: Duration::from_millis(100),
            // Generous: a daemon that blocked would wait forever, one that answers takes milliseconds.
            deadline: Duration::from_secs(10),
            max_wall: Duration::from_secs(300),
        }
    }
}

/// Hostile clients of one kind.
#[derive(Debug, Default)]
struct KindStats {
    opened: AtomicU64,
    /// Closed by the daemon without an answer (eviction, header deadline).
    closed: AtomicU64,
    /// Closed by the daemon with an answer (e.g. 408 for a body past its deadline).
    answered: Mutex<Vec<u16>>,
}

/// The counts of one kind of hostile client.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AttackCounts {
    pub clients: usize,
    pub connections: u64,
    pub closed_without_answer: u64,
    /// Answers the daemon gave before closing, by status.
    pub answers: std::collections::BTreeMap<u16, u64>,
}

impl AttackCounts {
    fn from(clients: usize, s: &KindStats) -> AttackCounts {
        let mut answers = std::collections::BTreeMap::new();
        for st in s.answered.lock().unwrap_or_else(|e| e.into_inner()).iter() {
            *answers.entry(*st).or_default() += 1;
        }
        AttackCounts {
            clients,
            connections: s.opened.load(Ordering::Relaxed),
            closed_without_answer: s.closed.load(Ordering::Relaxed),
            answers,
        }
    }

    /// Connections the daemon ended, with or without an answer.
    pub fn ended_by_daemon(&self) -> u64 {
        self.closed_without_answer + self.answers.values().sum::<u64>()
    }
}

/// The oversized requests of one kind.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OversizedCounts {
    pub sent: u64,
    /// Answered 413.
    pub refused_413: u64,
    /// The connection closed before the body was taken, without an answer.
    pub closed: u64,
    /// Any other answer (a 2xx would be an accepted body), by status.
    pub other: std::collections::BTreeMap<u16, u64>,
    /// Neither answered nor closed within the deadline.
    pub hung: u64,
}

/// Everything the HTTP abuse soak measured.
#[derive(Debug, Clone)]
pub struct HttpAbuseReport {
    pub campaign: SoakCampaign,
    pub max_connections: usize,
    pub header_read_timeout_s: f64,
    pub body_read_timeout_s: f64,
    pub body_limit_bytes: usize,
    pub time_scale: f64,
    pub deadline_s: f64,
    pub header_tricklers: AttackCounts,
    pub body_tricklers: AttackCounts,
    pub idle: AttackCounts,
    /// Announced, chunked, streamed.
    pub oversized: [OversizedCounts; 3],
    /// Status requests: latencies of those answered 200 within the deadline (s), sorted.
    pub probe_latencies_s: Vec<f64>,
    /// Status requests not answered 200 within the deadline, with what happened.
    pub probe_failures: Vec<String>,
    pub final_state: Option<CampaignState>,
    pub last_error: Option<String>,
    /// The final points against the plan and the simulator's ground truth.
    pub committed: RowSummary,
    /// Wall time of the campaign under attack (s).
    pub campaign_wall_s: f64,
    pub wall_s: f64,
    /// The soak could not finish (what stopped it).
    pub problems: Vec<String>,
}

impl HttpAbuseReport {
    pub fn probes(&self) -> u64 {
        (self.probe_latencies_s.len() + self.probe_failures.len()) as u64
    }

    /// The `q` quantile of the answered status requests' latency (s).
    pub fn latency_quantile_s(&self, q: f64) -> f64 {
        let v = &self.probe_latencies_s;
        if v.is_empty() {
            return f64::NAN;
        }
        let i = ((v.len() - 1) as f64 * q).round() as usize;
        v[i.min(v.len() - 1)]
    }

    /// Every broken invariant, in words; empty when the soak passed.
    pub fn violations(&self) -> Vec<String> {
        let mut v: Vec<String> = self.problems.clone();
        if !self.probe_failures.is_empty() {
            v.push(format!(
                "{} of {} status requests not answered within {} s: {}",
                self.probe_failures.len(),
                self.probes(),
                self.deadline_s,
                self.probe_failures
                    .iter()
                    .take(5)
                    .cloned()
                    .collect::<Vec<_>>()
                    .join("; ")
            ));
        }
        if self.probe_latencies_s.is_empty() {
            v.push("no status request was answered".into());
        }
        for (name, o) in ["announced", "chunked", "streamed"].iter().zip(&self.oversized) {
            if o.sent == 0 {
                v.push(format!("no {name} oversized body was sent"));
            }
            if !o.other.is_empty() || o.hung > 0 {
                v.push(format!(
                    "{name} oversized bodies: answered {:?}, {} neither answered nor closed",
                    o.other, o.hung
                ));
            }
        }
        if self.oversized[0].closed > 0 {
            v.push(format!(
                "{} announced oversized bodies got no 413",
                self.oversized[0].closed
            ));
        }
        for (name, a) in [
            ("header tricklers", &self.header_tricklers),
            ("body tricklers", &self.body_tricklers),
            ("idle connections", &self.idle),
        ] {
            if a.clients > 0 && a.ended_by_daemon() == 0 {
                v.push(format!("the daemon never closed one of the {name}"));
            }
            if a.answers.keys().any(|s| (200..300).contains(s)) {
                v.push(format!("{name} got a success answer: {:?}", a.answers));
            }
        }
        if self.final_state != Some(CampaignState::Completed) {
            v.push(format!(
                "the campaign ended {:?} ({})",
                self.final_state,
                self.last_error.clone().unwrap_or_default()
            ));
        }
        v.extend(self.committed.violations());
        v
    }

    /// Points lost or wrong.
    pub fn data_lost(&self) -> u64 {
        self.committed.lost()
    }
}

// ---------------------------------------------------------------- the soak

/// Run the HTTP abuse soak.
pub fn run_http_abuse(cfg: &HttpAbuseConfig) -> Result<HttpAbuseReport, SoakError> {
    let wall = Instant::now();
    let file = InstrumentFile::simulated();
    let campaign = build_campaign("http-abuse", cfg.points, cfg.seed, &file)?;
    std::fs::create_dir_all(&cfg.data_dir)
        .map_err(SoakError::io(format!("cannot create {}", cfg.data_dir.display())))?;

    // The daemon, on its own runtime and threads.
    let (addr_tx, addr_rx) = std::sync::mpsc::channel::<Result<SocketAddr, String>>();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let daemon = {
        let (data, api_config, scale) = (cfg.data_dir.clone(), cfg.api.clone(), cfg.time_scale);
        std::thread::spawn(move || {
            let rt = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
                Ok(rt) => rt,
                Err(e) => {
                    let _ = addr_tx.send(Err(format!("daemon runtime: {e}")));
                    return;
                }
            };
            rt.block_on(async {
                match LoopbackDaemon::start(file, &data, scale, &api_config).await {
                    Err(e) => {
                        let _ = addr_tx.send(Err(e));
                    }
                    Ok(daemon) => {
                        let _ = addr_tx.send(Ok(daemon.addr));
                        let _ = stop_rx.await;
                        daemon.shut_down().await;
                    }
                }
            });
        })
    };
    let addr = addr_rx
        .recv()
        .map_err(|_| SoakError::Setup("the daemon thread ended before listening".into()))?
        .map_err(SoakError::Setup)?;

    let clients = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(SoakError::io("cannot start the clients' runtime"))?;
    let cfg_arc = Arc::new(cfg.clone());
    let outcome = clients.block_on(abuse(addr, cfg_arc, &campaign));
    drop(clients);
    let _ = stop_tx.send(());
    if daemon.join().is_err() {
        return Err(SoakError::Setup("the daemon thread panicked".into()));
    }

    // The store, read back on its own.
    let store = Store::open(&cfg.data_dir)?;
    let record = store.campaigns()?.into_iter().next();
    let points = match &record {
        Some(r) => store.points(r.id)?,
        None => Vec::new(),
    };
    let committed = RowSummary::of(
        campaign.total_points,
        &points,
        &crate::truth_check::Tolerance::ideal(),
    );
    Ok(HttpAbuseReport {
        max_connections: cfg.api.max_connections,
        header_read_timeout_s: cfg.api.header_read_timeout.as_secs_f64(),
        body_read_timeout_s: cfg.api.body_read_timeout.as_secs_f64(),
        body_limit_bytes: cfg.api.body_limit_bytes,
        time_scale: cfg.time_scale,
        deadline_s: cfg.deadline.as_secs_f64(),
        header_tricklers: outcome.header,
        body_tricklers: outcome.body,
        idle: outcome.idle,
        oversized: outcome.oversized,
        probe_latencies_s: outcome.latencies,
        probe_failures: outcome.failures,
        final_state: record.as_ref().map(|r| r.state),
        last_error: record.and_then(|r| r.last_error),
        committed,
        campaign,
        campaign_wall_s: outcome.campaign_wall_s,
        wall_s: wall.elapsed().as_secs_f64(),
        problems: outcome.problems,
    })
}

struct Outcome {
    header: AttackCounts,
    body: AttackCounts,
    idle: AttackCounts,
    oversized: [OversizedCounts; 3],
    latencies: Vec<f64>,
    failures: Vec<String>,
    campaign_wall_s: f64,
    problems: Vec<String>,
}

async fn abuse(addr: SocketAddr, cfg: Arc<HttpAbuseConfig>, campaign: &SoakCampaign) -> Outcome {
    let mut problems = Vec::new();
    let started = Instant::now();
    // Submit the campaign through the API, as `gonio ctl submit` does.
    let submit = format!(
        "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/toml\r\n{}: http-abuse.toml\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{}",
        api::ORIGIN_HEADER,
        campaign.text.len(),
        campaign.text
    );
    let id = match tokio::time::timeout(cfg.deadline, exchange(addr, submit.as_bytes())).await {
        Ok(Ok(a)) if a.status == 201 => serde_json::from_str::<serde_json::Value>(&a.body)
            .ok()
            .and_then(|v| v.get("id").and_then(|i| i.as_i64())),
        Ok(Ok(a)) => {
            problems.push(format!("submission answered {}: {}", a.status, a.body));
            None
        }
        Ok(Err(e)) => {
            problems.push(format!("submission: {e}"));
            None
        }
        Err(_) => {
            problems.push("submission: no answer within the deadline".into());
            None
        }
    };

    let stop = Arc::new(AtomicBool::new(false));
    let stats: [Arc<KindStats>; 3] = Default::default();
    let mut tasks = Vec::new();
    for (kind, n, s) in [
        (Kind::Header, cfg.header_tricklers, &stats[0]),
        (Kind::Body, cfg.body_tricklers, &stats[1]),
        (Kind::Idle, cfg.idle, &stats[2]),
    ] {
        for _ in 0..n {
            tasks.push(tokio::spawn(attacker(
                kind,
                addr,
                Arc::clone(&cfg),
                Arc::clone(&stop),
                Arc::clone(s),
            )));
        }
    }
    let oversized_task = {
        let (cfg, stop) = (Arc::clone(&cfg), Arc::clone(&stop));
        tokio::spawn(async move {
            let mut counts: [OversizedCounts; 3] = Default::default();
            let mut k = 0usize;
            while !stop.load(Ordering::Relaxed) {
                oversized(addr, k, cfg.api.body_limit_bytes, cfg.deadline, &mut counts[k]).await;
                k = (k + 1) % 3;
                tokio::time::sleep(cfg.oversized_period).await;
            }
            counts
        })
    };

    // The status client, until the campaign is final.
    let mut latencies = Vec::new();
    let mut failures = Vec::new();
    if let Some(id) = id {
        let request =
            format!("GET /api/campaigns/{id} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
        let mut tick = tokio::time::interval(cfg.probe_period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            if started.elapsed() > cfg.max_wall {
                problems.push(format!(
                    "the campaign was not final after {:.0} s",
                    cfg.max_wall.as_secs_f64()
                ));
                break;
            }
            let t = Instant::now();
            let answer = tokio::time::timeout(cfg.deadline, exchange(addr, request.as_bytes())).await;
            let dt = t.elapsed().as_secs_f64();
            match answer {
                Ok(Ok(a)) if a.status == 200 => {
                    latencies.push(dt);
                    if state_of(&a.body).is_some_and(|s| s.is_final()) {
                        break;
                    }
                }
                Ok(Ok(a)) => failures.push(format!("answered {} after {dt:.3} s: {}", a.status, a.body)),
                Ok(Err(e)) => failures.push(format!("{e} after {dt:.3} s")),
                Err(_) => failures.push(format!("no answer within {} s", cfg.deadline.as_secs_f64())),
            }
        }
    }
    let campaign_wall_s = started.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    for t in &tasks {
        t.abort();
    }
    let oversized = match tokio::time::timeout(cfg.deadline * 2, oversized_task).await {
        Ok(Ok(c)) => c,
        _ => {
            problems.push("the oversized-body client did not stop".into());
            Default::default()
        }
    };
    latencies.sort_by(f64::total_cmp);
    Outcome {
        header: AttackCounts::from(cfg.header_tricklers, &stats[0]),
        body: AttackCounts::from(cfg.body_tricklers, &stats[1]),
        idle: AttackCounts::from(cfg.idle, &stats[2]),
        oversized,
        latencies,
        failures,
        campaign_wall_s,
        problems,
    }
}

#[cfg(test)]
mod tests;
