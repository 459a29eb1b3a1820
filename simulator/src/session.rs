//! The serial side shared by the RS-232 emulators: a byte-stream session between a host stream and one
//! emulator, with the fault injection applied to what the device sends.
//!
//! An emulator is plain synchronous code: it takes received bytes at a simulated time and returns what it sends
//! and when. The session task does the waiting (on the simulated clock) and the I/O.
//!
//! Timing is kept honest under load and at large time scales, where a real millisecond of scheduling delay is
//! many simulated ones: the host's end of the link ([`SerialStream`]) stamps every write with the simulated time
//! it was made, and the emulator learns when each byte was sent, not only when its task got to read it; and an
//! emulator hears when each of its replies reached the host ([`SerialEmulator::delivered`]). A device that
//! cannot take input for a while (the SMC100 after a set command) measures that while from when the host sent
//! the command, and it is never still busy with a reply the host has already read.

use std::collections::{BTreeMap, VecDeque};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream, ReadBuf};

use crate::clock::SimClock;
use crate::faults::{DeviceFaults, ReplyFate};

/// Bytes the device sends at simulated time `at_s` (one reply: the unit of fault injection).
#[derive(Debug, Clone, PartialEq)]
pub struct Output {
    pub at_s: f64,
    pub bytes: Vec<u8>,
}

/// The device side of a serial protocol.
pub trait SerialEmulator: Send + std::fmt::Debug {
    /// A new connection: forget any partial input line.
    fn reset_input(&mut self);
    /// Bytes received at `now_s`; returns what the device sends, in time order.
    fn receive(&mut self, data: &[u8], now_s: f64) -> Vec<Output>;
    /// Bytes the host sent at `sent_s`, received by the device's task at `now_s` (not before: the task may have
    /// been busy or not scheduled). A device whose behaviour depends on when input arrives uses `sent_s`.
    fn receive_sent(&mut self, data: &[u8], _sent_s: f64, now_s: f64) -> Vec<Output> {
        self.receive(data, now_s)
    }
    /// When the device next has something unsolicited to say (alerts), if ever.
    fn next_event_s(&mut self, now_s: f64) -> Option<f64>;
    /// Unsolicited output due at `now_s`.
    fn poll_events(&mut self, now_s: f64) -> Vec<Output>;
    /// Stop every axis at once (the daemon's emergency stop), as the device's own stop would.
    fn estop(&mut self, now_s: f64);
    /// `out`, one of the replies this emulator returned, has reached the host at `now_s` (or was lost on the
    /// line by a fault at that moment): the host may answer it from now on. The session may deliver a reply a
    /// hair before its wire time is over (see [`SHORTEST_REAL_WAIT`]), never after the host has it.
    fn delivered(&mut self, _out: &Output, _now_s: f64) {}
    /// Command lines the device lost because they came while it could not take them (SMC100 input pacing), by
    /// command code.
    fn lost_input(&self) -> BTreeMap<String, u64> {
        BTreeMap::new()
    }
}

pub type SharedEmulator = Arc<Mutex<dyn SerialEmulator>>;

fn lock(emu: &SharedEmulator) -> std::sync::MutexGuard<'_, dyn SerialEmulator + 'static> {
    emu.lock().unwrap_or_else(|e| e.into_inner())
}

/// The serial line's speed: a reply is complete only once its last byte has crossed the wire (8N1: ten bits a
/// byte), so a 57600-baud SMC100 status reply takes about 2 ms, as on the real link. And the device's own time
/// to answer before its reply starts (the hardware's `reply_latency_ms`: the SMC100 manual gives about 10 ms to
/// execute a position query); what a query reports is taken when it arrives.
///
/// A device may also act on what it is sent some time after it was sent (`with_act_after_s`: the hardware's
/// `position_sampled_ms`, when a controller takes the position it reports): it then answers that much sooner
/// after acting, the same time after the query.
#[derive(Debug, Clone, Copy)]
pub struct LineRate {
    bytes_per_s: f64,
    latency_s: f64,
    act_after_s: f64,
}

impl LineRate {
    /// `baud` bits per second, 8N1 framing; a zero or absurd rate means an instantaneous line.
    pub fn from_baud(baud: u32) -> LineRate {
        LineRate {
            bytes_per_s: f64::from(baud) / 10.0,
            latency_s: 0.0,
            act_after_s: 0.0,
        }
    }

    /// The device acting on each command `act_after_s` after it was sent, within its latency (negative or not a
    /// number: at once).
    pub fn with_act_after_s(self, act_after_s: f64) -> LineRate {
        LineRate {
            act_after_s: if act_after_s.is_finite() {
                act_after_s.clamp(0.0, self.latency_s)
            } else {
                0.0
            },
            ..self
        }
    }

    /// The device answering each query `latency_s` after it arrives (negative or not a number: at once).
    pub fn with_latency_s(self, latency_s: f64) -> LineRate {
        LineRate {
            latency_s: if latency_s.is_finite() {
                latency_s.max(0.0)
            } else {
                0.0
            },
            ..self
        }
    }

    /// Simulated seconds to send `n` bytes.
    fn wire_s(&self, n: usize) -> f64 {
        if self.bytes_per_s > 0.0 {
            n as f64 / self.bytes_per_s
        } else {
            0.0
        }
    }
}

/// Below this much real time, a reply is written at once rather than after a timer: tokio's timer rounds every
/// wait up to its next 1 ms tick, which at a large time scale would cost each exchange a real millisecond (a
/// thousand simulated seconds at 1e6) instead of microseconds. The reply is then early by less than this in real
/// time, far below what the time scale already blurs.
const SHORTEST_REAL_WAIT: Duration = Duration::from_micros(50);

/// When the bytes of a link's writes were sent: per write not yet read through by the device, the count of
/// bytes written up to its end and the simulated time of the write.
#[derive(Debug, Default)]
struct Stamps {
    written: u64,
    writes: VecDeque<(u64, f64)>,
}

/// The host's end of a simulated serial link: a byte stream whose writes are stamped with the simulated time
/// they were made (see the module doc), so that the device takes each line at the moment it was sent.
#[derive(Debug)]
pub struct SerialStream {
    io: DuplexStream,
    stamps: Arc<Mutex<Stamps>>,
    clock: SimClock,
}

/// The device's end of a link: the bytes and, for each, when the host sent it.
#[derive(Debug)]
pub(crate) struct DeviceEnd {
    io: DuplexStream,
    stamps: Arc<Mutex<Stamps>>,
    read: u64,
}

/// A link with `capacity` bytes of buffering each way: the host's end and the device's.
pub(crate) fn link(clock: SimClock, capacity: usize) -> (SerialStream, DeviceEnd) {
    let (host, dev) = tokio::io::duplex(capacity);
    let stamps = Arc::new(Mutex::new(Stamps::default()));
    (
        SerialStream {
            io: host,
            stamps: Arc::clone(&stamps),
            clock,
        },
        DeviceEnd {
            io: dev,
            stamps,
            read: 0,
        },
    )
}

impl DeviceEnd {
    /// Split `n` bytes just read into the runs sent by one write each: (length, simulated time sent). Bytes
    /// with no stamp (none are expected) count as sent at `now_s`.
    fn runs(&mut self, n: usize, now_s: f64) -> Vec<(usize, f64)> {
        let mut stamps = self.stamps.lock().unwrap_or_else(|e| e.into_inner());
        let end = self.read + n as u64;
        let mut runs = Vec::new();
        while self.read < end {
            let (write_end, sent_s) = stamps.writes.front().copied().unwrap_or((end, now_s));
            let upto = write_end.clamp(self.read + 1, end);
            runs.push(((upto - self.read) as usize, sent_s.min(now_s)));
            self.read = upto;
            if write_end <= upto {
                stamps.writes.pop_front();
            }
        }
        runs
    }
}

impl AsyncRead for SerialStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_read(cx, buf)
    }
}

impl AsyncWrite for SerialStream {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        // The stamp is recorded under the lock the device takes to read stamps, held across the write, so that
        // the device never reads bytes whose stamp is not there yet.
        let mut stamps = this.stamps.lock().unwrap_or_else(|e| e.into_inner());
        let sent_s = this.clock.now_s();
        let r = Pin::new(&mut this.io).poll_write(cx, data);
        if let Poll::Ready(Ok(n)) = r
            && n > 0
        {
            stamps.written += n as u64;
            let end = stamps.written;
            stamps.writes.push_back((end, sent_s));
        }
        r
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_shutdown(cx)
    }
}

/// Serve one host connection until the host closes it or the device vanishes (fault), which closes the stream
/// so that the host reads EOF.
pub(crate) async fn serve(
    mut end: DeviceEnd,
    emu: SharedEmulator,
    faults: DeviceFaults,
    clock: SimClock,
    device: String,
    line: LineRate,
) {
    lock(&emu).reset_input();
    let mut buf = [0u8; 1024];
    loop {
        let now = clock.now_s();
        if !faults.injector().link_up(now) {
            faults.injector().note_disconnect(&device, now);
            return;
        }
        let next_event = lock(&emu).next_event_s(now);
        let wake = match (next_event, faults.injector().next_disconnect_s(now)) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let outputs = tokio::select! {
            r = end.io.read(&mut buf) => match r {
                Ok(0) | Err(_) => {
                    tracing::debug!(device, "host closed the serial connection");
                    return;
                }
                Ok(n) => {
                    let now = clock.now_s();
                    let mut outputs = Vec::new();
                    let mut data = buf.get(..n).unwrap_or_default();
                    for (len, sent_s) in end.runs(n, now) {
                        let (run, rest) = data.split_at(len.min(data.len()));
                        data = rest;
                        tracing::trace!(device, rx = %String::from_utf8_lossy(run).escape_debug(), sent_s, "device received");
                        // Acted on when the device gets to it: a look ahead of at most its latency.
                        let at_s = (sent_s + line.act_after_s).max(now);
                        outputs.extend(lock(&emu).receive_sent(run, sent_s, at_s));
                    }
                    outputs
                }
            },
            _ = clock.sleep_until_s(wake.unwrap_or(0.0)), if wake.is_some() => {
                // Converting to tokio instants may round a hair early: the event is due at `wake` at the latest.
                let at = clock.now_s().max(wake.unwrap_or(0.0));
                lock(&emu).poll_events(at)
            }
        };
        if !send(&mut end.io, &emu, outputs, &faults, &clock, &device, line).await {
            faults.injector().note_disconnect(&device, clock.now_s());
            return;
        }
    }
}

/// Write the outputs at their times; false when the link went down (or the host vanished) meanwhile.
async fn send(
    io: &mut DuplexStream,
    emu: &SharedEmulator,
    outputs: Vec<Output>,
    faults: &DeviceFaults,
    clock: &SimClock,
    device: &str,
    line: LineRate,
) -> bool {
    for out in outputs {
        let delay = faults.reply_delay_s();
        let done_s = out.at_s + (line.latency_s - line.act_after_s) + delay + line.wire_s(out.bytes.len());
        if clock.real_duration(done_s - clock.now_s()) >= SHORTEST_REAL_WAIT {
            clock.sleep_until_s(done_s).await;
        }
        let now = clock.now_s();
        if !faults.injector().link_up(now) {
            return false;
        }
        // Before the host can see it: whatever the host sends once it has this reply must find the device
        // done with it, however early the shortcut above wrote it.
        lock(emu).delivered(&out, now);
        let ReplyFate::Send(bytes) = faults.reply(out.bytes) else {
            continue;
        };
        tracing::debug!(device, tx = %String::from_utf8_lossy(&bytes).escape_debug(), "device sent");
        if io.write_all(&bytes).await.is_err() || io.flush().await.is_err() {
            // The host end is gone; nothing more to do, and this is not a fault.
            return true;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn each_byte_carries_the_time_its_write_was_made() {
        let clock = SimClock::new(10.0);
        let (mut host, mut dev) = link(clock, 1024);
        host.write_all(b"1PA5\r\n").await.expect("write");
        tokio::time::advance(Duration::from_millis(100)).await;
        host.write_all(b"1TE\r\n").await.expect("write");
        tokio::time::advance(Duration::from_millis(100)).await;
        // The device's task reads late, both writes at once: each keeps its own time.
        let mut buf = [0u8; 64];
        let n = dev.io.read(&mut buf).await.expect("read");
        assert_eq!(&buf[..n], b"1PA5\r\n1TE\r\n");
        let runs = dev.runs(n, clock.now_s());
        assert_eq!(runs.len(), 2, "{runs:?}");
        assert_eq!(runs[0].0, 6);
        assert_eq!(runs[1].0, 5);
        assert!(runs[0].1.abs() < 1e-6, "{runs:?}");
        assert!((runs[1].1 - 1.0).abs() < 1e-6, "{runs:?}");
        // A write read in two pieces: both pieces carry its time.
        host.write_all(b"2TS\r\n").await.expect("write");
        let t = clock.now_s();
        tokio::time::advance(Duration::from_millis(100)).await;
        let n = dev.io.read(&mut buf[..2]).await.expect("read");
        assert_eq!(dev.runs(n, clock.now_s()), vec![(2, t)]);
        let n = dev.io.read(&mut buf).await.expect("read");
        assert_eq!(dev.runs(n, clock.now_s()), vec![(3, t)]);
    }
}
