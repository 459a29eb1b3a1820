//! A line-oriented byte-stream port with exactly one owner.
//!
//! Several controllers daisy-chained on one serial port share one [`LinePort`]. An exchange (write a request,
//! read its reply) holds the port's *reader* lock for its whole duration, so requests are serialised and a reply
//! is always read by the request that caused it; the driver matches it (address, message id) and discards stale
//! lines with a trace. The *writer* has its own lock, held only while one line is written: a stop can therefore
//! be written at once by [`LinePort::send_priority`] even while another exchange waits for its reply.
//!
//! Three kinds of link, one code path above them:
//! - a real serial port or a pseudo-terminal opened by path with `serialport` (blocking I/O on a dedicated reader
//!   thread with a short read timeout, writes on tokio's blocking pool, so a blocked read never blocks the runtime);
//! - any in-memory `AsyncRead + AsyncWrite` stream (for example the simulator's `DuplexStream`).
//!
//! A lost link is reported as [`TransportError::Disconnected`]; [`LinePort::reconnect`] opens it again.

use std::io::{self, Read, Write};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadHalf, WriteHalf};
use tokio::sync::{Mutex, MutexGuard, mpsc};
use tokio::time::Instant;

use super::escape_bytes;

/// Longest line accepted before the buffer is declared garbage (no device here sends lines this long).
const MAX_LINE: usize = 4096;

/// Transport-level failures; drivers add the device and request context.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransportError {
    #[error("timed out")]
    Timeout,
    #[error("link lost: {0}")]
    Disconnected(String),
    #[error("garbled input: {0}")]
    Garbled(String),
}

/// An in-memory or otherwise async byte stream.
pub trait AsyncStream: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> AsyncStream for T {}

/// A boxed async stream.
pub type BoxStream = Box<dyn AsyncStream>;

/// Serial line settings for a port opened by path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    pub path: String,
    pub baud: u32,
    /// XON/XOFF software flow control (the SMC100 uses it).
    pub xon_xoff: bool,
}

impl SerialSettings {
    /// Settings for an instrument-file device on a real port or pty path (`None` for the embedded simulator or
    /// a USB device): the file's baud rate or the protocol's factory default, XON/XOFF for the SMC100.
    pub fn for_device(device: &gonio_instrument::Device) -> Option<SerialSettings> {
        // "sim" and "sim-pty" name the simulator, not a path (the rig opens a sim-pty device by its terminal).
        let path = device
            .port
            .as_deref()
            .filter(|p| *p != "sim" && *p != gonio_instrument::SIM_PTY_PORT)?;
        if device.protocol == gonio_instrument::Protocol::Pm100 {
            return None;
        }
        Some(SerialSettings {
            path: path.to_string(),
            baud: device.line_baud(),
            xon_xoff: device.protocol == gonio_instrument::Protocol::Smc100,
        })
    }
}

/// How to (re)open a port.
#[derive(Clone)]
pub enum PortOpener {
    /// A serial port or a pseudo-terminal, by path.
    Serial(SerialSettings),
    /// Any async stream; the closure is called again on reconnect.
    Stream(Arc<dyn Fn() -> io::Result<BoxStream> + Send + Sync>),
}

impl std::fmt::Debug for PortOpener {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PortOpener::Serial(s) => f.debug_tuple("Serial").field(s).finish(),
            PortOpener::Stream(_) => f.write_str("Stream(..)"),
        }
    }
}

enum ReadSource {
    Stream(ReadHalf<BoxStream>),
    Serial(mpsc::Receiver<io::Result<Vec<u8>>>),
    Closed(String),
}

enum WriteSink {
    Stream(WriteHalf<BoxStream>),
    Serial(Arc<std::sync::Mutex<Box<dyn serialport::SerialPort>>>),
    Closed(String),
}

/// The read side of a port: a source plus the bytes received but not yet consumed.
struct Reader {
    source: ReadSource,
    buf: Vec<u8>,
}

/// One owner for one port. Cheap to share behind an `Arc`.
pub struct LinePort {
    name: String,
    opener: PortOpener,
    reader: Mutex<Reader>,
    writer: Mutex<WriteSink>,
}

impl std::fmt::Debug for LinePort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinePort")
            .field("name", &self.name)
            .field("opener", &self.opener)
            .finish()
    }
}

impl LinePort {
    /// Open a port. `name` appears in traces and errors (e.g. "arms").
    pub fn open(name: impl Into<String>, opener: PortOpener) -> Result<LinePort, TransportError> {
        let name = name.into();
        let (source, sink) = open_link(&name, &opener)?;
        tracing::info!(port = %name, ?opener, "port opened");
        Ok(LinePort {
            name,
            opener,
            reader: Mutex::new(Reader {
                source,
                buf: Vec::new(),
            }),
            writer: Mutex::new(sink),
        })
    }

    /// Wrap one already-open stream; reconnecting is impossible (the stream cannot be made again).
    pub fn from_stream(name: impl Into<String>, stream: BoxStream) -> LinePort {
        let cell = std::sync::Mutex::new(Some(stream));
        let opener = PortOpener::Stream(Arc::new(move || {
            cell.lock().ok().and_then(|mut s| s.take()).ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::NotConnected,
                    "the in-memory stream cannot be reopened",
                )
            })
        }));
        // The first call cannot fail: the cell holds the stream.
        match LinePort::open(name, opener.clone()) {
            Ok(p) => p,
            Err(e) => LinePort {
                name: "unopenable".into(),
                opener,
                reader: Mutex::new(Reader {
                    source: ReadSource::Closed(e.to_string()),
                    buf: Vec::new(),
                }),
                writer: Mutex::new(WriteSink::Closed(e.to_string())),
            },
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Start an exchange: holds the reader until the guard drops, so no other request can interleave.
    pub async fn session(&self) -> Session<'_> {
        Session {
            port: self,
            reader: self.reader.lock().await,
        }
    }

    /// Write one whole line now, without waiting for any exchange in flight (for stops). No reply is read here.
    pub async fn send_priority(&self, bytes: &[u8], deadline: Instant) -> Result<(), TransportError> {
        tracing::debug!(port = %self.name, tx = %escape_bytes(bytes), "priority write");
        let mut w = self.writer.lock().await;
        write_sink(&mut w, bytes, deadline).await
    }

    /// Close and reopen the link (after a disconnect). Buffered input is dropped.
    pub async fn reconnect(&self) -> Result<(), TransportError> {
        let mut r = self.reader.lock().await;
        let mut w = self.writer.lock().await;
        // Close first so a serial port is released before it is opened again (ports are opened exclusively).
        r.source = ReadSource::Closed("reconnecting".into());
        *w = WriteSink::Closed("reconnecting".into());
        r.buf.clear();
        // A serial port is opened exclusively and the old reader thread releases its handle within one read
        // timeout (50 ms): try a few times before giving up.
        let mut attempt = 0;
        let (source, sink) = loop {
            attempt += 1;
            match open_link(&self.name, &self.opener) {
                Ok(link) => break link,
                Err(e) if attempt < 5 && matches!(self.opener, PortOpener::Serial(_)) => {
                    tracing::warn!(port = %self.name, attempt, error = %e, "reopen failed; retrying");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                Err(e) => return Err(e),
            }
        };
        r.source = source;
        *w = sink;
        tracing::info!(port = %self.name, "port reconnected");
        Ok(())
    }
}

/// An exchange in progress on a port (see [`LinePort::session`]).
pub struct Session<'a> {
    port: &'a LinePort,
    reader: MutexGuard<'a, Reader>,
}

impl std::fmt::Debug for Session<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session").field("port", &self.port.name).finish()
    }
}

impl Session<'_> {
    /// Drop whatever arrived before this request (stale replies, alerts): traced, never silently.
    pub async fn discard_stale(&mut self) -> Result<(), TransportError> {
        // Take whatever has already arrived since the last exchange, without waiting for more. (Not a read with a
        // deadline of "now": tokio's timer rounds every deadline up to its next 1 ms tick, which cost a whole
        // tick per exchange, the largest part of an exchange's time over a pseudo-terminal.)
        while fill_ready(&mut self.reader).await? {}
        if !self.reader.buf.is_empty() {
            tracing::debug!(port = %self.port.name, stale = %escape_bytes(&self.reader.buf), "discarding stale input");
            self.reader.buf.clear();
        }
        Ok(())
    }

    /// Write bytes (one whole request).
    pub async fn send(&mut self, bytes: &[u8], deadline: Instant) -> Result<(), TransportError> {
        tracing::debug!(port = %self.port.name, tx = %escape_bytes(bytes), "write");
        let mut w = self.port.writer.lock().await;
        write_sink(&mut w, bytes, deadline).await
    }

    /// Read one line ending in `\n`; the terminator and a preceding `\r` are removed.
    pub async fn read_line(&mut self, deadline: Instant) -> Result<Vec<u8>, TransportError> {
        self.read_until(b"\n", deadline).await.map(|mut line| {
            if line.last() == Some(&b'\r') {
                line.pop();
            }
            line
        })
    }

    /// Read up to and including `pattern`; returns what came before it.
    pub async fn read_until(&mut self, pattern: &[u8], deadline: Instant) -> Result<Vec<u8>, TransportError> {
        loop {
            if let Some(at) = find(&self.reader.buf, pattern) {
                let rest = self.reader.buf.split_off(at + pattern.len());
                let mut line = std::mem::replace(&mut self.reader.buf, rest);
                line.truncate(at);
                tracing::debug!(port = %self.port.name, rx = %escape_bytes(&line), "read");
                return Ok(line);
            }
            if self.reader.buf.len() > MAX_LINE {
                let junk = std::mem::take(&mut self.reader.buf);
                tracing::warn!(port = %self.port.name, bytes = junk.len(), "line too long, discarded");
                return Err(TransportError::Garbled(format!(
                    "{} bytes without a terminator",
                    junk.len()
                )));
            }
            fill(&mut self.reader, deadline).await?;
        }
    }
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || hay.len() < needle.len() {
        return None;
    }
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Move the bytes that are already available into the buffer, without waiting: `Ok(true)` when some were,
/// `Ok(false)` when none are pending.
async fn fill_ready(reader: &mut Reader) -> Result<bool, TransportError> {
    match &mut reader.source {
        ReadSource::Closed(why) => Err(TransportError::Disconnected(why.clone())),
        ReadSource::Stream(s) => {
            let mut chunk = [0u8; 512];
            let mut buf = tokio::io::ReadBuf::new(&mut chunk);
            // One poll of the stream; `Pending` (nothing there yet) ends the loop instead of waiting.
            let polled = std::future::poll_fn(|cx| {
                std::task::Poll::Ready(std::pin::Pin::new(&mut *s).poll_read(cx, &mut buf))
            })
            .await;
            match polled {
                std::task::Poll::Pending => Ok(false),
                std::task::Poll::Ready(Ok(())) if buf.filled().is_empty() => {
                    reader.source = ReadSource::Closed("end of stream".into());
                    Err(TransportError::Disconnected("end of stream".into()))
                }
                std::task::Poll::Ready(Ok(())) => {
                    reader.buf.extend_from_slice(buf.filled());
                    Ok(true)
                }
                std::task::Poll::Ready(Err(e)) => {
                    let why = e.to_string();
                    reader.source = ReadSource::Closed(why.clone());
                    Err(TransportError::Disconnected(why))
                }
            }
        }
        ReadSource::Serial(rx) => match rx.try_recv() {
            Ok(Ok(bytes)) => {
                reader.buf.extend_from_slice(&bytes);
                Ok(true)
            }
            Ok(Err(e)) => {
                let why = e.to_string();
                reader.source = ReadSource::Closed(why.clone());
                Err(TransportError::Disconnected(why))
            }
            Err(mpsc::error::TryRecvError::Empty) => Ok(false),
            Err(mpsc::error::TryRecvError::Disconnected) => {
                reader.source = ReadSource::Closed("reader thread ended".into());
                Err(TransportError::Disconnected("reader thread ended".into()))
            }
        },
    }
}

/// Read one chunk into the buffer, or fail at the deadline.
async fn fill(reader: &mut Reader, deadline: Instant) -> Result<(), TransportError> {
    match &mut reader.source {
        ReadSource::Closed(why) => Err(TransportError::Disconnected(why.clone())),
        ReadSource::Stream(s) => {
            let mut chunk = [0u8; 512];
            match tokio::time::timeout_at(deadline, s.read(&mut chunk)).await {
                Err(_) => Err(TransportError::Timeout),
                Ok(Ok(0)) => {
                    reader.source = ReadSource::Closed("end of stream".into());
                    Err(TransportError::Disconnected("end of stream".into()))
                }
                Ok(Ok(n)) => {
                    reader.buf.extend_from_slice(chunk.get(..n).unwrap_or_default());
                    Ok(())
                }
                Ok(Err(e)) => {
                    let why = e.to_string();
                    reader.source = ReadSource::Closed(why.clone());
                    Err(TransportError::Disconnected(why))
                }
            }
        }
        ReadSource::Serial(rx) => match tokio::time::timeout_at(deadline, rx.recv()).await {
            Err(_) => Err(TransportError::Timeout),
            Ok(Some(Ok(bytes))) => {
                reader.buf.extend_from_slice(&bytes);
                Ok(())
            }
            Ok(Some(Err(e))) => {
                let why = e.to_string();
                reader.source = ReadSource::Closed(why.clone());
                Err(TransportError::Disconnected(why))
            }
            Ok(None) => {
                reader.source = ReadSource::Closed("reader thread ended".into());
                Err(TransportError::Disconnected("reader thread ended".into()))
            }
        },
    }
}

async fn write_sink(sink: &mut WriteSink, bytes: &[u8], deadline: Instant) -> Result<(), TransportError> {
    let result = match sink {
        WriteSink::Closed(why) => return Err(TransportError::Disconnected(why.clone())),
        WriteSink::Stream(s) => {
            match tokio::time::timeout_at(deadline, async {
                s.write_all(bytes).await?;
                s.flush().await
            })
            .await
            {
                Err(_) => return Err(TransportError::Timeout),
                Ok(r) => r,
            }
        }
        WriteSink::Serial(port) => {
            let port = Arc::clone(port);
            let data = bytes.to_vec();
            let job = tokio::task::spawn_blocking(move || -> io::Result<()> {
                let mut p = port
                    .lock()
                    .map_err(|_| io::Error::other("serial port lock poisoned"))?;
                p.write_all(&data)?;
                p.flush()
            });
            match tokio::time::timeout_at(deadline, job).await {
                Err(_) => return Err(TransportError::Timeout),
                Ok(Err(join)) => Err(io::Error::other(join.to_string())),
                Ok(Ok(r)) => r,
            }
        }
    };
    result.map_err(|e| {
        let why = e.to_string();
        *sink = WriteSink::Closed(why.clone());
        TransportError::Disconnected(why)
    })
}

fn open_link(name: &str, opener: &PortOpener) -> Result<(ReadSource, WriteSink), TransportError> {
    match opener {
        PortOpener::Stream(make) => {
            let stream = make().map_err(|e| TransportError::Disconnected(e.to_string()))?;
            let (r, w) = tokio::io::split(stream);
            Ok((ReadSource::Stream(r), WriteSink::Stream(w)))
        }
        PortOpener::Serial(settings) => open_serial(name, settings),
    }
}

fn open_serial(name: &str, s: &SerialSettings) -> Result<(ReadSource, WriteSink), TransportError> {
    let flow = if s.xon_xoff {
        serialport::FlowControl::Software
    } else {
        serialport::FlowControl::None
    };
    let port = serialport::new(&s.path, s.baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(flow)
        // Short, so the reader thread notices promptly that the port owner has gone away.
        .timeout(Duration::from_millis(50))
        .open()
        .map_err(|e| TransportError::Disconnected(format!("cannot open {}: {e}", s.path)))?;
    let read_port = port
        .try_clone()
        .map_err(|e| TransportError::Disconnected(format!("{}: {e}", s.path)))?;
    let (tx, rx) = mpsc::channel(64);
    let thread_name = format!("serial-rx {name}");
    std::thread::Builder::new()
        .name(thread_name)
        .spawn(move || serial_reader(read_port, tx))
        .map_err(|e| TransportError::Disconnected(format!("cannot start the reader thread: {e}")))?;
    Ok((
        ReadSource::Serial(rx),
        WriteSink::Serial(Arc::new(std::sync::Mutex::new(port))),
    ))
}

/// Blocking reader: forwards chunks until the port fails or the owner drops the receiver.
fn serial_reader(mut port: Box<dyn serialport::SerialPort>, tx: mpsc::Sender<io::Result<Vec<u8>>>) {
    let mut chunk = [0u8; 512];
    loop {
        match port.read(&mut chunk) {
            Ok(0) => {
                let _ = tx.blocking_send(Err(io::Error::new(io::ErrorKind::UnexpectedEof, "port closed")));
                return;
            }
            Ok(n) => {
                if tx
                    .blocking_send(Ok(chunk.get(..n).unwrap_or_default().to_vec()))
                    .is_err()
                {
                    return;
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
                ) =>
            {
                if tx.is_closed() {
                    return;
                }
            }
            Err(e) => {
                let _ = tx.blocking_send(Err(e));
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serial_settings_follow_the_instrument_file() {
        let mut file = gonio_instrument::InstrumentFile::simulated();
        let arms = file
            .instrument
            .devices
            .iter_mut()
            .find(|d| d.name == "arms")
            .expect("arms");
        assert_eq!(
            SerialSettings::for_device(arms),
            None,
            "port = \"sim\" is the embedded simulator"
        );
        arms.port = Some("/dev/ttyUSB3".into());
        assert_eq!(
            SerialSettings::for_device(arms),
            Some(SerialSettings {
                path: "/dev/ttyUSB3".into(),
                baud: 57_600,
                xon_xoff: true
            })
        );
        arms.baud = Some(9600);
        assert_eq!(SerialSettings::for_device(arms).map(|s| s.baud), Some(9600));
    }

    #[tokio::test(start_paused = true)]
    async fn stale_input_is_dropped_and_the_next_reply_read() {
        use tokio::io::AsyncWriteExt;
        let (host, mut dev) = tokio::io::duplex(256);
        let port = LinePort::from_stream("t", Box::new(host));
        dev.write_all(b"1TP9.5\r\nhalf a li").await.expect("write");
        tokio::task::yield_now().await;
        let mut s = port.session().await;
        s.discard_stale().await.expect("discard");
        dev.write_all(b"1TP7\r\n").await.expect("write");
        let line = s
            .read_line(Instant::now() + Duration::from_millis(100))
            .await
            .expect("line");
        assert_eq!(line, b"1TP7");
        // A closed far end is reported, not waited for.
        drop(dev);
        drop(s);
        let mut s = port.session().await;
        assert!(matches!(
            s.discard_stale().await,
            Err(TransportError::Disconnected(_))
        ));
    }

    #[test]
    fn dropping_stale_input_uses_no_timer() {
        // On a runtime without a time driver any timer panics. Dropping stale input must not wait for one: a read
        // with a deadline of "now" still lasts until the timer's next 1 ms tick, once per exchange.
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("runtime");
        rt.block_on(async {
            use tokio::io::AsyncWriteExt;
            let (host, mut dev) = tokio::io::duplex(256);
            let port = LinePort::from_stream("t", Box::new(host));
            dev.write_all(b"stale\r\n").await.expect("write");
            let mut s = port.session().await;
            s.discard_stale().await.expect("with input pending");
            s.discard_stale().await.expect("with nothing pending");
        });
    }

    #[test]
    fn find_locates_terminators() {
        assert_eq!(find(b"abc\r\n", b"\n"), Some(4));
        assert_eq!(find(b"3\r> ", b"> "), Some(2));
        assert_eq!(find(b">", b"> "), None);
        assert_eq!(find(b"", b"\n"), None);
    }
}
