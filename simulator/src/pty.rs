//! A simulated serial device served on a real pseudo-terminal, so that a host opens it BY PATH exactly like a
//! real serial port (`gonio sim`, and the rig for `port = "sim-pty"`).
//!
//! The slave end is put in raw mode; the master is bridged to the device's emulator by a tokio task. We keep a
//! slave descriptor open ourselves, so the master never reads EIO while no client has the port open. When a
//! fault disconnects the device, the bridge drops what the client sends and reconnects once the device is back.
//! [`PtyDevice`] owns the descriptors and the task: dropping it stops the bridge and closes the terminal.

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;

use crate::instrument::{SimError, SimInstrument};

/// One simulated serial device on a pseudo-terminal. Keeps its terminal and bridge task alive until dropped.
#[derive(Debug)]
pub struct PtyDevice {
    device: String,
    path: PathBuf,
    task: JoinHandle<()>,
    /// Our own slave descriptor (see the module doc). Closed after the task is aborted.
    _slave: OwnedFd,
}

impl PtyDevice {
    /// Open a pseudo-terminal for the serial device `device` of `sim` and bridge it to the device's emulator
    /// (the bridge task runs on the current tokio runtime).
    pub fn serve(sim: &SimInstrument, device: &str) -> Result<PtyDevice, SimError> {
        // Fail early, with the simulator's own reason, for an unknown or non-serial device.
        if !sim.serial_devices().iter().any(|(n, _)| n == device) {
            // serial_port gives the precise error (unknown device or wrong kind).
            sim.serial_port(device)?;
        }
        let handle = tokio::runtime::Handle::try_current().map_err(|_| SimError::NoRuntime {
            device: device.to_string(),
        })?;
        let err = |what: &str, e: &dyn std::fmt::Display| SimError::Pty {
            device: device.to_string(),
            message: format!("{what}: {e}"),
        };
        let pty = nix::pty::openpty(None, None).map_err(|e| err("cannot open a pseudo-terminal", &e))?;
        make_raw(&pty.slave).map_err(|e| err("cannot set the terminal to raw mode", &e))?;
        let path =
            nix::unistd::ttyname(pty.slave.as_fd()).map_err(|e| err("cannot name the terminal", &e))?;
        fcntl(pty.master.as_fd(), FcntlArg::F_SETFL(OFlag::O_NONBLOCK))
            .map_err(|e| err("cannot make the terminal non-blocking", &e))?;
        // `AsyncFd::new` needs the runtime's reactor: enter the runtime we spawn on.
        let _enter = handle.enter();
        // `AsyncFd::new` is deprecated because a borrowed descriptor could be closed while registered; an
        // `OwnedFd` is owned by the registration itself, so that cannot happen here (and `register` is unsafe).
        #[allow(deprecated)]
        let master = AsyncFd::new(pty.master).map_err(|e| err("cannot register the terminal", &e))?;
        let task = handle.spawn(bridge(sim.clone(), device.to_string(), master));
        tracing::info!(device, path = %path.display(), "simulated device served on a pseudo-terminal");
        Ok(PtyDevice {
            device: device.to_string(),
            path,
            task,
            _slave: pty.slave,
        })
    }

    /// The terminal's path (e.g. `/dev/pts/7`), to open like a serial port.
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
    }
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
                tracing::info!(device = %name, "pty bridge: {e}");
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
                        tracing::warn!(device = %name, "pty bridge: terminal read failed: {e}");
                        return;
                    }
                },
                r = stream.read(&mut from_dev) => match r {
                    Ok(0) | Err(_) => {
                        tracing::warn!(device = %name, "pty bridge: device disconnected");
                        break;
                    }
                    Ok(n) => {
                        if let Err(e) = write_master(&master, &from_dev[..n]).await {
                            tracing::warn!(device = %name, "pty bridge: terminal write failed: {e}");
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
        let sim = SimInstrument::new(
            &gonio_instrument::InstrumentFile::simulated(),
            Arc::new(Dark),
            1.0,
        )
        .expect("sim");
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
            while !got.ends_with(b"> ") {
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
        // Echo and CR, the answer (position 1 at power-up) and CR, then the prompt (FW102C manual).
        assert_eq!(text, "pos?\r1\r> ");
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
