//! Shared set-up of the daemon's tests: the HTTP API in process on the simulated instrument (tokio's paused
//! clock; the data directory a temporary directory the test may fill), a campaign stored and run by the engine
//! directly ([`stored_campaign`]), and a real TCP server ([`tcp`]).

#![allow(dead_code)]

pub mod tcp;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode};
use gonio_daemon::api::{self, ApiConfig};
use gonio_daemon::control::Control;
use gonio_daemon::engine::{Event, prepare_campaign, run_campaign};
use gonio_daemon::rig::Rig;
use gonio_daemon::service::{EngineRunner, Service, ShutdownTrigger};
use gonio_daemon::store::{CampaignId, CampaignState, Store};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use http_body_util::BodyExt;
use serde_json::Value;
use tower::ServiceExt;

pub struct App {
    pub router: Router,
    pub rig: Rig,
    pub data: tempfile::TempDir,
    trigger: ShutdownTrigger,
}

impl Drop for App {
    fn drop(&mut self) {
        self.trigger.trigger();
    }
}

/// A daemon whose data directory (store and the files campaigns may name) is `data`.
pub async fn app(data: tempfile::TempDir) -> App {
    let instrument = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&instrument, None, 1.0)
        .await
        .expect("simulated rig");
    let runner = Arc::new(EngineRunner::new(
        instrument,
        SIMULATED_INSTRUMENT_TOML.to_string(),
        data.path().to_path_buf(),
        rig.clone(),
    ));
    let store = Store::open(data.path()).expect("store");
    let service = Service::new(store, runner, Control::new()).expect("service");
    let trigger = ShutdownTrigger::new();
    let (complete, _) = tokio::sync::mpsc::channel(1);
    {
        let (service, shutdown) = (service.clone(), trigger.subscribe());
        tokio::spawn(async move { service.run_queue(shutdown, complete).await });
    }
    let router = api::router(service, &ApiConfig::default(), trigger.subscribe());
    App {
        router,
        rig,
        data,
        trigger,
    }
}

impl App {
    pub async fn json(&self, method: &str, path: &str, body: &str) -> (StatusCode, Value) {
        let request = Request::builder()
            .method(method)
            .uri(path)
            .body(Body::from(body.to_string()))
            .expect("request");
        let response = tokio::time::timeout(Duration::from_secs(600), self.router.clone().oneshot(request))
            .await
            .expect("answer in time")
            .expect("infallible");
        let status = response.status();
        let bytes = response.into_body().collect().await.expect("body").to_bytes();
        let value = serde_json::from_slice(&bytes).unwrap_or_else(|e| {
            panic!(
                "{method} {path}: not JSON ({e}): {}",
                String::from_utf8_lossy(&bytes)
            )
        });
        (status, value)
    }

    /// The campaign's `state` as the API reports it.
    pub async fn state(&self, id: u64) -> String {
        let (status, v) = self.json("GET", &format!("/api/campaigns/{id}"), "").await;
        assert_eq!(status, StatusCode::OK, "{v}");
        v["state"].as_str().expect("state").to_string()
    }
}

/// A campaign prepared and stored for the simulated instrument, with the rig to run it on.
pub struct StoredCampaign {
    pub store: Arc<Mutex<Store>>,
    pub id: CampaignId,
    /// Points the plan holds.
    pub total_points: u64,
    pub rig: Rig,
    pub file: InstrumentFile,
    /// The data directory (store and files); removed when dropped.
    pub dir: tempfile::TempDir,
}

/// Prepare `text` (as if read from `file_name`), store it and connect the simulated rig.
pub async fn stored_campaign(text: &str, file_name: &str) -> StoredCampaign {
    let file = InstrumentFile::simulated();
    let dir = tempfile::tempdir().expect("tempdir");
    let prepared = prepare_campaign(text, file_name, dir.path(), &file).expect("valid campaign");
    let mut store = Store::open(dir.path()).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(text, SIMULATED_INSTRUMENT_TOML))
        .expect("create");
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    StoredCampaign {
        store: Arc::new(Mutex::new(store)),
        id,
        total_points: prepared.total_points,
        rig,
        file,
        dir,
    }
}

impl StoredCampaign {
    /// Run the campaign in a task of its own under `control`.
    pub fn spawn_run(
        &self,
        control: &Control,
    ) -> tokio::task::JoinHandle<Result<CampaignState, gonio_daemon::engine::EngineError>> {
        let (store, rig, control, id) = (
            Arc::clone(&self.store),
            self.rig.clone(),
            control.clone(),
            self.id,
        );
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    }
}

/// The index of the next point the engine announces.
pub async fn next_point(rx: &mut tokio::sync::broadcast::Receiver<Event>) -> u64 {
    loop {
        if let Event::Point { point, .. } = rx.recv().await.expect("event") {
            return point.index;
        }
    }
}
