//! A simulated serial device served on a real pseudo-terminal, so that a host opens it BY PATH exactly like a
//! real serial port (`gonio sim`, and the rig for `port = "sim-pty"`).
//!
//! The slave end is put in raw mode; the master is bridged to the device's emulator by a tokio task. Two ways to
//! show a disconnect fault (`[simulator.faults] disconnect_after_s`):
//! - [`PtyDevice::serve`] keeps the terminal: we hold a slave descriptor ourselves, so the master never reads EIO
//!   while no client has the port open, and while the device is gone the bridge swallows what the client sends
//!   (a cable pulled between adapter and controller: the port stays, the device goes silent).
//! - [`PtyDevice::serve_linked`] makes the port itself vanish, as a USB-serial adapter does when unplugged: the
//!   stable path is a symbolic link (like `/dev/serial/by-id/...`) to the current terminal; on disconnect the
//!   link is removed and the terminal hung up (a client's open descriptor reads end-of-file or EIO), and when the
//!   device comes back a fresh terminal appears behind the same link.
//!
//! [`PtyDevice`] owns the descriptors and the task: dropping it stops the bridge, closes the terminal and
//! removes the link.

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;

use crate::instrument::{SimError, SimInstrument};
use crate::session::SerialStream;

/// How often (real time) a bridge looks whether a disconnected device is back.
const RECONNECT_POLL: Duration = Duration::from_millis(50);

/// One simulated serial device on a pseudo-terminal. Keeps its terminal and bridge task alive until dropped.
#[derive(Debug)]
pub struct PtyDevice {
    device: String,
    path: PathBuf,
    task: JoinHandle<()>,
    /// Our own slave descriptor, in the mode that keeps the terminal (see the module doc). Closed after the
    /// task is aborted. In linked mode the task owns its terminals.
    _slave: Option<OwnedFd>,
    /// The link to remove on drop, in linked mode.
    link: Option<PathBuf>,
}

/// An open terminal: the master registered with the reactor, our slave descriptor and the slave's path.
struct Terminal {
    master: AsyncFd<OwnedFd>,
    slave: OwnedFd,
    path: PathBuf,
}

impl PtyDevice {
    /// Open a pseudo-terminal for the serial device `device` of `sim` and bridge it to the device's emulator
    /// (the bridge task runs on the current tokio runtime). A disconnect fault leaves the terminal in place.
    pub fn serve(sim: &SimInstrument, device: &str) -> Result<PtyDevice, SimError> {
        let handle = runtime_for(sim, device)?;
        let _enter = handle.enter();
        let terminal = open_terminal(device)?;
        let path = terminal.path.clone();
        let task = handle.spawn(bridge_keeping_terminal(
            sim.clone(),
            device.to_string(),
            terminal.master,
        ));
        tracing::info!(device, path = %path.display(), "simulated device served on a pseudo-terminal");
        Ok(PtyDevice {
            device: device.to_string(),
            path,
            task,
            _slave: Some(terminal.slave),
            link: None,
        })
    }

    /// Serve `device` behind the symbolic link `link` (replaced if it exists), which vanishes while the device
    /// is disconnected and then points at a fresh terminal (see the module doc). [`PtyDevice::path`] is the link.
    pub fn serve_linked(sim: &SimInstrument, device: &str, link: &Path) -> Result<PtyDevice, SimError> {
        let handle = runtime_for(sim, device)?;
        let _enter = handle.enter();
        // The first terminal is opened here, so that the caller can print the path as soon as we return.
        let first = match sim.serial_port(device) {
            Ok(stream) => {
                let terminal = open_terminal(device)?;
                point_link(link, &terminal.path).map_err(|e| SimError::Pty {
                    device: device.to_string(),
                    message: format!(
                        "cannot link {} to {}: {e}",
                        link.display(),
                        terminal.path.display()
                    ),
                })?;
                Some((terminal, stream))
            }
            Err(SimError::Disconnected { .. }) => None,
            Err(e) => return Err(e),
        };
        let task = handle.spawn(bridge_linked(
            sim.clone(),
            device.to_string(),
            link.to_path_buf(),
            first,
        ));
        tracing::info!(device, link = %link.display(), "simulated device served behind a link to a pseudo-terminal");
        Ok(PtyDevice {
            device: device.to_string(),
            path: link.to_path_buf(),
            task,
            _slave: None,
            link: Some(link.to_path_buf()),
        })
    }

    /// The path to open like a serial port: the terminal (e.g. `/dev/pts/7`), or the link in linked mode.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The simulated device it serves.
    pub fn device(&self) -> &str {
        &self.device
    }
}

impl Drop for PtyDevice {
    fn drop(&mut self) {
        // Stop the bridge first; the slave descriptor closes after this (field drop order).
        self.task.abort();
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// The runtime to spawn the bridge on, after checking that `device` is one of `sim`'s serial devices.
fn runtime_for(sim: &SimInstrument, device: &str) -> Result<tokio::runtime::Handle, SimError> {
    // Fail early, with the simulator's own reason, for an unknown or non-serial device.
    if !sim.serial_devices().iter().any(|(n, _)| n == device) {
        // serial_port gives the precise error (unknown device or wrong kind).
        sim.serial_port(device)?;
    }
    tokio::runtime::Handle::try_current().map_err(|_| SimError::NoRuntime {
        device: device.to_string(),
    })
}

/// Open a raw-mode pseudo-terminal with a non-blocking master registered with the current runtime's reactor.
fn open_terminal(device: &str) -> Result<Terminal, SimError> {
    let err = |what: &str, e: &dyn std::fmt::Display| SimError::Pty {
        device: device.to_string(),
        message: format!("{what}: {e}"),
    };
    let pty = nix::pty::openpty(None, None).map_err(|e| err("cannot open a pseudo-terminal", &e))?;
    make_raw(&pty.slave).map_err(|e| err("cannot set the terminal to raw mode", &e))?;
    let path = nix::unistd::ttyname(pty.slave.as_fd()).map_err(|e| err("cannot name the terminal", &e))?;
    fcntl(pty.master.as_fd(), FcntlArg::F_SETFL(OFlag::O_NONBLOCK))
        .map_err(|e| err("cannot make the terminal non-blocking", &e))?;
    // `AsyncFd::new` is deprecated because a borrowed descriptor could be closed while registered; an
    // `OwnedFd` is owned by the registration itself, so that cannot happen here (and `register` is unsafe).
    #[allow(deprecated)]
    let master = AsyncFd::new(pty.master).map_err(|e| err("cannot register the terminal", &e))?;
    Ok(Terminal {
        master,
        slave: pty.slave,
        path,
    })
}

fn make_raw(fd: &OwnedFd) -> std::io::Result<()> {
    let mut t = tcgetattr(fd.as_fd()).map_err(std::io::Error::from)?;
    cfmakeraw(&mut t);
    tcsetattr(fd.as_fd(), SetArg::TCSANOW, &t).map_err(std::io::Error::from)
}

/// Point `link` at `target` atomically: a client never sees a link to a dead terminal or a missing link
/// while the device is up.
fn point_link(link: &Path, target: &Path) -> std::io::Result<()> {
    let mut tmp = link.as_os_str().to_owned();
    tmp.push(format!(".new-{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}

/// Why a bridge between a terminal and a device session ended.
enum BridgeEnd {
    /// The device went away (disconnect fault): its session closed.
    DeviceGone,
    /// The terminal failed: nothing more to serve.
    TerminalFailed,
}

/// Copy bytes both ways between the terminal and one session of the device, until either side ends.
async fn pump(name: &str, master: &AsyncFd<OwnedFd>, stream: &mut SerialStream) -> BridgeEnd {
    let mut buf = [0u8; 1024];
    let mut from_dev = [0u8; 1024];
    loop {
        tokio::select! {
            r = read_master(master, &mut buf) => match r {
                Ok(n) => {
                    if stream.write_all(&buf[..n]).await.is_err() {
                        return BridgeEnd::DeviceGone;
                    }
                }
                Err(e) => {
                    tracing::warn!(device = %name, "pty bridge: terminal read failed: {e}");
                    return BridgeEnd::TerminalFailed;
                }
            },
            r = stream.read(&mut from_dev) => match r {
                Ok(0) | Err(_) => {
                    tracing::warn!(device = %name, "pty bridge: device disconnected");
                    return BridgeEnd::DeviceGone;
                }
                Ok(n) => {
                    if let Err(e) = write_master(master, &from_dev[..n]).await {
                        tracing::warn!(device = %name, "pty bridge: terminal write failed: {e}");
                        return BridgeEnd::TerminalFailed;
                    }
                }
            },
        }
    }
}

/// Bridge for [`PtyDevice::serve`]: the terminal stays; while the device is gone, what the client sends is
/// swallowed, and the bridge reconnects once the device is back.
async fn bridge_keeping_terminal(sim: SimInstrument, name: String, master: AsyncFd<OwnedFd>) {
    let mut buf = [0u8; 1024];
    loop {
        match sim.serial_port(&name) {
            Ok(mut stream) => match pump(&name, &master, &mut stream).await {
                BridgeEnd::DeviceGone => continue,
                BridgeEnd::TerminalFailed => return,
            },
            Err(e) => {
                tracing::info!(device = %name, "pty bridge: {e}");
                // Device gone: swallow what the client sends, retry a little later.
                let wait = tokio::time::sleep(RECONNECT_POLL);
                tokio::pin!(wait);
                loop {
                    tokio::select! {
                        _ = &mut wait => break,
                        r = read_master(&master, &mut buf) => if r.is_err() { return },
                    }
                }
            }
        }
    }
}

/// Bridge for [`PtyDevice::serve_linked`]: one terminal per connection of the device; the link exists exactly
/// while the device is connected.
async fn bridge_linked(
    sim: SimInstrument,
    name: String,
    link: PathBuf,
    mut current: Option<(Terminal, SerialStream)>,
) {
    loop {
        let (terminal, mut stream) = match current.take() {
            Some(live) => live,
            None => match wait_for_device(&sim, &name).await {
                Some(stream) => {
                    let terminal = match open_terminal(&name) {
                        Ok(t) => t,
                        Err(e) => {
                            tracing::error!(device = %name, "pty bridge: {e}");
                            return;
                        }
                    };
                    if let Err(e) = point_link(&link, &terminal.path) {
                        tracing::error!(device = %name, link = %link.display(), "pty bridge: cannot relink: {e}");
                        return;
                    }
                    tracing::warn!(device = %name, link = %link.display(), path = %terminal.path.display(),
                        "pty bridge: device back on a new terminal");
                    (terminal, stream)
                }
                None => return,
            },
        };
        let end = pump(&name, &terminal.master, &mut stream).await;
        // Unplugged: the path vanishes first, then the terminal hangs up (closing both ends).
        let _ = std::fs::remove_file(&link);
        tracing::warn!(device = %name, link = %link.display(), "pty bridge: port vanished (link removed, terminal hung up)");
        drop(terminal);
        if matches!(end, BridgeEnd::TerminalFailed) {
            return;
        }
    }
}

/// Poll until the device accepts a session again; None if it never can (not a disconnect).
async fn wait_for_device(sim: &SimInstrument, name: &str) -> Option<SerialStream> {
    loop {
        match sim.serial_port(name) {
            Ok(stream) => return Some(stream),
            Err(SimError::Disconnected { .. }) => tokio::time::sleep(RECONNECT_POLL).await,
            Err(e) => {
                tracing::error!(device = %name, "pty bridge: {e}");
                return None;
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

#[cfg(test)]
mod tests {
    use std::io::{Read, Write};
    use std::sync::Arc;

    use super::*;
    use crate::scene::{Band, Pose, Scene};

    #[derive(Debug)]
    struct Dark;
    impl Scene for Dark {
        fn detector_power_w(&self, _: &Pose, _: &Band, _: f64) -> f64 {
            0.0
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn the_wheel_answers_on_its_terminal_opened_by_path() {
        // The recorded noise at open switched on, so the terminal is shown to carry it as the wheel sends it.
        let mut file = gonio_instrument::InstrumentFile::simulated();
        file.simulator.quirks.fw102c_noise_at_open = true;
        let sim = SimInstrument::new(&file, Arc::new(Dark), 1.0).expect("sim");
        let pty = PtyDevice::serve(&sim, "wheel").expect("serve");
        assert_eq!(pty.device(), "wheel");
        let path = pty.path().to_path_buf();
        // A blocking client, as any program would open a serial port: the FW102C echoes and answers `pos?`.
        let reply = tokio::task::spawn_blocking(move || {
            let mut f = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(&path)
                .expect("open");
            f.write_all(b"pos?\r").expect("write");
            let mut got = Vec::new();
            let mut b = [0u8; 64];
            while !got.ends_with(b"pos?\r1\r> ") {
                let n = f.read(&mut b).expect("read");
                got.extend_from_slice(&b[..n]);
            }
            got
        });
        let reply = tokio::time::timeout(std::time::Duration::from_secs(10), reply)
            .await
            .expect("the wheel answered in time")
            .expect("client");
        let text = String::from_utf8_lossy(&reply);
        // The noise of a freshly opened port (a recorded real-wheel quirk, switched on here), then echo and CR, the
        // answer (position 1 at power-up) and CR, then the prompt (FW102C manual).
        assert_eq!(text, "\0\0\0Command error CMD_NOT_DEFINED\r> pos?\r1\r> ");
        assert_eq!(
            PtyDevice::serve(&sim, "meter")
                .expect_err("USB device")
                .to_string(),
            SimError::WrongKind {
                device: "meter".into(),
                protocol: "pm100",
                wanted: "serial"
            }
            .to_string()
        );
    }
}
