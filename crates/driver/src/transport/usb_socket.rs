//! A USB pipe carried over a Unix socket: how a simulated power meter in another process (`gonio sim
//! --link-dir`) is reached exactly like a USB device, so that a run against a separate simulator takes the same
//! code path as a run against the real instrument (the USBTMC and SCPI layers above cannot tell the difference).
//!
//! The framing is the one documented in ARCHITECTURE.md ("USB over a socket"): each request and each reply is a
//! little-endian `u32` length followed by that many bytes; a request starts with an operation byte, a reply with
//! a status byte. One request is in flight at a time (the socket is the device's single bulk/control channel).
//! The USB timeout travels with the request and is enforced by the device side; we wait that long plus
//! [`TRANSPORT_MARGIN`] for the reply, and a socket that fails or closes is a device that vanished
//! ([`UsbError::NoDevice`]), as when a USB cable is pulled.

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::usb::{BoxFuture, UsbError, UsbPipe};

/// Prefix of an instrument file's `port` naming a USB device behind a socket: `usb-socket:/path/to/socket`.
pub const PORT_PREFIX: &str = "usb-socket:";

/// Extra time allowed for the socket itself beyond the USB timeout the device enforces.
pub const TRANSPORT_MARGIN: Duration = Duration::from_secs(2);

/// Largest frame either side accepts (a USBTMC transfer is far smaller).
pub const MAX_FRAME: usize = 1 << 20;

/// Operation codes of a request.
mod op {
    pub const BULK_OUT: u8 = 1;
    pub const BULK_IN: u8 = 2;
    pub const CONTROL_IN: u8 = 3;
    pub const CLEAR_HALT: u8 = 4;
    pub const DESCRIBE: u8 = 5;
}

/// Status codes of a reply.
mod status {
    pub const OK: u8 = 0;
    pub const TIMEOUT: u8 = 1;
    pub const PIPE: u8 = 2;
    pub const NO_DEVICE: u8 = 3;
    pub const OTHER: u8 = 4;
}

/// What the device said about itself when the pipe was opened.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SocketDeviceInfo {
    pub bulk_out_endpoint: u8,
    pub bulk_in_endpoint: u8,
    pub interface_number: u8,
    pub vendor_id: u16,
    pub product_id: u16,
    pub serial_number: String,
}

/// A [`UsbPipe`] over a Unix socket (see the module doc).
#[derive(Debug)]
pub struct SocketUsbPipe {
    path: PathBuf,
    stream: Arc<Mutex<UnixStream>>,
    info: SocketDeviceInfo,
}

impl SocketUsbPipe {
    /// Connect to the device socket at `path` and ask the device for its endpoints and identity.
    /// Blocking (a local connect and one exchange); call it from the blocking pool in async code.
    pub fn open(path: &Path) -> Result<SocketUsbPipe, UsbError> {
        let stream = UnixStream::connect(path).map_err(|e| match e.kind() {
            std::io::ErrorKind::PermissionDenied => UsbError::Access(format!("{}: {e}", path.display())),
            _ => {
                tracing::debug!(path = %path.display(), "usb socket: cannot connect: {e}");
                UsbError::NoDevice
            }
        })?;
        let stream = Arc::new(Mutex::new(stream));
        let reply = exchange(&stream, path, &[op::DESCRIBE], TRANSPORT_MARGIN)?;
        let info = parse_describe(&reply)
            .ok_or_else(|| UsbError::Other(format!("{}: malformed device description", path.display())))?;
        tracing::info!(path = %path.display(), vid = info.vendor_id, pid = info.product_id,
            serial = %info.serial_number, "usb socket: device opened");
        Ok(SocketUsbPipe {
            path: path.to_path_buf(),
            stream,
            info,
        })
    }

    /// The device's identity as it described itself.
    pub fn info(&self) -> &SocketDeviceInfo {
        &self.info
    }

    /// Send one request on the blocking pool and wait for its reply payload (after an OK status).
    async fn call(&self, request: Vec<u8>, timeout: Duration) -> Result<Vec<u8>, UsbError> {
        let stream = Arc::clone(&self.stream);
        let path = self.path.clone();
        tokio::task::spawn_blocking(move || exchange(&stream, &path, &request, timeout + TRANSPORT_MARGIN))
            .await
            .map_err(|e| UsbError::Other(format!("usb socket worker: {e}")))?
    }
}

/// Parse a DESCRIBE reply payload: out, in, interface, vid, pid, then the serial number as UTF-8.
fn parse_describe(p: &[u8]) -> Option<SocketDeviceInfo> {
    let (&[out, inp, iface], rest) = p.split_first_chunk::<3>()?;
    let (vid, rest) = rest.split_first_chunk::<2>()?;
    let (pid, serial) = rest.split_first_chunk::<2>()?;
    Some(SocketDeviceInfo {
        bulk_out_endpoint: out,
        bulk_in_endpoint: inp,
        interface_number: iface,
        vendor_id: u16::from_le_bytes(*vid),
        product_id: u16::from_le_bytes(*pid),
        serial_number: String::from_utf8(serial.to_vec()).ok()?,
    })
}

/// One request/reply exchange under the stream's lock, with `wait` as the socket deadline. Returns the reply
/// payload after an OK status; every other status becomes the matching [`UsbError`].
fn exchange(
    stream: &Mutex<UnixStream>,
    path: &Path,
    request: &[u8],
    wait: Duration,
) -> Result<Vec<u8>, UsbError> {
    let mut s = stream
        .lock()
        .map_err(|_| UsbError::Other("usb socket: lock poisoned".into()))?;
    let gone = |what: &str, e: std::io::Error| {
        tracing::warn!(path = %path.display(), "usb socket: {what}: {e}");
        UsbError::NoDevice
    };
    s.set_read_timeout(Some(wait))
        .map_err(|e| gone("set timeout", e))?;
    s.set_write_timeout(Some(wait))
        .map_err(|e| gone("set timeout", e))?;
    let len = u32::try_from(request.len()).map_err(|_| UsbError::Other("request too large".into()))?;
    let mut frame = Vec::with_capacity(4 + request.len());
    frame.extend_from_slice(&len.to_le_bytes());
    frame.extend_from_slice(request);
    s.write_all(&frame).map_err(|e| gone("write", e))?;
    let mut len = [0u8; 4];
    s.read_exact(&mut len).map_err(|e| gone("read", e))?;
    let len = u32::from_le_bytes(len) as usize;
    if len == 0 || len > MAX_FRAME {
        return Err(gone(
            "read",
            std::io::Error::new(std::io::ErrorKind::InvalidData, format!("bad reply length {len}")),
        ));
    }
    let mut reply = vec![0u8; len];
    s.read_exact(&mut reply).map_err(|e| gone("read", e))?;
    let (&code, payload) = reply.split_first().ok_or(UsbError::NoDevice)?;
    match code {
        status::OK => Ok(payload.to_vec()),
        status::TIMEOUT => {
            let transferred = payload
                .first_chunk::<4>()
                .map(|b| u32::from_le_bytes(*b) as usize)
                .unwrap_or(0);
            Err(UsbError::Timeout { transferred })
        }
        status::PIPE => Err(UsbError::Pipe),
        status::NO_DEVICE => Err(UsbError::NoDevice),
        status::OTHER => Err(UsbError::Other(String::from_utf8_lossy(payload).into_owned())),
        other => Err(UsbError::Other(format!(
            "usb socket: unknown reply status {other}"
        ))),
    }
}

fn timeout_ms(timeout: Duration) -> [u8; 4] {
    u32::try_from(timeout.as_millis())
        .unwrap_or(u32::MAX)
        .to_le_bytes()
}

impl UsbPipe for SocketUsbPipe {
    fn bulk_out<'a>(&'a self, data: &'a [u8], timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>> {
        Box::pin(async move {
            let mut req = vec![op::BULK_OUT];
            req.extend_from_slice(&timeout_ms(timeout));
            req.extend_from_slice(data);
            let reply = self.call(req, timeout).await?;
            reply
                .first_chunk::<4>()
                .map(|b| u32::from_le_bytes(*b) as usize)
                .ok_or_else(|| UsbError::Other("usb socket: short bulk-out reply".into()))
        })
    }

    fn bulk_in(&self, max_len: usize, timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            let mut req = vec![op::BULK_IN];
            req.extend_from_slice(&timeout_ms(timeout));
            req.extend_from_slice(&u32::try_from(max_len).unwrap_or(u32::MAX).to_le_bytes());
            let data = self.call(req, timeout).await?;
            if data.len() > max_len {
                return Err(UsbError::Other(format!(
                    "usb socket: {} bytes for a {max_len}-byte transfer",
                    data.len()
                )));
            }
            Ok(data)
        })
    }

    fn control_in(
        &self,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
        timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            let mut req = vec![op::CONTROL_IN];
            req.extend_from_slice(&timeout_ms(timeout));
            req.extend_from_slice(&[request_type, request]);
            req.extend_from_slice(&value.to_le_bytes());
            req.extend_from_slice(&index.to_le_bytes());
            req.extend_from_slice(&u16::try_from(max_len).unwrap_or(u16::MAX).to_le_bytes());
            let data = self.call(req, timeout).await?;
            if data.len() > max_len {
                return Err(UsbError::Other(format!(
                    "usb socket: {} bytes for a {max_len}-byte control transfer",
                    data.len()
                )));
            }
            Ok(data)
        })
    }

    fn clear_halt(&self, endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>> {
        Box::pin(async move {
            self.call(vec![op::CLEAR_HALT, endpoint], Duration::from_secs(1))
                .await
                .map(|_| ())
        })
    }

    fn bulk_out_endpoint(&self) -> u8 {
        self.info.bulk_out_endpoint
    }

    fn bulk_in_endpoint(&self) -> u8 {
        self.info.bulk_in_endpoint
    }

    fn interface_number(&self) -> u8 {
        self.info.interface_number
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_description_is_parsed_and_a_short_one_refused() {
        let mut p = vec![0x02, 0x81, 0x00];
        p.extend_from_slice(&0x1313u16.to_le_bytes());
        p.extend_from_slice(&0x8072u16.to_le_bytes());
        p.extend_from_slice(b"P2000001");
        let info = parse_describe(&p).expect("valid");
        assert_eq!(info.vendor_id, 0x1313);
        assert_eq!(info.product_id, 0x8072);
        assert_eq!(info.bulk_in_endpoint, 0x81);
        assert_eq!(info.serial_number, "P2000001");
        for cut in 0..7 {
            assert!(parse_describe(&p[..cut]).is_none(), "{cut} bytes");
        }
    }

    /// A scripted device on the other end of a socket pair: replies are decoded into the right errors.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn statuses_map_to_usb_errors_and_a_closed_socket_is_a_vanished_device() {
        let dir = tempfile_dir();
        let path = dir.join("meter.sock");
        let listener = std::os::unix::net::UnixListener::bind(&path).expect("bind");
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().expect("accept");
            let mut replies: Vec<Vec<u8>> = vec![
                {
                    let mut d = vec![status::OK, 0x02, 0x81, 0x00];
                    d.extend_from_slice(&0x1313u16.to_le_bytes());
                    d.extend_from_slice(&0x8072u16.to_le_bytes());
                    d.extend_from_slice(b"S1");
                    d
                },
                vec![status::OK, 12, 0, 0, 0],
                vec![status::TIMEOUT, 3, 0, 0, 0],
                vec![status::PIPE],
                vec![status::OK, b'h', b'i'],
            ];
            replies.reverse();
            let mut seen = Vec::new();
            while let Some(reply) = replies.pop() {
                let mut len = [0u8; 4];
                s.read_exact(&mut len).expect("len");
                let mut req = vec![0u8; u32::from_le_bytes(len) as usize];
                s.read_exact(&mut req).expect("req");
                seen.push(req);
                s.write_all(&(reply.len() as u32).to_le_bytes()).expect("w");
                s.write_all(&reply).expect("w");
            }
            seen
        });
        let p = path.clone();
        let pipe = tokio::task::spawn_blocking(move || SocketUsbPipe::open(&p))
            .await
            .expect("join")
            .expect("open");
        assert_eq!(pipe.bulk_in_endpoint(), 0x81);
        assert_eq!(pipe.info().serial_number, "S1");
        let t = Duration::from_millis(250);
        assert_eq!(pipe.bulk_out(b"0123456789ab", t).await, Ok(12));
        assert_eq!(
            pipe.bulk_in(64, t).await,
            Err(UsbError::Timeout { transferred: 3 })
        );
        assert_eq!(pipe.bulk_in(64, t).await, Err(UsbError::Pipe));
        assert_eq!(
            pipe.bulk_in(1, t).await.map_err(|_| ()),
            Err(()),
            "more than asked for"
        );
        let seen = server.join().expect("server");
        assert_eq!(seen[0], vec![op::DESCRIBE]);
        let mut want = vec![op::BULK_OUT];
        want.extend_from_slice(&250u32.to_le_bytes());
        want.extend_from_slice(b"0123456789ab");
        assert_eq!(seen[1], want);
        let mut want = vec![op::BULK_IN];
        want.extend_from_slice(&250u32.to_le_bytes());
        want.extend_from_slice(&64u32.to_le_bytes());
        assert_eq!(seen[2], want);
        // The server is gone now: the device vanished.
        assert_eq!(pipe.bulk_in(64, t).await, Err(UsbError::NoDevice));
        assert_eq!(
            SocketUsbPipe::open(&path).map(|_| ()),
            Err(UsbError::NoDevice),
            "nobody listens any more"
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    fn tempfile_dir() -> PathBuf {
        let dir = std::env::temp_dir().join(format!("gonio-usb-socket-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("mkdir");
        dir
    }
}
