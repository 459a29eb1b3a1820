//! The manual's command list beyond motion: the stored parameters (limits, the states they may be set in, the
//! controller versions that have them) and the error strings `TB` prints.
//!
//! Unconfirmed: the parameters' power-up values and upper limits (the manual gives them per stage, from the
//! stage's EEPROM); the values here are plausible for a URS100BCC rotation stage.

use super::machine::{Group, wrong_state_error};

/// Where a parameter may be set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum SetIn {
    /// CONFIGURATION only (stored in the controller's memory by `PW0`).
    Configuration,
    /// CONFIGURATION, NOT REFERENCED, READY or DISABLE; not while moving or homing.
    NotMoving,
}

/// Which controller versions have the command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Version {
    Both,
    /// Servo (DC motor) controllers only: the PP version answers error W.
    Cc,
    /// Stepper controllers only: the CC version answers error X.
    Pp,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Param {
    pub code: &'static str,
    pub default: f64,
    pub min: f64,
    pub max: f64,
    pub set_in: SetIn,
    pub version: Version,
}

const fn p(code: &'static str, default: f64, min: f64, max: f64, set_in: SetIn, version: Version) -> Param {
    Param {
        code,
        default,
        min,
        max,
        set_in,
        version,
    }
}

use SetIn::{Configuration as C, NotMoving as N};
use Version::{Both, Cc, Pp};

/// Stored parameters of the command list (VA, AC, SL and SR are the axis's own, see `commands`).
pub(super) const PARAMS: &[Param] = &[
    p("BA", 0.0, 0.0, 1e12, C, Both),   // backlash compensation
    p("BH", 0.0, 0.0, 1e12, C, Both),   // hysteresis compensation
    p("DV", 12.0, 12.0, 48.0, C, Pp),   // driver voltage
    p("FD", 1e3, 1e-6, 2e3, C, Cc),     // low-pass filter for Kd (Hz)
    p("FE", 0.05, 1e-6, 1e12, C, Cc),   // following error limit
    p("FF", 0.0, 0.0, 1e12, N, Cc),     // friction compensation
    p("FR", 2e-5, 1e-6, 1e12, C, Pp),   // stepper motor resolution
    p("HT", 1.0, 0.0, 4.0, C, Both),    // HOME search type
    p("JM", 1.0, 0.0, 2.0, N, Both),    // keypad enable
    p("JR", 0.04, 1e-3, 1e12, C, Both), // jerk time
    p("KD", 0.0, 0.0, 1e12, N, Cc),     // derivative gain
    p("KI", 0.0, 0.0, 1e12, N, Cc),     // integral gain
    p("KP", 0.0, 0.0, 1e12, N, Cc),     // proportional gain
    p("KV", 0.0, 0.0, 1e12, N, Cc),     // velocity feed forward
    p("OH", 5.0, 1e-6, 1e12, C, Both),  // HOME search velocity
    p("OT", 100.0, 1.0, 1e3, C, Both),  // HOME search time-out (s)
    p("QI", 1.0, 0.05, 3.0, C, Cc),     // motor's current limits (A)
    p("SA", 1.0, 1.0, 31.0, C, Both),   // RS-485 address (taken at the next power-up)
    p("SB", 0.0, 0.0, 15.0, N, Both),   // TTL output value
    p("SC", 1.0, 0.0, 1.0, N, Cc),      // control loop state (closed = 1)
    p("SU", 1e-4, 1e-6, 1e12, C, Both), // encoder increment value
    p("VB", 0.0, 0.0, 1e12, C, Pp),     // base velocity
];

pub(super) fn param(code: &str) -> Option<&'static Param> {
    PARAMS.iter().find(|p| p.code == code)
}

/// The letter a set of `param` is refused with in state group `g`, if it is.
pub(super) fn refusal(param: &Param, g: Group, state_code: u8) -> Option<char> {
    match (param.set_in, g) {
        (SetIn::Configuration, Group::Configuration) => None,
        (SetIn::Configuration, _) => Some(wrong_state_error(state_code)),
        (SetIn::NotMoving, Group::Moving | Group::Homing) => Some(wrong_state_error(state_code)),
        (SetIn::NotMoving, _) => None,
    }
}

/// The error strings of the manual's `TE`/`TB` table.
pub(super) fn error_text(code: char) -> Option<&'static str> {
    Some(match code {
        '@' => "No error",
        'A' => "Unknown message code or floating point controller address.",
        'B' => "Controller address not correct.",
        'C' => "Parameter missing or out of range.",
        'D' => "Command not allowed.",
        'E' => "Home sequence already started.",
        'F' => "ESP stage name unknown.",
        'G' => "Displacement out of limits.",
        'H' => "Command not allowed in NOT REFERENCED state.",
        'I' => "Command not allowed in CONFIGURATION state.",
        'J' => "Command not allowed in DISABLE state.",
        'K' => "Command not allowed in READY state.",
        'L' => "Command not allowed in HOMING state.",
        'M' => "Command not allowed in MOVING state.",
        'N' => "Current position out of software limit.",
        'S' => "Communication Time Out.",
        'U' => "Error during EEPROM access.",
        'V' => "Error during command execution.",
        'W' => "Command not allowed for PP version.",
        'X' => "Command not allowed for CC version.",
        _ => return None,
    })
}
