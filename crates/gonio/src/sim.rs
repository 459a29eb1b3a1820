//! `gonio sim`: serve the simulated instrument's serial devices on pseudo-terminals until interrupted.
//!
//! One pseudo-terminal per serial device (SMC100 chain, Zaber chain, FW102C wheel), its slave in raw mode, its
//! master bridged to the device's emulator. stdout gets one JSON line per device, then `{"ready":true}`; the
//! paths can be opened by any program exactly like real serial ports. Without `--link-dir` the USB power meter
//! exists in process only and says so. SIGINT or SIGTERM ends the program cleanly (exit 0).
//!
//! With `--link-dir DIR`, each printed path is instead a stable symbolic link `DIR/<device>` to the current
//! terminal, and a disconnect fault (`[simulator.faults] disconnect_after_s`) makes the port vanish as an unplugged
//! USB-serial adapter does: the link disappears and the terminal hangs up, and when the device comes back
//! (`reconnect_after_s`) the same link leads to a fresh terminal. Without it the terminal stays and the device
//! just falls silent while disconnected. `--link-dir` also serves the USB power meter on a Unix socket
//! `DIR/<meter>` (instrument file: `port = "usb-socket:DIR/<meter>"`), so that another process can run a whole
//! campaign against this simulator through exactly the code path of real hardware. The simulated operator
//! takes commands on stdin: `sample out` / `sample in` (see [`simulated_operator`]).
//!
//! With `--usb-gadget DIR` (a mounted FunctionFS function, see tests/usb_gadget/), the power meter is served
//! instead as a real USB device through that function (`gonio_simulator::ffs`), and stdin also takes the USB
//! faults: `usb halt in`, `usb halt out` (an endpoint halts) and `usb delay MS` (the next reply comes MS
//! milliseconds of real time late).
//!
//! The terminals and their bridges are `gonio_simulator::pty::PtyDevice`s (see there for the details).

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

use gonio_instrument::InstrumentFile;
use gonio_simulator::SimInstrument;
use gonio_simulator::ffs::FfsDevice;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::pty::PtyDevice;
use gonio_simulator::scene::Scene;
use gonio_simulator::usb_socket::UsbSocketDevice;

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
    /// Serve each device behind a stable link DIR/<device> that vanishes while the device is disconnected
    /// (created if missing; the links are removed on exit).
    #[arg(long, value_name = "DIR")]
    pub link_dir: Option<PathBuf>,
    /// Serve the power meter as a USB device through the FunctionFS function mounted at DIR (Linux gadget).
    #[arg(long, value_name = "DIR")]
    pub usb_gadget: Option<PathBuf>,
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
    let optics = build_optics(&file, &args.material)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| CliError::io("cannot start the async runtime", e))?;
    if let Some(dir) = &args.link_dir {
        std::fs::create_dir_all(dir)
            .map_err(|e| CliError::io(format!("cannot create --link-dir {}", dir.display()), e))?;
    }
    let served = Served {
        time_scale: args.time_scale,
        link_dir: args.link_dir.as_deref(),
        usb_gadget: args.usb_gadget.as_deref(),
    };
    let result = runtime.block_on(serve(file, optics, served));
    // The bridges are idle reads: cancel them at once rather than waiting for the default shutdown.
    runtime.shutdown_timeout(std::time::Duration::from_millis(100));
    // The terminals close only now, so no bridge sees its slave vanish (EIO) while the runtime still runs.
    drop(result?);
    Ok(())
}

/// The optical scene: the faithful optics with the sample `material` (a file or a preset), sized to the
/// holder's largest sample, seeded from `[simulator] seed`.
fn build_optics(file: &InstrumentFile, material: &str) -> Result<Arc<Optics>, CliError> {
    let material = gonio_brdf::material::Material::from_file_or_preset(material)
        .map_err(|e| CliError::input(format!("--material {material:?}: {e}")))?;
    let sample = SampleSpec {
        material,
        radius_mm: file.instrument.sample_holder.max_sample_radius_mm,
        orientation_deg: 0.0,
    };
    // The same hidden imperfections the in-process simulator draws from this file and seed, and the source as it
    // really is.
    let hidden = gonio_simulator::imperfections::HiddenTruth::draw(file);
    let real = gonio_simulator::imperfections::HiddenTruth::real_instrument(file, hidden.as_ref());
    let optics = Optics::new(&real, sample, file.simulator.seed)
        .map_err(|e| CliError::input(format!("simulated optics: {e}")))?
        .with_hidden_truth(hidden.as_ref());
    Ok(Arc::new(optics))
}

/// How and where the devices are served.
struct Served<'a> {
    time_scale: f64,
    link_dir: Option<&'a std::path::Path>,
    usb_gadget: Option<&'a std::path::Path>,
}

/// Serve until SIGINT/SIGTERM; returns the terminals, to be closed after the runtime stopped.
async fn serve(
    file: InstrumentFile,
    optics: Arc<Optics>,
    served: Served<'_>,
) -> Result<(Vec<PtyDevice>, Vec<UsbSocketDevice>), CliError> {
    let Served {
        time_scale,
        link_dir,
        usb_gadget,
    } = served;
    let scene: Arc<dyn Scene> = optics.clone();
    let sim = SimInstrument::new(&file, scene, time_scale).map_err(|e| CliError::input(e.to_string()))?;
    let mut stdout = std::io::stdout().lock();
    let mut keep = Vec::new();
    for (name, protocol) in sim.serial_devices() {
        let served = match link_dir {
            Some(dir) => PtyDevice::serve_linked(&sim, &name, &dir.join(&name)),
            None => PtyDevice::serve(&sim, &name),
        };
        let pty =
            served.map_err(|e| CliError::io(format!("cannot serve {name}"), std::io::Error::other(e)))?;
        let line = serde_json::json!({"device": name, "protocol": protocol.name(), "path": pty.path().display().to_string()});
        writeln!(stdout, "{line}").map_err(|e| CliError::io("stdout", e))?;
        keep.push(pty);
    }
    let mut sockets = Vec::new();
    let mut gadget = None;
    for name in sim.usb_devices() {
        let line = match (link_dir, usb_gadget) {
            (_, Some(dir)) if gadget.is_none() => {
                let device = FfsDevice::serve(&sim, &name, dir, tokio::runtime::Handle::current())
                    .map_err(|e| CliError::io(format!("cannot serve {name}"), std::io::Error::other(e)))?;
                gadget = Some(Arc::new(device));
                serde_json::json!({"device": name, "protocol": "pm100", "path": dir.display().to_string(),
                    "transport": "functionfs"})
            }
            (Some(dir), _) => {
                let socket = UsbSocketDevice::serve(&sim, &name, &dir.join(&name))
                    .map_err(|e| CliError::io(format!("cannot serve {name}"), std::io::Error::other(e)))?;
                let path = socket.path().display().to_string();
                sockets.push(socket);
                serde_json::json!({"device": name, "protocol": "pm100", "path": path, "transport": "usb-socket",
                    "port": format!("{}{path}", gonio_driver::transport::usb_socket::PORT_PREFIX)})
            }
            (None, _) => serde_json::json!({"device": name, "protocol": "pm100", "path": null,
                "note": "USB device: in-process only (--link-dir serves it on a socket)"}),
        };
        writeln!(stdout, "{line}").map_err(|e| CliError::io("stdout", e))?;
    }
    writeln!(stdout, "{}", serde_json::json!({"ready": true})).map_err(|e| CliError::io("stdout", e))?;
    stdout.flush().map_err(|e| CliError::io("stdout", e))?;
    drop(stdout);
    // Detached: it blocks on stdin, and ends with the process.
    std::thread::spawn(move || simulated_operator(optics, gadget, time_scale));

    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .map_err(|e| CliError::io("cannot listen for SIGTERM", e))?;
    let mut int = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
        .map_err(|e| CliError::io("cannot listen for SIGINT", e))?;
    tokio::select! {
        _ = term.recv() => tracing::info!("gonio sim: SIGTERM, stopping"),
        _ = int.recv() => tracing::info!("gonio sim: SIGINT, stopping"),
    }
    Ok((keep, sockets))
}

/// The simulated operator of a separate simulator: stdin lines `sample out` and `sample in` take the sample out
/// of the holder (the detector then sees the direct beam, for an absolute calibration) and put it back; each
/// answered by a JSON line `{"sample_mounted":...}`, anything else by `{"error":...}`. End of input ends this,
/// not the simulator. With a USB gadget, `usb halt in|out` and `usb delay MS` inject its faults. Runs on its own
/// thread (blocking reads of stdin).
fn simulated_operator(optics: Arc<Optics>, gadget: Option<Arc<FfsDevice>>, time_scale: f64) {
    use std::io::BufRead;
    for line in std::io::stdin().lock().lines() {
        let Ok(line) = line else { return };
        let reply = match line.trim() {
            "" => continue,
            "sample out" => {
                optics.set_sample_mounted(false);
                serde_json::json!({"sample_mounted": false})
            }
            "sample in" => {
                optics.set_sample_mounted(true);
                serde_json::json!({"sample_mounted": true})
            }
            other => match (other.strip_prefix("usb "), &gadget) {
                (Some(fault), Some(gadget)) => usb_fault(gadget, fault, time_scale),
                _ => serde_json::json!({
                    "error": format!("unknown command {other:?}; expected \"sample out\" or \"sample in\"")
                }),
            },
        };
        tracing::info!(%reply, "simulated operator");
        let mut stdout = std::io::stdout().lock();
        if writeln!(stdout, "{reply}").and_then(|()| stdout.flush()).is_err() {
            return;
        }
    }
}

/// One USB fault command on the gadget: `halt in`, `halt out`, `delay MS` (real milliseconds).
fn usb_fault(gadget: &FfsDevice, command: &str, time_scale: f64) -> serde_json::Value {
    match command.split_whitespace().collect::<Vec<_>>()[..] {
        ["halt", "in"] => {
            gadget.halt_in();
            serde_json::json!({"usb_fault": "halt in"})
        }
        ["halt", "out"] => {
            gadget.halt_out();
            serde_json::json!({"usb_fault": "halt out"})
        }
        ["delay", ms] => match ms.parse::<f64>() {
            Ok(ms) if ms.is_finite() && ms >= 0.0 => {
                gadget.delay_next_reply(ms / 1000.0 * time_scale);
                serde_json::json!({"usb_fault": "delay", "ms": ms})
            }
            _ => serde_json::json!({"error": format!("usb delay: not a number of milliseconds: {ms:?}")}),
        },
        _ => {
            serde_json::json!({"error": format!("unknown usb fault {command:?}; expected halt in|out or delay MS")})
        }
    }
}
