//! `gonio sim`: serve the simulated instrument's serial devices on pseudo-terminals until interrupted.
//!
//! One pseudo-terminal per serial device (SMC100 chain, Zaber chain, FW102C wheel), its slave in raw mode, its
//! master bridged to the device's emulator. stdout gets one JSON line per device, then `{"ready":true}`; the
//! paths can be opened by any program exactly like real serial ports. The USB power meter exists in process only
//! and says so. SIGINT or SIGTERM ends the program cleanly (exit 0).
//!
//! We keep a slave descriptor open ourselves, so the master never reads EIO while no client has the port open.
//! When a fault disconnects a device, its bridge drops what the client sends and reconnects once the device
//! is back.

use std::io::Write;
use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::sync::Arc;

use gonio_instrument::InstrumentFile;
use gonio_simulator::SimInstrument;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::Scene;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Simulated seconds per real second (1.0 = real time).
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Sample material: a material file or a preset name.
    #[arg(long, default_value = "spectralon")]
    pub material: String,
}

pub fn run(args: SimArgs) -> Result<(), CliError> {
    let file = match &args.instrument {
        Some(path) => InstrumentFile::load(path).map_err(|e| CliError::input(e.to_string()))?,
        None => InstrumentFile::simulated(),
    };
    if !(args.time_scale.is_finite() && args.time_scale > 0.0) {
        return Err(CliError::input(format!(
            "--time-scale must be finite and > 0, got {}",
            args.time_scale
        )));
    }
    let scene = build_scene(&file, &args.material)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| CliError::io("cannot start the async runtime", e))?;
    let result = runtime.block_on(serve(file, scene, args.time_scale));
    // The bridges are idle reads: cancel them at once rather than waiting for the default shutdown.
    runtime.shutdown_timeout(std::time::Duration::from_millis(100));
    // The terminals close only now, so no bridge sees its slave vanish (EIO) while the runtime still runs.
    drop(result?);
    Ok(())
}

/// The optical scene: the faithful optics with the sample `material` (a file or a preset), sized to the
/// holder's largest sample, seeded from `[simulator] seed`.
fn build_scene(file: &InstrumentFile, material: &str) -> Result<Arc<dyn Scene>, CliError> {
    let material = gonio_brdf::material::Material::from_file_or_preset(material)
        .map_err(|e| CliError::input(format!("--material {material:?}: {e}")))?;
    let sample = SampleSpec {
        material,
        radius_mm: file.instrument.sample_holder.max_sample_radius_mm,
        orientation_deg: 0.0,
    };
    let optics = Optics::new(&file.instrument, sample, file.simulator.seed)
        .map_err(|e| CliError::input(format!("simulated optics: {e}")))?;
    Ok(Arc::new(optics))
}

/// Serve until SIGINT/SIGTERM; returns our own slave descriptors, to be closed after the runtime stopped.
async fn serve(
    file: InstrumentFile,
    scene: Arc<dyn Scene>,
    time_scale: f64,
) -> Result<Vec<OwnedFd>, CliError> {
    let sim = SimInstrument::new(&file, scene, time_scale).map_err(|e| CliError::input(e.to_string()))?;
    let mut stdout = std::io::stdout().lock();
    let mut keep = Vec::new();
    for (name, protocol) in sim.serial_devices() {
        let pty = nix::pty::openpty(None, None)
            .map_err(|e| CliError::io(format!("cannot open a pseudo-terminal for {name}"), e.into()))?;
        make_raw(&pty.slave)
            .map_err(|e| CliError::io(format!("cannot set {name}'s terminal to raw mode"), e))?;
        let path = nix::unistd::ttyname(pty.slave.as_fd())
            .map_err(|e| CliError::io(format!("cannot name {name}'s terminal"), e.into()))?;
        let line = serde_json::json!({"device": name, "protocol": protocol.name(), "path": path.display().to_string()});
        writeln!(stdout, "{line}").map_err(|e| CliError::io("stdout", e))?;
        fcntl(pty.master.as_fd(), FcntlArg::F_SETFL(OFlag::O_NONBLOCK))
            .map_err(|e| CliError::io(format!("cannot make {name}'s terminal non-blocking"), e.into()))?;
        // `AsyncFd::new` is deprecated because a borrowed descriptor could be closed while registered; an
        // `OwnedFd` is owned by the registration itself, so that cannot happen here (and `register` is unsafe).
        #[allow(deprecated)]
        let master = AsyncFd::new(pty.master).map_err(|e| CliError::io("cannot register the terminal", e))?;
        tokio::spawn(bridge(sim.clone(), name.clone(), master));
        // Our own slave descriptor keeps the master from reading EIO while no client has the port open.
        keep.push(pty.slave);
    }
    for name in sim.usb_devices() {
        let line = serde_json::json!({"device": name, "protocol": "pm100", "path": null, "note": "USB device: in-process only"});
        writeln!(stdout, "{line}").map_err(|e| CliError::io("stdout", e))?;
    }
    writeln!(stdout, "{}", serde_json::json!({"ready": true})).map_err(|e| CliError::io("stdout", e))?;
    stdout.flush().map_err(|e| CliError::io("stdout", e))?;
    drop(stdout);

    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .map_err(|e| CliError::io("cannot listen for SIGTERM", e))?;
    let mut int = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
        .map_err(|e| CliError::io("cannot listen for SIGINT", e))?;
    tokio::select! {
        _ = term.recv() => tracing::info!("gonio sim: SIGTERM, stopping"),
        _ = int.recv() => tracing::info!("gonio sim: SIGINT, stopping"),
    }
    Ok(keep)
}

fn make_raw(fd: &OwnedFd) -> std::io::Result<()> {
    let mut t = tcgetattr(fd.as_fd()).map_err(std::io::Error::from)?;
    cfmakeraw(&mut t);
    tcsetattr(fd.as_fd(), SetArg::TCSANOW, &t).map_err(std::io::Error::from)
}

/// Copy bytes both ways between the pty master and the device's emulator; reconnect after a disconnect fault.
async fn bridge(sim: SimInstrument, name: String, master: AsyncFd<OwnedFd>) {
    let mut buf = [0u8; 1024];
    let mut from_dev = [0u8; 1024];
    loop {
        let stream = match sim.serial_port(&name) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::info!(device = %name, "gonio sim: {e}");
                None
            }
        };
        let Some(mut stream) = stream else {
            // Device gone: swallow what the client sends, retry a little later.
            let wait = tokio::time::sleep(std::time::Duration::from_millis(50));
            tokio::pin!(wait);
            loop {
                tokio::select! {
                    _ = &mut wait => break,
                    r = read_master(&master, &mut buf) => if r.is_err() { return },
                }
            }
            continue;
        };
        loop {
            tokio::select! {
                r = read_master(&master, &mut buf) => match r {
                    Ok(n) => {
                        if stream.write_all(&buf[..n]).await.is_err() { break; }
                    }
                    Err(e) => {
                        tracing::warn!(device = %name, "gonio sim: terminal read failed: {e}");
                        return;
                    }
                },
                r = stream.read(&mut from_dev) => match r {
                    Ok(0) | Err(_) => {
                        tracing::warn!(device = %name, "gonio sim: device disconnected");
                        break;
                    }
                    Ok(n) => {
                        if let Err(e) = write_master(&master, &from_dev[..n]).await {
                            tracing::warn!(device = %name, "gonio sim: terminal write failed: {e}");
                            return;
                        }
                    }
                },
            }
        }
    }
}

async fn read_master(master: &AsyncFd<OwnedFd>, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        let mut guard = master.readable().await?;
        match guard.try_io(|fd| nix::unistd::read(fd.get_ref().as_fd(), buf).map_err(std::io::Error::from)) {
            Ok(Ok(0)) => continue,
            Ok(result) => return result,
            Err(_would_block) => continue,
        }
    }
}

async fn write_master(master: &AsyncFd<OwnedFd>, mut data: &[u8]) -> std::io::Result<()> {
    while !data.is_empty() {
        let mut guard = master.writable().await?;
        match guard.try_io(|fd| nix::unistd::write(fd.get_ref().as_fd(), data).map_err(std::io::Error::from))
        {
            Ok(Ok(n)) => data = &data[n..],
            Ok(Err(e)) => return Err(e),
            Err(_would_block) => continue,
        }
    }
    Ok(())
}
