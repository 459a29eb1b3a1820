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
//! Warning flags: WR (no reference position) until homed, FS (stalled and stopped) after a stall, WL
//! (unexpected limit) after running into a limit switch, NI (movement interrupted) after a stop or a new
//! movement command during a movement. Absolute movements are refused (BADCOMMAND) while WR is set.
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
//! Still unconfirmed against the manual: silence on a bad checksum, the flag field of a `warnings clear`
//! reply, BADCOMMAND for absolute moves without reference, and the `device.id`/`version` values.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use gonio_instrument::Axis;

use crate::clock::SimClock;
use crate::faults::DeviceFaults;
use crate::motion::{AxisMotion, MoveEnd};
use crate::recording::MotionCommand;
use crate::session::{Output, SerialEmulator};

/// Longest command the device buffers before discarding it.
const MAX_COMMAND: usize = 256;
/// Largest packet the device sends or accepts, as reported by `get comm.packet.size.max`.
const PACKET_SIZE_MAX: u32 = 80;
/// Firmware version reported by `get version` (a real firmware release; the build number is made up).
const FIRMWARE_VERSION: &str = "7.38";
/// Device id reported by `get device.id` / `get deviceid`. UNCONFIRMED: not checked against Zaber's device
/// database (unreachable here); a host library that identifies devices online would look this id up.
const DEVICE_ID: u32 = 50081;
const VELOCITY_DATA_PER_USTEP_S: f64 = 1.6384;
const ACCEL_DATA_PER_USTEP_S2: f64 = 1.6384 / 10_000.0;
/// Slow final approach of the homing search (s).
const HOMING_SEARCH_S: f64 = 0.5;

/// LRC checksum of `body` as the protocol defines it: two's complement of the byte sum, modulo 256.
pub fn lrc(body: &[u8]) -> u8 {
    let sum = body.iter().fold(0u8, |s, b| s.wrapping_add(*b));
    (!sum).wrapping_add(1)
}

#[derive(Debug)]
struct ZAxis {
    number: u8,
    axis: Axis,
    motion: Arc<Mutex<AxisMotion>>,
    microstep_deg: f64,
    speed_deg_s: f64,
    accel_deg_s2: f64,
    limit_min: i64,
    limit_max: i64,
    referenced: bool,
    homing: bool,
    /// A movement is under way whose end has not been handled yet.
    busy: bool,
    flags: BTreeSet<&'static str>,
    /// When the last movement ended and its alert is due.
    alert_due_s: Option<f64>,
}

impl ZAxis {
    fn motion(&self) -> std::sync::MutexGuard<'_, AxisMotion> {
        self.motion.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn pos_steps(&self, now: f64) -> i64 {
        let deg = self.motion().encoder_deg(now);
        (deg / self.microstep_deg).round() as i64
    }

    /// Handle the end of a movement that finished by `now`.
    fn update(&mut self, now: f64, alerts: bool) {
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
    fn start(&mut self, now: f64, target_deg: f64, speed_deg_s: f64, faults: &DeviceFaults) {
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

/// The device's current warning flags, highest priority first (faults, warnings, notices).
fn ordered_flags(axes: &[&ZAxis]) -> Vec<&'static str> {
    let mut all: BTreeSet<&'static str> = BTreeSet::new();
    for a in axes {
        all.extend(a.flags.iter().copied());
    }
    let rank = |f: &str| match f.as_bytes().first() {
        Some(b'F') => 0,
        Some(b'W') => 1,
        _ => 2,
    };
    let mut v: Vec<&'static str> = all.into_iter().collect();
    v.sort_by_key(|f| (rank(f), *f));
    v
}

#[derive(Debug)]
struct ZDevice {
    number: u8,
    axes: Vec<ZAxis>,
    alert: bool,
    checksum_replies: bool,
    serial: u32,
}

/// A parsed command.
#[derive(Debug)]
struct Command<'a> {
    device: u8,
    axis: u8,
    id: Option<u8>,
    words: Vec<&'a str>,
}

/// Parse the text between `/` and the checksum. None: unparsable header (e.g. a number out of range).
fn parse(body: &str) -> Option<Command<'_>> {
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

enum Outcome {
    Ok(String),
    Rejected(&'static str),
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
        }
    }

    fn handle(&mut self, raw: &[u8], now: f64) -> Vec<Output> {
        let Ok(text) = std::str::from_utf8(raw) else {
            return Vec::new();
        };
        // Checksum: verified when present; a wrong one means the command is ignored.
        let body = match text.rsplit_once(':') {
            Some((body, cs)) if cs.len() == 2 && cs.bytes().all(|b| b.is_ascii_hexdigit()) => {
                let Ok(cs) = u8::from_str_radix(cs, 16) else {
                    return Vec::new();
                };
                let sum = body.bytes().fold(0u8, |s, b| s.wrapping_add(b));
                if sum.wrapping_add(cs) != 0 {
                    tracing::debug!(chain = %self.name, cmd = text, "Zaber: bad checksum, command ignored");
                    return Vec::new();
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

fn execute(dev: &mut ZDevice, cmd: &Command<'_>, now: f64, faults: &DeviceFaults) -> Outcome {
    if cmd.axis != 0 && !dev.axes.iter().any(|a| a.number == cmd.axis) {
        return Outcome::Rejected("BADAXIS");
    }
    let words = &cmd.words;
    let device_scope = cmd.axis == 0;
    let Some(first) = words.first() else {
        // The empty command: a status reply.
        return Outcome::Ok("0".into());
    };
    let targets = |dev: &mut ZDevice| -> Vec<usize> {
        (0..dev.axes.len())
            .filter(|i| device_scope || dev.axes[*i].number == cmd.axis)
            .collect()
    };
    match (*first, words.len()) {
        ("home", 1) => {
            for i in targets(dev) {
                let a = &mut dev.axes[i];
                a.motion().note_command(now, MotionCommand::Home);
                let v = a.speed_deg_s;
                a.start(now, 0.0, v, faults);
                a.motion().dwell(now, HOMING_SEARCH_S);
                a.homing = true;
            }
            Outcome::Ok("0".into())
        }
        ("move", 2) | ("move", 3) if words[1] != "vel" => {
            let kind = words[1];
            let arg: Option<i64> = words.get(2).and_then(|w| w.parse().ok());
            if words.len() == 3 && arg.is_none() {
                return Outcome::Rejected("BADDATA");
            }
            let idx = targets(dev);
            // Check every axis first: a rejected command moves nothing.
            let mut plan = Vec::new();
            for &i in &idx {
                let a = &mut dev.axes[i];
                let steps = match (kind, arg) {
                    ("abs", Some(n)) => n,
                    ("rel", Some(n)) => {
                        let from = (a.motion().target_deg() / a.microstep_deg).round() as i64;
                        from.saturating_add(n)
                    }
                    ("max", None) => a.limit_max,
                    ("min", None) => a.limit_min,
                    _ => return Outcome::Rejected("BADCOMMAND"),
                };
                let target_deg = steps as f64 * a.microstep_deg;
                a.motion().note_command(now, MotionCommand::MoveTo { target_deg });
                if kind != "rel" && !a.referenced {
                    return Outcome::Rejected("BADCOMMAND");
                }
                if !(a.limit_min..=a.limit_max).contains(&steps) {
                    return Outcome::Rejected("BADDATA");
                }
                plan.push((i, steps));
            }
            for (i, steps) in plan {
                let a = &mut dev.axes[i];
                let target = steps as f64 * a.microstep_deg;
                let v = a.speed_deg_s;
                a.start(now, target, v, faults);
            }
            Outcome::Ok("0".into())
        }
        // `move vel N`: turn at N (velocity data units, sign = direction) until stopped or until the travel
        // limit, where the device stops by itself. Velocity moves need no reference position. `move vel 0`
        // decelerates to rest. The vendor host library sends this for `Axis.move_velocity`.
        ("move", 3) if words[1] == "vel" => {
            let Some(data) = words.get(2).and_then(|w| w.parse::<i64>().ok()) else {
                return Outcome::Rejected("BADDATA");
            };
            for i in targets(dev) {
                let a = &mut dev.axes[i];
                let speed_deg_s = data.unsigned_abs() as f64 / VELOCITY_DATA_PER_USTEP_S * a.microstep_deg;
                if data == 0 {
                    a.motion()
                        .note_command(now, MotionCommand::Stop { abrupt: false });
                    if a.motion().is_moving(now) {
                        let acc = a.accel_deg_s2;
                        a.motion().stop(now, acc);
                    }
                    continue;
                }
                let limit = if data > 0 { a.limit_max } else { a.limit_min };
                let target = limit as f64 * a.microstep_deg;
                a.motion()
                    .note_command(now, MotionCommand::MoveTo { target_deg: target });
                a.start(now, target, speed_deg_s, faults);
            }
            Outcome::Ok("0".into())
        }
        ("stop", 1) | ("estop", 1) => {
            for i in targets(dev) {
                let a = &mut dev.axes[i];
                let abrupt = *first == "estop";
                a.motion().note_command(now, MotionCommand::Stop { abrupt });
                if a.motion().is_moving(now) {
                    a.flags.insert("NI");
                    let acc = a.accel_deg_s2;
                    if *first == "stop" {
                        a.motion().stop(now, acc);
                    } else {
                        a.motion().halt(now);
                    }
                    a.homing = false;
                }
            }
            Outcome::Ok("0".into())
        }
        ("warnings", 1) | ("warnings", 2) => {
            if words.len() == 2 && words[1] != "clear" {
                return Outcome::Rejected("BADCOMMAND");
            }
            let idx = targets(dev);
            let axes: Vec<&ZAxis> = idx.iter().map(|i| &dev.axes[*i]).collect();
            let flags = ordered_flags(&axes);
            let mut data = format!("{:02}", flags.len());
            for f in &flags {
                data.push(' ');
                data.push_str(f);
            }
            if words.len() == 2 {
                for i in idx {
                    let a = &mut dev.axes[i];
                    // Conditions that still hold cannot be cleared.
                    a.flags.retain(|f| *f == "WR" && !a.referenced);
                }
            }
            Outcome::Ok(data)
        }
        ("tools", _) if words.get(1) == Some(&"echo") => Outcome::Ok(words[2..].join(" ")),
        ("get", 2) => get(dev, cmd, words[1], now),
        ("set", 3) => set(dev, cmd, words[1], words[2], now),
        _ => Outcome::Rejected("BADCOMMAND"),
    }
}

fn fmt_setting(x: f64) -> String {
    let r = (x * 1e3).round() / 1e3;
    format!("{r}")
}

fn get(dev: &mut ZDevice, cmd: &Command<'_>, setting: &str, now: f64) -> Outcome {
    let device_value = match setting {
        "system.serial" => Some(dev.serial.to_string()),
        "device.id" | "deviceid" => Some(DEVICE_ID.to_string()),
        "comm.packet.size.max" => Some(PACKET_SIZE_MAX.to_string()),
        "comm.alert" => Some(u8::from(dev.alert).to_string()),
        "comm.checksum" => Some(u8::from(dev.checksum_replies).to_string()),
        "comm.address" => Some(dev.number.to_string()),
        "comm.rs232.baud" => Some("115200".into()),
        "comm.protocol" | "comm.rs232.protocol" => Some("2".into()),
        "system.axiscount" => Some(dev.axes.len().to_string()),
        "version" => Some(FIRMWARE_VERSION.into()),
        "version.build" => Some("12345".into()),
        "system.access" => Some("1".into()),
        _ => None,
    };
    if let Some(v) = device_value {
        return if cmd.axis != 0 {
            Outcome::Rejected("DEVICEONLY")
        } else {
            Outcome::Ok(v)
        };
    }
    let mut values = Vec::new();
    for a in dev.axes.iter().filter(|a| cmd.axis == 0 || a.number == cmd.axis) {
        let usteps_per_deg = 1.0 / a.microstep_deg;
        let v = match setting {
            "pos" => a.pos_steps(now).to_string(),
            "encoder.pos" => a.pos_steps(now).to_string(),
            "maxspeed" => fmt_setting((a.speed_deg_s * usteps_per_deg * VELOCITY_DATA_PER_USTEP_S).round()),
            "accel" => fmt_setting((a.accel_deg_s2 * usteps_per_deg * ACCEL_DATA_PER_USTEP_S2).round()),
            "limit.min" => a.limit_min.to_string(),
            "limit.max" => a.limit_max.to_string(),
            "limit.home.pos" => "0".into(),
            "resolution" => "64".into(),
            // An integrated device has no peripheral: `peripheral.id` (FW7 name) and `peripheralid` (the older
            // name, still the one the vendor host library asks) are both rejected as unknown settings.
            // UNCONFIRMED against a real X-series device; the library accepts BADCOMMAND here.
            "peripheral.id" | "peripheralid" => return Outcome::Rejected("BADCOMMAND"),
            _ => return Outcome::Rejected("BADCOMMAND"),
        };
        values.push(v);
    }
    Outcome::Ok(values.join(" "))
}

fn set(dev: &mut ZDevice, cmd: &Command<'_>, setting: &str, value: &str, now: f64) -> Outcome {
    let int: Option<i64> = value.parse().ok();
    match setting {
        "comm.alert" | "comm.checksum" => {
            if cmd.axis != 0 {
                return Outcome::Rejected("DEVICEONLY");
            }
            let on = match int {
                Some(0) => false,
                Some(1) => true,
                _ => return Outcome::Rejected("BADDATA"),
            };
            if setting == "comm.alert" {
                dev.alert = on;
            } else {
                dev.checksum_replies = on;
            }
            return Outcome::Ok("0".into());
        }
        "system.serial" | "device.id" | "system.axiscount" | "version" | "comm.packet.size.max" => {
            return Outcome::Rejected("BADCOMMAND");
        }
        _ => {}
    }
    let Some(n) = int else {
        return Outcome::Rejected("BADDATA");
    };
    let idx: Vec<usize> = (0..dev.axes.len())
        .filter(|i| cmd.axis == 0 || dev.axes[*i].number == cmd.axis)
        .collect();
    for i in idx {
        let a = &mut dev.axes[i];
        let deg_per_ustep = a.microstep_deg;
        match setting {
            "maxspeed" if n > 0 => a.speed_deg_s = n as f64 / VELOCITY_DATA_PER_USTEP_S * deg_per_ustep,
            "accel" if n > 0 => a.accel_deg_s2 = n as f64 / ACCEL_DATA_PER_USTEP_S2 * deg_per_ustep,
            "limit.min" if n <= a.limit_max => a.limit_min = n,
            "limit.max" if n >= a.limit_min => a.limit_max = n,
            "pos" => {
                if a.motion().is_moving(now) {
                    return Outcome::Rejected("BADDATA");
                }
                a.motion().set_position(now, n as f64 * deg_per_ustep);
                a.referenced = true;
                a.flags.remove("WR");
            }
            "maxspeed" | "accel" | "limit.min" | "limit.max" => return Outcome::Rejected("BADDATA"),
            _ => return Outcome::Rejected("BADCOMMAND"),
        }
    }
    Outcome::Ok("0".into())
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
