//! Thorlabs FW102C filter wheel: the device side of its serial protocol.
//!
//! Commands end with CR (a LF is ignored). The wheel echoes the command and a CR, prints the reply and a CR for
//! queries, then the `> ` prompt. `pos=N` turns the wheel the shortest way round, taking `seconds_per_position`
//! per step (twice that in slow mode, `speed=0`); the prompt comes when the wheel has arrived, and the wheel reads
//! no further command meanwhile. An unknown command answers `Command error CMD_NOT_DEFINED`, a bad argument
//! `Command error CMD_ARG_INVALID`. While the wheel turns the beam is blocked; the blank position is dark.
//!
//! Protocol notes, and where each comes from:
//! - Timing: users of real wheels report about 1 s per position at speed 1 and about 2 s at speed 0 (3 s for
//!   180 degrees). `[instrument.filter_wheel] seconds_per_position` is the time at the configured `speed`; the
//!   emulated wheel runs twice as long per position at speed 0 as at speed 1.
//! - Power-up: speed 0 and sensors 1 (modes a wheel keeps after `save`; the manual's power-up values are
//!   unconfirmed, these demand the most of a host). With `sensors=1` the position sensors stay lit while the
//!   wheel is idle and add stray light to the detector; real-hardware drivers set `sensors=0` at start-up for
//!   that reason. The stray photocurrent here ([`SENSOR_STRAY_A`]) is an unconfirmed magnitude.
//! - Right after the port opens, NUL bytes and a `Command error CMD_NOT_DEFINED` (then the prompt) can arrive
//!   (reported by users of real wheels): `[simulator.quirks] fw102c_noise_at_open`, off by default (the manual
//!   describes none), on in config/instruments/realistic.toml; here they come just ahead of the first answer on
//!   each connection. Unconfirmed: how many NUL bytes (here three) and
//!   whether the prompt follows.

use gonio_instrument::FilterWheel;

use crate::scene::Band;
use crate::session::{Output, SerialEmulator};

pub const IDN: &str = "THORLABS FW102C/FW212C Filter Wheel version 1.07";
const PROMPT: &[u8] = b"> ";
const MAX_LINE: usize = 64;
/// Photocurrent the lit position sensors add at the detector while `sensors=1` (A). Unconfirmed magnitude.
pub const SENSOR_STRAY_A: f64 = 1.0e-10;
/// What arrives right after the port opens (see the module notes).
const OPEN_NOISE: &[u8] = b"\0\0\0Command error CMD_NOT_DEFINED\r> ";

#[derive(Debug)]
pub struct Fw102c {
    name: String,
    /// Bands of positions 1..=pcount (index 0 is position 1).
    bands: Vec<Band>,
    pcount: u8,
    position: u8,
    /// Time per position at speed 1 (s).
    fast_s: f64,
    speed: u8,
    sensors: u8,
    trig: u8,
    baud: u8,
    /// While the wheel turns: (start, end) in simulated seconds.
    moving: Option<(f64, f64)>,
    /// The wheel reads no input before this time (it is turning).
    busy_until_s: f64,
    input: Vec<u8>,
    overflow: bool,
    noise_at_open: bool,
    /// The open noise is still to be sent on this connection.
    noise_pending: bool,
}

impl Fw102c {
    /// A wheel with the quirks off; see [`Fw102c::with_noise_at_open`].
    pub fn new(name: &str, config: Option<&FilterWheel>) -> Fw102c {
        let top = config
            .and_then(|w| w.positions.iter().map(|p| p.position).max())
            .unwrap_or(6);
        let pcount = if top > 6 { 12 } else { 6 };
        let bands = (1..=12u8)
            .map(|n| {
                config
                    .and_then(|w| w.positions.iter().find(|p| p.position == n))
                    .filter(|p| !p.blank)
                    .map(|p| Band {
                        band_nm: p.band_nm,
                        transmission: p.transmission,
                    })
                    .unwrap_or(Band::BLANK)
            })
            .collect();
        Fw102c {
            name: name.to_string(),
            bands,
            pcount,
            position: 1,
            // The configured time is at the configured speed; speed 0 takes twice as long as speed 1.
            fast_s: config
                .map(|w| {
                    if w.speed == 0 {
                        w.seconds_per_position / 2.0
                    } else {
                        w.seconds_per_position
                    }
                })
                .unwrap_or(1.0),
            speed: 0,
            sensors: 1,
            trig: 0,
            baud: 1,
            moving: None,
            busy_until_s: 0.0,
            input: Vec::new(),
            overflow: false,
            noise_at_open: false,
            noise_pending: false,
        }
    }

    /// NUL bytes and `CMD_NOT_DEFINED` right after each port open (see the module notes).
    pub fn with_noise_at_open(mut self, on: bool) -> Fw102c {
        self.noise_at_open = on;
        self
    }

    /// Stray photocurrent the wheel adds at the detector at `t_s` (A): the lit position sensors.
    pub fn stray_a(&self, _t_s: f64) -> f64 {
        if self.sensors == 1 { SENSOR_STRAY_A } else { 0.0 }
    }

    /// What is in the beam at `t_s`: the blank while the wheel is between positions.
    pub fn band_at(&self, t_s: f64) -> Band {
        if let Some((start, end)) = self.moving
            && t_s >= start
            && t_s < end
        {
            return Band::BLANK;
        }
        self.bands
            .get(usize::from(self.position).saturating_sub(1))
            .copied()
            .unwrap_or(Band::BLANK)
    }

    /// Execute one command at `now`; returns the reply text (without echo and prompt) and when the prompt comes.
    fn execute(&mut self, cmd: &str, now: f64) -> (Option<String>, f64) {
        const NOT_DEFINED: &str = "Command error CMD_NOT_DEFINED";
        const ARG_INVALID: &str = "Command error CMD_ARG_INVALID";
        let (key, arg) = match cmd.split_once('=') {
            Some((k, v)) => (k, Some(v)),
            None => (cmd, None),
        };
        let bool_arg = |v: &str| match v {
            "0" => Some(0u8),
            "1" => Some(1u8),
            _ => None,
        };
        match (key, arg) {
            ("*idn?", None) => (Some(IDN.into()), now),
            ("pos?", None) => (Some(self.position.to_string()), now),
            ("pcount?", None) => (Some(self.pcount.to_string()), now),
            ("speed?", None) => (Some(self.speed.to_string()), now),
            ("sensors?", None) => (Some(self.sensors.to_string()), now),
            ("trig?", None) => (Some(self.trig.to_string()), now),
            ("baud?", None) => (Some(self.baud.to_string()), now),
            ("save", None) => (None, now),
            ("pos", Some(v)) => match v.trim().parse::<u8>() {
                Ok(n) if (1..=self.pcount).contains(&n) => {
                    let count = i32::from(self.pcount);
                    let d = (i32::from(n) - i32::from(self.position)).rem_euclid(count);
                    let steps = d.min(count - d);
                    let per = if self.speed == 1 {
                        self.fast_s
                    } else {
                        2.0 * self.fast_s
                    };
                    let end = now + f64::from(steps) * per;
                    tracing::debug!(wheel = %self.name, from = self.position, to = n, steps, end_s = end, "FW102C move");
                    self.position = n;
                    self.moving = (steps > 0).then_some((now, end));
                    (None, end)
                }
                _ => (Some(ARG_INVALID.into()), now),
            },
            ("pcount", Some(v)) => match v.trim() {
                "6" => {
                    self.pcount = 6;
                    self.position = self.position.min(6);
                    (None, now)
                }
                "12" => {
                    self.pcount = 12;
                    (None, now)
                }
                _ => (Some(ARG_INVALID.into()), now),
            },
            ("speed" | "sensors" | "trig" | "baud", Some(v)) => match bool_arg(v.trim()) {
                Some(b) => {
                    match key {
                        "speed" => self.speed = b,
                        "sensors" => self.sensors = b,
                        "trig" => self.trig = b,
                        _ => self.baud = b,
                    }
                    (None, now)
                }
                None => (Some(ARG_INVALID.into()), now),
            },
            _ => (Some(NOT_DEFINED.into()), now),
        }
    }
}

impl SerialEmulator for Fw102c {
    fn reset_input(&mut self) {
        self.input.clear();
        self.overflow = false;
        self.noise_pending = self.noise_at_open;
    }

    fn receive(&mut self, data: &[u8], now_s: f64) -> Vec<Output> {
        let mut out = Vec::new();
        // The noise of a freshly opened port reaches the host ahead of the first answer. (Sent with the first
        // answer rather than at the open itself: a terminal that echoed it back would feed it to the wheel.)
        if std::mem::take(&mut self.noise_pending) {
            tracing::debug!(wheel = %self.name, "FW102C: noise right after the port opened");
            out.push(Output {
                at_s: now_s,
                bytes: OPEN_NOISE.to_vec(),
            });
        }
        for &b in data {
            match b {
                b'\r' => {
                    let line = std::mem::take(&mut self.input);
                    let overflow = std::mem::replace(&mut self.overflow, false);
                    // The wheel reads the next command only once the previous one finished.
                    let t = now_s.max(self.busy_until_s);
                    let text = String::from_utf8_lossy(&line).into_owned();
                    let mut echo = line.clone();
                    echo.push(b'\r');
                    out.push(Output { at_s: t, bytes: echo });
                    let (reply, done) = if overflow {
                        (Some("Command error CMD_NOT_DEFINED".to_string()), t)
                    } else {
                        self.execute(text.trim(), t)
                    };
                    if let Some(r) = reply {
                        let mut bytes = r.into_bytes();
                        bytes.push(b'\r');
                        out.push(Output { at_s: t, bytes });
                    }
                    out.push(Output {
                        at_s: done,
                        bytes: PROMPT.to_vec(),
                    });
                    self.busy_until_s = done;
                }
                b'\n' => {}
                _ if self.input.len() >= MAX_LINE => self.overflow = true,
                _ => self.input.push(b),
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

    fn estop(&mut self, _now_s: f64) {
        // The wheel has no stop command; it finishes its turn.
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default wheel, set to speed 1 as the driver sets it.
    fn wheel() -> Fw102c {
        let file = gonio_instrument::InstrumentFile::simulated();
        let mut w = Fw102c::new("wheel", file.instrument.filter_wheel.as_ref());
        assert_eq!(text(&w.receive(b"speed=1\r", 0.0)), "speed=1\r> ");
        w
    }

    fn text(out: &[Output]) -> String {
        out.iter()
            .map(|o| String::from_utf8_lossy(&o.bytes).into_owned())
            .collect()
    }

    #[test]
    fn query_echoes_replies_and_prompts() {
        let mut w = wheel();
        let out = w.receive(b"pos?\r", 0.0);
        assert_eq!(text(&out), "pos?\r1\r> ");
        assert_eq!(text(&w.receive(b"*idn?\r", 0.0)), format!("*idn?\r{IDN}\r> "));
    }

    #[test]
    fn move_goes_the_shortest_way_and_prompts_after_it() {
        let mut w = wheel();
        // 1 -> 6 on a 6-position wheel is one step backwards.
        let out = w.receive(b"pos=6\r", 10.0);
        assert_eq!(text(&out), "pos=6\r> ");
        let prompt = out.last().expect("prompt");
        assert!((prompt.at_s - 11.0).abs() < 1e-12, "1 s per position at speed 1");
        assert_eq!(w.band_at(10.5), Band::BLANK);
        // Position 6 is the blank in the default instrument.
        assert_eq!(w.band_at(11.0), Band::BLANK);
        let out = w.receive(b"pos=3\r", 11.0);
        assert!((out.last().expect("prompt").at_s - 11.0 - 3.0).abs() < 1e-12);
        assert_eq!(w.band_at(14.0).band_nm, Some(650.0));
        // Slow mode: twice as long.
        w.receive(b"speed=0\r", 20.0);
        let out = w.receive(b"pos=4\r", 20.0);
        assert!((out.last().expect("prompt").at_s - 22.0).abs() < 1e-12);
    }

    #[test]
    fn powers_up_slow_with_sensors_lit_and_noise_on_open() {
        let file = gonio_instrument::InstrumentFile::simulated();
        let mut w = Fw102c::new("wheel", file.instrument.filter_wheel.as_ref()).with_noise_at_open(true);
        assert_eq!(text(&w.receive(b"speed?\r", 0.0)), "speed?\r0\r> ");
        assert_eq!(text(&w.receive(b"sensors?\r", 0.0)), "sensors?\r1\r> ");
        assert_eq!(w.stray_a(0.0), SENSOR_STRAY_A);
        w.receive(b"sensors=0\r", 0.0);
        assert_eq!(w.stray_a(0.0), 0.0);
        assert_eq!(
            text(&w.receive(b"pos?\r", 0.0)),
            "pos?\r1\r> ",
            "no noise before a connection"
        );
        w.reset_input();
        assert_eq!(
            text(&w.receive(b"pos?\r", 1.0)),
            "\0\0\0Command error CMD_NOT_DEFINED\r> pos?\r1\r> "
        );
        assert_eq!(
            text(&w.receive(b"pos?\r", 1.0)),
            "pos?\r1\r> ",
            "once per connection"
        );
    }

    #[test]
    fn errors_use_the_documented_text() {
        let mut w = wheel();
        assert_eq!(
            text(&w.receive(b"hello\r", 0.0)),
            "hello\rCommand error CMD_NOT_DEFINED\r> "
        );
        assert_eq!(
            text(&w.receive(b"pos=7\r", 0.0)),
            "pos=7\rCommand error CMD_ARG_INVALID\r> "
        );
        assert_eq!(
            text(&w.receive(b"\r", 0.0)),
            "\rCommand error CMD_NOT_DEFINED\r> "
        );
    }

    #[test]
    fn commands_queued_behind_a_move_run_after_it() {
        let mut w = wheel();
        let out = w.receive(b"pos=2\rpos?\r", 0.0);
        assert_eq!(text(&out), "pos=2\r> pos?\r2\r> ");
        assert!(out.iter().skip(2).all(|o| (o.at_s - 1.0).abs() < 1e-12));
    }
}
