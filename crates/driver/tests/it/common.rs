//! Helpers shared by the tests.

use std::sync::Once;

/// Route driver traces to the test output (`RUST_LOG=gonio_driver=debug cargo test` to see the bytes).
pub fn trace() {
    static INIT: Once = Once::new();
    INIT.call_once(|| {
        let filter = tracing_subscriber::EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("off"));
        let _ = tracing_subscriber::fmt()
            .with_env_filter(filter)
            .with_test_writer()
            .try_init();
    });
}

/// The axis named `name` of the default simulated instrument.
pub fn sim_axis(name: &str) -> gonio_instrument::Axis {
    gonio_instrument::InstrumentFile::simulated()
        .instrument
        .axes
        .into_iter()
        .find(|a| a.name == name)
        .unwrap_or_else(|| panic!("no axis {name} in the simulated instrument"))
}

use std::os::fd::AsRawFd;
use std::sync::Arc;
use std::time::Duration;

use gonio_driver::transport::{LinePort, PortOpener, SerialSettings};
use gonio_simulator::SimInstrument;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Every `[simulator.quirks]` entry at the variant that demands the most of a host (SMC100 paced by 60 ms and
/// losing its first TS, FW102C noise at open, Zaber rejecting a bad checksum on every device, PM100 `INFINITY`),
/// set explicitly: the drivers' tests do not depend on which variant the defaults take.
pub fn demanding_quirks() -> gonio_instrument::Quirks {
    gonio_instrument::Quirks {
        pm100_overrange: gonio_instrument::Pm100Overrange::Infinity,
        smc100_min_command_gap_ms: 60.0,
        smc100_drop_first_ts: true,
        fw102c_noise_at_open: true,
        zaber_bad_checksum: gonio_instrument::ZaberBadChecksum::RejectAll,
    }
}

/// Every `[simulator.quirks]` entry as the manuals describe the device, set explicitly (where a manual says
/// both, as for a Zaber bad checksum, the variant [`demanding_quirks`] does not take).
pub fn manual_quirks() -> gonio_instrument::Quirks {
    gonio_instrument::Quirks {
        pm100_overrange: gonio_instrument::Pm100Overrange::ScpiOverflow,
        smc100_min_command_gap_ms: 0.0,
        smc100_drop_first_ts: false,
        fw102c_noise_at_open: false,
        zaber_bad_checksum: gonio_instrument::ZaberBadChecksum::Ignore,
    }
}

/// The simulated instrument with its default file under [`demanding_quirks`] (the variants these tests were
/// written against; the conformance tests run each variant on its own) and fault knobs set by `faults`.
pub fn sim_with(faults: impl FnOnce(&mut gonio_instrument::Faults), time_scale: f64) -> SimInstrument {
    let mut file = gonio_instrument::InstrumentFile::simulated();
    file.simulator.quirks = demanding_quirks();
    faults(&mut file.simulator.faults);
    let scene = Arc::new(gonio_simulator::scene::UniformScene { power_w: 2.0e-6 });
    SimInstrument::new(&file, scene, time_scale).expect("simulated instrument")
}

/// The simulated instrument file under [`demanding_quirks`] modified by `f` (quirks, detector, wheel...), with
/// the scene of [`sim_with`].
pub fn sim_file(f: impl FnOnce(&mut gonio_instrument::InstrumentFile), time_scale: f64) -> SimInstrument {
    let mut file = gonio_instrument::InstrumentFile::simulated();
    file.simulator.quirks = demanding_quirks();
    f(&mut file);
    let scene = Arc::new(gonio_simulator::scene::UniformScene { power_w: 2.0e-6 });
    SimInstrument::new(&file, scene, time_scale).expect("simulated instrument")
}

/// A port on the simulator's in-process stream for `device`; reconnecting asks the simulator again.
pub fn sim_port(sim: &SimInstrument, device: &str) -> Arc<LinePort> {
    let opener = gonio_engine::rig::sim_link::serial_opener(sim.clone(), device);
    Arc::new(LinePort::open(device, opener).expect("open the simulated port"))
}

/// The simulator's USB device as a [`gonio_driver::transport::usb::UsbPipe`]: the daemon's adapter.
pub use gonio_engine::rig::sim_link::SimPipe;

/// A pseudo-terminal whose master side is bridged to the simulator's stream for `device`. Returns the slave's
/// path (to open with `serialport`, exactly like a real port) and the bridge task.
pub fn pty_bridge(sim: &SimInstrument, device: &str) -> (String, tokio::task::JoinHandle<()>) {
    let pty = nix::pty::openpty(None, None).expect("openpty");
    let path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))
        .expect("slave path")
        .to_string_lossy()
        .to_string();
    nix::fcntl::fcntl(
        &pty.master,
        nix::fcntl::FcntlArg::F_SETFL(nix::fcntl::OFlag::O_NONBLOCK),
    )
    .expect("nonblocking");
    // `AsyncFd::new` is deprecated for types that do not own their fd; a `File` made from the `OwnedFd` does, and
    // the safe constructor is the only one allowed here (unsafe code is denied).
    #[allow(deprecated)]
    let master = AsyncFd::new(std::fs::File::from(pty.master)).expect("async fd");
    let mut stream = sim.serial_port(device).expect("simulated port");
    let slave = pty.slave;
    let task = tokio::spawn(async move {
        use std::io::{Read, Write};
        // Keep the slave open for the bridge's lifetime so the master never sees a hang-up between host opens.
        let _slave = slave;
        let mut from_host = [0u8; 1024];
        let mut from_dev = [0u8; 1024];
        loop {
            tokio::select! {
                guard = master.readable() => {
                    let Ok(mut guard) = guard else { return };
                    match guard.try_io(|f| f.get_ref().read(&mut from_host)) {
                        Ok(Ok(0)) => return,
                        Ok(Ok(n)) => { if stream.write_all(&from_host[..n]).await.is_err() { return; } }
                        Ok(Err(e)) if e.raw_os_error() == Some(nix::libc::EIO) => {
                            // No one has the slave open right now (between opens): wait and try again.
                            tokio::time::sleep(Duration::from_millis(10)).await;
                        }
                        Ok(Err(_)) => return,
                        Err(_would_block) => {}
                    }
                }
                r = stream.read(&mut from_dev) => {
                    let n = match r { Ok(0) | Err(_) => return, Ok(n) => n };
                    let mut data = &from_dev[..n];
                    while !data.is_empty() {
                        let Ok(mut guard) = master.writable().await else { return };
                        match guard.try_io(|f| f.get_ref().write(data)) {
                            Ok(Ok(w)) => data = &data[w..],
                            Ok(Err(_)) => return,
                            Err(_would_block) => {}
                        }
                    }
                }
            }
        }
    });
    (path, task)
}

/// Open a pty path like a real serial port.
pub fn pty_port(name: &str, path: &str, baud: u32, xon_xoff: bool) -> Arc<LinePort> {
    Arc::new(
        LinePort::open(
            name,
            PortOpener::Serial(SerialSettings {
                path: path.to_string(),
                baud,
                xon_xoff,
            }),
        )
        .expect("open the pty by path"),
    )
}
