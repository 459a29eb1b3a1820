//! A web page in the operator's browser cannot drive the daemon (issue #8, security): over real TCP connections
//! to the daemon's own server loop on 127.0.0.1, without a token (the loopback default), requests are written
//! byte for byte as a browser sends them.
//! - DNS rebinding: a page at `http://rebound.example:PORT` (its name resolving to 127.0.0.1) names that host in
//!   `Host`: refused with 421 before any route runs, GET and POST alike, status page included.
//! - Cross-site requests: a page elsewhere makes the browser POST with its own `Origin`: refused with 403, and
//!   nothing changes (no campaign is stored, no emergency stop is raised).
//! - The status page's own requests (`Origin` = its own origin, `Host` = the address it was loaded from), and
//!   the CLI's and curl's (no `Origin`), are served.

use crate::common;

use std::net::SocketAddr;
use std::sync::LazyLock;
use std::time::Duration;

use common::tcp::{Server, server};
use gonio_daemon::api::ApiConfig;
use gonio_testkit::CampaignText;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const ANSWER: Duration = Duration::from_secs(20);

static CAMPAIGN: LazyLock<String> = LazyLock::new(|| {
    CampaignText::in_plane_grid("origin", "[30.0]", "{ from = 10.0, to = 60.0, step = 25.0 }")
        .calibration("simulate_operator = true")
        .material("preset = \"spectralon\"")
        .to_string()
});

/// Status and body of the answer to one raw request (`Connection: close`: the body runs to EOF).
async fn exchange(addr: SocketAddr, raw: String) -> (u16, String) {
    tokio::time::timeout(ANSWER, async {
        let mut stream = TcpStream::connect(addr).await.expect("connect");
        stream.write_all(raw.as_bytes()).await.expect("send");
        let mut buf = Vec::new();
        let _ = stream.read_to_end(&mut buf).await;
        let text = String::from_utf8_lossy(&buf).into_owned();
        let status = text
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no status line in {text:?}"));
        let body = text
            .split_once("\r\n\r\n")
            .map(|(_, b)| b.to_string())
            .unwrap_or_default();
        (status, body)
    })
    .await
    .unwrap_or_else(|_| panic!("no answer within {ANSWER:?} to {raw}"))
}

/// A request as a browser (or curl) writes it; `origin` only when given.
fn request(method: &str, path: &str, host: &str, origin: Option<&str>, body: &str) -> String {
    let origin = origin.map(|o| format!("Origin: {o}\r\n")).unwrap_or_default();
    format!(
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\n{origin}Content-Type: application/toml\r\nContent-Length: {}\r\n\
         Connection: close\r\n\r\n{body}",
        body.len()
    )
}

async fn campaigns(s: &Server) -> serde_json::Value {
    let host = s.addr.to_string();
    let (status, body) = exchange(s.addr, request("GET", "/api/campaigns", &host, None, "")).await;
    assert_eq!(status, 200, "{body}");
    serde_json::from_str(&body).expect("JSON")
}

#[tokio::test]
async fn a_rebound_host_name_is_refused_on_every_route() {
    let s = server(ApiConfig::default()).await;
    let port = s.addr.port();
    let rebound = format!("rebound.example:{port}");
    let origin = format!("http://{rebound}");
    for (method, path, origin, body) in [
        ("GET", "/api/campaigns", None, ""),
        ("GET", "/", None, ""),
        ("GET", "/api/events", None, ""),
        // The page's own origin under the rebound name: same-origin for the browser, foreign for the daemon.
        ("POST", "/api/campaigns", Some(origin.as_str()), CAMPAIGN.as_str()),
        ("POST", "/api/estop", Some(origin.as_str()), ""),
    ] {
        let (status, body) = exchange(s.addr, request(method, path, &rebound, origin, body)).await;
        assert_eq!(status, 421, "{method} {path}: {body}");
        let error = serde_json::from_str::<serde_json::Value>(&body).expect("JSON error")["error"]
            .as_str()
            .expect("message")
            .to_string();
        assert!(
            error.contains("rebound.example")
                && error.contains("DNS rebinding")
                && error.contains("127.0.0.1")
                && error.contains("--allow-host"),
            "{error}"
        );
    }
    // Names that only look like ours.
    for host in [
        format!("localhost.rebound.example:{port}"),
        format!("127.0.0.1.nip.io:{port}"),
    ] {
        let (status, _) = exchange(s.addr, request("GET", "/api/campaigns", &host, None, "")).await;
        assert_eq!(status, 421, "{host}");
    }
    assert_eq!(
        campaigns(&s).await,
        serde_json::json!([]),
        "nothing was submitted"
    );
}

#[tokio::test]
async fn a_post_from_another_origin_is_refused_and_changes_nothing() {
    let s = server(ApiConfig::default()).await;
    let host = s.addr.to_string();
    let port = s.addr.port();
    for origin in [
        "http://evil.example".to_string(),
        "https://evil.example".to_string(),
        "null".to_string(),
        // Another server on this machine (another port), and HTTPS at our address: other origins.
        format!("http://127.0.0.1:{}", port.wrapping_add(1)),
        format!("https://127.0.0.1:{port}"),
        format!("http://localhost:{port}"),
    ] {
        for (path, body) in [
            ("/api/campaigns", CAMPAIGN.as_str()),
            ("/api/estop", ""),
            ("/api/campaigns/1/abort", ""),
        ] {
            let (status, answer) = exchange(s.addr, request("POST", path, &host, Some(&origin), body)).await;
            assert_eq!(status, 403, "POST {path} from {origin}: {answer}");
            assert!(
                answer.contains("another") || answer.contains("not from this daemon's own page"),
                "{answer}"
            );
        }
        // Reading is not refused for the origin alone (the browser keeps the answer from a foreign page).
        let (status, _) = exchange(s.addr, request("GET", "/api/campaigns", &host, Some(&origin), "")).await;
        assert_eq!(status, 200, "GET from {origin}");
    }
    assert_eq!(
        campaigns(&s).await,
        serde_json::json!([]),
        "no campaign was stored"
    );
}

#[tokio::test]
async fn the_status_page_and_clients_without_origin_are_served() {
    let s = server(ApiConfig::default()).await;
    let host = s.addr.to_string();
    let own = format!("http://{host}");
    // The status page, loaded from http://127.0.0.1:PORT/, posting to its own origin.
    let (status, body) = exchange(s.addr, request("GET", "/", &host, None, "")).await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = exchange(
        s.addr,
        request("POST", "/api/campaigns", &host, Some(&own), CAMPAIGN.as_str()),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    // Origin compares case-insensitively on the scheme and host.
    let loud = format!("HTTP://{host}");
    let (status, body) = exchange(
        s.addr,
        request("POST", "/api/campaigns/1/pause", &host, Some(&loud), ""),
    )
    .await;
    assert_ne!(status, 403, "{body}");
    assert_ne!(status, 421, "{body}");
    // The page loaded as http://localhost:PORT/ is its own origin too.
    let local = format!("localhost:{}", s.addr.port());
    let (status, body) = exchange(
        s.addr,
        request(
            "POST",
            "/api/campaigns",
            &local,
            Some(&format!("http://{local}")),
            CAMPAIGN.as_str(),
        ),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    // curl and the CLI: no Origin.
    let (status, body) = exchange(
        s.addr,
        request("POST", "/api/campaigns", &host, None, CAMPAIGN.as_str()),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    let (status, body) = exchange(s.addr, request("GET", "/api/campaigns/3", "localhost", None, "")).await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(campaigns(&s).await.as_array().map(Vec::len), Some(3));
}

#[tokio::test]
async fn a_configured_host_name_is_served() {
    let s = server(ApiConfig {
        allowed_hosts: vec!["lab-pc.example".into()],
        ..ApiConfig::default()
    })
    .await;
    let host = format!("lab-pc.example:{}", s.addr.port());
    let (status, body) = exchange(
        s.addr,
        request(
            "POST",
            "/api/campaigns",
            &host,
            Some(&format!("http://{host}")),
            CAMPAIGN.as_str(),
        ),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    let (status, _) = exchange(
        s.addr,
        request("GET", "/api/campaigns", "other.example", None, ""),
    )
    .await;
    assert_eq!(status, 421);
}
