//! Zaber ASCII devices daisy-chained on one port: the device side of the protocol.
//!
//! Command `/[device [axis [id]]] command [args][:CC]` ended by CR, LF or CRLF; reply
//! `@DD A [id] FL STATUS WW data[:CC]\r\n`. Device 0 (or none) addresses every device, and each replies. Axis 0
//! (or none) is the whole device. A message id is echoed. A command carrying a checksum (`:CC`, the LRC of the
//! bytes between `/` and `:`) is verified and silently ignored when wrong; replies carry a checksum when the
//! device setting `comm.checksum` is 1. Alerts `!DD A STATUS WW` are sent when a movement ends and
//! `comm.alert` is 1. Positions are in microsteps, speeds and accelerations in the device's data units
//! (velocity data = microsteps/s x 1.6384, acceleration data = microsteps/s^2 x 1.6384 / 10000).
//!
//! Split by job: `device` (axes, warning flags, the parsed command), `commands` (what each command does), this
//! module (the port: framing, checksums, the chain's replies).
//!
//! Warning flags: WR (no reference position) until homed, FS (stalled and stopped) after a stall, WL
//! (unexpected limit) after running into a limit switch, NI (movement interrupted) after a stop or a new
//! movement command during a movement; the reply shows the first set in the manual's priority order FD FS FE
//! WL WV WT WM WR NC NI NU (not alphabetical). Every movement to a position (`move abs`, `rel`, `min`, `max`)
//! is refused while WR is set: the firmware-6 ASCII manual shows `/move rel 10000` on an unhomed device
//! answered `@01 0 RJ IDLE WR BADDATA`.
//!
//! Checked against the vendor host library (zaber-motion 10.3, `tests/zaber_host_library.py`): it opens the
//! port, detects both devices (`/0 0 00` broadcast, then per device `get comm.packet.size.max`, and with
//! identification `get deviceid`, `system.serial`, `version`, `version.build`, `device.hw.modified`,
//! `comm.command.packets.max`, `comm.word.size.max`, `get.settings.max`, `system.axiscount`, per axis
//! `resolution` and `peripheralid`), homes (`home`, `warnings clear`, empty-command polls, alert), moves
//! (`move abs`, `move rel`, `move vel`, `stop`), reads `pos` and settings, maps `RJ BADDATA` to its
//! BadDataException and verifies reply checksums after `set comm.checksum 1`. It sends a message id and a
//! checksum on every command. Settings this emulation rejects as unknown (`device.hw.modified`,
//! `comm.command.packets.max`, `comm.word.size.max`, `get.settings.max`, `peripheralid`) are tolerated by the
//! library; in every exchange observed it then sent single-packet commands and single-setting gets, so `cont`
//! packets and `#` info messages are not emulated. Identification itself needs Zaber's online device database (not
//! reachable offline), so the library test runs with `identify_devices=False`, in native units.
//!
//! Protocol notes, and where each comes from (the firmware-6 ASCII protocol manual unless said otherwise):
//! - A bad checksum: the manual says both that every device on the chain replies with a rejection and that the
//!   message is ignored. `[simulator.quirks] zaber_bad_checksum` picks: `reject-all` (default: each device
//!   answers `@DD 0 [id] RJ IDLE -- BADDATA`, several replies to one message) or `ignore` (no reply).
//!   Unconfirmed: the rejection's reason word and flag field.
//! - Numbers in commands may be written in hexadecimal as `0x...`.
//! - `get deviceid` answers 20022 and `get version` 6.06, the manual's example values.
//! - Still unconfirmed: the flag field of a `warnings clear` reply.

mod commands;
mod device;

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use gonio_instrument::{Axis, ZaberBadChecksum};

use crate::clock::SimClock;
use crate::faults::DeviceFaults;
use crate::motion::AxisMotion;
use crate::session::{Output, SerialEmulator};
use commands::execute;
use device::{Outcome, ZAxis, ZDevice, ordered_flags, parse};

/// Longest command the device buffers before discarding it.
const MAX_COMMAND: usize = 256;
/// Largest packet the device sends or accepts, as reported by `get comm.packet.size.max`.
const PACKET_SIZE_MAX: u32 = 80;
/// Firmware version reported by `get version`: the firmware-6 manual's example value (the build number is made up).
const FIRMWARE_VERSION: &str = "6.06";
/// Device id reported by `get device.id` / `get deviceid`: the firmware-6 manual's example value.
const DEVICE_ID: u32 = 20022;
const VELOCITY_DATA_PER_USTEP_S: f64 = 1.6384;
const ACCEL_DATA_PER_USTEP_S2: f64 = 1.6384 / 10_000.0;
/// Slow final approach of the homing search (s).
const HOMING_SEARCH_S: f64 = 0.5;

/// LRC checksum of `body` as the protocol defines it: two's complement of the byte sum, modulo 256.
pub fn lrc(body: &[u8]) -> u8 {
    let sum = body.iter().fold(0u8, |s, b| s.wrapping_add(*b));
    (!sum).wrapping_add(1)
}

/// The port with its chain of Zaber devices.
#[derive(Debug)]
pub struct ZaberChain {
    name: String,
    devices: Vec<ZDevice>,
    input: Vec<u8>,
    in_command: bool,
    faults: DeviceFaults,
    clock: SimClock,
    bad_checksum: ZaberBadChecksum,
}

impl ZaberChain {
    pub fn new(
        name: &str,
        axes: Vec<(Axis, Arc<Mutex<AxisMotion>>)>,
        faults: DeviceFaults,
        clock: SimClock,
    ) -> ZaberChain {
        let mut devices: Vec<ZDevice> = Vec::new();
        for (axis, motion) in axes {
            let microstep_deg = axis.microstep_deg.unwrap_or(1.0);
            let p = *motion.lock().unwrap_or_else(|e| e.into_inner()).params();
            let z = ZAxis {
                number: axis.zaber_axis.max(1),
                speed_deg_s: axis.max_speed_deg_s,
                accel_deg_s2: axis.accel_deg_s2,
                limit_min: (p.hw_min_deg / microstep_deg).ceil() as i64,
                limit_max: (p.hw_max_deg / microstep_deg).floor() as i64,
                microstep_deg,
                axis: axis.clone(),
                motion,
                referenced: false,
                homing: false,
                busy: false,
                flags: BTreeSet::from(["WR"]),
                alert_due_s: None,
            };
            match devices.iter_mut().find(|d| d.number == axis.address) {
                Some(d) => d.axes.push(z),
                None => devices.push(ZDevice {
                    number: axis.address,
                    axes: vec![z],
                    alert: false,
                    checksum_replies: false,
                    serial: 33_000 + u32::from(axis.address),
                }),
            }
        }
        devices.sort_by_key(|d| d.number);
        for d in &mut devices {
            d.axes.sort_by_key(|a| a.number);
        }
        ZaberChain {
            name: name.to_string(),
            devices,
            input: Vec::new(),
            in_command: false,
            faults,
            clock,
            bad_checksum: ZaberBadChecksum::Ignore,
        }
    }

    /// What a bad checksum gets (see the module notes); [`ZaberChain::new`] ignores the message.
    pub fn with_bad_checksum(mut self, bad_checksum: ZaberBadChecksum) -> ZaberChain {
        self.bad_checksum = bad_checksum;
        self
    }

    /// Every device's rejection of a message with a bad checksum.
    fn reject_bad_checksum(&self, body: &str, now: f64) -> Vec<Output> {
        let id = parse(body)
            .and_then(|c| c.id)
            .map(|i| format!(" {i}"))
            .unwrap_or_default();
        self.devices
            .iter()
            .map(|dev| Output {
                at_s: now,
                bytes: frame(
                    b'@',
                    &format!("{:02} 0{id} RJ IDLE -- BADDATA", dev.number),
                    dev.checksum_replies,
                ),
            })
            .collect()
    }

    fn handle(&mut self, raw: &[u8], now: f64) -> Vec<Output> {
        let Ok(text) = std::str::from_utf8(raw) else {
            return Vec::new();
        };
        // Checksum: verified when present; a wrong one is rejected by every device, or ignored.
        let body = match text.rsplit_once(':') {
            Some((body, cs)) if cs.len() == 2 && cs.bytes().all(|b| b.is_ascii_hexdigit()) => {
                let Ok(cs) = u8::from_str_radix(cs, 16) else {
                    return Vec::new();
                };
                let sum = body.bytes().fold(0u8, |s, b| s.wrapping_add(b));
                if sum.wrapping_add(cs) != 0 {
                    tracing::debug!(chain = %self.name, cmd = text, variant = ?self.bad_checksum, "Zaber: bad checksum");
                    return match self.bad_checksum {
                        ZaberBadChecksum::RejectAll => self.reject_bad_checksum(body, now),
                        ZaberBadChecksum::Ignore => Vec::new(),
                    };
                }
                body
            }
            _ => text,
        };
        let Some(cmd) = parse(body) else {
            tracing::debug!(chain = %self.name, cmd = text, "Zaber: unparsable header, ignored");
            return Vec::new();
        };
        let faults = self.faults.clone();
        let mut out = Vec::new();
        for dev in &mut self.devices {
            if cmd.device != 0 && cmd.device != dev.number {
                continue;
            }
            for a in &mut dev.axes {
                a.update(now, dev.alert);
            }
            let outcome = execute(dev, &cmd, now, &faults);
            let mut axes: Vec<&ZAxis> = dev
                .axes
                .iter()
                .filter(|a| cmd.axis == 0 || a.number == cmd.axis)
                .collect();
            if axes.is_empty() {
                // A bad axis number: the reply shows the whole device's state.
                axes = dev.axes.iter().collect();
            }
            let busy = axes.iter().any(|a| a.busy);
            let flag = ordered_flags(&axes).first().copied().unwrap_or("--");
            let (fl, data) = match outcome {
                Outcome::Ok(d) => ("OK", d),
                Outcome::Rejected(reason) => ("RJ", reason.to_string()),
            };
            let id = cmd.id.map(|i| format!(" {i}")).unwrap_or_default();
            let status = if busy { "BUSY" } else { "IDLE" };
            let body = format!("{:02} {}{id} {fl} {status} {flag} {data}", dev.number, cmd.axis);
            out.push(Output {
                at_s: now,
                bytes: frame(b'@', &body, dev.checksum_replies),
            });
        }
        out
    }
}

/// `<lead><body>[:CC]\r\n`.
fn frame(lead: u8, body: &str, checksum: bool) -> Vec<u8> {
    let mut bytes = vec![lead];
    bytes.extend_from_slice(body.as_bytes());
    if checksum {
        bytes.extend_from_slice(format!(":{:02X}", lrc(body.as_bytes())).as_bytes());
    }
    bytes.extend_from_slice(b"\r\n");
    bytes
}

impl SerialEmulator for ZaberChain {
    fn reset_input(&mut self) {
        self.input.clear();
        self.in_command = false;
    }

    fn receive(&mut self, data: &[u8], now_s: f64) -> Vec<Output> {
        let mut out = Vec::new();
        for &b in data {
            match b {
                b'/' if !self.in_command => {
                    self.in_command = true;
                    self.input.clear();
                }
                b'\r' | b'\n' => {
                    if std::mem::replace(&mut self.in_command, false) {
                        let cmd = std::mem::take(&mut self.input);
                        tracing::debug!(chain = %self.name, cmd = %String::from_utf8_lossy(&cmd), "Zaber command");
                        out.extend(self.handle(&cmd, now_s));
                    }
                }
                // Backspace erases, DEL discards the incomplete command.
                0x08 => {
                    self.input.pop();
                }
                0x7f => {
                    self.in_command = false;
                    self.input.clear();
                }
                _ if !self.in_command => {}
                0x20..=0x7e if self.input.len() < MAX_COMMAND => self.input.push(b),
                _ => {
                    // Unsupported character or overlong command: discarded.
                    self.in_command = false;
                    self.input.clear();
                }
            }
        }
        out
    }

    fn next_event_s(&mut self, now_s: f64) -> Option<f64> {
        let mut next: Option<f64> = None;
        for dev in &mut self.devices {
            if !dev.alert {
                continue;
            }
            for a in &mut dev.axes {
                let t = match a.alert_due_s {
                    Some(t) => Some(t),
                    None if a.busy => a.motion().end_time_s().or(Some(now_s)),
                    None => None,
                };
                if let Some(t) = t {
                    next = Some(next.map_or(t, |n| n.min(t)));
                }
            }
        }
        next
    }

    fn poll_events(&mut self, now_s: f64) -> Vec<Output> {
        let _ = self.clock;
        let mut out = Vec::new();
        for dev in &mut self.devices {
            for i in 0..dev.axes.len() {
                dev.axes[i].update(now_s, dev.alert);
                if dev.axes[i].alert_due_s.is_some_and(|t| t <= now_s) {
                    dev.axes[i].alert_due_s = None;
                    if !dev.alert {
                        continue;
                    }
                    let a = &dev.axes[i];
                    let flag = ordered_flags(&[a]).first().copied().unwrap_or("--");
                    let status = if a.busy { "BUSY" } else { "IDLE" };
                    let body = format!("{:02} {} {status} {flag}", dev.number, a.number);
                    out.push(Output {
                        at_s: now_s,
                        bytes: frame(b'!', &body, dev.checksum_replies),
                    });
                }
            }
        }
        out
    }

    fn estop(&mut self, now_s: f64) {
        for dev in &mut self.devices {
            for a in &mut dev.axes {
                a.update(now_s, dev.alert);
                if a.motion().is_moving(now_s) {
                    a.motion().halt(now_s);
                    a.flags.insert("NI");
                    a.homing = false;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lrc_matches_the_documented_vectors() {
        assert_eq!(lrc(b"1"), 0xCF);
        assert_eq!(lrc(b"2 0 5 get maxspeed"), 0x52);
        assert_eq!(lrc(b"1 tools echo"), 0xBF);
    }

    #[test]
    fn header_numbers_are_device_axis_id() {
        let c = parse("1 2 33 get pos").expect("parses");
        assert_eq!((c.device, c.axis, c.id), (1, 2, Some(33)));
        assert_eq!(c.words, vec!["get", "pos"]);
        let c = parse("home").expect("parses");
        assert_eq!((c.device, c.axis, c.id), (0, 0, None));
        assert!(parse("100 home").is_none());
        assert!(parse("1 1 100 home").is_none());
    }
}
