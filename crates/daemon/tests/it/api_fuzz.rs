//! The HTTP API's routes fed random requests in process: random methods and paths built from the API's own
//! words, random headers (origin names, tokens, content types), and random or mutated campaign bodies. Never a
//! panic and never a 500; every refusal is a documented status with a JSON `{"error": "..."}` that says what
//! was wrong; a refused campaign names the file it came from.
//!
//! Cases: `GONIO_FUZZ_CASES` (default: a fast tier), e.g. `GONIO_FUZZ_CASES=20000 cargo test --release
//! -p gonio-daemon --test it api_fuzz` for a large run.

use crate::common;

use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use common::{App, Setup};
use gonio_daemon::api::{self, ApiConfig};
use gonio_testkit::CampaignText;
use http_body_util::BodyExt;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use tower::ServiceExt;

const TOKEN: &str = "fuzz-token-0123456789";

fn cases(default: u32) -> u32 {
    std::env::var("GONIO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The valid campaign the fuzzer mutates.
fn campaign() -> String {
    CampaignText::in_plane_grid("fuzz", "[30.0]", "{ from = 10.0, to = 60.0, step = 25.0 }")
        .calibration("simulate_operator = true")
        .material("preset = \"spectralon\"")
        .to_string()
}

#[derive(Debug, Clone)]
struct Req {
    method: &'static str,
    path: String,
    origin: Option<String>,
    token: Option<String>,
    content_type: Option<&'static str>,
    body: Vec<u8>,
}

fn path() -> impl Strategy<Value = String> {
    let segment = prop_oneof![
        4 => prop::sample::select(vec![
            "campaigns", "campaigns", "1", "2", "0", "-1", "99999999999999999999", "abc", "points.csv", "pause",
            "resume", "abort", "confirm", "estop", "events", "%00", "..", "", "%2e%2e", "api", "1.5", "0x1",
            "align", "calibrations", "report.json",
        ])
        .prop_map(str::to_string),
        1 => "[A-Za-z0-9._~-]{0,12}",
    ];
    let api = proptest::collection::vec(segment, 0..4).prop_map(|s| format!("/api/{}", s.join("/")));
    prop_oneof![8 => api, 1 => "/[A-Za-z0-9/._~-]{0,20}".prop_map(|p| p)]
}

fn body() -> impl Strategy<Value = Vec<u8>> {
    let mutated =
        (proptest::collection::vec((any::<prop::sample::Index>(), "[ -~\n]{0,8}"), 0..4)).prop_map(|edits| {
            let mut lines: Vec<String> = campaign().lines().map(str::to_string).collect();
            for (at, text) in edits {
                let i = at.index(lines.len());
                if text.is_empty() {
                    lines.remove(i);
                } else {
                    lines[i] = format!("{}{text}", lines[i]);
                }
            }
            lines.join("\n").into_bytes()
        });
    prop_oneof![
        3 => mutated,
        1 => proptest::collection::vec(any::<u8>(), 0..200),
        1 => "\\PC{0,100}".prop_map(String::into_bytes),
        1 => Just(Vec::new()),
    ]
}

fn request() -> impl Strategy<Value = Req> {
    // Half the requests submit a campaign (the route that reads a body), the rest go anywhere.
    let method_and_path = prop_oneof![
        1 => Just(("POST", "/api/campaigns".to_string())),
        1 => (
            prop::sample::select(vec!["GET", "POST", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS"]),
            path(),
        ),
    ];
    (
        method_and_path,
        prop::option::of(prop_oneof!["[ -~]{0,20}", "\\PC{0,300}"]),
        prop_oneof![
            4 => Just(Some(TOKEN.to_string())),
            1 => Just(None),
            1 => "[ -~]{0,24}".prop_map(Some),
        ],
        prop::option::of(prop::sample::select(vec![
            "application/toml",
            "text/plain",
            "application/json",
            "x/y",
        ])),
        body(),
    )
        .prop_map(|((method, path), origin, token, content_type, body)| Req {
            method,
            path,
            origin,
            token,
            content_type,
            body,
        })
}

/// The daemon without its queue: submitted campaigns stay queued, which is all the routes need.
async fn app() -> App {
    let setup = Setup {
        config: ApiConfig {
            token: Some(TOKEN.into()),
            body_limit_bytes: 4096,
            ..ApiConfig::default()
        },
        queue: false,
        ..Setup::default()
    };
    common::app_with(tempfile::tempdir().expect("tempdir"), setup).await
}

/// Statuses the API documents (202: an alignment accepted, `POST /api/align`).
const DOCUMENTED: &[u16] = &[200, 201, 202, 400, 401, 404, 405, 408, 409, 413, 503];

async fn check(router: &Router, r: &Req) -> Result<(), TestCaseError> {
    let mut b = Request::builder().method(r.method).uri(r.path.as_str());
    if let Some(t) = &r.token {
        b = b.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    if let Some(o) = &r.origin
        && axum::http::HeaderValue::from_str(o).is_ok()
    {
        b = b.header(api::ORIGIN_HEADER, o.as_str());
    }
    if let Some(ct) = r.content_type {
        b = b.header(header::CONTENT_TYPE, ct);
    }
    // Paths that are not URIs never reach the daemon (the HTTP parser refuses them).
    let Ok(req) = b.body(Body::from(r.body.clone())) else {
        return Ok(());
    };
    let response = tokio::time::timeout(Duration::from_secs(600), router.clone().oneshot(req))
        .await
        .map_err(|_| TestCaseError::fail("no answer: a hang"))?
        .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
    let status = response.status();
    if std::env::var("GONIO_FUZZ_DEBUG").is_ok() {
        eprintln!("{} {} -> {status}", r.method, r.path);
    }
    prop_assert!(
        DOCUMENTED.contains(&status.as_u16()),
        "{} {}: status {}",
        r.method,
        r.path,
        status
    );
    let streaming = response
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"text/event-stream"));
    if streaming {
        // The event stream never ends by itself: its head is what there is to check.
        prop_assert_eq!(status, StatusCode::OK);
        return Ok(());
    }
    let bytes = response
        .into_body()
        .collect()
        .await
        .map_err(|e| TestCaseError::fail(e.to_string()))?
        .to_bytes();
    if r.method == "HEAD" {
        return Ok(());
    }
    if status.as_u16() >= 400 {
        let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| {
            TestCaseError::fail(format!(
                "{status}: not JSON ({e}): {:?}",
                String::from_utf8_lossy(&bytes)
            ))
        })?;
        let message = v["error"].as_str().unwrap_or_default();
        prop_assert!(!message.is_empty(), "{}: {}", status, v);
        let submit = r.method == "POST" && r.path == "/api/campaigns" && r.token.as_deref() == Some(TOKEN);
        if submit && status == StatusCode::BAD_REQUEST && !message.contains("UTF-8") {
            // The refusal names the file: the client's name for it, or "submitted campaign".
            let named = r
                .origin
                .as_deref()
                .filter(|o| !o.is_empty() && o.len() <= 256 && !o.chars().any(char::is_control))
                .filter(|o| {
                    axum::http::HeaderValue::from_str(o).is_ok() && std::str::from_utf8(o.as_bytes()).is_ok()
                })
                .unwrap_or("submitted campaign");
            prop_assert!(
                message.contains(named) || message.contains("submitted campaign"),
                "refusal without the file's name {:?}: {}",
                named,
                message
            );
        }
    } else if status == StatusCode::CREATED {
        let v: serde_json::Value =
            serde_json::from_slice(&bytes).map_err(|e| TestCaseError::fail(format!("201 not JSON: {e}")))?;
        prop_assert!(v["id"].as_i64().is_some(), "{}", v);
    }
    Ok(())
}

#[test]
fn random_requests_get_documented_answers_and_never_a_500() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("runtime");
    let app = rt.block_on(app());
    let mut runner = TestRunner::new(Config {
        cases: cases(1500),
        failure_persistence: None,
        ..Config::default()
    });
    let result = runner.run(&request(), |r| rt.block_on(check(&app.router, &r)));
    drop(app);
    if let Err(e) = result {
        panic!("{e}");
    }
}
