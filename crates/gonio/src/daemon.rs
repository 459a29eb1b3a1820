//! `gonio daemon`: the long-running acquisition service with its HTTP/JSON control API.
//!
//! Listens on loopback by default; any other address needs a token (`--token` or `GONIO_TOKEN`), which every
//! request must then carry. Stops on SIGINT/SIGTERM: the running campaign pauses at a safe point (or is
//! emergency-stopped after the grace period) and is resumed first at the next start. Requests must name a host
//! the daemon knows (loopback, the listening address, or `--allow-host`), and state-changing requests from a
//! browser must come from the daemon's own origin (crates/daemon/src/api/origin.rs).

use std::io::Write as _;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use clap::Args;
use gonio_daemon::api::{self, ApiConfig, DEFAULT_LISTEN};
use gonio_daemon::service::{EngineRunner, Service};
use gonio_engine::control::Control;
use gonio_engine::rig::{DEFAULT_DRY_RUN_TIME_SCALE, Rig};
use gonio_engine::store::Store;
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};

use crate::CliError;

#[derive(Debug, Args)]
pub struct DaemonArgs {
    /// Address to listen on. Anything but loopback requires a token. Port 0 picks a free port.
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
    /// Data directory (the store `gonio.sqlite` lives there).
    #[arg(long, default_value = "gonio-data")]
    pub data: PathBuf,
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Token every request must carry (`Authorization: Bearer <token>`); default: the GONIO_TOKEN variable.
    #[arg(long)]
    pub token: Option<String>,
    /// Simulated seconds per real second for simulated devices (dry-runs).
    #[arg(long, default_value_t = DEFAULT_DRY_RUN_TIME_SCALE)]
    pub sim_time_scale: f64,
    /// Seconds a running campaign is given to reach a safe point at shutdown before an emergency stop.
    #[arg(long, default_value_t = 20.0)]
    pub shutdown_grace_s: f64,
    /// A host name clients may use to reach the daemon (repeatable), e.g. `--allow-host lab-pc.example.org`.
    /// Requests naming any other host are refused (421) so that a web page cannot reach the daemon by DNS
    /// rebinding; loopback names and addresses, and the listening address, are always allowed.
    #[arg(long = "allow-host", value_name = "NAME")]
    pub allow_hosts: Vec<String>,
    /// Calibration file from `gonio align` for this instrument file: kept in the store and applied to every
    /// campaign submitted to this daemon (refused when it was made for another instrument file). Without it the
    /// store's latest calibration made for this instrument file is applied, if there is one.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
}

pub fn run(args: DaemonArgs) -> Result<(), CliError> {
    let token = args.token.clone().or_else(|| std::env::var("GONIO_TOKEN").ok());
    // The token rule comes first: refuse before touching anything.
    api::check_listen(args.listen, token.as_deref()).map_err(|e| CliError::input(e.to_string()))?;
    if !(args.sim_time_scale.is_finite() && args.sim_time_scale > 0.0) {
        return Err(CliError::input(format!(
            "--sim-time-scale must be positive, got {}",
            args.sim_time_scale
        )));
    }
    if !(args.shutdown_grace_s.is_finite() && args.shutdown_grace_s >= 0.0) {
        return Err(CliError::input(format!(
            "--shutdown-grace-s must be >= 0, got {}",
            args.shutdown_grace_s
        )));
    }
    let (instrument, instrument_toml) = match &args.instrument {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| CliError::io(format!("cannot read {}", path.display()), e))?;
            let file = InstrumentFile::parse(&text, &path.display().to_string())
                .map_err(|e| CliError::input(e.to_string()))?;
            (file, text)
        }
        None => (InstrumentFile::simulated(), SIMULATED_INSTRUMENT_TOML.to_string()),
    };
    let calibration = args
        .calibration
        .as_deref()
        .map(|p| {
            crate::calibration::read_calibration(p, &instrument_toml)
                .map(|text| (text, p.display().to_string()))
        })
        .transpose()?;
    // Submitted campaigns may name material files inside the data directory only (issue #8: paths in configs).
    let base_dir = args.data.clone();
    let store = Store::open(&args.data).map_err(|e| CliError::input(e.to_string()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::io("cannot start the async runtime", e))?;
    runtime.block_on(async move {
        let rig = Rig::connect_with_time_scale(&instrument, None, args.sim_time_scale)
            .await
            .map_err(|e| CliError::input(format!("cannot connect the instrument: {e}")))?;
        let runner = Arc::new(EngineRunner::new(instrument, instrument_toml, base_dir, rig));
        let service = Service::new(store, runner, Control::new())
            .map_err(|e| CliError::input(e.to_string()))?
            .with_shutdown_grace(Duration::from_secs_f64(args.shutdown_grace_s));
        // The file given wins over the store's latest calibration; it is kept in the store too.
        if let Some((text, origin)) = &calibration {
            service
                .use_calibration_file(text, origin)
                .map_err(|e| CliError::input(e.to_string()))?;
        }
        let listener = tokio::net::TcpListener::bind(args.listen)
            .await
            .map_err(|e| CliError::io(format!("cannot listen on {}", args.listen), e))?;
        let addr = listener
            .local_addr()
            .map_err(|e| CliError::io("cannot read the listening address", e))?;
        println!(
            "gonio daemon listening on http://{addr} (data in {})",
            args.data.display()
        );
        let _ = std::io::stdout().flush();
        let config = ApiConfig {
            token,
            allowed_hosts: args.allow_hosts,
            ..ApiConfig::default()
        };
        api::run_daemon(listener, service, &config, stop_signal()).await;
        println!("gonio daemon stopped");
        Ok(())
    })
}

/// SIGINT (Ctrl-C) or SIGTERM.
async fn stop_signal() {
    let ctrl_c = async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!("cannot listen for Ctrl-C: {e}");
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::error!("cannot listen for SIGTERM: {e}");
                std::future::pending::<()>().await;
            }
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}
