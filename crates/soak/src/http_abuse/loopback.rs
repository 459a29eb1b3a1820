//! The daemon under attack: its service as `gonio daemon` builds it, served on a loopback port.

use super::*;

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
pub(super) fn state_of(body: &str) -> Option<CampaignState> {
    let v: serde_json::Value = serde_json::from_str(body).ok()?;
    let s = v.get("state")?.as_str()?;
    CampaignState::ALL.into_iter().find(|c| c.as_str() == s)
}
