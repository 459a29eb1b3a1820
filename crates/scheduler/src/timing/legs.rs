//! What a commanded leg of an axis costs beyond its motion: the exchanges gonio's axis drivers
//! (`crates/driver`) make around every move, by protocol and line speed. The motion itself is the trapezoid of
//! `profile`; this is everything the daemon waits for that is not motion.
//!
//! A leg of motion time `T` takes `first_seen_s` when the motion is over by the driver's first question
//! (`T <= first_question_s`), else `T + seen_after_s` ([`LegTiming::leg_s`]): the motion starts with the leg's
//! first command (below):
//! - **SMC100** (one command or query per line, `crates/driver/src/smc100`): the move is `PA`, then the
//!   controller's pause after a set command ([`SMC100_SET_GAP_S`]) and `TE`; the wait then asks `PT TS` at once
//!   (and the read-back `TP TP` with it when the move should be over by then), and otherwise `TS`, then `TP TP`,
//!   just after the predicted end counted from the `PA` ([`ARRIVAL_MARGIN_S`]). So the motion starts with the
//!   leg, is seen over the margin and three exchanges after it ends, and never sooner than the pause and five
//!   exchanges after it started (a backlash overshoot of a few hundredths of a degree costs that pause, not its
//!   motion).
//! - **Zaber ASCII** (`crates/driver/src/zaber`): `move abs`; the wait asks `get pos` (busy or idle, and where)
//!   at once and just after the predicted end counted from the `move abs` reply. The motion starts with the leg
//!   and is seen the margin and two exchanges after it ends.
//!
//! Where a leg starts is where the axis came to rest, read back at the end of the leg before
//! (`gonio_driver::axis_driver::AxisCore`), so neither driver reads it again before the move; only the first
//! move after a homing, a stop or an error does (`TP TP` before `PA`, `get pos` before `move abs`), once an axis
//! a run, which the model leaves out.
//! - An axis on another protocol (none today) keeps one exchange for the arrival.
//!
//! One exchange is a short request and its reply on the wire: the reply's bytes at the line's speed (8N1: ten
//! bits a byte), rounded up to the whole millisecond at which the host sees it (the 1 ms latency timer of a
//! USB-serial adapter; the dry-run's clock ticks in milliseconds too), plus what the controller takes to answer
//! (the SMC100 manual's "command execution time", about 10 ms for a position query): the device's
//! `reply_latency_ms`, which `gonio selftest` measures and writes; absent, none, and the model is then short by
//! that much per exchange on hardware that takes it.

use gonio_instrument::{Instrument, Protocol};

/// The SMC100 driver's pause after a set command before the next command to the same controller
/// (`gonio_driver::smc100::SET_GAP`; crates/engine/tests/it/timing.rs holds the two equal).
pub const SMC100_SET_GAP_S: f64 = 0.065;

/// How long after a move's predicted end the driver asks whether it is over (`gonio_driver::poll::ARRIVAL_MARGIN`;
/// crates/engine/tests/it/timing.rs holds the two equal).
pub const ARRIVAL_MARGIN_S: f64 = 0.001;

/// Bytes of a typical SMC100 reply (`1TS000028\r\n`, `1TP-45.02\r\n`).
const SMC100_REPLY_BYTES: usize = 11;

/// Bytes of a typical Zaber ASCII reply with checksum (`@01 1 83 OK IDLE -- 247458:F3\r\n`).
const ZABER_REPLY_BYTES: usize = 31;

/// Time of one exchange whose reply is `reply_bytes` long at `baud` (8N1), seen at the next whole millisecond.
pub fn exchange_s(reply_bytes: usize, baud: u32) -> f64 {
    exchange_after_s(reply_bytes, baud, 0.0)
}

/// As [`exchange_s`] with a device that takes `latency_s` to answer besides its reply's time on the line
/// (`reply_latency_ms` of the instrument file).
pub fn exchange_after_s(reply_bytes: usize, baud: u32, latency_s: f64) -> f64 {
    let latency_s = if latency_s.is_finite() {
        latency_s.max(0.0)
    } else {
        0.0
    };
    if baud == 0 {
        return 0.001 + latency_s;
    }
    let wire_s = reply_bytes as f64 * 10.0 / f64::from(baud);
    // The sum rounded, less a hair that keeps a whole millisecond from rounding up once more.
    ((wire_s + latency_s) * 1000.0 - 1e-9).ceil() / 1000.0
}

/// The driver's time around each leg of one axis (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LegTiming {
    /// From the end of the motion until the driver has seen it over, its position read back.
    pub seen_after_s: f64,
    /// From the start of the motion until the driver's first question about it goes out.
    pub first_question_s: f64,
    /// From the start of the motion until a motion over by the first question is seen over.
    pub first_seen_s: f64,
    /// Setting the axis's speed and acceleration (the first sweep of an axis: the driver does not know what the
    /// device holds until it has written both).
    pub set_speed_s: f64,
    /// Setting the axis's speed alone (a later sweep, and the axis's own speed restored after sweeping: the
    /// acceleration is the axis's own throughout, which the driver does not write again).
    pub set_velocity_s: f64,
    /// From the move command until the driver's `start_move` returns (the SMC100's pause and `TE` after `PA`).
    pub start_return_s: f64,
    /// One status question while a sweep ends (SMC100: `TS` and the verified read-back).
    pub status_s: f64,
    /// The arrival check of an axis already stopped (SMC100: `PT TS` and the verified read-back).
    pub arrived_s: f64,
}

impl LegTiming {
    /// A leg whose motion takes `motion_s`, from its first exchange until the driver has seen it over.
    pub fn leg_s(&self, motion_s: f64) -> f64 {
        if motion_s <= self.first_question_s {
            self.first_seen_s
        } else {
            (motion_s + self.seen_after_s).max(self.first_seen_s)
        }
    }

    /// An axis on a protocol without a model here: the arrival seen one exchange after the motion.
    pub fn generic() -> LegTiming {
        LegTiming {
            seen_after_s: super::EXCHANGE_S,
            first_question_s: 0.0,
            first_seen_s: super::EXCHANGE_S,
            set_speed_s: 0.0,
            set_velocity_s: 0.0,
            start_return_s: 0.0,
            status_s: super::EXCHANGE_S,
            arrived_s: super::EXCHANGE_S,
        }
    }

    /// The leg timing of an axis driven over `protocol` at `baud`, its controller taking `latency_s` to answer.
    pub fn for_protocol(protocol: Protocol, baud: u32, latency_s: f64) -> LegTiming {
        match protocol {
            Protocol::Smc100 => {
                let e = exchange_after_s(SMC100_REPLY_BYTES, baud, latency_s);
                LegTiming {
                    seen_after_s: ARRIVAL_MARGIN_S + 3.0 * e,
                    // The pause, TE, then PT and TS; with TP TP when over.
                    first_question_s: SMC100_SET_GAP_S + 2.0 * e,
                    first_seen_s: SMC100_SET_GAP_S + 5.0 * e,
                    // `VA` and `AC`, each a set command: the pause, then `TE`.
                    set_speed_s: 2.0 * (SMC100_SET_GAP_S + e),
                    set_velocity_s: SMC100_SET_GAP_S + e,
                    start_return_s: SMC100_SET_GAP_S + e,
                    status_s: 3.0 * e,
                    arrived_s: 4.0 * e,
                }
            }
            Protocol::ZaberAscii => {
                let e = exchange_after_s(ZABER_REPLY_BYTES, baud, latency_s);
                LegTiming {
                    seen_after_s: ARRIVAL_MARGIN_S + 2.0 * e,
                    // The move abs reply, then get pos.
                    first_question_s: e,
                    first_seen_s: 2.0 * e,
                    // `set maxspeed`, `set accel`, each acknowledged.
                    set_speed_s: 2.0 * e,
                    set_velocity_s: e,
                    start_return_s: 0.0,
                    status_s: e,
                    arrived_s: e,
                }
            }
            Protocol::Fw102c | Protocol::Pm100 => LegTiming::generic(),
        }
    }

    /// The leg timing of the axis `axis_index` of `instrument`: its device's protocol and line speed.
    pub fn of_axis(instrument: &Instrument, axis_index: usize) -> LegTiming {
        let device = instrument
            .axes
            .get(axis_index)
            .and_then(|a| instrument.devices.iter().find(|d| d.name == a.device));
        match device {
            Some(d) => LegTiming::for_protocol(
                d.protocol,
                d.line_baud(),
                d.reply_latency_ms.unwrap_or(0.0) / 1000.0,
            ),
            None => LegTiming::generic(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_exchange_is_its_reply_on_the_wire_rounded_up_to_the_millisecond() {
        // 11 bytes at 57600 baud: 1.91 ms on the wire, seen at 2 ms; 31 bytes at 115200: 2.69 ms, seen at 3 ms.
        assert!((exchange_s(11, 57_600) - 0.002).abs() < 1e-12);
        assert!((exchange_s(31, 115_200) - 0.003).abs() < 1e-12);
        // A slower line costs more: 11 bytes at 9600 baud, 11.5 ms.
        assert!((exchange_s(11, 9_600) - 0.012).abs() < 1e-12);
        // A controller taking 10 ms to answer: 11.91 ms, seen at 12 ms; a whole 10 ms on a 2 ms reply, 12 ms.
        assert!((exchange_after_s(11, 57_600, 0.010) - 0.012).abs() < 1e-12);
        assert!((exchange_after_s(20, 10_000, 0.010) - 0.030).abs() < 1e-12);
        assert_eq!(exchange_after_s(11, 57_600, f64::NAN), exchange_s(11, 57_600));
    }

    #[test]
    fn a_controller_that_takes_its_time_to_answer_makes_every_exchange_of_a_leg_longer() {
        let quick = LegTiming::for_protocol(Protocol::Smc100, 57_600, 0.0);
        let slow = LegTiming::for_protocol(Protocol::Smc100, 57_600, 0.010);
        // A 1 s move: three exchanges after it (none before: the start is where the axis came to rest), each
        // 10 ms longer.
        assert!((slow.leg_s(1.0) - quick.leg_s(1.0) - 0.030).abs() < 1e-12);
        let quick = LegTiming::for_protocol(Protocol::ZaberAscii, 115_200, 0.0);
        let slow = LegTiming::for_protocol(Protocol::ZaberAscii, 115_200, 0.010);
        assert!((slow.leg_s(1.0) - quick.leg_s(1.0) - 0.020).abs() < 1e-12);
    }

    #[test]
    fn a_short_smc100_leg_costs_the_pause_after_its_move_command_a_long_one_its_motion() {
        let smc = LegTiming::for_protocol(Protocol::Smc100, 57_600, 0.0);
        // A 32 ms backlash overshoot: the pause and five exchanges after the PA.
        assert!((smc.leg_s(0.032) - (0.065 + 0.010)).abs() < 1e-12);
        // A 1 s move: the motion, then TS TP TP just after its end.
        assert!((smc.leg_s(1.0) - (1.0 + 0.001 + 0.006)).abs() < 1e-12);
        let zaber = LegTiming::for_protocol(Protocol::ZaberAscii, 115_200, 0.0);
        assert!((zaber.leg_s(1.0) - (1.0 + 0.001 + 0.006)).abs() < 1e-12);
        // A 2 ms move is over by the first get pos, 3 ms in: seen at its reply.
        assert!((zaber.leg_s(0.002) - 0.006).abs() < 1e-12);
    }
}
