//! The daemon's control API against hostile and broken clients, over real TCP connections on 127.0.0.1.
//!
//! First the CI-sized HTTP abuse soak: slow, idle and body-trickling clients beyond the daemon's connection limit
//! and oversized bodies while it runs a campaign; the daemon answers every status request, refuses every oversized
//! body, closes the slow connections, and the campaign completes with every point.
//!
//! Then each kind of abuse alone, on a daemon as `gonio daemon` runs it ([`LoopbackDaemon`]: `api::run_daemon`,
//! its own server loop `api::serve_with`): slowloris clients trickling headers or bodies, idle connections, floods
//! of connections, oversized bodies and headers, garbage bytes, event streams that never end, and requests without
//! the token. In every case the daemon keeps answering other clients. These run on the real clock with limits
//! shortened to a second or two; each bounded wait is far longer than what the daemon needs, so a pass does not
//! depend on the machine's speed, and a daemon that blocked would show as the wait running out.

use std::net::SocketAddr;
use std::time::Duration;

use gonio_daemon::api::{self, ApiConfig};
use gonio_engine::rig::DEFAULT_DRY_RUN_TIME_SCALE;
use gonio_engine::store::CampaignState;
use gonio_instrument::InstrumentFile;
use gonio_soak::http_abuse::{
    Answer, HttpAbuseConfig, LoopbackDaemon, daemon_service, exchange, read_answer, run_http_abuse,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

#[test]
fn hostile_clients_cannot_stop_the_daemon_or_its_campaign() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = HttpAbuseConfig::quick(30, 4, dir.path().join("data"));
    let slow = cfg.header_tricklers + cfg.body_tricklers + cfg.idle;
    assert!(
        slow > cfg.api.max_connections,
        "more slow clients than the daemon admits"
    );
    let r = run_http_abuse(&cfg).expect("the soak runs");
    eprintln!(
        "probes {} (slowest {:.3} s), header {:?}, body {:?}, idle {:?}, oversized {:?}, campaign {:.1} s",
        r.probes(),
        r.latency_quantile_s(1.0),
        r.header_tricklers,
        r.body_tricklers,
        r.idle,
        r.oversized,
        r.campaign_wall_s
    );
    assert_eq!(r.violations(), Vec::<String>::new());
    assert_eq!(r.data_lost(), 0);
    assert!(r.probe_failures.is_empty(), "{:?}", r.probe_failures);
    assert!(r.probes() >= 2, "the status was asked more than once");
    // Every oversized body refused; the announced ones with 413 before any byte of the body was sent.
    let announced = &r.oversized[0];
    assert!(
        announced.sent > 0 && announced.refused_413 == announced.sent,
        "{announced:?}"
    );
    for o in &r.oversized {
        assert!(o.sent > 0 && o.refused_413 + o.closed == o.sent, "{o:?}");
    }
    // The daemon closed slow connections (evicted for newcomers, or past the header deadline).
    assert!(
        r.header_tricklers.ended_by_daemon() > 0,
        "{:?}",
        r.header_tricklers
    );
    assert!(r.idle.ended_by_daemon() > 0, "{:?}", r.idle);
    // A body within the limit is waited for, never refused at once: only evictions and the body deadline (408)
    // end a trickled body.
    assert!(r.body_tricklers.ended_by_daemon() > 0, "{:?}", r.body_tricklers);
    assert!(
        r.body_tricklers.answers.keys().all(|s| *s == 408),
        "{:?}",
        r.body_tricklers
    );
    assert_eq!(r.final_state, Some(CampaignState::Completed));
    assert_eq!(r.committed.rows, 30);
    assert!(r.committed.indices_in_order);
    assert_eq!(r.committed.points.valid, 30);
}

// ---------------------------------------------------------------- each kind of abuse alone

/// Longest wait for an answer the daemon should give at once (generous: a blocked daemon waits forever).
const ANSWER: Duration = Duration::from_secs(10);

/// The daemon on a loopback port with the API limits of `config`, its data in a directory of its own; stopped
/// when dropped.
struct Server {
    addr: SocketAddr,
    _daemon: LoopbackDaemon,
    _dir: tempfile::TempDir,
}

async fn server(config: ApiConfig) -> Server {
    let dir = tempfile::tempdir().expect("tempdir");
    let daemon = LoopbackDaemon::start(
        InstrumentFile::simulated(),
        dir.path(),
        DEFAULT_DRY_RUN_TIME_SCALE,
        &config,
    )
    .await
    .expect("the daemon starts");
    Server {
        addr: daemon.addr,
        _daemon: daemon,
        _dir: dir,
    }
}

/// Send a raw request on a new connection and read the answer, within [`ANSWER`].
async fn ask(addr: SocketAddr, raw: &[u8]) -> Answer {
    tokio::time::timeout(ANSWER, exchange(addr, raw))
        .await
        .unwrap_or_else(|_| panic!("no answer within {ANSWER:?} to {}", String::from_utf8_lossy(raw)))
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(raw)))
}

fn get(path: &str, token: Option<&str>) -> Vec<u8> {
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n{auth}Connection: close\r\n\r\n").into_bytes()
}

/// A normal client still gets the campaign list.
async fn assert_served(addr: SocketAddr) {
    let a = ask(addr, &get("/api/campaigns", None)).await;
    assert_eq!(a.status, 200, "{a:?}");
    assert_eq!(a.body, "[]");
}

/// Wait until the server closes `stream` (EOF or reset), within `within`; true if it did.
async fn closed_by_server(stream: &mut TcpStream, within: Duration) -> bool {
    let mut sink = [0u8; 1024];
    tokio::time::timeout(within, async {
        loop {
            match stream.read(&mut sink).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
        }
    })
    .await
    .is_ok()
}

/// Keep a connection busy the slowloris way: a request line, then one header byte every `period`.
fn trickle(mut stream: TcpStream, start: &'static [u8], period: Duration) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        if stream.write_all(start).await.is_err() {
            return;
        }
        loop {
            tokio::time::sleep(period).await;
            if stream.write_all(b"x").await.is_err() {
                return;
            }
        }
    })
}

fn config(f: impl FnOnce(&mut ApiConfig)) -> ApiConfig {
    let mut c = ApiConfig::default();
    f(&mut c);
    c
}

#[tokio::test]
async fn slowloris_headers_cannot_lock_out_other_clients() {
    // Long header deadline: the newcomer gets in because an idle trickler is closed, not because one timed out.
    let s = server(config(|c| {
        c.max_connections = 6;
        c.header_read_timeout = Duration::from_secs(120);
    }))
    .await;
    let mut tricklers = Vec::new();
    for _ in 0..6 {
        let stream = TcpStream::connect(s.addr).await.expect("connect");
        tricklers.push(trickle(
            stream,
            b"GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\nX-Slow: ",
            Duration::from_millis(200),
        ));
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    for _ in 0..5 {
        assert_served(s.addr).await;
    }
    // Each newcomer displaced one trickler: some of them were closed by the server.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let ended = tricklers.iter().filter(|t| t.is_finished()).count();
    assert!(ended >= 1, "no slow connection was closed");
    for t in tricklers {
        t.abort();
    }
}

#[tokio::test]
async fn headers_trickled_past_the_deadline_end_the_connection() {
    let s = server(config(|c| c.header_read_timeout = Duration::from_secs(1))).await;
    // Trickling, and silent: both are closed after the header deadline, and the server goes on serving.
    let mut slow = TcpStream::connect(s.addr).await.expect("connect");
    slow.write_all(b"GET /api/campaigns HTTP/1.1\r\nHost: t")
        .await
        .expect("send");
    let mut silent = TcpStream::connect(s.addr).await.expect("connect");
    let writer = tokio::spawn(async move {
        for _ in 0..100 {
            tokio::time::sleep(Duration::from_millis(100)).await;
            if slow.write_all(b"e").await.is_err() {
                return true;
            }
        }
        false
    });
    assert!(
        closed_by_server(&mut silent, ANSWER).await,
        "a silent connection stays open"
    );
    assert!(
        tokio::time::timeout(ANSWER, writer)
            .await
            .expect("in time")
            .expect("join"),
        "a trickling connection stays open"
    );
    assert_served(s.addr).await;
}

#[tokio::test]
async fn a_keep_alive_connection_idle_past_the_deadline_is_closed() {
    let s = server(config(|c| c.header_read_timeout = Duration::from_secs(1))).await;
    let mut stream = TcpStream::connect(s.addr).await.expect("connect");
    stream
        .write_all(b"GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\n\r\n")
        .await
        .expect("send");
    let a = tokio::time::timeout(ANSWER, read_answer(&mut stream))
        .await
        .expect("in time")
        .expect("answer");
    assert_eq!(a.status, 200);
    assert!(
        closed_by_server(&mut stream, ANSWER).await,
        "an idle keep-alive connection stays open"
    );
}

#[tokio::test]
async fn a_body_trickled_past_the_deadline_gets_408() {
    let s = server(config(|c| c.body_read_timeout = Duration::from_secs(1))).await;
    let stream = TcpStream::connect(s.addr).await.expect("connect");
    let (mut rd, mut wr) = stream.into_split();
    wr.write_all(
        b"POST /api/campaigns HTTP/1.1\r\nHost: localhost\r\nContent-Length: 1000\r\n\r\n[campaign]\n",
    )
    .await
    .expect("send");
    let trickler = tokio::spawn(async move {
        loop {
            tokio::time::sleep(Duration::from_millis(100)).await;
            if wr.write_all(b"#").await.is_err() {
                return;
            }
        }
    });
    let a = tokio::time::timeout(ANSWER, read_answer(&mut rd))
        .await
        .expect("an answer in time")
        .expect("an answer");
    trickler.abort();
    assert_eq!(a.status, 408, "{a:?}");
    assert!(a.body.contains("did not arrive within 1 s"), "{a:?}");
    assert_served(s.addr).await;
}

#[tokio::test]
async fn body_tricklers_cannot_lock_out_other_clients() {
    let s = server(config(|c| {
        c.max_connections = 4;
        c.body_read_timeout = Duration::from_secs(120);
    }))
    .await;
    let mut tricklers = Vec::new();
    for _ in 0..4 {
        let stream = TcpStream::connect(s.addr).await.expect("connect");
        tricklers.push(trickle(
            stream,
            b"POST /api/campaigns HTTP/1.1\r\nHost: localhost\r\nContent-Length: 100000\r\n\r\n[campaign]\n",
            Duration::from_millis(200),
        ));
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    for _ in 0..3 {
        assert_served(s.addr).await;
    }
    for t in tricklers {
        t.abort();
    }
}

#[tokio::test]
async fn a_flood_of_connections_leaves_the_daemon_serving() {
    let s = server(config(|c| c.max_connections = 8)).await;
    // Three times the limit, all idle.
    let mut idle = Vec::new();
    for _ in 0..24 {
        idle.push(TcpStream::connect(s.addr).await.expect("connect"));
    }
    assert_served(s.addr).await;
    // Most of the idle ones were closed to make room; the daemon holds no more than its limit.
    let mut closed = 0;
    for stream in &mut idle {
        if closed_by_server(stream, Duration::from_millis(50)).await {
            closed += 1;
        }
    }
    assert!(
        closed >= 24 - 8,
        "only {closed} of 24 idle connections were closed"
    );
    drop(idle);
    assert_served(s.addr).await;
}

#[tokio::test]
async fn oversized_bodies_and_headers_are_refused_without_reading_them() {
    let s = server(config(|c| c.body_limit_bytes = 4096)).await;
    // Announced: refused at once, the 10 MB are never sent.
    let a = ask(
        s.addr,
        b"POST /api/campaigns HTTP/1.1\r\nHost: localhost\r\nContent-Length: 10000000\r\nConnection: close\r\n\r\n",
    )
    .await;
    assert_eq!(a.status, 413, "{a:?}");
    assert!(a.body.contains("4096"), "{a:?}");
    // Chunked, past the limit.
    let mut raw = b"POST /api/campaigns HTTP/1.1\r\nHost: localhost\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
        .to_vec();
    for _ in 0..8 {
        raw.extend_from_slice(format!("{:x}\r\n{}\r\n", 1000, "#".repeat(1000)).as_bytes());
    }
    raw.extend_from_slice(b"0\r\n\r\n");
    let a = ask(s.addr, &raw).await;
    assert_eq!(a.status, 413, "{a:?}");
    // A header block past hyper's limit.
    let big = format!(
        "GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\nX-Big: {}\r\nConnection: close\r\n\r\n",
        "a".repeat(1 << 20)
    );
    let answer = tokio::time::timeout(ANSWER, async {
        let mut stream = TcpStream::connect(s.addr).await.expect("connect");
        // The server may close before taking it all: a failed write is a refusal too.
        let _ = stream.write_all(big.as_bytes()).await;
        read_answer(&mut stream).await
    })
    .await
    .expect("in time");
    if let Some(a) = answer {
        assert_eq!(a.status, 431, "{a:?}");
    }
    assert_served(s.addr).await;
}

#[tokio::test]
async fn garbage_on_the_wire_is_refused_and_the_daemon_goes_on() {
    // Input that is not yet a whole request (blank lines) waits for the header deadline, then closes.
    let s = server(config(|c| c.header_read_timeout = Duration::from_secs(1))).await;
    let junk: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    for raw in [
        junk.as_slice(),
        b"\r\n\r\n\r\n",
        b"GET / HTTP/9.9\r\n\r\n",
        b"GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\nContent-Length: -1\r\n\r\n",
        b"GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n",
        b"POST /api/campaigns HTTP/1.1\r\nHost: localhost\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",
    ] {
        let answer = tokio::time::timeout(ANSWER, async {
            let mut stream = TcpStream::connect(s.addr).await.expect("connect");
            let _ = stream.write_all(raw).await;
            read_answer(&mut stream).await
        })
        .await
        .unwrap_or_else(|_| {
            panic!(
                "the daemon neither answered nor closed: {}",
                String::from_utf8_lossy(raw)
            )
        });
        if let Some(a) = answer {
            assert!((400..500).contains(&a.status), "{a:?}");
        }
        assert_served(s.addr).await;
    }
}

#[tokio::test]
async fn event_streams_are_bounded() {
    let s = server(config(|c| c.max_event_streams = 2)).await;
    let open = |addr| async move {
        let mut stream = TcpStream::connect(addr).await.expect("connect");
        stream.write_all(&get("/api/events", None)).await.expect("send");
        let a = tokio::time::timeout(ANSWER, read_answer(&mut stream))
            .await
            .expect("in time")
            .expect("answer");
        (stream, a)
    };
    let (first, a) = open(s.addr).await;
    assert_eq!(a.status, 200, "{a:?}");
    assert!(a.head.contains("text/event-stream"), "{a:?}");
    let (_second, a) = open(s.addr).await;
    assert_eq!(a.status, 200, "{a:?}");
    let (_, a) = open(s.addr).await;
    assert_eq!(a.status, 503, "{a:?}");
    assert!(a.body.contains("event streams"), "{a:?}");
    // The rest of the API is unaffected, and a closed stream frees its place.
    assert_served(s.addr).await;
    drop(first);
    let mut reopened = None;
    for _ in 0..50 {
        let (stream, a) = open(s.addr).await;
        if a.status == 200 {
            reopened = Some(stream);
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(reopened.is_some(), "a closed event stream never freed its place");
}

#[tokio::test]
async fn with_a_token_every_api_request_needs_it_over_tcp() {
    let token = "9f86d081884c7d659a2feaa0c55ad015";
    let s = server(config(|c| c.token = Some(token.into()))).await;
    let requests: [(&str, &str); 9] = [
        ("GET", "/api/campaigns"),
        ("POST", "/api/campaigns"),
        ("GET", "/api/campaigns/1"),
        ("GET", "/api/campaigns/1/points.csv"),
        ("POST", "/api/campaigns/1/pause"),
        ("POST", "/api/campaigns/1/abort"),
        ("POST", "/api/estop"),
        ("GET", "/api/events"),
        ("GET", "/api/no-such-route"),
    ];
    let wrong_tokens = [
        None,
        Some(String::new()),
        Some(token[..31].to_string()),
        Some(format!("{token}0")),
        Some(token.to_ascii_uppercase()),
        Some(format!(" {token}")),
    ];
    for (method, path) in requests {
        for wrong in &wrong_tokens {
            let auth = wrong
                .as_ref()
                .map(|t| format!("Authorization: Bearer {t}\r\n"))
                .unwrap_or_default();
            let raw = format!(
                "{method} {path} HTTP/1.1\r\nHost: localhost\r\n{auth}Content-Length: 0\r\nConnection: close\r\n\r\n"
            );
            let a = ask(s.addr, raw.as_bytes()).await;
            assert_eq!(a.status, 401, "{method} {path} with {wrong:?}: {a:?}");
            assert!(
                a.head.to_ascii_lowercase().contains("www-authenticate: bearer"),
                "{a:?}"
            );
        }
        // Other schemes carrying the right token are not accepted either.
        let raw = format!(
            "{method} {path} HTTP/1.1\r\nHost: localhost\r\nAuthorization: Basic {token}\r\nContent-Length: 0\r\n\
             Connection: close\r\n\r\n"
        );
        assert_eq!(ask(s.addr, raw.as_bytes()).await.status, 401, "{method} {path}");
    }
    // The right token, with the scheme in any case (RFC 9110): through the token check.
    for scheme in ["Bearer", "bearer", "BEARER"] {
        let raw = format!(
            "GET /api/campaigns HTTP/1.1\r\nHost: localhost\r\nAuthorization: {scheme} {token}\r\nConnection: close\r\n\r\n"
        );
        let a = ask(s.addr, raw.as_bytes()).await;
        assert_eq!(a.status, 200, "{scheme}: {a:?}");
    }
    let a = ask(s.addr, &get("/api/events", Some(token))).await;
    assert_eq!(a.status, 200, "{a:?}");
}

#[test]
fn the_daemon_listens_on_loopback_unless_told_otherwise() {
    let default: SocketAddr = api::DEFAULT_LISTEN.parse().expect("an address");
    assert!(default.ip().is_loopback(), "{default}");
    assert!(api::check_listen(default, None).is_ok());
    for addr in [
        "0.0.0.0:7878",
        "[::]:7878",
        "192.0.2.1:7878",
        "[::ffff:127.0.0.1]:7878",
    ] {
        let addr: SocketAddr = addr.parse().expect("address");
        assert!(api::check_listen(addr, None).is_err(), "{addr} without a token");
        assert!(api::check_listen(addr, Some("t")).is_ok(), "{addr} with a token");
    }
}

#[tokio::test]
async fn run_daemon_refuses_a_public_listener_without_a_token() {
    let dir = tempfile::tempdir().expect("tempdir");
    let service = daemon_service(
        InstrumentFile::simulated(),
        dir.path(),
        DEFAULT_DRY_RUN_TIME_SCALE,
    )
    .await
    .expect("the daemon's service");
    // Bound on every interface: run_daemon returns at once instead of serving (the signal never comes).
    let listener = tokio::net::TcpListener::bind("0.0.0.0:0").await.expect("bind");
    let returned = tokio::time::timeout(
        ANSWER,
        api::run_daemon(listener, service, &ApiConfig::default(), std::future::pending()),
    )
    .await;
    assert!(returned.is_ok(), "run_daemon served on 0.0.0.0 without a token");
}

#[test]
fn the_token_comparison_is_plain_equality() {
    // The constant-time comparison must still be a correct comparison, for every length relation.
    let expected = b"s3cret-token";
    let mut cases: Vec<Vec<u8>> = vec![Vec::new(), expected.to_vec(), b"s3cret-token\0".to_vec()];
    for i in 0..expected.len() {
        let mut flipped = expected.to_vec();
        flipped[i] ^= 0x20;
        cases.push(flipped);
        cases.push(expected[..i].to_vec());
        let mut zero_padded = expected[..i].to_vec();
        zero_padded.resize(expected.len(), 0);
        cases.push(zero_padded);
    }
    for given in cases {
        assert_eq!(
            api::constant_time_eq(&given, expected),
            given == expected,
            "{:?}",
            String::from_utf8_lossy(&given)
        );
    }
}
