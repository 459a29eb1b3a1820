//! The simulated USB power meter served on a Unix socket, so that a host in ANOTHER process (`gonio run` against
//! `gonio sim --link-dir`) reaches it like a USB device: bulk OUT/IN, class control-IN requests and clear-halt,
//! with the USB timeout enforced here as a device's host controller would.
//!
//! Framing (documented in ARCHITECTURE.md, "USB over a socket"; written here from that text, independently of
//! the driver's side): every message is a little-endian `u32` length and that many bytes. Requests start with an
//! operation byte: 1 bulk OUT (`u32` timeout ms, data), 2 bulk IN (`u32` timeout ms, `u32` max length),
//! 3 control IN (`u32` timeout ms, request type, request, `u16` value, `u16` index, `u16` max length),
//! 4 clear halt (endpoint), 5 describe. Replies start with a status byte: 0 OK (bulk OUT: `u32` bytes written;
//! IN: the data; describe: OUT endpoint, IN endpoint, interface, `u16` vendor id, `u16` product id, serial
//! number), 1 timeout (`u32` bytes transferred), 2 endpoint halted, 3 no device, 4 other (UTF-8 message).
//!
//! A disconnect fault behaves as a pulled USB cable: the device answers "no device" and closes the connection;
//! while it is down, new connections are closed at once; once it is back, a new connection opens it again.
//! A malformed request closes the connection (a confused host is disconnected, never answered with a guess).

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{UnixListener, UnixStream};
use tokio::task::JoinHandle;

use crate::instrument::{SimError, SimInstrument};
use crate::pm100::{SimUsbDevice, UsbSimError};

/// Largest request accepted (a USBTMC transfer is far smaller).
const MAX_FRAME: usize = 1 << 20;

/// The power meter `device` of a simulator, served on the socket at `path` until dropped.
#[derive(Debug)]
pub struct UsbSocketDevice {
    path: PathBuf,
    task: JoinHandle<()>,
}

impl UsbSocketDevice {
    /// Bind `path` (replacing a stale socket file) and serve the USB device `device` of `sim` there, one host
    /// connection at a time, on the current tokio runtime.
    pub fn serve(sim: &SimInstrument, device: &str, path: &Path) -> Result<UsbSocketDevice, SimError> {
        if !sim.usb_devices().iter().any(|d| d == device) {
            // usb_device gives the precise reason (unknown device, or not a USB one).
            sim.usb_device(device)?;
        }
        let err = |what: &str, e: std::io::Error| SimError::Pty {
            device: device.to_string(),
            message: format!("{what} {}: {e}", path.display()),
        };
        let _ = std::fs::remove_file(path);
        let listener = UnixListener::bind(path).map_err(|e| err("cannot bind the USB socket", e))?;
        let task = tokio::spawn(accept_loop(sim.clone(), device.to_string(), listener));
        tracing::info!(device, path = %path.display(), "simulated USB device served on a socket");
        Ok(UsbSocketDevice {
            path: path.to_path_buf(),
            task,
        })
    }

    /// The socket's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for UsbSocketDevice {
    fn drop(&mut self) {
        self.task.abort();
        let _ = std::fs::remove_file(&self.path);
    }
}

async fn accept_loop(sim: SimInstrument, name: String, listener: UnixListener) {
    loop {
        let mut conn = match listener.accept().await {
            Ok((conn, _)) => conn,
            Err(e) => {
                tracing::error!(device = %name, "usb socket: accept failed: {e}");
                return;
            }
        };
        match sim.usb_device(&name) {
            Ok(dev) => {
                tracing::debug!(device = %name, "usb socket: host connected");
                serve_host(&name, &dev, &mut conn).await;
                tracing::debug!(device = %name, "usb socket: host connection ended");
            }
            // Unplugged: the host's open fails (the connection closes unanswered).
            Err(e) => tracing::info!(device = %name, "usb socket: refused a connection: {e}"),
        }
    }
}

/// Answer one host's requests until it leaves, sends garbage, or the device is disconnected.
async fn serve_host(name: &str, dev: &SimUsbDevice, conn: &mut UnixStream) {
    loop {
        let mut len = [0u8; 4];
        if conn.read_exact(&mut len).await.is_err() {
            return;
        }
        let len = u32::from_le_bytes(len) as usize;
        if len == 0 || len > MAX_FRAME {
            tracing::warn!(device = %name, len, "usb socket: bad request length, closing");
            return;
        }
        let mut request = vec![0u8; len];
        if conn.read_exact(&mut request).await.is_err() {
            return;
        }
        let Some(reply) = answer(dev, &request).await else {
            tracing::warn!(device = %name, "usb socket: malformed request, closing");
            return;
        };
        let gone = reply.first() == Some(&3);
        let mut frame = (reply.len() as u32).to_le_bytes().to_vec();
        frame.extend_from_slice(&reply);
        if conn.write_all(&frame).await.is_err() || gone {
            return;
        }
    }
}

fn ms(b: [u8; 4]) -> Duration {
    Duration::from_millis(u64::from(u32::from_le_bytes(b)))
}

/// The reply to one request; None for a malformed request.
async fn answer(dev: &SimUsbDevice, request: &[u8]) -> Option<Vec<u8>> {
    let (&op, args) = request.split_first()?;
    let result: Result<Vec<u8>, UsbSimError> = match op {
        1 => {
            let (t, data) = args.split_first_chunk::<4>()?;
            dev.bulk_out(dev.bulk_out_endpoint(), data, ms(*t))
                .await
                .map(|n| (n as u32).to_le_bytes().to_vec())
        }
        2 => {
            let (t, rest) = args.split_first_chunk::<4>()?;
            let max = u32::from_le_bytes(*rest.first_chunk::<4>()?) as usize;
            let timeout = ms(*t);
            // The device side enforces the host's timeout, as the host controller would.
            match tokio::time::timeout(timeout, dev.bulk_in(dev.bulk_in_endpoint(), max, timeout)).await {
                Ok(r) => r,
                Err(_) => Err(UsbSimError::Timeout { transferred: 0 }),
            }
        }
        3 => {
            let (t, rest) = args.split_first_chunk::<4>()?;
            let (&[rt, rq], rest) = rest.split_first_chunk::<2>()?;
            let (value, rest) = rest.split_first_chunk::<2>()?;
            let (index, rest) = rest.split_first_chunk::<2>()?;
            let max = u16::from_le_bytes(*rest.first_chunk::<2>()?) as usize;
            dev.control_in(
                rt,
                rq,
                u16::from_le_bytes(*value),
                u16::from_le_bytes(*index),
                max,
                ms(*t),
            )
            .await
        }
        4 => {
            let &endpoint = args.first()?;
            dev.clear_halt(endpoint).await.map(|()| Vec::new())
        }
        5 => {
            let mut d = vec![dev.bulk_out_endpoint(), dev.bulk_in_endpoint(), 0];
            d.extend_from_slice(&dev.vendor_id().to_le_bytes());
            d.extend_from_slice(&dev.product_id().to_le_bytes());
            d.extend_from_slice(dev.serial_number().as_bytes());
            Ok(d)
        }
        _ => return None,
    };
    Some(match result {
        Ok(payload) => [vec![0], payload].concat(),
        Err(UsbSimError::Timeout { transferred }) => {
            [vec![1], (transferred as u32).to_le_bytes().to_vec()].concat()
        }
        Err(UsbSimError::Pipe { .. }) => vec![2],
        Err(UsbSimError::NoDevice) => vec![3],
        Err(e @ UsbSimError::InvalidParam(_)) => [vec![4], e.to_string().into_bytes()].concat(),
    })
}

#[cfg(test)]
mod tests {
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

    async fn call(conn: &mut UnixStream, request: &[u8]) -> Vec<u8> {
        conn.write_all(&(request.len() as u32).to_le_bytes())
            .await
            .expect("w");
        conn.write_all(request).await.expect("w");
        let mut len = [0u8; 4];
        conn.read_exact(&mut len).await.expect("reply length");
        let mut reply = vec![0u8; u32::from_le_bytes(len) as usize];
        conn.read_exact(&mut reply).await.expect("reply");
        reply
    }

    /// `*IDN?` through USBTMC frames written by hand (USBTMC spec: DEV_DEP_MSG_OUT = 1, REQUEST_DEV_DEP_MSG_IN = 2).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_host_describes_the_device_and_asks_idn_through_the_socket() {
        let sim = SimInstrument::new(
            &gonio_instrument::InstrumentFile::simulated(),
            Arc::new(Dark),
            1.0,
        )
        .expect("sim");
        let dir = std::env::temp_dir().join(format!("gonio-sim-usb-socket-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("mkdir");
        let path = dir.join("meter");
        let served = UsbSocketDevice::serve(&sim, "meter", &path).expect("serve");
        let mut conn = UnixStream::connect(served.path()).await.expect("connect");

        let d = call(&mut conn, &[5]).await;
        assert_eq!(d[0], 0, "OK");
        assert_eq!(u16::from_le_bytes([d[4], d[5]]), 0x1313, "Thorlabs vendor id");
        let (out_ep, in_ep) = (d[1], d[2]);
        assert!(in_ep & 0x80 != 0 && out_ep & 0x80 == 0);

        let msg = b"*IDN?\n";
        let mut frame = vec![1, 1, !1u8, 0];
        frame.extend_from_slice(&(msg.len() as u32).to_le_bytes());
        frame.extend_from_slice(&[1, 0, 0, 0]);
        frame.extend_from_slice(msg);
        frame.resize(frame.len().div_ceil(4) * 4, 0);
        let mut req = vec![1];
        req.extend_from_slice(&1000u32.to_le_bytes());
        req.extend_from_slice(&frame);
        let r = call(&mut conn, &req).await;
        assert_eq!(r[0], 0);
        assert_eq!(u32::from_le_bytes([r[1], r[2], r[3], r[4]]) as usize, frame.len());

        let mut ask = vec![2, 2, !2u8, 0];
        ask.extend_from_slice(&256u32.to_le_bytes());
        ask.extend_from_slice(&[0, 0, 0, 0]);
        let mut req = vec![1];
        req.extend_from_slice(&1000u32.to_le_bytes());
        req.extend_from_slice(&ask);
        assert_eq!(call(&mut conn, &req).await[0], 0);
        let mut req = vec![2];
        req.extend_from_slice(&1000u32.to_le_bytes());
        req.extend_from_slice(&512u32.to_le_bytes());
        let r = call(&mut conn, &req).await;
        assert_eq!(r[0], 0, "OK");
        let text = String::from_utf8_lossy(&r[13..]);
        assert!(text.starts_with("Thorlabs,PM100USB,"), "{text:?}");

        // A bulk IN with nothing to send times out after the host's timeout, with nothing transferred.
        let mut req = vec![2];
        req.extend_from_slice(&50u32.to_le_bytes());
        req.extend_from_slice(&512u32.to_le_bytes());
        assert_eq!(call(&mut conn, &req).await, vec![1, 0, 0, 0, 0]);

        // An unknown operation closes the connection without an answer.
        conn.write_all(&1u32.to_le_bytes()).await.expect("w");
        conn.write_all(&[99]).await.expect("w");
        let mut b = [0u8; 1];
        assert_eq!(conn.read(&mut b).await.expect("read"), 0, "closed");
        drop(served);
        assert!(!path.exists(), "the socket file is removed");
        let _ = std::fs::remove_dir_all(dir);
    }
}
