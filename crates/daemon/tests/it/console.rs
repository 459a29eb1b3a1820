//! The console through the HTTP API on the simulated instrument (tokio's paused clock): state, moves by axis
//! and by geometry, jog, homing, the wheel, readings (counted and streamed), refusals that move nothing, the
//! one-owner rule against a running and a paused campaign, and the emergency stop during a console move.

use crate::common;

use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::App;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_testkit::CampaignText;
use http_body_util::BodyExt;
use serde_json::{Value, json};
use tower::ServiceExt;

async fn app() -> App {
    common::app(tempfile::tempdir().expect("tempdir")).await
}

/// Every axis's `position_deg` from a state, by name.
fn positions(state: &Value) -> Vec<(String, f64)> {
    state["axes"]
        .as_array()
        .expect("axes")
        .iter()
        .map(|a| {
            (
                a["name"].as_str().expect("name").to_string(),
                a["position_deg"].as_f64().expect("position"),
            )
        })
        .collect()
}

fn position(axes: &[(String, f64)], name: &str) -> f64 {
    axes.iter()
        .find(|(n, _)| n == name)
        .map(|(_, p)| *p)
        .expect("axis")
}

/// The pose of a state's axes (physical degrees).
fn pose_of(axes: &[(String, f64)]) -> Pose {
    Pose::new(
        position(axes, "light"),
        position(axes, "detector"),
        position(axes, "tilt"),
        position(axes, "rotation"),
    )
}

impl App {
    async fn state_now(&self) -> Value {
        let (status, s) = self.json("GET", "/api/console/state", "").await;
        assert_eq!(status, StatusCode::OK, "{s}");
        s
    }

    async fn post(&self, path: &str, body: Value) -> (StatusCode, Value) {
        self.json("POST", path, &body.to_string()).await
    }
}

#[tokio::test(start_paused = true)]
async fn the_console_moves_homes_turns_the_wheel_and_reads_the_meter() {
    let app = app().await;
    let file = InstrumentFile::simulated();
    let tolerance = |name: &str| {
        file.instrument
            .axes
            .iter()
            .find(|a| a.name == name)
            .expect("axis")
            .tolerance_deg
    };

    // Before homing nothing moves, and the state says why.
    let s = app.state_now().await;
    assert_eq!(s["axes"].as_array().map(Vec::len), Some(4), "{s}");
    assert!(s["axes"][0]["referenced"] == false, "{s}");
    let (status, body) = app
        .post("/api/console/move", json!({"axes": {"detector": 40.0}}))
        .await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert!(
        body["error"]
            .as_str()
            .is_some_and(|m| m.contains("not referenced")),
        "{body}"
    );

    let (status, s) = app.post("/api/console/home", json!({})).await;
    assert_eq!(status, StatusCode::OK, "{s}");
    assert!(
        s["axes"]
            .as_array()
            .expect("axes")
            .iter()
            .all(|a| a["referenced"] == true),
        "{s}"
    );

    // Several axes in one safe move; the controllers read back the targets.
    let (status, moved) = app
        .post(
            "/api/console/move",
            json!({"axes": {"light": -30.0, "detector": 40.0, "tilt": 2.0}}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{moved}");
    let axes = positions(&app.state_now().await);
    for (name, want) in [
        ("light", -30.0),
        ("detector", 40.0),
        ("tilt", 2.0),
        ("rotation", 0.0),
    ] {
        let got = position(&axes, name);
        assert!(
            (got - want).abs() <= tolerance(name),
            "{name} at {got}, asked {want}"
        );
    }

    // Jog.
    let (status, body) = app
        .post("/api/console/jog", json!({"axis": "detector", "delta_deg": -2.5}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let got = position(&positions(&app.state_now().await), "detector");
    assert!((got - 37.5).abs() <= tolerance("detector"), "detector at {got}");

    // By geometry: the pose reached measures it (the kinematics read forward from the controllers' positions).
    let g = Geometry::new(45.0, 0.0, 20.0, 180.0);
    let (status, body) = app
        .post("/api/console/move", json!({"geometry": [45.0, 0.0, 20.0, 180.0]}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let reached =
        Kinematics::new(&file.instrument).forward_geometry(&pose_of(&positions(&app.state_now().await)));
    assert!(
        reached.max_direction_angle_deg(&g) < 0.01,
        "reached {reached:?} for {g:?}"
    );

    // Unsafe and malformed requests: refused with the rule, nothing moved.
    let before = positions(&app.state_now().await);
    for (body, status_wanted, says) in [
        (
            json!({"axes": {"detector": 150.0}}),
            StatusCode::CONFLICT,
            "axes.detector.max_deg",
        ),
        (
            json!({"axes": {"detector": position(&before, "light") + 3.0}}),
            StatusCode::CONFLICT,
            "safety.min_arm_separation_deg",
        ),
        (
            json!({"geometry": [88.0, 0.0, 30.0, 180.0]}),
            StatusCode::CONFLICT,
            "safety.grazing_limit_deg",
        ),
        (
            json!({"geometry": [30.0, 0.0, 31.0, 0.0]}),
            StatusCode::CONFLICT,
            "safety.retro_block_deg",
        ),
        (
            json!({"axes": {"elbow": 3.0}}),
            StatusCode::BAD_REQUEST,
            "no axis named",
        ),
        (
            json!({"axes": {"tilt": 1.0}, "geometry": [30.0, 0.0, 30.0, 180.0]}),
            StatusCode::BAD_REQUEST,
            "either",
        ),
        (json!({"speed": 3}), StatusCode::BAD_REQUEST, "expected JSON like"),
    ] {
        let (status, answer) = app.post("/api/console/move", body.clone()).await;
        assert_eq!(status, status_wanted, "{body}: {answer}");
        assert!(
            answer["error"].as_str().is_some_and(|m| m.contains(says)),
            "{body}: {answer}"
        );
    }
    assert_eq!(
        positions(&app.state_now().await),
        before,
        "a refused request moves nothing"
    );

    // The wheel, by band and by position.
    let wheel = file.instrument.filter_wheel.as_ref().expect("wheel");
    let band = wheel
        .positions
        .iter()
        .rev()
        .find(|f| f.band_nm.is_some())
        .expect("a band");
    let nm = band.band_nm.unwrap_or_default();
    let (status, body) = app
        .post("/api/console/filter", json!({"filter": format!("{nm}nm")}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["position"].as_u64(), Some(u64::from(band.position)));
    let s = app.state_now().await;
    assert_eq!(
        s["wheel"]["position"].as_u64(),
        Some(u64::from(band.position)),
        "{s}"
    );
    assert_eq!(s["wheel"]["band_nm"].as_f64(), Some(nm), "{s}");
    let (status, body) = app.post("/api/console/filter", json!({"filter": 1})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(app.state_now().await["wheel"]["position"].as_u64(), Some(1));
    let (status, body) = app.post("/api/console/filter", json!({"filter": "1234nm"})).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");

    // Readings: each with its time, pose, band and range; time goes forward.
    let (status, readings) = app.json("GET", "/api/console/read?count=3", "").await;
    assert_eq!(status, StatusCode::OK, "{readings}");
    let list = readings.as_array().expect("list");
    assert_eq!(list.len(), 3, "{readings}");
    let first_band = wheel
        .positions
        .iter()
        .find(|f| f.position == 1)
        .and_then(|f| f.band_nm);
    for r in list {
        assert!(r["power_w"].as_f64().is_some_and(f64::is_finite), "{r}");
        assert!(r["range_w"].as_f64().is_some_and(|w| w > 0.0), "{r}");
        assert_eq!(r["band_nm"].as_f64(), first_band, "{r}");
        assert_eq!(r["filter_position"].as_u64(), Some(1), "{r}");
        assert_eq!(r["axes"].as_array().map(Vec::len), Some(4), "{r}");
    }
    let times: Vec<f64> = list.iter().map(|r| r["t_s"].as_f64().expect("t")).collect();
    assert!(times.windows(2).all(|w| w[1] > w[0]), "{times:?}");
    let (status, _) = app.json("GET", "/api/console/read?count=0", "").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);

    // Home one axis.
    let (status, s) = app.post("/api/console/home", json!({"axis": "tilt"})).await;
    assert_eq!(status, StatusCode::OK, "{s}");
    let tilt = position(&positions(&s), "tilt");
    assert!(tilt.abs() <= tolerance("tilt"), "tilt homed to {tilt}");
}

#[tokio::test(start_paused = true)]
async fn the_reading_stream_sends_readings_until_the_client_leaves() {
    let app = app().await;
    let request = Request::builder()
        .uri("/api/console/readings?interval_ms=100")
        .body(Body::empty())
        .expect("request");
    let response = app.router.clone().oneshot(request).await.expect("infallible");
    assert_eq!(response.status(), StatusCode::OK);
    let mut body = response.into_body();
    let mut text = String::new();
    let mut readings = Vec::new();
    while readings.len() < 3 {
        let frame = tokio::time::timeout(Duration::from_secs(60), body.frame())
            .await
            .expect("a reading in time")
            .expect("stream open")
            .expect("frame");
        if let Ok(data) = frame.into_data() {
            text.push_str(&String::from_utf8_lossy(&data));
        }
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            if block.contains("event: reading") {
                let data = block
                    .lines()
                    .find_map(|l| l.strip_prefix("data: "))
                    .expect("data");
                readings.push(serde_json::from_str::<Value>(data).expect("json"));
            }
        }
    }
    let t: Vec<f64> = readings.iter().map(|r| r["t_s"].as_f64().expect("t")).collect();
    assert!(
        t.windows(2).all(|w| w[1] >= w[0] + 0.1 - 1e-9),
        "at the interval asked: {t:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn the_console_waits_for_a_running_campaign_and_works_while_it_is_paused() {
    let app = app().await;
    let text = CampaignText::in_plane("owned", 12)
        .calibration("method = \"absolute\"")
        .calibration("simulate_operator = true")
        .to_string();
    let (status, body) = app.json("POST", "/api/campaigns", &text).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let id = body["id"].as_i64().expect("id");
    loop {
        let (_, c) = app.json("GET", &format!("/api/campaigns/{id}"), "").await;
        if c["points_done"].as_u64() >= Some(2) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    for (path, body) in [
        ("/api/console/jog", json!({"axis": "tilt", "delta_deg": 1.0})),
        ("/api/console/home", json!({})),
        ("/api/console/filter", json!({"filter": 1})),
    ] {
        let (status, answer) = app.post(path, body).await;
        assert_eq!(status, StatusCode::CONFLICT, "{path}: {answer}");
        let m = answer["error"].as_str().unwrap_or_default();
        assert!(
            m.contains(&format!("campaign {id}")) && m.contains("owned"),
            "{path}: {m}"
        );
    }
    let (status, body) = app.json("GET", "/api/console/state", "").await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");

    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/pause"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    while app.state(id as u64).await != "paused" {
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The person moves the sample and the detector while the campaign is paused.
    let (status, body) = app
        .post("/api/console/jog", json!({"axis": "tilt", "delta_deg": 3.0}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = app
        .post("/api/console/jog", json!({"axis": "detector", "delta_deg": 12.0}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");

    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/resume"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    while app.state(id as u64).await != "completed" {
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    // Every point once, measured where it should be: the campaign moved back from where the console left it.
    let request = Request::builder()
        .uri(format!("/api/campaigns/{id}/points.csv"))
        .body(Body::empty())
        .expect("request");
    let response = app.router.clone().oneshot(request).await.expect("infallible");
    let csv = response.into_body().collect().await.expect("body").to_bytes();
    let csv = String::from_utf8_lossy(&csv).to_string();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no {name} in {header:?}"))
    };
    let (value, truth, index) = (col("brdf_sr"), col("brdf_true_sr"), col("index"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 12, "{csv}");
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row[index], i.to_string());
        let (v, t): (f64, f64) = (
            row[value].parse().expect("value"),
            row[truth].parse().expect("truth"),
        );
        assert!(
            (v - t).abs() <= 0.01 * t.abs(),
            "point {i}: {v} against the truth {t}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn an_emergency_stop_halts_a_console_move() {
    let app = app().await;
    let (status, body) = app.post("/api/console/home", json!({})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = app
        .post(
            "/api/console/move",
            json!({"axes": {"light": -90.0, "detector": 0.0}}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    // A long move of the detector arm, stopped a little after it started.
    let router = app.router.clone();
    let long_move = tokio::spawn(async move {
        let request = Request::builder()
            .method("POST")
            .uri("/api/console/move")
            .body(Body::from(json!({"axes": {"detector": 95.0}}).to_string()))
            .expect("request");
        let response = router.oneshot(request).await.expect("infallible");
        let status = response.status();
        let bytes = response.into_body().collect().await.expect("body").to_bytes();
        (status, serde_json::from_slice::<Value>(&bytes).expect("json"))
    });
    tokio::time::sleep(Duration::from_secs(2)).await;
    let (status, body) = app.json("POST", "/api/estop", "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, answer) = tokio::time::timeout(Duration::from_secs(60), long_move)
        .await
        .expect("the move ends at the stop")
        .expect("task");
    assert_eq!(status, StatusCode::INTERNAL_SERVER_ERROR, "{answer}");
    assert!(
        answer["error"]
            .as_str()
            .is_some_and(|m| m.contains("emergency stop")),
        "{answer}"
    );
    tokio::time::sleep(Duration::from_secs(5)).await;
    let s = app.state_now().await;
    let detector = s["axes"]
        .as_array()
        .and_then(|a| a.iter().find(|a| a["name"] == "detector"))
        .expect("detector")
        .clone();
    let at = detector["position_deg"].as_f64().expect("position");
    assert!(at > 0.5 && at < 90.0, "halted on the way, at {at} deg: {s}");
    assert_eq!(detector["moving"], false, "{s}");
    // The instrument is usable again after the stop.
    let (status, body) = app
        .post("/api/console/jog", json!({"axis": "detector", "delta_deg": 1.0}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
}
