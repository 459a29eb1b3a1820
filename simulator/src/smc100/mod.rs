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
//!   smc100_min_command_gap_ms`: 0 by default, every line taken as the manual describes; 60 in
//!   config/instruments/realistic.toml): a set command keeps its controller busy for that long from when the
//!   host sent it, a query until its reply has crossed the line (never after the host has the reply); a
//!   command line sent while the controller it addresses is busy is lost. Both are judged on the host's
//!   timeline (the session stamps each write), so scheduling delays of the simulator's own task, which a large
//!   time scale multiplies, cannot make a paced host lose a line. Each controller on the chain has its own
//!   processor: one busy controller does not make the others lose input (unconfirmed: whether the first
//!   controller, which relays the RS-485 chain, does).
//! - The first `TS` after power-up or reset, and the first right after a homing completes, may get no reply
//!   at all (reported by a real-hardware driver as undocumented): `smc100_drop_first_ts`, off by default (the
//!   manual answers every `TS`), on in config/instruments/realistic.toml.

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
    /// Until when input for a controller is lost, by address.
    busy: BTreeMap<u8, Busy>,
    /// Command lines lost to pacing, by command code, for the tests and the soak reports.
    lost_to_pacing: BTreeMap<String, u64>,
}

/// A controller that cannot take input yet: until `until_s` (simulated s), or until its reply has reached the
/// host when `replying` (a reply the host has can no longer be keeping the controller busy).
#[derive(Debug, Clone, Copy)]
struct Busy {
    until_s: f64,
    replying: bool,
}

/// The address a line (command or reply) starts with.
fn address_of(line: &[u8]) -> Option<u8> {
    let digits = line.iter().take_while(|b| b.is_ascii_digit()).count();
    std::str::from_utf8(line.get(..digits)?).ok()?.parse().ok()
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
            busy: BTreeMap::new(),
            lost_to_pacing: BTreeMap::new(),
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

    /// Take one complete line, sent by the host at `sent_s` and read at `now_s`: lost when it was sent while its
    /// controller was busy, else executed at `now_s`; the reply, if any.
    ///
    /// Pacing is judged on the host's own timeline, so that it holds at any time scale and under any load: a set
    /// command keeps its controller busy for the gap from when it was sent, and a query until its reply has
    /// crossed the line or reached the host ([`SerialEmulator::delivered`]), whichever is first: the host cannot
    /// answer a reply before it has it, so a host waiting for each reply never loses a line to one.
    fn take_line(&mut self, line: &[u8], sent_s: f64, now_s: f64) -> Option<Output> {
        let paced = self.set_busy_s > 0.0;
        let address = address_of(line);
        let busy_until = address.and_then(|a| self.busy.get(&a)).map_or(0.0, |b| b.until_s);
        if paced && sent_s < busy_until - 1e-9 {
            let code = line
                .get(line.iter().take_while(|b| b.is_ascii_digit()).count()..)
                .and_then(|rest| rest.get(..2))
                .map_or_else(
                    || "?".to_string(),
                    |c| String::from_utf8_lossy(c).to_ascii_uppercase(),
                );
            *self.lost_to_pacing.entry(code).or_default() += 1;
            tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(line).escape_debug(), sent_s, busy_for_s = busy_until - sent_s, "SMC100: command arrived while its controller was busy, lost");
            return None;
        }
        tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(line).escape_debug(), sent_s, now_s, "SMC100 command");
        let reply = self.execute(line, now_s);
        let Some(reply) = reply else {
            if paced && let Some(a) = address {
                let busy = Busy {
                    until_s: sent_s + self.set_busy_s,
                    replying: false,
                };
                self.busy.insert(a, busy);
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
            // Until the reply has crossed the line, or reached the host if the session delivers it sooner.
            let busy = Busy {
                until_s: now_s + bytes.len() as f64 / LINE_BYTES_PER_S,
                replying: true,
            };
            self.busy.insert(a, busy);
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
        self.receive_sent(data, now_s, now_s)
    }

    fn receive_sent(&mut self, data: &[u8], sent_s: f64, now_s: f64) -> Vec<Output> {
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
                if let Some(reply) = self.take_line(&line, sent_s, now_s) {
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

    fn delivered(&mut self, out: &Output, now_s: f64) {
        if let Some(b) = address_of(&out.bytes).and_then(|a| self.busy.get_mut(&a))
            && b.replying
        {
            b.until_s = b.until_s.min(now_s);
            b.replying = false;
        }
    }

    fn lost_input(&self) -> BTreeMap<String, u64> {
        self.lost_to_pacing.clone()
    }

    fn estop(&mut self, now_s: f64) {
        for c in &mut self.controllers {
            c.update(now_s, self.drop_first_ts);
            c.motion().halt(now_s);
            c.update(now_s, self.drop_first_ts);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crate::SimInstrument;
    use crate::scene::UniformScene;
    use crate::session::{Output, SharedEmulator};

    fn arms() -> SharedEmulator {
        // The recorded pacing (config/instruments/realistic.toml), which these tests are about; every TS answered.
        let mut file = gonio_instrument::InstrumentFile::simulated();
        file.simulator.quirks.smc100_min_command_gap_ms = 60.0;
        file.simulator.quirks.smc100_drop_first_ts = false;
        let sim = SimInstrument::new(&file, Arc::new(UniformScene { power_w: 1e-4 }), 1.0).expect("sim");
        sim.serial_emulator("arms").expect("arms").1
    }

    fn text(out: &[Output]) -> String {
        out.iter()
            .map(|o| String::from_utf8_lossy(&o.bytes).into_owned())
            .collect()
    }

    /// The set command's busy while runs from when the host sent it: a line the host sent 61 ms after a set
    /// command is taken even when the emulator read the set command late (its task was held up), and one sent
    /// 59 ms after it is lost even when read late.
    #[test]
    fn pacing_is_judged_on_the_hosts_timeline() {
        let emu = arms();
        let mut c = emu.lock().expect("lock");
        assert_eq!(c.receive_sent(b"1PA5\r\n", 1.000, 1.050), vec![]);
        assert_eq!(
            c.receive_sent(b"1TE\r\n", 1.059, 1.200),
            vec![],
            "sent within the 60 ms: lost"
        );
        assert_eq!(c.lost_input(), [("TE".to_string(), 1)].into());
        assert_eq!(c.receive_sent(b"1PA5\r\n", 2.000, 2.050), vec![]);
        assert_eq!(text(&c.receive_sent(b"1TE\r\n", 2.061, 2.061)), "1TEH\r\n");
        assert_eq!(c.lost_input(), [("TE".to_string(), 1)].into());
    }

    /// A query's reply keeps its controller busy until it has crossed the line, not after the host has it.
    #[test]
    fn a_delivered_reply_frees_its_controller() {
        let emu = arms();
        let mut c = emu.lock().expect("lock");
        let out = c.receive_sent(b"2TS\r\n", 5.0, 5.0);
        assert_eq!(text(&out), "2TS00000A\r\n");
        // Sent before the reply was over the line (57600 baud: 1.9 ms): lost, as in a burst.
        assert_eq!(c.receive_sent(b"2TS\r\n", 5.001, 5.001), vec![]);
        let out = c.receive_sent(b"2TS\r\n", 6.0, 6.0);
        // The session wrote the reply early (at a large time scale it does not wait microseconds): the host may
        // answer at once.
        c.delivered(&out[0], 6.0001);
        assert_eq!(text(&c.receive_sent(b"2TS\r\n", 6.0001, 6.0001)), "2TS00000A\r\n");
        assert_eq!(c.lost_input(), [("TS".to_string(), 1)].into());
    }
}
