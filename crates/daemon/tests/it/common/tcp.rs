//! The daemon as `run_daemon` builds it, listening on a real TCP port on 127.0.0.1: its own server loop
//! ([`api::serve_with`]) and a router that knows the address it listens on. No queue runs, so a submitted
//! campaign stays queued.

use std::net::SocketAddr;
use std::path::Path;

use gonio_daemon::api::{self, ApiConfig};
use gonio_daemon::service::{Service, ShutdownTrigger};
use gonio_engine::rig::Rig;
use gonio_instrument::InstrumentFile;

pub struct Server {
    pub addr: SocketAddr,
    trigger: ShutdownTrigger,
    _dir: tempfile::TempDir,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.trigger.trigger();
    }
}

/// The daemon's service on the simulated instrument (on the real clock: the server does real I/O), its data
/// directory `data`.
pub async fn service(data: &Path) -> Service {
    let rig = Rig::connect(&InstrumentFile::simulated(), None)
        .await
        .expect("simulated rig");
    super::service(
        &rig,
        gonio_instrument::SIMULATED_INSTRUMENT_TOML,
        data,
        data.to_path_buf(),
    )
}

/// Start the server with `config` (its `listen_addr` becomes the address actually bound).
pub async fn server(config: ApiConfig) -> Server {
    let dir = tempfile::tempdir().expect("tempdir");
    let service = service(dir.path()).await;
    let trigger = ShutdownTrigger::new();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("addr");
    let config = ApiConfig {
        listen_addr: Some(addr),
        ..config
    };
    let router = api::router(service, &config, trigger.subscribe());
    let (complete, _) = tokio::sync::mpsc::channel(1);
    tokio::spawn(api::serve_with(
        listener,
        router,
        config.connection_limits(),
        trigger.subscribe(),
        complete,
    ));
    Server {
        addr,
        trigger,
        _dir: dir,
    }
}
