//! What each command does on one device: movements, settings, warnings.

use super::device::{Command, Outcome, ZAxis, ZDevice, ordered_flags};
use super::{
    ACCEL_DATA_PER_USTEP_S2, DEVICE_ID, FIRMWARE_VERSION, HOMING_SEARCH_S, PACKET_SIZE_MAX,
    VELOCITY_DATA_PER_USTEP_S,
};
use crate::faults::DeviceFaults;
use crate::recording::MotionCommand;

/// A number as the device reads it: decimal, or hexadecimal written `0x...`.
pub(super) fn number(word: &str) -> Option<i64> {
    let (neg, digits) = match word.strip_prefix('-') {
        Some(d) => (true, d),
        None => (false, word),
    };
    let n = match digits.strip_prefix("0x").or_else(|| digits.strip_prefix("0X")) {
        Some(hex) if !hex.is_empty() => i64::from_str_radix(hex, 16).ok()?,
        Some(_) => return None,
        None => digits.parse::<i64>().ok()?,
    };
    Some(if neg { -n } else { n })
}

pub(super) fn execute(dev: &mut ZDevice, cmd: &Command<'_>, now: f64, faults: &DeviceFaults) -> Outcome {
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
            let arg: Option<i64> = words.get(2).and_then(|w| number(w));
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
                // Unhomed: every movement to a position is refused, relative ones too (manual: `/move rel 10000`
                // answered `RJ IDLE WR BADDATA`).
                if !a.referenced {
                    return Outcome::Rejected("BADDATA");
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
            let Some(data) = words.get(2).and_then(|w| number(w)) else {
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
    let int: Option<i64> = number(value);
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

#[cfg(test)]
mod tests {
    use super::number;

    #[test]
    fn numbers_in_decimal_or_hexadecimal() {
        assert_eq!(number("10000"), Some(10000));
        assert_eq!(number("-25"), Some(-25));
        assert_eq!(number("0x2710"), Some(10000));
        assert_eq!(number("0XfF"), Some(255));
        assert_eq!(number("-0x10"), Some(-16));
        assert_eq!(number("0x"), None);
        assert_eq!(number("0xg"), None);
        assert_eq!(number("1.5"), None);
    }
}
