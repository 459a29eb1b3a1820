//! One Zaber device and its axes: motion, warning flags in the manual's priority order, and the parsed command.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use gonio_instrument::Axis;

use crate::faults::DeviceFaults;
use crate::motion::AxisMotion;
use crate::move_end::MoveEnd;

#[derive(Debug)]
pub(super) struct ZAxis {
    pub(super) number: u8,
    pub(super) axis: Axis,
    pub(super) motion: Arc<Mutex<AxisMotion>>,
    pub(super) microstep_deg: f64,
    pub(super) speed_deg_s: f64,
    pub(super) accel_deg_s2: f64,
    pub(super) limit_min: i64,
    pub(super) limit_max: i64,
    pub(super) referenced: bool,
    pub(super) homing: bool,
    /// A movement is under way whose end has not been handled yet.
    pub(super) busy: bool,
    pub(super) flags: BTreeSet<&'static str>,
    /// When the last movement ended and its alert is due.
    pub(super) alert_due_s: Option<f64>,
}

impl ZAxis {
    pub(super) fn motion(&self) -> std::sync::MutexGuard<'_, AxisMotion> {
        self.motion.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(super) fn pos_steps(&self, now: f64) -> i64 {
        let deg = self.motion().encoder_deg(now);
        (deg / self.microstep_deg).round() as i64
    }

    /// Handle the end of a movement that finished by `now`.
    pub(super) fn update(&mut self, now: f64, alerts: bool) {
        if !self.busy {
            return;
        }
        let (moving, end, end_s) = {
            let mut m = self.motion();
            let end_s = m.end_time_s();
            (m.is_moving(now), m.end_reason(), end_s)
        };
        if moving {
            return;
        }
        let _ = end_s;
        self.busy = false;
        match end {
            MoveEnd::Arrived if self.homing => {
                self.motion().set_position(now, 0.0);
                self.referenced = true;
                self.flags.remove("WR");
            }
            MoveEnd::Stalled => {
                tracing::warn!(axis = %self.axis.name, "Zaber: stall, FS");
                self.flags.insert("FS");
            }
            MoveEnd::LimitNegative | MoveEnd::LimitPositive => {
                self.flags.insert("WL");
            }
            _ => {}
        }
        self.homing = false;
        if alerts {
            self.alert_due_s = Some(now);
        }
    }

    /// Start a movement to `target_deg` at `speed_deg_s` (the axis' `maxspeed` for every move but `move vel`).
    pub(super) fn start(&mut self, now: f64, target_deg: f64, speed_deg_s: f64, faults: &DeviceFaults) {
        if self.motion().is_moving(now) {
            self.flags.insert("NI");
        }
        // Only a move that travels can stall.
        let travels = (self.motion().motor_deg(now) - target_deg).abs() > 0.0;
        let stall = if travels {
            faults.stall(&self.axis.name)
        } else {
            None
        };
        let a = self.accel_deg_s2;
        self.motion().start_move(now, target_deg, speed_deg_s, a, stall);
        self.busy = true;
        self.alert_due_s = None;
    }
}

/// The warning flags in the firmware-6 ASCII manual's priority order: the reply shows the first one set.
pub(super) const FLAG_PRIORITY: [&str; 11] =
    ["FD", "FS", "FE", "WL", "WV", "WT", "WM", "WR", "NC", "NI", "NU"];

/// The device's current warning flags, highest priority first (the manual's order; any other flag after them,
/// faults before warnings before notices).
pub(super) fn ordered_flags(axes: &[&ZAxis]) -> Vec<&'static str> {
    let mut all: BTreeSet<&'static str> = BTreeSet::new();
    for a in axes {
        all.extend(a.flags.iter().copied());
    }
    let rank = |f: &str| match FLAG_PRIORITY.iter().position(|p| *p == f) {
        Some(i) => (0, i),
        None => match f.as_bytes().first() {
            Some(b'F') => (1, 0),
            Some(b'W') => (1, 1),
            _ => (1, 2),
        },
    };
    let mut v: Vec<&'static str> = all.into_iter().collect();
    v.sort_by_key(|f| (rank(f), *f));
    v
}

#[derive(Debug)]
pub(super) struct ZDevice {
    pub(super) number: u8,
    pub(super) axes: Vec<ZAxis>,
    pub(super) alert: bool,
    pub(super) checksum_replies: bool,
    pub(super) serial: u32,
}

/// A parsed command.
#[derive(Debug)]
pub(super) struct Command<'a> {
    pub(super) device: u8,
    pub(super) axis: u8,
    pub(super) id: Option<u8>,
    pub(super) words: Vec<&'a str>,
}

/// Parse the text between `/` and the checksum. None: unparsable header (e.g. a number out of range).
pub(super) fn parse(body: &str) -> Option<Command<'_>> {
    let mut words: Vec<&str> = body.split_ascii_whitespace().collect();
    let mut numbers = Vec::new();
    while numbers.len() < 3 {
        match words.first() {
            Some(w) if w.bytes().all(|b| b.is_ascii_digit()) => {
                numbers.push(w.parse::<u32>().ok()?);
                words.remove(0);
            }
            _ => break,
        }
    }
    let device = u8::try_from(*numbers.first().unwrap_or(&0))
        .ok()
        .filter(|d| *d <= 99)?;
    let axis = u8::try_from(*numbers.get(1).unwrap_or(&0))
        .ok()
        .filter(|a| *a <= 9)?;
    let id = match numbers.get(2) {
        Some(id) => Some(u8::try_from(*id).ok().filter(|i| *i <= 99)?),
        None => None,
    };
    Some(Command {
        device,
        axis,
        id,
        words,
    })
}

pub(super) enum Outcome {
    Ok(String),
    Rejected(&'static str),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_follow_the_manual_priority_not_the_alphabet() {
        let motion = Arc::new(Mutex::new(AxisMotion::new(
            crate::motion::AxisParams {
                hw_min_deg: -1.0,
                hw_max_deg: 1.0,
                backlash_deg: 0.0,
                encoder_resolution_deg: 0.0,
            },
            0.0,
        )));
        let axis = gonio_instrument::InstrumentFile::simulated().instrument.axes[2].clone();
        let a = ZAxis {
            number: 1,
            axis,
            motion,
            microstep_deg: 1.0,
            speed_deg_s: 1.0,
            accel_deg_s2: 1.0,
            limit_min: -1,
            limit_max: 1,
            referenced: false,
            homing: false,
            busy: false,
            flags: BTreeSet::from(["WM", "WR", "WV", "NI", "FS", "FD", "XX"]),
            alert_due_s: None,
        };
        assert_eq!(ordered_flags(&[&a]), ["FD", "FS", "WV", "WM", "WR", "NI", "XX"]);
    }
}
