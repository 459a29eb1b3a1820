//! Newport SMC100 controllers daisy-chained on one RS-232 port: the device side of the protocol.
//!
//! Split by job: [`machine`] (the state machine, TS bits, TE letters of wrong states), [`params`] (the
//! stored parameters of the command list, TB's strings), [`commands`] (one command line), this module (the
//! port: line framing, input pacing, the chain).
//!
//! Command `<addr><CC><arg>\r\n`; queries answer `<addr><CC><value>\r\n`, set commands are silent and record
//! their error for `TE`. The state machine: NOT REFERENCED (0A..11) -> HOMING (1E) -> READY (32..35) <->
//! MOVING (28), DISABLE (3C..3E) via `MM`, CONFIGURATION (14) via `PW`. A stalled move ends in DISABLE from
//! MOVING with the following-error bit; running into a limit switch ends in NOT REFERENCED from MOVING with the
//! end-of-run bit. Output is plain ASCII text, so it never contains XON (0x11) or XOFF (0x13).
//!
//! Addressing: a command for an address in 1..31 that no controller on the chain has gets no answer (nobody is
//! there); a missing or out-of-range address is error B on the first controller of the chain.
//!
//! Protocol notes, and where each comes from:
//! - The whole command list of the SMC100CC/PP user manual: AC BA BH DV FD FE FF FR HT ID JM JR KD KI KP KV MM
//!   OH OR OT PA PR PT PW QI RA RB RS RS## SA SB SC SE SL SR ST SU TB TE TH TP TS VA VB VE ZT ZX. PP-only
//!   commands (DV, FR, VB) are error X on this CC controller. `TB` answers `<addr>TB<letter> <text>` with the
//!   manual's error strings. Unconfirmed: whether a `TB` without argument clears the error as `TE` does (here
//!   it does), the parameters' power-up values, `ZT`'s line order (here alphabetical), `RA`/`RB` values.
//! - `VE` answers `1VE SMC_CC - Controller-driver version  3. 1. 2` and `TP` prints up to 10 decimals: a
//!   real controller's replies, recorded by a real-hardware driver.
//! - In READY, `TP` equals the set-point within the encoder resolution (manual, `TP`: "should be equal or very
//!   close to the set point"): the encoder is on the motor side of the backlash; the load may lag by the
//!   backlash, which only the optics see.
//! - Input pacing: host drivers written against real controllers pace their commands (the widely copied
//!   Python SMC100 driver waits 60 ms after each set command, "arrived at by trial and error"; others up to
//!   0.5 s) and report late replies landing in the next read. Emulated (`[simulator.quirks]
//!   smc100_min_command_gap_ms`, default 60): a set command keeps its controller busy for that long, a query
//!   until its reply has crossed the line; a command line arriving while the controller it addresses is busy
//!   is lost. Each controller on the chain has its own processor: one busy controller does not make the others
//!   lose input (unconfirmed: whether the first controller, which relays the RS-485 chain, does).
//! - The first `TS` after power-up or reset, and the first right after a homing completes, may get no reply
//!   at all (reported by a real-hardware driver as undocumented): `smc100_drop_first_ts`, default on.

mod commands;
mod machine;
mod params;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use gonio_instrument::{Axis, Quirks};

use crate::faults::DeviceFaults;
use crate::motion::AxisMotion;
use crate::session::{Output, SerialEmulator};
use machine::Controller;
pub use machine::{error_bits, state};

/// Longest command line the controller buffers; longer input is discarded up to the next terminator.
const MAX_LINE: usize = 256;
/// Duration of the homing search's slow final approach to the switch (s).
const HOMING_SEARCH_S: f64 = 1.0;
/// Time the controller needs to store its configuration after `PW0` (s), unresponsive meanwhile.
const PW0_SAVE_S: f64 = 10.0;
/// Time a reset (`RS`) takes before the controller answers again (s).
const RESET_S: f64 = 2.0;
/// The controller's serial rate (57600 baud, 8N1: ten bits a byte).
const LINE_BYTES_PER_S: f64 = 5760.0;

/// One RS-232 port with a chain of SMC100 controllers.
#[derive(Debug)]
pub struct Smc100Chain {
    name: String,
    controllers: Vec<Controller>,
    input: Vec<u8>,
    discarding: bool,
    faults: DeviceFaults,
    /// A set command keeps the controller busy this long (s); 0 takes every line.
    set_busy_s: f64,
    drop_first_ts: bool,
    /// Input for a controller arriving before its time here is lost (s), by address.
    busy_until_s: BTreeMap<u8, f64>,
    /// Command lines lost to pacing, for the tests and the soak reports.
    lost_to_pacing: u64,
}

/// Format a number as the controller does: plain decimal, no exponent, at most 6 decimals.
fn fmt_num(x: f64) -> String {
    let r = (x * 1e6).round() / 1e6;
    let r = if r == 0.0 { 0.0 } else { r };
    format!("{r}")
}

/// Format a position (`TP`, `TH`, `PA?`): up to 10 decimals, as a real controller prints them.
fn fmt_position(x: f64) -> String {
    let r = (x * 1e10).round() / 1e10;
    let r = if r == 0.0 { 0.0 } else { r };
    format!("{r}")
}

impl Smc100Chain {
    /// A chain behaving as the manual describes: no input pacing, every TS answered. See
    /// [`Smc100Chain::with_quirks`] for the recorded real-device variants.
    pub fn new(name: &str, axes: Vec<(Axis, Arc<Mutex<AxisMotion>>)>, faults: DeviceFaults) -> Smc100Chain {
        let mut controllers: Vec<Controller> = axes
            .into_iter()
            .map(|(axis, motion)| {
                let p = *motion.lock().unwrap_or_else(|e| e.into_inner()).params();
                Controller {
                    address: axis.address,
                    velocity_deg_s: axis.max_speed_deg_s,
                    accel_deg_s2: axis.accel_deg_s2,
                    sl_deg: p.hw_min_deg,
                    sr_deg: p.hw_max_deg,
                    stage_id: format!("{}_URS100BCC", axis.name.to_ascii_uppercase()),
                    axis,
                    motion,
                    state: state::NOT_REF_FROM_RESET,
                    latched_bits: 0,
                    last_error: '@',
                    deaf_until_s: 0.0,
                    params: BTreeMap::new(),
                    drop_next_ts: false,
                    se_target: None,
                }
            })
            .collect();
        controllers.sort_by_key(|c| c.address);
        Smc100Chain {
            name: name.to_string(),
            controllers,
            input: Vec::new(),
            discarding: false,
            faults,
            set_busy_s: 0.0,
            drop_first_ts: false,
            busy_until_s: BTreeMap::new(),
            lost_to_pacing: 0,
        }
    }

    /// The recorded real-device variants of `[simulator.quirks]`: input pacing, the unanswered first TS.
    pub fn with_quirks(mut self, quirks: &Quirks) -> Smc100Chain {
        self.set_busy_s = quirks.smc100_min_command_gap_ms.max(0.0) / 1e3;
        self.drop_first_ts = quirks.smc100_drop_first_ts;
        for c in &mut self.controllers {
            c.drop_next_ts = self.drop_first_ts;
        }
        self
    }

    /// Command lines lost because they arrived while the controller was busy.
    pub fn lost_to_pacing(&self) -> u64 {
        self.lost_to_pacing
    }

    /// Take one complete line at `now_s`: lost while its controller is busy, else executed; the reply, if any.
    fn take_line(&mut self, line: &[u8], now_s: f64) -> Option<Output> {
        let paced = self.set_busy_s > 0.0;
        let digits = line.iter().take_while(|b| b.is_ascii_digit()).count();
        let address: Option<u8> = std::str::from_utf8(&line[..digits])
            .ok()
            .and_then(|a| a.parse().ok());
        let busy_until = address
            .and_then(|a| self.busy_until_s.get(&a).copied())
            .unwrap_or(0.0);
        if paced && now_s < busy_until - 1e-9 {
            self.lost_to_pacing += 1;
            tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(line).escape_debug(), busy_for_s = busy_until - now_s, "SMC100: command arrived while its controller was busy, lost");
            return None;
        }
        tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(line).escape_debug(), "SMC100 command");
        let reply = self.execute(line, now_s);
        let Some(reply) = reply else {
            if paced && let Some(a) = address {
                self.busy_until_s.insert(a, now_s + self.set_busy_s);
            }
            return None;
        };
        // Text only: XON/XOFF can never appear, but make it impossible by construction.
        let mut bytes: Vec<u8> = reply
            .into_bytes()
            .into_iter()
            .filter(|b| *b != 0x11 && *b != 0x13)
            .collect();
        bytes.extend_from_slice(b"\r\n");
        if paced && let Some(a) = address {
            self.busy_until_s
                .insert(a, now_s + bytes.len() as f64 / LINE_BYTES_PER_S);
        }
        Some(Output { at_s: now_s, bytes })
    }
}

impl SerialEmulator for Smc100Chain {
    fn reset_input(&mut self) {
        self.input.clear();
        self.discarding = false;
    }

    fn receive(&mut self, data: &[u8], now_s: f64) -> Vec<Output> {
        let mut out = Vec::new();
        for &b in data {
            if b == b'\n' {
                let mut line = std::mem::take(&mut self.input);
                if line.last() == Some(&b'\r') {
                    line.pop();
                }
                if std::mem::replace(&mut self.discarding, false) || line.is_empty() {
                    continue;
                }
                if let Some(reply) = self.take_line(&line, now_s) {
                    out.push(reply);
                }
            } else if self.input.len() >= MAX_LINE {
                self.input.clear();
                self.discarding = true;
            } else if !self.discarding {
                self.input.push(b);
            }
        }
        out
    }

    fn next_event_s(&mut self, _now_s: f64) -> Option<f64> {
        None
    }

    fn poll_events(&mut self, _now_s: f64) -> Vec<Output> {
        Vec::new()
    }

    fn estop(&mut self, now_s: f64) {
        for c in &mut self.controllers {
            c.update(now_s, self.drop_first_ts);
            c.motion().halt(now_s);
            c.update(now_s, self.drop_first_ts);
        }
    }
}
