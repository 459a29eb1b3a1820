//! One command line, executed by the addressed controller: the manual's whole command list.

use super::machine::{Group, group, state, wrong_state_error};
use super::params::{self, Version};
use super::{HOMING_SEARCH_S, PW0_SAVE_S, RESET_S, Smc100Chain, fmt_num, fmt_position};
use crate::motion::trapezoid_time_s;
use crate::recording::MotionCommand;

/// The version string `VE` answers (two spaces before the version, which is printed with spaces between its
/// digits), as a real SMC100CC answers.
const VERSION: &str = "SMC_CC - Controller-driver version  3. 1. 2";

impl Smc100Chain {
    /// Execute one line (without its terminator); the reply line(s) without terminator, if any.
    pub(super) fn execute(&mut self, line: &[u8], now: f64) -> Option<String> {
        // `SE` without an address starts every move stored by `<addr>SE<target>` at once.
        if line == b"SE" {
            let faults = self.faults.clone();
            for c in &mut self.controllers {
                c.update(now, self.drop_first_ts);
                if let Some(target) = c.se_target.take() {
                    if group(c.state) == Group::Ready {
                        c.start_move(now, target, &faults);
                    } else {
                        c.last_error = wrong_state_error(c.state);
                    }
                }
            }
            return None;
        }
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
        let drop_first_ts = self.drop_first_ts;
        let ctrl = self.controllers.iter_mut().find(|c| c.address == address)?;
        if now < ctrl.deaf_until_s {
            tracing::debug!(address, "SMC100: controller busy, command lost");
            return None;
        }
        ctrl.update(now, drop_first_ts);
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
                if std::mem::take(&mut ctrl.drop_next_ts) {
                    tracing::debug!(address, "SMC100: TS after power-up or homing, no reply");
                    return None;
                }
                let bits = ctrl.error_bits(now);
                reply(format!("{bits:04X}{:02X}", ctrl.state))
            }
            "TE" => {
                let e = std::mem::replace(&mut ctrl.last_error, '@');
                reply(e.to_string())
            }
            "TB" => {
                // With a letter: that code's text; without: the last error's, which it clears as TE does.
                let letter = match arg.chars().next() {
                    Some(c) if arg.len() == 1 && c != '?' => c,
                    _ => std::mem::replace(&mut ctrl.last_error, '@'),
                };
                match params::error_text(letter) {
                    Some(text) => reply(format!("{letter} {text}")),
                    None => {
                        ctrl.last_error = 'C';
                        None
                    }
                }
            }
            // The servo loop holds the motor-side encoder on the set-point: at rest in READY TP equals it (within
            // the encoder resolution), as the manual says; backlash is between the encoder and the load.
            "TP" => reply(fmt_position(ctrl.motion().motor_encoder_deg(now))),
            "TH" => reply(fmt_position(ctrl.motion().motor_deg(now))),
            "ID" if query || arg.is_empty() => reply(ctrl.stage_id.clone()),
            "ID" => {
                if g == Group::Configuration {
                    ctrl.stage_id = arg.to_string();
                } else {
                    ctrl.last_error = wrong_state_error(ctrl.state);
                }
                None
            }
            "VE" => reply(format!(" {VERSION}")),
            "RA" => reply(fmt_num(0.0)),
            "RB" => reply("15".into()),
            "ZT" => {
                // Every parameter, one line each, as the manual lists them.
                let mut lines = vec![
                    format!("{addr_text}AC{}", fmt_num(ctrl.accel_deg_s2)),
                    format!("{addr_text}ID{}", ctrl.stage_id),
                    format!("{addr_text}SL{}", fmt_num(ctrl.sl_deg)),
                    format!("{addr_text}SR{}", fmt_num(ctrl.sr_deg)),
                    format!("{addr_text}VA{}", fmt_num(ctrl.velocity_deg_s)),
                ];
                for p in params::PARAMS.iter().filter(|p| p.version != Version::Pp) {
                    let v = ctrl.params.get(p.code).copied().unwrap_or(p.default);
                    lines.push(format!("{addr_text}{}{}", p.code, fmt_num(v)));
                }
                lines.sort();
                Some(lines.join("\r\n"))
            }
            "ZX" if query => reply(fmt_num(ctrl.params.get("ZX").copied().unwrap_or(2.0))),
            "ZX" => {
                match (num, g) {
                    (Some(x), Group::Configuration) if [1.0, 2.0, 3.0].contains(&x) => {
                        ctrl.params.insert("ZX", x);
                    }
                    (Some(_), Group::Configuration) | (None, _) => ctrl.last_error = 'C',
                    (Some(_), _) => ctrl.last_error = wrong_state_error(ctrl.state),
                }
                None
            }
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
                // `RS##` also resets the controller's RS-485 address to 1 (taken at the next power-up).
                if arg == "##" {
                    ctrl.params.insert("SA", 1.0);
                } else if !arg.is_empty() {
                    ctrl.last_error = 'C';
                    return None;
                }
                ctrl.motion().halt(now);
                ctrl.state = state::NOT_REF_FROM_RESET;
                ctrl.latched_bits = 0;
                ctrl.last_error = '@';
                ctrl.deaf_until_s = now + RESET_S;
                ctrl.drop_next_ts = drop_first_ts;
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
            "PA" | "PR" | "SE" if query => {
                let target = ctrl.motion().target_deg();
                reply(fmt_position(target))
            }
            "PA" | "PR" | "SE" => {
                let Some(x) = num else {
                    ctrl.last_error = 'C';
                    return None;
                };
                let target = if code == "PR" {
                    ctrl.motion().motor_deg(now) + x
                } else {
                    x
                };
                if code == "SE" {
                    // Stored; `SE` without an address starts it.
                    if !(ctrl.sl_deg - 1e-9..=ctrl.sr_deg + 1e-9).contains(&target) {
                        ctrl.last_error = 'G';
                    } else {
                        ctrl.se_target = Some(target);
                    }
                    return None;
                }
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
            other => {
                let Some(p) = params::param(other) else {
                    ctrl.last_error = 'A';
                    return None;
                };
                if p.version == Version::Pp {
                    ctrl.last_error = 'X';
                    return None;
                }
                if query {
                    return reply(fmt_num(ctrl.params.get(p.code).copied().unwrap_or(p.default)));
                }
                let Some(x) = num.filter(|x| (p.min..=p.max).contains(x)) else {
                    ctrl.last_error = 'C';
                    return None;
                };
                if let Some(letter) = params::refusal(p, g, ctrl.state) {
                    ctrl.last_error = letter;
                    return None;
                }
                ctrl.params.insert(p.code, x);
                None
            }
        }
    }
}
