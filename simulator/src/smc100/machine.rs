//! The controller's state machine: the states `TS` reports, the positioner error bits, which state refuses what
//! (the `TE` letters H..M), and how a move or a homing ends.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use gonio_instrument::Axis;

use crate::faults::DeviceFaults;
use crate::motion::AxisMotion;
use crate::move_end::MoveEnd;

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
pub(super) enum Group {
    NotReferenced,
    Configuration,
    Homing,
    Moving,
    Ready,
    Disable,
}

pub(super) fn group(code: u8) -> Group {
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
pub(super) fn wrong_state_error(code: u8) -> char {
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
pub(super) struct Controller {
    pub(super) address: u8,
    pub(super) axis: Axis,
    pub(super) motion: Arc<Mutex<AxisMotion>>,
    pub(super) state: u8,
    /// Latched positioner errors (following error); end-of-run bits are computed from the switches.
    pub(super) latched_bits: u16,
    pub(super) last_error: char,
    pub(super) velocity_deg_s: f64,
    pub(super) accel_deg_s2: f64,
    pub(super) sl_deg: f64,
    pub(super) sr_deg: f64,
    /// The controller ignores input until then (storing configuration, resetting).
    pub(super) deaf_until_s: f64,
    /// The other parameters of the command list (gains, home search, TTL output, ...), by command code.
    pub(super) params: BTreeMap<&'static str, f64>,
    /// Stage identifier (`ID`).
    pub(super) stage_id: String,
    /// The next `TS` gets no reply (after power-up, and once a homing completes): see the module notes.
    pub(super) drop_next_ts: bool,
    /// Target stored by `SE` for a simultaneous start.
    pub(super) se_target: Option<f64>,
}

impl Controller {
    pub(super) fn motion(&self) -> std::sync::MutexGuard<'_, AxisMotion> {
        self.motion.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Let the state machine catch up with the physics at `now`.
    pub(super) fn update(&mut self, now: f64, drop_first_ts: bool) {
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
            (Group::Homing, MoveEnd::Arrived) => {
                // A real-hardware driver reports that the first TS right after homing may get no reply.
                self.drop_next_ts = drop_first_ts;
                state::READY_FROM_HOMING
            }
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

    pub(super) fn error_bits(&self, now: f64) -> u16 {
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

    pub(super) fn start_move(&mut self, now: f64, target: f64, faults: &DeviceFaults) {
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
