//! The daemon's calibrations: the alignment as an API action on the realistic simulated instrument (a dated
//! calibration in the store, of the same shape as `gonio align`'s, given to every campaign submitted after it),
//! refused while a campaign owns the instrument; the store's latest calibration of this instrument file applied
//! at start-up and never one made for another file; `--calibration` files kept in the store once. Tokio's paused
//! clock: the alignment's minutes of instrument time take no wall time.

use crate::common;

use std::collections::BTreeSet;
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::{App, Setup};
use gonio_brdf::material::Material;
use gonio_engine::align::file::{CalibrationFile, Header, Value as CalValue};
use gonio_engine::align::{OperatorStep, Placement, run_alignment};
use gonio_engine::control::Control;
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignId, NewInstrumentCalibration, Store};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_results::provenance_summary::{iso8601_utc, sha256_hex};
use gonio_scheduler::timing::TimeModel;
use gonio_testkit::CampaignText;
use http_body_util::BodyExt;
use serde_json::Value;
use tower::ServiceExt;

const REALISTIC: &str = include_str!("../../../../config/instruments/realistic.toml");

fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64()
}

async fn app_on(instrument_toml: &str, data: tempfile::TempDir) -> App {
    common::app_with(
        data,
        Setup {
            instrument_toml: Some(instrument_toml.to_string()),
            ..Setup::default()
        },
    )
    .await
}

fn small_campaign(id: &str, points: usize) -> String {
    CampaignText::in_plane(id, points)
        .calibration("method = \"absolute\"")
        .calibration("simulate_operator = true")
        .to_string()
}

impl App {
    /// A route's body as text, with its status.
    async fn text(&self, path: &str) -> (StatusCode, String) {
        let request = Request::builder().uri(path).body(Body::empty()).expect("request");
        let response = self.router.clone().oneshot(request).await.expect("infallible");
        let status = response.status();
        let bytes = response.into_body().collect().await.expect("body").to_bytes();
        (status, String::from_utf8_lossy(&bytes).into_owned())
    }

    /// Poll the alignment until it is neither running nor waiting (at most `limit_s` simulated seconds).
    async fn alignment_outcome(&self, limit_s: u64) -> Value {
        for _ in 0..limit_s {
            let (status, a) = self.json("GET", "/api/align", "").await;
            assert_eq!(status, StatusCode::OK, "{a}");
            if a["state"] != "running" && a["state"] != "waiting-operator" {
                return a;
            }
            tokio::time::sleep(Duration::from_secs(1)).await;
        }
        panic!("the alignment did not end within {limit_s} s");
    }

    /// The campaign's stored alignment text and calibration id, read from the store itself.
    fn stored_alignment(&self, id: i64) -> (Option<String>, Option<i64>) {
        let store = Store::open(self.data.path()).expect("store");
        let c = store.campaign(CampaignId(id)).expect("campaign");
        (c.alignment_toml, c.calibration_id.map(|c| c.0))
    }
}

/// `gonio align`'s calibration on a rig of its own: the procedure run directly, as the command runs it.
async fn calibration_like_gonio_align(instrument_toml: &str) -> CalibrationFile {
    let file = InstrumentFile::parse(instrument_toml, "instrument").expect("instrument");
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let mirror = Material::preset("mirror").expect("mirror");
    let holder = rig
        .alignment_holder(&mirror, None, 25.0)
        .expect("holder")
        .expect("dry-run");
    let operator = |p: Placement| -> OperatorStep<'_> {
        holder.hold(p.held());
        Box::pin(std::future::ready(Ok(())))
    };
    let mut motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
    let report = run_alignment(&mut motion, &operator, Default::default())
        .await
        .expect("alignment");
    CalibrationFile::from_report(&report, instrument_toml, unix_now_s())
}

fn value_names(c: &CalibrationFile) -> BTreeSet<String> {
    c.values.iter().map(|v| v.name.clone()).collect()
}

#[tokio::test(start_paused = true)]
async fn the_alignment_action_stores_a_dated_calibration_that_campaigns_submitted_after_it_get() {
    let app = app_on(REALISTIC, tempfile::tempdir().expect("tempdir")).await;
    let (_, idle) = app.json("GET", "/api/align", "").await;
    assert_eq!(idle["state"], "idle", "{idle}");
    // Before any calibration a campaign is given none.
    let before = app.submit(&small_campaign("before", 3)).await;
    assert_eq!(app.stored_alignment(before), (None, None));
    let (_, view) = app.json("GET", &format!("/api/campaigns/{before}"), "").await;
    assert!(view["calibration_id"].is_null(), "{view}");
    while app.state(before as u64).await != "completed" {
        tokio::time::sleep(Duration::from_secs(1)).await;
    }

    let t0 = unix_now_s();
    let (status, started) = app.json("POST", "/api/align", "{}").await;
    assert_eq!(status, StatusCode::ACCEPTED, "{started}");
    assert_eq!(
        (
            started["state"].as_str(),
            started["started_by"].as_str(),
            started["dry_run"].as_bool()
        ),
        (Some("running"), Some("loopback"), Some(true)),
        "{started}"
    );
    // One alignment at a time, and the console waits for it.
    let (status, again) = app.json("POST", "/api/align", "{}").await;
    assert_eq!(status, StatusCode::CONFLICT, "{again}");
    let (status, console) = app.json("GET", "/api/console/state", "").await;
    assert_eq!(status, StatusCode::CONFLICT, "{console}");
    assert!(
        console["error"]
            .as_str()
            .unwrap_or_default()
            .contains("alignment"),
        "{console}"
    );

    let done = app.alignment_outcome(3600).await;
    let t1 = unix_now_s();
    assert_eq!(done["state"], "completed", "{done}");
    let id = done["calibration_id"].as_i64().expect("calibration id");
    assert!(done["instrument_s"].as_f64().is_some_and(|s| s > 60.0), "{done}");

    let (status, list) = app.json("GET", "/api/calibrations", "").await;
    assert_eq!(status, StatusCode::OK, "{list}");
    let list = list.as_array().expect("list");
    assert_eq!(list.len(), 1, "{list:?}");
    let listed = &list[0];
    assert_eq!(listed["id"].as_i64(), Some(id));
    assert_eq!(
        (
            listed["current"].as_bool(),
            listed["for_this_instrument"].as_bool(),
            listed["has_report"].as_bool()
        ),
        (Some(true), Some(true), Some(true)),
        "{listed}"
    );
    assert!(
        listed["source"].as_str().unwrap_or_default().contains("loopback"),
        "{listed}"
    );
    assert_eq!(
        listed["instrument_sha256"].as_str(),
        Some(sha256_hex(REALISTIC.as_bytes()).as_str())
    );

    // The file itself: made for this instrument file, dated now, every value with its u.
    let (status, text) = app.text(&format!("/api/calibrations/{id}")).await;
    assert_eq!(status, StatusCode::OK, "{text}");
    let cal = CalibrationFile::parse(&text, "stored").expect("a calibration file");
    cal.check_instrument(REALISTIC, "stored")
        .expect("for this instrument file");
    let created = cal.calibration.created_utc.clone();
    assert_eq!(listed["created_utc"].as_str(), Some(created.as_str()));
    assert!(
        iso8601_utc(t0.floor()) <= created && created <= iso8601_utc(t1.ceil()),
        "{created} not between {} and {}",
        iso8601_utc(t0),
        iso8601_utc(t1)
    );
    assert!(cal.values.iter().all(|v| v.u > 0.0), "{text}");
    // The same keys as `gonio align`'s file on the same instrument.
    let reference = calibration_like_gonio_align(REALISTIC).await;
    assert_eq!(value_names(&cal), value_names(&reference));
    assert_eq!(cal.unobservable.len(), reference.unobservable.len());
    let (status, report) = app.text(&format!("/api/calibrations/{id}/report.json")).await;
    assert_eq!(status, StatusCode::OK, "{report}");
    let report: Value = serde_json::from_str(&report).expect("json");
    assert!(
        report["estimated"].is_object() && report["scans"].is_array(),
        "{report}"
    );

    // A campaign submitted now is given it, and runs with it.
    let after = app.submit(&small_campaign("after", 3)).await;
    assert_eq!(app.stored_alignment(after), (Some(text.clone()), Some(id)));
    let (_, view) = app.json("GET", &format!("/api/campaigns/{after}"), "").await;
    assert_eq!(view["calibration_id"].as_i64(), Some(id), "{view}");
    while app.state(after as u64).await != "completed" {
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    // The one submitted before keeps having none.
    assert_eq!(app.stored_alignment(before), (None, None));
    // The console is the instrument's again.
    let (status, console) = app.json("GET", "/api/console/state", "").await;
    assert_eq!(status, StatusCode::OK, "{console}");
}

#[tokio::test(start_paused = true)]
async fn the_alignment_is_refused_while_a_campaign_owns_the_instrument() {
    let app = app_on(SIMULATED_INSTRUMENT_TOML, tempfile::tempdir().expect("tempdir")).await;
    let id = app.submit(&small_campaign("owner", 12)).await;
    loop {
        let (_, c) = app.json("GET", &format!("/api/campaigns/{id}"), "").await;
        if c["points_done"].as_u64() >= Some(1) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let (status, body) = app.json("POST", "/api/align", "{}").await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    let m = body["error"].as_str().unwrap_or_default();
    assert!(
        m.contains(&format!("campaign {id}")) && m.contains("owner"),
        "{m}"
    );
    let (_, status_now) = app.json("GET", "/api/align", "").await;
    assert_eq!(status_now["state"], "idle", "nothing started: {status_now}");
    let (status, list) = app.json("GET", "/api/calibrations", "").await;
    assert_eq!((status, list), (StatusCode::OK, Value::Array(vec![])));
    // A mirror that is no preset is refused before anything is taken.
    let (status, body) = app
        .json("POST", "/api/align", r#"{"mirror": "no-such-preset"}"#)
        .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let (status, body) = app.json("POST", "/api/align/confirm", "").await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    let (status, _) = app.text("/api/calibrations/7").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (_, c) = app.json("GET", &format!("/api/campaigns/{id}"), "").await;
    assert_eq!(c["state"], "running", "the campaign goes on: {c}");
}

/// A calibration file for `instrument_toml`, made at `created_utc`, whose detector zero is `zero_deg`.
fn calibration_text(instrument_toml: &str, created_utc: &str, zero_deg: f64) -> String {
    CalibrationFile {
        calibration: Header {
            instrument: "test".into(),
            instrument_sha256: sha256_hex(instrument_toml.as_bytes()),
            software: "gonio test".into(),
            created_utc: created_utc.into(),
            dry_run: true,
            method: "made by the test".into(),
        },
        values: vec![CalValue {
            name: "detector_zero_deg".into(),
            value: zero_deg,
            u: 0.001,
            unit: "deg".into(),
            observable: true,
        }],
        unobservable: vec![],
        detector: None,
        source: None,
    }
    .to_toml()
    .expect("toml")
}

fn keep(store: &mut Store, text: &str) -> i64 {
    let cal = CalibrationFile::parse(text, "test").expect("calibration");
    let h = cal.calibration;
    store
        .add_instrument_calibration(&NewInstrumentCalibration {
            instrument: h.instrument,
            instrument_sha256: h.instrument_sha256,
            created_utc: h.created_utc,
            software: h.software,
            method: h.method,
            source: "test".into(),
            calibration_toml: text.to_string(),
            report_json: None,
        })
        .expect("add")
        .0
}

#[tokio::test(start_paused = true)]
async fn the_latest_calibration_of_this_instrument_file_is_applied_and_never_another_files() {
    let other_instrument = format!("{SIMULATED_INSTRUMENT_TOML}\n# another instrument file\n");
    let foreign = calibration_text(&other_instrument, "2099-01-01T00:00:00Z", 0.5);
    let older = calibration_text(SIMULATED_INSTRUMENT_TOML, "2026-01-01T00:00:00Z", 0.01);
    let newer = calibration_text(SIMULATED_INSTRUMENT_TOML, "2026-06-01T00:00:00Z", 0.02);

    // Only another instrument file's calibration in the store: none is applied.
    let data = tempfile::tempdir().expect("tempdir");
    let foreign_id = keep(&mut Store::open(data.path()).expect("store"), &foreign);
    let app = app_on(SIMULATED_INSTRUMENT_TOML, data).await;
    let id = app.submit(&small_campaign("plain", 2)).await;
    assert_eq!(app.stored_alignment(id), (None, None));
    let (_, list) = app.json("GET", "/api/calibrations", "").await;
    assert_eq!(list[0]["id"].as_i64(), Some(foreign_id));
    assert_eq!(
        (
            list[0]["for_this_instrument"].as_bool(),
            list[0]["current"].as_bool()
        ),
        (Some(false), Some(false)),
        "{list}"
    );
    // Nor can it be given as a file: refused, naming the instrument file it was made for.
    let err = app
        .service
        .use_calibration_file(&foreign, "foreign.toml")
        .expect_err("another instrument file's");
    assert!(
        err.to_string().contains("foreign.toml") && err.to_string().contains("SHA-256"),
        "{err}"
    );
    drop(app);

    // With this file's calibrations too, made before the foreign one: the latest of this file's is applied.
    let data = tempfile::tempdir().expect("tempdir");
    let (newer_id, older_id) = {
        let mut store = Store::open(data.path()).expect("store");
        let newer_id = keep(&mut store, &newer);
        keep(&mut store, &foreign);
        let older_id = keep(&mut store, &older);
        (newer_id, older_id)
    };
    let app = app_on(SIMULATED_INSTRUMENT_TOML, data).await;
    let id = app.submit(&small_campaign("aligned", 2)).await;
    assert_eq!(app.stored_alignment(id), (Some(newer.clone()), Some(newer_id)));

    // A file given (`gonio daemon --calibration`) wins, and is kept once however often it is given.
    let given = calibration_text(SIMULATED_INSTRUMENT_TOML, "2025-01-01T00:00:00Z", 0.03);
    let given_id = app
        .service
        .use_calibration_file(&given, "given.toml")
        .expect("given");
    assert_eq!(
        app.service
            .use_calibration_file(&given, "given.toml")
            .expect("again"),
        given_id
    );
    let id = app.submit(&small_campaign("given", 2)).await;
    assert_eq!(app.stored_alignment(id), (Some(given.clone()), Some(given_id.0)));
    // The store's copy of a file already there is reused, not stored again.
    assert_eq!(
        app.service
            .use_calibration_file(&older, "older.toml")
            .expect("older")
            .0,
        older_id
    );
    let (_, list) = app.json("GET", "/api/calibrations", "").await;
    assert_eq!(list.as_array().map(Vec::len), Some(4), "{list}");
    let source = list
        .as_array()
        .and_then(|l| l.iter().find(|c| c["id"].as_i64() == Some(given_id.0)))
        .and_then(|c| c["source"].as_str())
        .unwrap_or_default()
        .to_string();
    assert!(source.contains("--calibration given.toml"), "{source}");
}

/// The console's pose (physical degrees) from a move's answer.
fn pose_of(axes: &Value) -> gonio_scheduler::kinematics::Pose {
    let get = |name: &str| {
        axes.as_array()
            .and_then(|a| a.iter().find(|p| p["name"] == name))
            .and_then(|p| p["position_deg"].as_f64())
            .unwrap_or_else(|| panic!("no {name} in {axes}"))
    };
    gonio_scheduler::kinematics::Pose::new(get("light"), get("detector"), get("tilt"), get("rotation"))
}

#[tokio::test(start_paused = true)]
async fn the_consoles_move_by_geometry_uses_the_current_calibration() {
    use gonio_engine::align::correction::PoseCorrection;

    let app = app_on(SIMULATED_INSTRUMENT_TOML, tempfile::tempdir().expect("tempdir")).await;
    let (status, body) = app.json("POST", "/api/console/home", "{}").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let geometry = r#"{"geometry": [30, 0, 40, 180]}"#;
    let (status, plain) = app.json("POST", "/api/console/move", geometry).await;
    assert_eq!(status, StatusCode::OK, "{plain}");
    let plain = pose_of(&plain);

    let text = calibration_text(SIMULATED_INSTRUMENT_TOML, "2026-01-01T00:00:00Z", 0.05);
    app.service
        .use_calibration_file(&text, "cal.toml")
        .expect("applied");
    let (status, aligned) = app.json("POST", "/api/console/move", geometry).await;
    assert_eq!(status, StatusCode::OK, "{aligned}");
    let aligned = pose_of(&aligned);
    let cal = CalibrationFile::parse(&text, "cal").expect("calibration");
    let expected = PoseCorrection::new(
        &InstrumentFile::simulated().instrument,
        cal.params(&InstrumentFile::simulated().instrument),
    )
    .correct(&plain);
    assert!(
        (aligned.detector_deg - plain.detector_deg + 0.05).abs() < 0.002,
        "{plain:?} -> {aligned:?}"
    );
    for (a, b) in [
        (aligned.light_deg, expected.light_deg),
        (aligned.detector_deg, expected.detector_deg),
        (aligned.tilt_deg, expected.tilt_deg),
        (aligned.rotation_deg, expected.rotation_deg),
    ] {
        assert!((a - b).abs() < 0.002, "{aligned:?} vs {expected:?}");
    }
}

impl App {
    /// Poll the alignment until it waits for the operator with an instruction containing `asks` (at most
    /// `limit_s` simulated seconds); its status.
    async fn alignment_waiting(&self, asks: &str, limit_s: u64) -> Value {
        for _ in 0..limit_s * 10 {
            let (_, a) = self.json("GET", "/api/align", "").await;
            let message = a["operator_message"].as_str().unwrap_or_default();
            if a["state"] == "waiting-operator" && message.contains(asks) {
                return a;
            }
            assert!(a["state"] == "running" || a["state"] == "waiting-operator", "{a}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!("the alignment did not ask the operator to {asks} within {limit_s} s");
    }
}

#[tokio::test(start_paused = true)]
async fn a_persons_operator_steps_wait_for_the_confirmation_and_an_abort_stores_nothing() {
    let app = app_on(SIMULATED_INSTRUMENT_TOML, tempfile::tempdir().expect("tempdir")).await;
    let body = r#"{"simulate_operator": false}"#;
    let (status, started) = app.json("POST", "/api/align", body).await;
    assert_eq!(status, StatusCode::ACCEPTED, "{started}");

    // Each step waits, however long the person takes, until it is confirmed.
    app.alignment_waiting("remove everything from the sample holder", 600)
        .await;
    tokio::time::sleep(Duration::from_secs(120)).await;
    let (_, still) = app.json("GET", "/api/align", "").await;
    assert_eq!(still["state"], "waiting-operator", "{still}");
    let (status, confirmed) = app.json("POST", "/api/align/confirm", "").await;
    assert_eq!(status, StatusCode::OK, "{confirmed}");
    app.alignment_waiting("mount the alignment mirror", 3600).await;
    // While it waits, the instrument is still the alignment's.
    let (status, console) = app.json("GET", "/api/console/state", "").await;
    assert_eq!(status, StatusCode::CONFLICT, "{console}");
    let (status, _) = app.json("POST", "/api/align/confirm", "").await;
    assert_eq!(status, StatusCode::OK);
    // The characterisation's last step reads the sample's reflection.
    app.alignment_waiting("mount the sample to be measured", 3600)
        .await;
    let (status, _) = app.json("POST", "/api/align/confirm", "").await;
    assert_eq!(status, StatusCode::OK);
    let done = app.alignment_outcome(3600).await;
    assert_eq!(done["state"], "completed", "{done}");
    // The simulated holder followed each confirmed step: the fit saw the beam, then the mirror, then the
    // sample (the characterisation's ranges are in the stored file).
    let id = done["calibration_id"].as_i64().expect("id");
    let (_, text) = app.text(&format!("/api/calibrations/{id}")).await;
    let stored = CalibrationFile::parse(&text, "stored").expect("a calibration");
    assert!(
        stored.detector.as_ref().is_some_and(|d| d.ranges.is_some()),
        "the daemon's alignment characterises too: {text}"
    );

    // An abort while waiting ends the alignment, stores nothing and gives the instrument back.
    let (status, _) = app.json("POST", "/api/align", body).await;
    assert_eq!(status, StatusCode::ACCEPTED);
    app.alignment_waiting("remove everything", 600).await;
    let (status, answer) = app.json("POST", "/api/align/abort", "").await;
    assert_eq!(status, StatusCode::OK, "{answer}");
    let ended = app.alignment_outcome(60).await;
    assert_eq!(ended["state"], "failed", "{ended}");
    assert!(
        ended["error"]
            .as_str()
            .unwrap_or_default()
            .contains("aborted while waiting"),
        "{ended}"
    );
    let (_, list) = app.json("GET", "/api/calibrations", "").await;
    assert_eq!(list.as_array().map(Vec::len), Some(1), "nothing stored: {list}");
    assert_eq!(
        list[0]["current"].as_bool(),
        Some(true),
        "the earlier one stays current: {list}"
    );
    let (status, console) = app.json("GET", "/api/console/state", "").await;
    assert_eq!(status, StatusCode::OK, "{console}");
}
