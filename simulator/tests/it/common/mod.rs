//! Helpers shared by the simulator's integration tests.
#![allow(dead_code)]

pub mod meter;

use std::sync::Arc;
use std::time::Duration;

use gonio_instrument::InstrumentFile;
use gonio_simulator::SerialStream;
use gonio_simulator::SimInstrument;
use gonio_simulator::scene::UniformScene;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// The default simulated instrument, modified by `f`, with a uniform scene of 1e-4 W.
pub fn sim_with(f: impl FnOnce(&mut InstrumentFile)) -> SimInstrument {
    let mut file = InstrumentFile::simulated();
    f(&mut file);
    SimInstrument::new(&file, Arc::new(UniformScene { power_w: 1e-4 }), 1.0)
        .expect("valid simulated instrument")
}

/// Like [`sim_with`], with the simulated clock running `time_scale` times faster than tokio's.
pub fn sim_scaled(f: impl FnOnce(&mut InstrumentFile), time_scale: f64) -> SimInstrument {
    let mut file = InstrumentFile::simulated();
    f(&mut file);
    SimInstrument::new(&file, Arc::new(UniformScene { power_w: 1e-4 }), time_scale)
        .expect("valid simulated instrument")
}

pub fn sim() -> SimInstrument {
    sim_with(|_| {})
}

/// Give `file` the recorded real-device variants that config/instruments/realistic.toml takes (input pacing,
/// the unanswered first TS, the wheel's noise at open, ...), read from that file so the tests follow it.
pub fn recorded_quirks(file: &mut InstrumentFile) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/instruments/realistic.toml");
    let realistic = InstrumentFile::load(&path).expect("config/instruments/realistic.toml");
    file.simulator.quirks = realistic.simulator.quirks;
}

/// A host's view of a serial port.
pub struct Port {
    pub io: SerialStream,
    pub pending: Vec<u8>,
    /// Every byte ever received, for checks over a whole exchange.
    pub all: Vec<u8>,
}

impl Port {
    pub fn open(sim: &SimInstrument, device: &str) -> Port {
        Port {
            io: sim.serial_port(device).expect("open"),
            pending: Vec::new(),
            all: Vec::new(),
        }
    }

    pub async fn send(&mut self, bytes: &[u8]) {
        self.io.write_all(bytes).await.expect("write");
    }

    /// Bytes up to and including `end`, or None if they do not come within `timeout`, or at EOF.
    pub async fn read_until(&mut self, end: &[u8], timeout: Duration) -> Option<String> {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            if let Some(i) = self.pending.windows(end.len()).position(|w| w == end) {
                let rest = self.pending.split_off(i + end.len());
                let got = std::mem::replace(&mut self.pending, rest);
                return Some(String::from_utf8_lossy(&got).into_owned());
            }
            let mut buf = [0u8; 256];
            match tokio::time::timeout_at(deadline, self.io.read(&mut buf)).await {
                Ok(Ok(0)) | Ok(Err(_)) | Err(_) => return None,
                Ok(Ok(n)) => {
                    self.pending.extend_from_slice(&buf[..n]);
                    self.all.extend_from_slice(&buf[..n]);
                }
            }
        }
    }

    /// One CRLF-terminated line (within 1 s of simulated time at scale 1).
    pub async fn line(&mut self) -> Option<String> {
        self.read_until(b"\r\n", Duration::from_secs(1)).await
    }

    /// Send a command and read one reply line.
    pub async fn query(&mut self, cmd: &str) -> Option<String> {
        self.send(cmd.as_bytes()).await;
        self.line().await
    }

    /// Nothing arrives within `timeout`.
    pub async fn silent_for(&mut self, timeout: Duration) -> bool {
        self.pending.is_empty() && self.read_until(b"\n", timeout).await.is_none()
    }

    /// True when the device closed the stream (EOF).
    pub async fn at_eof(&mut self, timeout: Duration) -> bool {
        let mut buf = [0u8; 64];
        matches!(
            tokio::time::timeout(timeout, self.io.read(&mut buf)).await,
            Ok(Ok(0)) | Ok(Err(_))
        )
    }
}
