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
use gonio_daemon::control::Control;
use gonio_daemon::rig::Rig;
use gonio_daemon::service::{EngineRunner, Service};
use gonio_daemon::store::{CampaignState, Store};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::SoakError;
use crate::rows::RowSummary;
use crate::setup::{SoakCampaign, build_campaign};

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

// ---------------------------------------------------------------- HTTP on the wire

/// A response as read off the wire.
#[derive(Debug)]
pub struct Answer {
    pub status: u16,
    /// The status line and headers, as sent.
    pub head: String,
    pub body: String,
}

/// Read one response (headers, then a Content-Length body, nothing more of an event stream, or else up to EOF);
/// None when the connection closes first. Shared with the daemon's abuse tests (`tests/http_abuse.rs`).
pub async fn read_answer(stream: &mut (impl tokio::io::AsyncRead + Unpin)) -> Option<Answer> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 4096];
    let head_end = loop {
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break i + 4;
        }
        match stream.read(&mut chunk).await {
            Ok(0) | Err(_) => return None,
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
        }
    };
    let head = String::from_utf8_lossy(&buf[..head_end]).into_owned();
    let status = head.split_whitespace().nth(1)?.parse().ok()?;
    let length = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.eq_ignore_ascii_case("content-length")
            .then(|| v.trim().parse::<usize>().ok())?
    });
    let mut body = buf[head_end..].to_vec();
    match length {
        Some(n) => {
            while body.len() < n {
                match stream.read(&mut chunk).await {
                    Ok(0) | Err(_) => break,
                    Ok(k) => body.extend_from_slice(&chunk[..k]),
                }
            }
        }
        // An event stream never ends: its head is the answer.
        None if head.to_ascii_lowercase().contains("text/event-stream") => {}
        None => {
            let _ = stream.read_to_end(&mut body).await;
        }
    }
    Some(Answer {
        status,
        head,
        body: String::from_utf8_lossy(&body).into_owned(),
    })
}

/// Send a request on a new connection and read the answer; Err says what went wrong.
pub async fn exchange(addr: SocketAddr, raw: &[u8]) -> Result<Answer, String> {
    let mut stream = TcpStream::connect(addr)
        .await
        .map_err(|e| format!("connect: {e}"))?;
    stream.write_all(raw).await.map_err(|e| format!("send: {e}"))?;
    read_answer(&mut stream)
        .await
        .ok_or_else(|| "closed without an answer".to_string())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Header,
    Body,
    Idle,
}

/// The length a body trickler announces: half the body limit, at most 100 kB.
pub fn slow_body_bytes(limit: usize) -> usize {
    (limit / 2).min(100_000)
}

/// One persistent hostile client: connect, misbehave until the daemon closes the connection, reconnect.
async fn attacker(
    kind: Kind,
    addr: SocketAddr,
    cfg: Arc<HttpAbuseConfig>,
    stop: Arc<AtomicBool>,
    stats: Arc<KindStats>,
) {
    let start = match kind {
        Kind::Header => "GET /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ".to_string(),
        // Within the body limit: the daemon must wait for it (up to its body deadline), not refuse it at once.
        Kind::Body => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {}\r\n\r\n[campaign]\n",
            slow_body_bytes(cfg.api.body_limit_bytes)
        ),
        Kind::Idle => String::new(),
    };
    let start = start.as_bytes();
    let mut buf = [0u8; 1024];
    while !stop.load(Ordering::Relaxed) {
        let Ok(mut stream) = TcpStream::connect(addr).await else {
            tokio::time::sleep(cfg.reconnect_after).await;
            continue;
        };
        stats.opened.fetch_add(1, Ordering::Relaxed);
        let mut ended_by_daemon = !start.is_empty() && stream.write_all(start).await.is_err();
        let mut status = None;
        while !ended_by_daemon && !stop.load(Ordering::Relaxed) {
            tokio::select! {
                r = stream.read(&mut buf) => {
                    if let Ok(n) = r && n > 0 {
                        status = std::str::from_utf8(&buf[..n])
                            .ok()
                            .and_then(|s| s.split_whitespace().nth(1))
                            .and_then(|s| s.parse::<u16>().ok());
                    }
                    ended_by_daemon = true;
                }
                _ = tokio::time::sleep(cfg.trickle_period) => {
                    if kind != Kind::Idle && stream.write_all(b"x").await.is_err() {
                        ended_by_daemon = true;
                    }
                }
            }
        }
        if ended_by_daemon {
            match status {
                Some(s) => stats.answered.lock().unwrap_or_else(|e| e.into_inner()).push(s),
                None => {
                    stats.closed.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        drop(stream);
        tokio::time::sleep(cfg.reconnect_after).await;
    }
}

/// One oversized request of kind `k` (0 announced, 1 chunked, 2 streamed): the body is written by its own task
/// while the answer is read, so that a refusal sent before the body is taken is seen.
async fn oversized(
    addr: SocketAddr,
    k: usize,
    limit: usize,
    deadline: Duration,
    counts: &mut OversizedCounts,
) {
    counts.sent += 1;
    let over = 2 * limit + 1;
    let head = match k {
        0 => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            10 * limit
        ),
        1 => "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
            .to_string(),
        _ => format!(
            "POST /api/campaigns HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {over}\r\nConnection: close\r\n\r\n"
        ),
    };
    let result = tokio::time::timeout(deadline, async move {
        let stream = TcpStream::connect(addr).await.ok()?;
        let (mut rd, mut wr) = stream.into_split();
        let writer = tokio::spawn(async move {
            if wr.write_all(head.as_bytes()).await.is_err() {
                return;
            }
            let piece = vec![b'#'; 16 * 1024];
            let mut sent = 0;
            while k != 0 && sent < over {
                let n = piece.len().min(over - sent);
                let ok = if k == 1 {
                    let framed = [format!("{n:x}\r\n").as_bytes(), &piece[..n], b"\r\n"].concat();
                    wr.write_all(&framed).await.is_ok()
                } else {
                    wr.write_all(&piece[..n]).await.is_ok()
                };
                if !ok {
                    return;
                }
                sent += n;
            }
            if k == 1 {
                let _ = wr.write_all(b"0\r\n\r\n").await;
            }
            // Keep the write half open until the reader is done.
            std::future::pending::<()>().await;
        });
        let answer = read_answer(&mut rd).await;
        writer.abort();
        Some(answer)
    })
    .await;
    match result {
        Err(_) => counts.hung += 1,
        Ok(None) | Ok(Some(None)) => counts.closed += 1,
        Ok(Some(Some(a))) if a.status == 413 => counts.refused_413 += 1,
        Ok(Some(Some(a))) => *counts.other.entry(a.status).or_default() += 1,
    }
}

/// The daemon's service as `gonio daemon` builds it: the store in `data`, the simulated instrument of `file` at
/// `time_scale` simulated seconds per second. No queue runs until it is served (`api::run_daemon`).
pub async fn daemon_service(file: InstrumentFile, data: &Path, time_scale: f64) -> Result<Service, String> {
    let rig = Rig::connect_with_time_scale(&file, None, time_scale)
        .await
        .map_err(|e| format!("instrument: {e}"))?;
    let runner = Arc::new(EngineRunner::new(
        file,
        SIMULATED_INSTRUMENT_TOML.to_string(),
        data.to_path_buf(),
        rig,
    ));
    let store = Store::open(data).map_err(|e| e.to_string())?;
    Service::new(store, runner, Control::new()).map_err(|e| e.to_string())
}

/// The daemon as `gonio daemon` runs it, on a loopback port: [`daemon_service`] served by `api::run_daemon` in a
/// task of the current runtime. Dropping it signals the shutdown; [`LoopbackDaemon::shut_down`] also waits for it.
#[derive(Debug)]
pub struct LoopbackDaemon {
    pub addr: SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<()>,
}

impl LoopbackDaemon {
    /// Start the daemon with its data in `data` and the API limits of `api_config` on 127.0.0.1, a free port.
    pub async fn start(
        file: InstrumentFile,
        data: &Path,
        time_scale: f64,
        api_config: &ApiConfig,
    ) -> Result<LoopbackDaemon, String> {
        let service = daemon_service(file, data, time_scale).await?;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(|e| format!("bind: {e}"))?;
        let addr = listener.local_addr().map_err(|e| format!("address: {e}"))?;
        let (stop, signal) = tokio::sync::oneshot::channel::<()>();
        let api_config = api_config.clone();
        let task = tokio::spawn(async move {
            // A dropped sender ends the wait as a sent signal does.
            api::run_daemon(listener, service, &api_config, async {
                let _ = signal.await;
            })
            .await;
        });
        Ok(LoopbackDaemon { addr, stop, task })
    }

    /// Signal the shutdown and wait until the daemon has finished it.
    pub async fn shut_down(self) {
        let _ = self.stop.send(());
        let _ = self.task.await;
    }
}

/// The campaign's state from a status answer.
fn state_of(body: &str) -> Option<CampaignState> {
    let v: serde_json::Value = serde_json::from_str(body).ok()?;
    let s = v.get("state")?.as_str()?;
    CampaignState::ALL.into_iter().find(|c| c.as_str() == s)
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
    let committed = RowSummary::of(campaign.total_points, &points);
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
mod tests {
    use super::*;

    #[test]
    fn the_state_is_read_from_a_status_answer() {
        assert_eq!(
            state_of(r#"{"id":1,"state":"completed","points_done":3}"#),
            Some(CampaignState::Completed)
        );
        assert_eq!(state_of(r#"{"state":"no-such-state"}"#), None);
        assert_eq!(state_of("not json"), None);
    }
}
