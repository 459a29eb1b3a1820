//! Newport SMC100 controllers daisy-chained on one RS-232 port: the device side of the protocol.
//!
//! Command `<addr><CC><arg>\r\n`; queries answer `<addr><CC><value>\r\n`, set commands are silent and record
//! their error for `TE`. The state machine: NOT REFERENCED (0A..11) -> HOMING (1E) -> READY (32..35) <->
//! MOVING (28), DISABLE (3C..3E) via `MM`, CONFIGURATION (14) via `PW`. A stalled move ends in DISABLE from
//! MOVING with the following-error bit; running into a limit switch ends in NOT REFERENCED from MOVING with the
//! end-of-run bit. Output is plain ASCII text, so it never contains XON (0x11) or XOFF (0x13).
//!
//! Addressing: a command for an address in 1..31 that no controller on the chain has gets no answer (nobody is
//! there); a missing or out-of-range address is error B on the first controller of the chain.

use std::sync::{Arc, Mutex};

use gonio_instrument::Axis;

use crate::faults::DeviceFaults;
use crate::motion::{AxisMotion, MoveEnd, trapezoid_time_s};
use crate::recording::MotionCommand;
use crate::session::{Output, SerialEmulator};

/// Longest command line the controller buffers; longer input is discarded up to the next terminator.
const MAX_LINE: usize = 256;
/// Duration of the homing search's slow final approach to the switch (s).
const HOMING_SEARCH_S: f64 = 1.0;
/// Time the controller needs to store its configuration after `PW0` (s), unresponsive meanwhile.
const PW0_SAVE_S: f64 = 10.0;
/// Time a reset (`RS`) takes before the controller answers again (s).
const RESET_S: f64 = 2.0;

/// Controller states as `TS` reports them (second part of the reply, two hex digits).
pub mod state {
    pub const NOT_REF_FROM_RESET: u8 = 0x0A;
    pub const NOT_REF_FROM_HOMING: u8 = 0x0B;
    pub const NOT_REF_FROM_CONFIG: u8 = 0x0C;
    pub const NOT_REF_FROM_DISABLE: u8 = 0x0D;
    pub const NOT_REF_FROM_READY: u8 = 0x0E;
    pub const NOT_REF_FROM_MOVING: u8 = 0x0F;
    pub const CONFIGURATION: u8 = 0x14;
    pub const HOMING: u8 = 0x1E;
    pub const MOVING: u8 = 0x28;
    pub const READY_FROM_HOMING: u8 = 0x32;
    pub const READY_FROM_MOVING: u8 = 0x33;
    pub const READY_FROM_DISABLE: u8 = 0x34;
    pub const DISABLE_FROM_READY: u8 = 0x3C;
    pub const DISABLE_FROM_MOVING: u8 = 0x3D;
}

/// Positioner error bits (first part of the `TS` reply, four hex digits).
pub mod error_bits {
    pub const FOLLOWING_ERROR: u16 = 0x0020;
    pub const POSITIVE_END_OF_RUN: u16 = 0x0002;
    pub const NEGATIVE_END_OF_RUN: u16 = 0x0001;
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Group {
    NotReferenced,
    Configuration,
    Homing,
    Moving,
    Ready,
    Disable,
}

fn group(code: u8) -> Group {
    match code {
        0x0A..=0x11 => Group::NotReferenced,
        0x14 => Group::Configuration,
        0x1E | 0x1F => Group::Homing,
        0x28 => Group::Moving,
        0x3C..=0x3E => Group::Disable,
        _ => Group::Ready,
    }
}

/// The `TE` letter for a command that the current state does not allow.
fn wrong_state_error(code: u8) -> char {
    match group(code) {
        Group::NotReferenced => 'H',
        Group::Configuration => 'I',
        Group::Disable => 'J',
        Group::Ready => 'K',
        Group::Homing => 'L',
        Group::Moving => 'M',
    }
}

#[derive(Debug)]
struct Controller {
    address: u8,
    axis: Axis,
    motion: Arc<Mutex<AxisMotion>>,
    state: u8,
    /// Latched positioner errors (following error); end-of-run bits are computed from the switches.
    latched_bits: u16,
    last_error: char,
    velocity_deg_s: f64,
    accel_deg_s2: f64,
    sl_deg: f64,
    sr_deg: f64,
    /// The controller ignores input until then (storing configuration, resetting).
    deaf_until_s: f64,
}

impl Controller {
    fn motion(&self) -> std::sync::MutexGuard<'_, AxisMotion> {
        self.motion.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Let the state machine catch up with the physics at `now`.
    fn update(&mut self, now: f64) {
        let g = group(self.state);
        if g != Group::Moving && g != Group::Homing {
            return;
        }
        let (moving, end) = {
            let mut m = self.motion();
            (m.is_moving(now), m.end_reason())
        };
        if moving {
            return;
        }
        self.state = match (g, end) {
            (Group::Homing, MoveEnd::Arrived) => state::READY_FROM_HOMING,
            (Group::Homing, MoveEnd::Stalled) => {
                self.latched_bits |= error_bits::FOLLOWING_ERROR;
                state::NOT_REF_FROM_HOMING
            }
            (Group::Homing, _) => state::NOT_REF_FROM_HOMING,
            (_, MoveEnd::Arrived | MoveEnd::Stopped | MoveEnd::Halted) => state::READY_FROM_MOVING,
            (_, MoveEnd::Stalled) => {
                self.latched_bits |= error_bits::FOLLOWING_ERROR;
                tracing::warn!(
                    address = self.address,
                    "SMC100: following error, DISABLE from MOVING"
                );
                state::DISABLE_FROM_MOVING
            }
            (_, MoveEnd::LimitNegative | MoveEnd::LimitPositive) => state::NOT_REF_FROM_MOVING,
        };
    }

    fn error_bits(&self, now: f64) -> u16 {
        let p = self.motion().motor_deg(now);
        let params = *self.motion().params();
        let mut bits = self.latched_bits;
        if p >= params.hw_max_deg - 1e-9 {
            bits |= error_bits::POSITIVE_END_OF_RUN;
        }
        if p <= params.hw_min_deg + 1e-9 {
            bits |= error_bits::NEGATIVE_END_OF_RUN;
        }
        bits
    }

    fn start_move(&mut self, now: f64, target: f64, faults: &DeviceFaults) {
        if !(self.sl_deg - 1e-9..=self.sr_deg + 1e-9).contains(&target) {
            self.last_error = 'G';
            return;
        }
        let travels = (self.motion().motor_deg(now) - target).abs() > 0.0;
        let stall = if travels {
            faults.stall(&self.axis.name)
        } else {
            None
        };
        let (v, a) = (self.velocity_deg_s, self.accel_deg_s2);
        let end = self.motion().start_move(now, target, v, a, stall);
        tracing::debug!(address = self.address, target, end_s = end, "SMC100 move started");
        self.state = state::MOVING;
    }
}

/// One RS-232 port with a chain of SMC100 controllers.
#[derive(Debug)]
pub struct Smc100Chain {
    name: String,
    controllers: Vec<Controller>,
    input: Vec<u8>,
    discarding: bool,
    faults: DeviceFaults,
}

/// Format a number as the controller does: plain decimal, no exponent, at most 6 decimals.
fn fmt_num(x: f64) -> String {
    let r = (x * 1e6).round() / 1e6;
    let r = if r == 0.0 { 0.0 } else { r };
    format!("{r}")
}

impl Smc100Chain {
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
                    axis,
                    motion,
                    state: state::NOT_REF_FROM_RESET,
                    latched_bits: 0,
                    last_error: '@',
                    deaf_until_s: 0.0,
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
        }
    }

    fn execute(&mut self, line: &[u8], now: f64) -> Option<String> {
        // Address: up to two digits.
        let digits = line.iter().take_while(|b| b.is_ascii_digit()).count();
        let (addr_text, rest) = line.split_at(digits);
        let addr_text = std::str::from_utf8(addr_text).unwrap_or_default();
        let address: Option<u8> = addr_text
            .parse()
            .ok()
            .filter(|a| (1..=31).contains(a) && digits <= 2);
        let Some(address) = address else {
            // Missing or invalid address: the controller on the port records error B.
            if let Some(first) = self.controllers.first_mut() {
                first.last_error = 'B';
            }
            tracing::debug!(chain = %self.name, line = %String::from_utf8_lossy(line), "SMC100: bad address");
            return None;
        };
        let faults = self.faults.clone();
        let ctrl = self.controllers.iter_mut().find(|c| c.address == address)?;
        if now < ctrl.deaf_until_s {
            tracing::debug!(address, "SMC100: controller busy, command lost");
            return None;
        }
        ctrl.update(now);
        let Some(code) = rest.get(..2).and_then(|c| std::str::from_utf8(c).ok()) else {
            ctrl.last_error = 'A';
            return None;
        };
        let arg = std::str::from_utf8(rest.get(2..).unwrap_or_default()).map(str::trim);
        let Ok(arg) = arg else {
            ctrl.last_error = 'A';
            return None;
        };
        let query = arg == "?";
        let num: Option<f64> = if arg.is_empty() || query {
            None
        } else {
            arg.parse().ok().filter(|x: &f64| x.is_finite())
        };
        // PW and MM take 0 or 1.
        let flag: Option<u8> = num.filter(|x| *x == 0.0 || *x == 1.0).map(|x| x as u8);
        let reply = |value: String| Some(format!("{addr_text}{code}{value}"));
        let g = group(ctrl.state);
        match code {
            "TS" => {
                let bits = ctrl.error_bits(now);
                reply(format!("{bits:04X}{:02X}", ctrl.state))
            }
            "TE" => {
                let e = std::mem::replace(&mut ctrl.last_error, '@');
                reply(e.to_string())
            }
            "TP" => {
                let p = ctrl.motion().encoder_deg(now);
                reply(fmt_num(p))
            }
            "TH" => {
                let p = ctrl.motion().motor_deg(now);
                reply(fmt_num(p))
            }
            "ID" => reply(format!("{}_URS100BCC", ctrl.axis.name.to_ascii_uppercase())),
            "VE" => reply(" SMC_CC - Controller-driver version 2.0.4".to_string()),
            "PW" if query => reply(if g == Group::Configuration { "1" } else { "0" }.into()),
            "PW" => {
                match (flag, g) {
                    (Some(1), Group::NotReferenced) => ctrl.state = state::CONFIGURATION,
                    (Some(0), Group::Configuration) => {
                        ctrl.state = state::NOT_REF_FROM_CONFIG;
                        ctrl.deaf_until_s = now + PW0_SAVE_S;
                    }
                    (Some(1), Group::Configuration) => {}
                    (Some(_), _) => ctrl.last_error = wrong_state_error(ctrl.state),
                    _ => ctrl.last_error = 'C',
                }
                None
            }
            "RS" => {
                ctrl.motion().halt(now);
                ctrl.state = state::NOT_REF_FROM_RESET;
                ctrl.latched_bits = 0;
                ctrl.last_error = '@';
                ctrl.deaf_until_s = now + RESET_S;
                None
            }
            "OR" => {
                ctrl.motion().note_command(now, MotionCommand::Home);
                match g {
                    Group::NotReferenced => {
                        let home = 0.0f64.clamp(ctrl.sl_deg.min(0.0), ctrl.sr_deg.max(0.0));
                        // Only a move that travels can stall.
                        let travels = (ctrl.motion().motor_deg(now) - home).abs() > 0.0;
                        let stall = if travels {
                            faults.stall(&ctrl.axis.name)
                        } else {
                            None
                        };
                        let (v, a) = (ctrl.velocity_deg_s, ctrl.accel_deg_s2);
                        let mut m = ctrl.motion();
                        m.start_move(now, home, v, a, stall);
                        if stall.is_none() {
                            m.dwell(now, HOMING_SEARCH_S);
                        }
                        drop(m);
                        ctrl.latched_bits = 0;
                        ctrl.state = state::HOMING;
                    }
                    Group::Homing => ctrl.last_error = 'E',
                    _ => ctrl.last_error = wrong_state_error(ctrl.state),
                }
                None
            }
            "PA" | "PR" if query => {
                let target = ctrl.motion().target_deg();
                reply(fmt_num(target))
            }
            "PA" | "PR" => {
                let Some(x) = num else {
                    ctrl.last_error = 'C';
                    return None;
                };
                let target = if code == "PA" {
                    x
                } else {
                    ctrl.motion().motor_deg(now) + x
                };
                ctrl.motion()
                    .note_command(now, MotionCommand::MoveTo { target_deg: target });
                if g != Group::Ready {
                    ctrl.last_error = wrong_state_error(ctrl.state);
                    return None;
                }
                ctrl.start_move(now, target, &faults);
                None
            }
            "PT" => {
                let Some(x) = num else {
                    ctrl.last_error = 'C';
                    return None;
                };
                if g == Group::Configuration {
                    ctrl.last_error = 'I';
                    return None;
                }
                reply(fmt_num(trapezoid_time_s(
                    x,
                    ctrl.velocity_deg_s,
                    ctrl.accel_deg_s2,
                )))
            }
            "ST" => {
                ctrl.motion()
                    .note_command(now, MotionCommand::Stop { abrupt: false });
                match g {
                    Group::Moving | Group::Homing => {
                        let a = ctrl.accel_deg_s2;
                        ctrl.motion().stop(now, a);
                    }
                    Group::Configuration => ctrl.last_error = 'I',
                    _ => {}
                }
                None
            }
            "MM" if query => reply(format!("{:02X}", ctrl.state)),
            "MM" => {
                match (flag, g) {
                    (Some(0), Group::Ready) => ctrl.state = state::DISABLE_FROM_READY,
                    (Some(1), Group::Disable) => {
                        ctrl.latched_bits = 0;
                        ctrl.state = state::READY_FROM_DISABLE;
                    }
                    (Some(1), Group::Ready) => {}
                    (Some(0), Group::Disable) => {}
                    (Some(_), _) => ctrl.last_error = wrong_state_error(ctrl.state),
                    _ => ctrl.last_error = 'C',
                }
                None
            }
            "VA" | "AC" | "SL" | "SR" => {
                let current = match code {
                    "VA" => ctrl.velocity_deg_s,
                    "AC" => ctrl.accel_deg_s2,
                    "SL" => ctrl.sl_deg,
                    _ => ctrl.sr_deg,
                };
                if query {
                    return reply(fmt_num(current));
                }
                let Some(x) = num else {
                    ctrl.last_error = 'C';
                    return None;
                };
                if matches!(g, Group::Moving | Group::Homing) {
                    ctrl.last_error = wrong_state_error(ctrl.state);
                    return None;
                }
                let ok = match code {
                    "VA" | "AC" => x > 0.0 && x < 1e12,
                    "SL" => (-1e12..=0.0).contains(&x),
                    _ => (0.0..=1e12).contains(&x),
                };
                if !ok {
                    ctrl.last_error = 'C';
                    return None;
                }
                match code {
                    "VA" => ctrl.velocity_deg_s = x,
                    "AC" => ctrl.accel_deg_s2 = x,
                    "SL" => ctrl.sl_deg = x,
                    _ => ctrl.sr_deg = x,
                }
                None
            }
            _ => {
                ctrl.last_error = 'A';
                None
            }
        }
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
                tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(&line).escape_debug(), "SMC100 command");
                if let Some(reply) = self.execute(&line, now_s) {
                    // Text only: XON/XOFF can never appear, but make it impossible by construction.
                    let mut bytes: Vec<u8> = reply
                        .into_bytes()
                        .into_iter()
                        .filter(|b| *b != 0x11 && *b != 0x13)
                        .collect();
                    bytes.extend_from_slice(b"\r\n");
                    out.push(Output { at_s: now_s, bytes });
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
            c.update(now_s);
            c.motion().halt(now_s);
            c.update(now_s);
        }
    }
}
