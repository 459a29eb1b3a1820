//! The HTTP/JSON control API in process: the router on a real service with the campaign engine on the
//! simulated instrument, on tokio's paused clock (simulated time passes only while every task waits, so runs
//! take no wall time and no test depends on the machine's speed).

use crate::common;

use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use common::{App, Setup};
use gonio_daemon::api::ApiConfig;
use gonio_testkit::CampaignText;
use http_body_util::BodyExt;
use serde_json::Value;
use tower::ServiceExt;

/// A small dry-run campaign: `points` outgoing angles at one band, one incidence.
fn campaign(id: &str, points: usize, simulate_operator: bool) -> String {
    CampaignText::in_plane(id, points)
        .calibration("method = \"absolute\"")
        .calibration(&format!("simulate_operator = {simulate_operator}"))
        .to_string()
}

/// A daemon running its queue.
async fn app_with(config: ApiConfig) -> App {
    let data = tempfile::tempdir().expect("tempdir");
    common::app_with(
        data,
        Setup {
            config,
            ..Setup::default()
        },
    )
    .await
}

async fn app() -> App {
    app_with(ApiConfig::default()).await
}

fn request(method: &str, path: &str, body: impl Into<Body>, token: Option<&str>) -> Request<Body> {
    let mut r = Request::builder().method(method).uri(path);
    if let Some(t) = token {
        r = r.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    r.body(body.into()).expect("request")
}

impl App {
    async fn send(&self, req: Request<Body>) -> (StatusCode, Vec<u8>) {
        let response = tokio::time::timeout(Duration::from_secs(600), self.router.clone().oneshot(req))
            .await
            .expect("answer in time")
            .expect("infallible");
        let status = response.status();
        let body = response
            .into_body()
            .collect()
            .await
            .expect("body")
            .to_bytes()
            .to_vec();
        (status, body)
    }

    async fn campaign(&self, id: i64) -> Value {
        let (status, body) = self.json("GET", &format!("/api/campaigns/{id}"), "").await;
        assert_eq!(status, StatusCode::OK, "{body}");
        body
    }

    /// Poll (advancing simulated time) until the campaign satisfies `done`; bounded.
    async fn wait_until(&self, id: i64, what: &str, done: impl Fn(&Value) -> bool) -> Value {
        for _ in 0..20_000 {
            let c = self.campaign(id).await;
            if done(&c) {
                return c;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        panic!("campaign {id} never became {what}: {}", self.campaign(id).await);
    }

    async fn wait_state(&self, id: i64, state: &str) -> Value {
        self.wait_until(id, state, |c| c["state"] == state).await
    }
}

#[tokio::test(start_paused = true)]
async fn submit_watch_events_complete_and_download_points_csv() {
    let app = app().await;
    let events = app
        .router
        .clone()
        .oneshot(request("GET", "/api/events", Body::empty(), None))
        .await
        .expect("sse");
    assert_eq!(events.status(), StatusCode::OK);
    assert!(
        events.headers()[header::CONTENT_TYPE]
            .to_str()
            .expect("ct")
            .starts_with("text/event-stream")
    );
    let id = app.submit(&campaign("first", 5, true)).await;
    let c = app.wait_state(id, "completed").await;
    assert_eq!(
        (c["points_done"].as_u64(), c["total_points"].as_u64()),
        (Some(5), Some(5)),
        "{c}"
    );

    // The event stream carried the states, every point and progress, as JSON with a type.
    let mut body = events.into_body();
    let mut text = String::new();
    let (mut points, mut progress, mut states) = (0, 0, Vec::new());
    while !states.iter().any(|s| s == "completed") {
        let frame = tokio::time::timeout(Duration::from_secs(5), body.frame())
            .await
            .expect("an event in time")
            .expect("stream open")
            .expect("frame");
        text.push_str(&String::from_utf8_lossy(&frame.into_data().unwrap_or_default()));
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            let Some(data) = block.lines().find_map(|l| l.strip_prefix("data: ")) else {
                continue;
            };
            let v: Value = serde_json::from_str(data).expect("event JSON");
            assert_eq!(v["campaign"], id, "{v}");
            let kind = v["type"].as_str().expect("type");
            assert!(block.contains(&format!("event: {kind}\n")), "{block}");
            match kind {
                "point" => points += 1,
                "progress" => progress += 1,
                "state" => states.push(v["state"].as_str().expect("state").to_string()),
                _ => {}
            }
        }
    }
    assert_eq!(points, 5);
    assert!(progress >= 5, "{progress}");
    assert_eq!(states.first().map(String::as_str), Some("queued"));
    assert!(states.iter().any(|s| s == "running"), "{states:?}");

    let (status, csv) = app
        .send(request(
            "GET",
            &format!("/api/campaigns/{id}/points.csv"),
            Body::empty(),
            None,
        ))
        .await;
    assert_eq!(status, StatusCode::OK);
    let csv = String::from_utf8(csv).expect("utf-8");
    let mut lines = csv.lines();
    let header = lines.next().expect("header");
    assert!(
        header.starts_with(&gonio_results::points::FIXED_COLUMNS.join(",")),
        "{header}"
    );
    assert!(
        header.ends_with(",brdf_true_sr,brdf_true_aperture_sr"),
        "dry-run columns: {header}"
    );
    let columns = header.split(',').count();
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 5);
    assert!(rows.iter().all(|r| r.split(',').count() == columns));

    // The measurement report, as `gonio report` writes it: every section of a dry-run, nothing fetched.
    let (status, page) = app
        .send(request(
            "GET",
            &format!("/api/campaigns/{id}/report.html"),
            Body::empty(),
            None,
        ))
        .await;
    assert_eq!(status, StatusCode::OK);
    let page = String::from_utf8(page).expect("utf-8");
    assert!(
        page.starts_with("<!DOCTYPE html>"),
        "{}",
        &page[..page.len().min(200)]
    );
    for section in gonio_results::report::SECTIONS {
        assert!(
            page.contains(&format!("<section id=\"{section}\">")),
            "no section {section}"
        );
    }
    assert!(page.contains("BRDF measurement report: first"));
    assert!(page.contains("5 of 5 done"), "the store's counts");
    assert!(!page.contains("<script") && !page.contains("src="));

    let (status, list) = app.json("GET", "/api/campaigns", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(list.as_array().map(Vec::len), Some(1));
    app.trigger.trigger();
}

#[tokio::test(start_paused = true)]
async fn a_bad_campaign_file_is_refused_with_a_message_naming_line_and_key() {
    let app = app().await;
    let bad = campaign("bad", 3, true).replace("averaging = 2", "averaging = 2\nspeed = 3");
    let (status, body) = app.json("POST", "/api/campaigns", &bad).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let message = body["error"].as_str().expect("error message");
    assert!(message.contains("speed"), "names the key: {message}");
    assert!(
        message.contains("line") || message.contains(":2"),
        "names the line: {message}"
    );
    let (status, body) = app.json("POST", "/api/campaigns", "[campaign\nid=").await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let (_, list) = app.json("GET", "/api/campaigns", "").await;
    assert_eq!(list, Value::Array(vec![]));
}

#[tokio::test(start_paused = true)]
async fn pause_at_a_safe_point_then_resume_completes() {
    let app = app().await;
    let id = app.submit(&campaign("pausable", 12, true)).await;
    app.wait_until(id, "running with points", |c| {
        c["points_done"].as_u64() >= Some(2)
    })
    .await;
    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/pause"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let paused = app.wait_state(id, "paused").await;
    let done = paused["points_done"].as_u64().expect("done");
    assert!((2..12).contains(&done), "{paused}");
    tokio::time::sleep(Duration::from_secs(120)).await;
    assert_eq!(
        app.campaign(id).await["points_done"].as_u64(),
        Some(done),
        "a paused campaign does not move"
    );
    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/pause"), "").await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert!(
        body["error"].as_str().is_some_and(|m| m.contains("paused")),
        "{body}"
    );
    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/resume"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let c = app.wait_state(id, "completed").await;
    assert_eq!(c["points_done"].as_u64(), Some(12));
    let (_, csv) = app
        .send(request(
            "GET",
            &format!("/api/campaigns/{id}/points.csv"),
            Body::empty(),
            None,
        ))
        .await;
    let indices: Vec<String> = String::from_utf8_lossy(&csv)
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next().map(str::to_string))
        .collect();
    assert_eq!(
        indices,
        (0..12).map(|i| i.to_string()).collect::<Vec<_>>(),
        "each point once, in order"
    );
}

#[tokio::test(start_paused = true)]
async fn abort_ends_the_campaign_and_further_requests_conflict() {
    let app = app().await;
    let id = app.submit(&campaign("abortable", 12, true)).await;
    app.wait_until(id, "running with points", |c| {
        c["points_done"].as_u64() >= Some(1)
    })
    .await;
    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/abort"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let c = app.wait_state(id, "aborted").await;
    assert!(c["points_done"].as_u64() < Some(12), "{c}");
    for action in ["pause", "resume", "abort", "confirm"] {
        let (status, body) = app
            .json("POST", &format!("/api/campaigns/{id}/{action}"), "")
            .await;
        assert_eq!(status, StatusCode::CONFLICT, "{action}: {body}");
        assert!(
            body["error"].as_str().is_some_and(|m| m.contains("aborted")),
            "{body}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn estop_halts_the_campaign_and_holds_the_queue_until_resumed() {
    let app = app().await;
    let a = app.submit(&campaign("first", 12, true)).await;
    let b = app.submit(&campaign("second", 3, true)).await;
    app.wait_until(a, "running with points", |c| c["points_done"].as_u64() >= Some(1))
        .await;
    let (status, body) = app.json("POST", "/api/estop", "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let stopped = app.wait_state(a, "paused").await;
    assert!(
        stopped["last_error"]
            .as_str()
            .is_some_and(|m| m.contains("emergency stop")),
        "{stopped}"
    );
    assert_eq!(app.campaign(b).await["state"], "paused");
    tokio::time::sleep(Duration::from_secs(120)).await;
    assert_eq!(
        app.campaign(b).await["state"],
        "paused",
        "nothing starts after an emergency stop"
    );
    let (status, _) = app.json("POST", &format!("/api/campaigns/{a}/resume"), "").await;
    assert_eq!(status, StatusCode::OK);
    let c = app.wait_state(a, "completed").await;
    assert_eq!(c["points_done"].as_u64(), Some(12));
}

#[tokio::test(start_paused = true)]
async fn a_campaign_waiting_for_the_operator_continues_after_confirm() {
    let app = app().await;
    let id = app.submit(&campaign("manual", 4, false)).await;
    let (status, body) = app
        .json("POST", &format!("/api/campaigns/{id}/confirm"), "")
        .await;
    assert!(
        status == StatusCode::CONFLICT || body["state"] == "waiting-operator",
        "{status} {body}"
    );
    let waiting = app.wait_state(id, "waiting-operator").await;
    assert!(
        waiting["operator_message"]
            .as_str()
            .is_some_and(|m| !m.is_empty()),
        "{waiting}"
    );
    // Nothing happens until the operator confirms (every confirmation-needing step is confirmed in turn).
    tokio::time::sleep(Duration::from_secs(600)).await;
    assert_eq!(app.campaign(id).await["state"], "waiting-operator");
    for _ in 0..50 {
        let c = app.campaign(id).await;
        match c["state"].as_str() {
            Some("completed") => break,
            Some("waiting-operator") => {
                let (status, body) = app
                    .json("POST", &format!("/api/campaigns/{id}/confirm"), "")
                    .await;
                assert_eq!(status, StatusCode::OK, "{body}");
            }
            _ => {}
        }
        tokio::time::sleep(Duration::from_secs(5)).await;
    }
    let c = app.wait_state(id, "completed").await;
    assert_eq!(c["points_done"].as_u64(), Some(4));
}

#[tokio::test(start_paused = true)]
async fn campaigns_queue_and_run_one_after_the_other() {
    let app = app().await;
    let mut events = app
        .router
        .clone()
        .oneshot(request("GET", "/api/events", Body::empty(), None))
        .await
        .expect("sse")
        .into_body();
    let a = app.submit(&campaign("first", 4, true)).await;
    let b = app.submit(&campaign("second", 3, true)).await;
    assert_eq!(app.campaign(b).await["state"], "queued");
    app.wait_state(b, "completed").await;
    // From the event stream: b starts only after a completed, and no point of a comes after b started.
    let mut text = String::new();
    let mut order = Vec::new();
    while !order.contains(&(b, "completed".to_string())) {
        let frame = tokio::time::timeout(Duration::from_secs(5), events.frame())
            .await
            .expect("event")
            .expect("open")
            .expect("frame");
        text.push_str(&String::from_utf8_lossy(&frame.into_data().unwrap_or_default()));
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            let Some(data) = block.lines().find_map(|l| l.strip_prefix("data: ")) else {
                continue;
            };
            let v: Value = serde_json::from_str(data).expect("json");
            let campaign = v["campaign"].as_i64().expect("campaign");
            let label = match v["type"].as_str() {
                Some("state") => v["state"].as_str().expect("state").to_string(),
                Some(other) => other.to_string(),
                None => continue,
            };
            order.push((campaign, label));
        }
    }
    let a_done = order
        .iter()
        .position(|e| *e == (a, "completed".to_string()))
        .expect("a completed");
    let b_running = order
        .iter()
        .position(|e| *e == (b, "running".to_string()))
        .expect("b ran");
    assert!(a_done < b_running, "{order:?}");
    assert!(order[b_running..].iter().all(|(c, _)| *c == b), "{order:?}");
}

#[tokio::test(start_paused = true)]
async fn unknown_ids_are_404_and_wrong_states_409() {
    let app = app().await;
    for (method, path) in [
        ("GET", "/api/campaigns/42"),
        ("GET", "/api/campaigns/42/points.csv"),
        ("GET", "/api/campaigns/42/report.html"),
        ("POST", "/api/campaigns/42/pause"),
        ("GET", "/api/campaigns/abc"),
        ("GET", "/api/nothing"),
    ] {
        let (status, body) = app.json(method, path, "").await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{method} {path}: {body}");
        assert!(body["error"].is_string(), "{body}");
    }
    let a = app.submit(&campaign("first", 30, true)).await;
    let b = app.submit(&campaign("second", 3, true)).await;
    // b is queued: nothing to confirm, nothing to resume.
    for action in ["confirm", "resume"] {
        let (status, body) = app
            .json("POST", &format!("/api/campaigns/{b}/{action}"), "")
            .await;
        assert_eq!(status, StatusCode::CONFLICT, "{action}: {body}");
        assert!(
            body["error"].as_str().is_some_and(|m| m.contains("queued")),
            "{body}"
        );
    }
    let (status, _) = app.json("POST", &format!("/api/campaigns/{a}/abort"), "").await;
    assert_eq!(status, StatusCode::OK);
    let (status, _) = app.json("POST", &format!("/api/campaigns/{b}/abort"), "").await;
    assert_eq!(status, StatusCode::OK);
}

#[tokio::test(start_paused = true)]
async fn with_a_token_every_request_must_carry_it() {
    let app = app_with(ApiConfig {
        token: Some("s3cret-token".into()),
        ..ApiConfig::default()
    })
    .await;
    for token in [None, Some("wrong"), Some("s3cret-token "), Some("")] {
        let (status, body) = app
            .send(request("GET", "/api/campaigns", Body::empty(), token))
            .await;
        assert_eq!(status, StatusCode::UNAUTHORIZED, "{token:?}");
        assert!(String::from_utf8_lossy(&body).contains("token"), "{token:?}");
        let (status, _) = app
            .send(request("POST", "/api/estop", Body::empty(), token))
            .await;
        assert_eq!(status, StatusCode::UNAUTHORIZED, "estop with {token:?}");
        let (status, _) = app
            .send(request("GET", "/api/events", Body::empty(), token))
            .await;
        assert_eq!(status, StatusCode::UNAUTHORIZED, "events with {token:?}");
    }
    let (status, body) = app
        .send(request(
            "GET",
            "/api/campaigns",
            Body::empty(),
            Some("s3cret-token"),
        ))
        .await;
    assert_eq!(status, StatusCode::OK, "{}", String::from_utf8_lossy(&body));
    let (status, _) = app
        .send(request(
            "POST",
            "/api/campaigns",
            campaign("tok", 2, true),
            Some("s3cret-token"),
        ))
        .await;
    assert_eq!(status, StatusCode::CREATED);
}

#[tokio::test(start_paused = true)]
async fn oversized_bodies_are_refused_with_413() {
    let limit = 4096;
    let app = app_with(ApiConfig {
        body_limit_bytes: limit,
        ..ApiConfig::default()
    })
    .await;
    let big = format!("{}\n# {}\n", campaign("big", 2, true), "x".repeat(limit));
    // Announced length.
    let (status, body) = app
        .send(request("POST", "/api/campaigns", big.clone(), None))
        .await;
    assert_eq!(
        status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        String::from_utf8_lossy(&body)
    );
    assert!(String::from_utf8_lossy(&body).contains("4096"));
    // Streamed without a length.
    let chunks: Vec<Result<Vec<u8>, std::io::Error>> =
        big.as_bytes().chunks(1000).map(|c| Ok(c.to_vec())).collect();
    let streamed = Body::from_stream(futures_util::stream::iter(chunks));
    let (status, _) = app.send(request("POST", "/api/campaigns", streamed, None)).await;
    assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE);
    // Just under the limit is read (and validated).
    let (status, _) = app
        .send(request(
            "POST",
            "/api/campaigns",
            campaign("small", 2, true),
            None,
        ))
        .await;
    assert_eq!(status, StatusCode::CREATED);
}

#[tokio::test(start_paused = true)]
async fn shutdown_ends_the_queue_and_the_event_streams() {
    let app = app().await;
    let events = app
        .router
        .clone()
        .oneshot(request("GET", "/api/events", Body::empty(), None))
        .await
        .expect("sse");
    let mut body = events.into_body();
    app.trigger.trigger();
    // The stream ends (rather than keeping connections open forever) and the queue loop returns.
    let end = tokio::time::timeout(Duration::from_secs(30), async {
        loop {
            match body.frame().await {
                None => break,
                Some(Err(e)) => panic!("stream error {e}"),
                Some(Ok(_)) => {}
            }
        }
    })
    .await;
    assert!(end.is_ok(), "event stream did not end at shutdown");
    let mut app = app;
    let queue = app.queue.take().expect("queue task");
    tokio::time::timeout(Duration::from_secs(30), queue)
        .await
        .expect("queue ends")
        .expect("join");
}
