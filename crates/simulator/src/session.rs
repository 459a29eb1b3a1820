//! The serial side shared by the RS-232 emulators: a byte-stream session between a host stream and one
//! emulator, with the fault injection applied to what the device sends.
//!
//! An emulator is plain synchronous code: it takes received bytes at a simulated time and returns what it sends
//! and when. The session task does the waiting (on the simulated clock) and the I/O.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

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
    /// When the device next has something unsolicited to say (alerts), if ever.
    fn next_event_s(&mut self, now_s: f64) -> Option<f64>;
    /// Unsolicited output due at `now_s`.
    fn poll_events(&mut self, now_s: f64) -> Vec<Output>;
    /// Stop every axis at once (the daemon's emergency stop), as the device's own stop would.
    fn estop(&mut self, now_s: f64);
}

pub type SharedEmulator = Arc<Mutex<dyn SerialEmulator>>;

fn lock(emu: &SharedEmulator) -> std::sync::MutexGuard<'_, dyn SerialEmulator + 'static> {
    emu.lock().unwrap_or_else(|e| e.into_inner())
}

/// The serial line's speed: a reply is complete only once its last byte has crossed the wire (8N1: ten bits a
/// byte), so a 57600-baud SMC100 status reply takes about 2 ms, as on the real link.
#[derive(Debug, Clone, Copy)]
pub struct LineRate {
    bytes_per_s: f64,
}

impl LineRate {
    /// `baud` bits per second, 8N1 framing; a zero or absurd rate means an instantaneous line.
    pub fn from_baud(baud: u32) -> LineRate {
        LineRate {
            bytes_per_s: f64::from(baud) / 10.0,
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

/// Serve one host connection until the host closes it or the device vanishes (fault), which closes the stream
/// so that the host reads EOF.
pub async fn serve(
    mut io: DuplexStream,
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
            r = io.read(&mut buf) => match r {
                Ok(0) | Err(_) => {
                    tracing::debug!(device, "host closed the serial connection");
                    return;
                }
                Ok(n) => {
                    let data = buf.get(..n).unwrap_or_default();
                    tracing::trace!(device, rx = %String::from_utf8_lossy(data).escape_debug(), "device received");
                    lock(&emu).receive(data, clock.now_s())
                }
            },
            _ = clock.sleep_until_s(wake.unwrap_or(0.0)), if wake.is_some() => {
                // Converting to tokio instants may round a hair early: the event is due at `wake` at the latest.
                let at = clock.now_s().max(wake.unwrap_or(0.0));
                lock(&emu).poll_events(at)
            }
        };
        if !send(&mut io, outputs, &faults, &clock, &device, line).await {
            faults.injector().note_disconnect(&device, clock.now_s());
            return;
        }
    }
}

/// Write the outputs at their times; false when the link went down (or the host vanished) meanwhile.
async fn send(
    io: &mut DuplexStream,
    outputs: Vec<Output>,
    faults: &DeviceFaults,
    clock: &SimClock,
    device: &str,
    line: LineRate,
) -> bool {
    for out in outputs {
        let delay = faults.reply_delay_s();
        let done_s = out.at_s + delay + line.wire_s(out.bytes.len());
        if clock.real_duration(done_s - clock.now_s()) >= SHORTEST_REAL_WAIT {
            clock.sleep_until_s(done_s).await;
        }
        if !faults.injector().link_up(clock.now_s()) {
            return false;
        }
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
