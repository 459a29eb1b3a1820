//! Shared set-up of the daemon's tests (one copy for all of them, so it is not a crate of its own: a test kit
//! crate would depend on the daemon it tests): the HTTP API in process on the simulated instrument (tokio's
//! paused clock; the data directory a temporary directory the test may fill; [`app`], [`app_with`]), a campaign
//! stored and run by the engine directly ([`stored_campaign`]), and a real TCP server ([`tcp`]).

#![allow(dead_code)]

pub mod tcp;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode};
use gonio_daemon::api::{self, ApiConfig};
use gonio_daemon::service::{EngineRunner, Service, ShutdownTrigger};
use gonio_engine::control::Control;
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignId, CampaignState, Store};
use gonio_engine::{Event, prepare_campaign, run_campaign};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use http_body_util::BodyExt;
use serde_json::Value;
use tower::ServiceExt;

pub struct App {
    pub router: Router,
    pub service: Service,
    pub rig: Rig,
    pub data: tempfile::TempDir,
    /// The queue task (with [`Setup::queue`]): it returns once the daemon shuts down.
    pub queue: Option<tokio::task::JoinHandle<()>>,
    pub trigger: ShutdownTrigger,
}

impl Drop for App {
    fn drop(&mut self) {
        self.trigger.trigger();
    }
}

/// How a test daemon is set up beyond its data directory.
pub struct Setup {
    pub config: ApiConfig,
    /// Run queued campaigns; without the queue task a submitted campaign stays queued.
    pub queue: bool,
    /// Where submitted campaigns' file names resolve; default the data directory.
    pub files_dir: Option<PathBuf>,
    /// The instrument file's text; default the embedded simulated instrument.
    pub instrument_toml: Option<String>,
}

impl Default for Setup {
    fn default() -> Setup {
        Setup {
            config: ApiConfig::default(),
            queue: true,
            files_dir: None,
            instrument_toml: None,
        }
    }
}

/// The daemon's service on the simulated instrument file `instrument_toml` reached through `rig`: its store in
/// `data`, submitted campaigns' file names resolving under `files_dir`.
pub fn service(rig: &Rig, instrument_toml: &str, data: &Path, files_dir: PathBuf) -> Service {
    let runner = Arc::new(EngineRunner::new(
        InstrumentFile::parse(instrument_toml, "instrument").expect("instrument file"),
        instrument_toml.to_string(),
        files_dir,
        rig.clone(),
    ));
    Service::new(Store::open(data).expect("store"), runner, Control::new()).expect("service")
}

/// A daemon whose data directory (store and the files campaigns may name) is `data`, running its queue.
pub async fn app(data: tempfile::TempDir) -> App {
    app_with(data, Setup::default()).await
}

/// A daemon on `data` set up as `setup` says.
pub async fn app_with(data: tempfile::TempDir, setup: Setup) -> App {
    let instrument_toml = setup
        .instrument_toml
        .unwrap_or_else(|| SIMULATED_INSTRUMENT_TOML.to_string());
    let file = InstrumentFile::parse(&instrument_toml, "instrument").expect("instrument file");
    // Scale 1 on the paused clock: the simulated instrument's own time, at no wall-time cost.
    let rig = Rig::connect_with_time_scale(&file, None, 1.0)
        .await
        .expect("simulated rig");
    let files_dir = setup.files_dir.unwrap_or_else(|| data.path().to_path_buf());
    let service = service(&rig, &instrument_toml, data.path(), files_dir);
    let trigger = ShutdownTrigger::new();
    let queue = setup.queue.then(|| {
        let (complete, _) = tokio::sync::mpsc::channel(1);
        let (service, shutdown) = (service.clone(), trigger.subscribe());
        tokio::spawn(async move { service.run_queue(shutdown, complete).await })
    });
    let router = api::router(service.clone(), &setup.config, trigger.subscribe());
    App {
        router,
        service,
        rig,
        data,
        queue,
        trigger,
    }
}

impl App {
    /// Submit a campaign; its id.
    pub async fn submit(&self, text: &str) -> i64 {
        let (status, body) = self.json("POST", "/api/campaigns", text).await;
        assert_eq!(status, StatusCode::CREATED, "{body}");
        body["id"].as_i64().expect("id")
    }

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
    ) -> tokio::task::JoinHandle<Result<CampaignState, gonio_engine::EngineError>> {
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
