//! The SMC100's replies: controller states, positioner error bits, TE error codes, reply lines, numbers.

/// Controller state, from the last two hex digits of `TS`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    NotReferenced(u8),
    Configuration,
    Homing(u8),
    Moving,
    Ready(u8),
    Disable(u8),
    Jogging(u8),
    Unknown(u8),
}

impl State {
    pub fn from_code(code: u8) -> State {
        match code {
            0x0A..=0x11 => State::NotReferenced(code),
            0x14 => State::Configuration,
            0x1E | 0x1F => State::Homing(code),
            0x28 => State::Moving,
            0x32..=0x35 => State::Ready(code),
            0x3C..=0x3E => State::Disable(code),
            0x46 | 0x47 => State::Jogging(code),
            other => State::Unknown(other),
        }
    }

    /// The manual's name for the state.
    pub fn describe(&self) -> String {
        match self {
            State::NotReferenced(c) => {
                let from = match c {
                    0x0A => "reset",
                    0x0B => "homing",
                    0x0C => "configuration",
                    0x0D => "disable",
                    0x0E => "ready",
                    0x0F => "moving",
                    0x10 => "ESP stage error",
                    _ => "jogging",
                };
                format!("NOT REFERENCED from {from} ({c:02X})")
            }
            State::Configuration => "CONFIGURATION (14)".into(),
            State::Homing(c) => format!("HOMING ({c:02X})"),
            State::Moving => "MOVING (28)".into(),
            State::Ready(c) => {
                let from = match c {
                    0x32 => "homing",
                    0x33 => "moving",
                    0x34 => "disable",
                    _ => "jogging",
                };
                format!("READY from {from} ({c:02X})")
            }
            State::Disable(c) => {
                let from = match c {
                    0x3C => "ready",
                    0x3D => "moving",
                    _ => "jogging",
                };
                format!("DISABLE from {from} ({c:02X})")
            }
            State::Jogging(c) => format!("JOGGING ({c:02X})"),
            State::Unknown(c) => format!("unknown state {c:02X}"),
        }
    }
}

/// Parsed `TS` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ts {
    pub errors: u16,
    pub state: State,
}

/// Names of the positioner error bits, most significant first.
pub fn describe_error_bits(bits: u16) -> Vec<&'static str> {
    const NAMES: [(u16, &str); 10] = [
        (0x0200, "80 W output power exceeded"),
        (0x0100, "DC voltage too low"),
        (0x0080, "wrong ESP stage"),
        (0x0040, "homing time-out"),
        (0x0020, "following error"),
        (0x0010, "short circuit detection"),
        (0x0008, "RMS current limit"),
        (0x0004, "peak current limit"),
        (0x0002, "positive end of run"),
        (0x0001, "negative end of run"),
    ];
    NAMES
        .iter()
        .filter(|(b, _)| bits & b != 0)
        .map(|(_, n)| *n)
        .collect()
}

/// Meaning of a `TE` error code.
pub fn describe_te(code: char) -> &'static str {
    match code {
        '@' => "no error",
        'A' => "unknown message code or floating point controller address",
        'B' => "controller address not correct",
        'C' => "parameter missing or out of range",
        'D' => "command not allowed",
        'E' => "home sequence already started",
        'G' => "displacement out of limits",
        'H' => "command not allowed in NOT REFERENCED state",
        'I' => "command not allowed in CONFIGURATION state",
        'J' => "command not allowed in DISABLE state",
        'K' => "command not allowed in READY state",
        'L' => "command not allowed in HOMING state",
        'M' => "command not allowed in MOVING state",
        'N' => "current position out of software limit",
        'S' => "communication time-out",
        'U' => "error during EEPROM access",
        'V' => "error during command execution",
        'W' => "command not allowed for PP version",
        'X' => "command not allowed for CC version",
        _ => "undocumented error code",
    }
}

/// Split a reply line `<addr><CC><value>` into its parts. `None` unless the address is 1..=31 in decimal and the
/// command is two ASCII letters. Never panics.
pub fn parse_reply(line: &[u8]) -> Option<(u8, [u8; 2], &str)> {
    let text = std::str::from_utf8(line).ok()?;
    let digits = text.bytes().take_while(u8::is_ascii_digit).count();
    if digits == 0 || digits > 2 {
        return None;
    }
    let addr: u8 = text.get(..digits)?.parse().ok()?;
    if !(1..=31).contains(&addr) {
        return None;
    }
    let cc = text.get(digits..digits + 2)?.as_bytes();
    if !cc.iter().all(u8::is_ascii_uppercase) {
        return None;
    }
    let value = text.get(digits + 2..)?;
    if !value.bytes().all(|b| b.is_ascii_graphic() || b == b' ') {
        return None;
    }
    Some((addr, [cc[0], cc[1]], value))
}

/// Parse the value of a `TS` reply: exactly six hex digits.
pub fn parse_ts(value: &str) -> Option<Ts> {
    if value.len() != 6 || !value.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let errors = u16::from_str_radix(value.get(..4)?, 16).ok()?;
    let state = State::from_code(u8::from_str_radix(value.get(4..)?, 16).ok()?);
    // Undocumented bits or states mean the line was corrupted on the way: ask again rather than act on it.
    if errors & 0xFC00 != 0 || matches!(state, State::Unknown(_)) {
        return None;
    }
    Some(Ts { errors, state })
}

/// Parse a decimal number as the controller prints it (`12.50000`, `-3`, `1.5E-3`); finite only.
pub fn parse_number(value: &str) -> Option<f64> {
    let v = value.trim();
    if v.is_empty()
        || !v
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E'))
    {
        return None;
    }
    v.parse::<f64>().ok().filter(|x| x.is_finite())
}

/// Parse a `TE` value: one character.
pub fn parse_te(value: &str) -> Option<char> {
    let mut chars = value.chars();
    let c = chars.next()?;
    if chars.next().is_some() || !(c == '@' || c.is_ascii_uppercase()) {
        return None;
    }
    Some(c)
}

/// Format a number for the wire: fixed point, no exponent.
pub(super) fn wire_number(x: f64) -> String {
    let s = format!("{x:.6}");
    if s == "-0.000000" { "0.000000".into() } else { s }
}

/// The number in reply `i` of an exchange, if it came and parses.
pub(super) fn number_at(replies: &[Option<String>], i: usize) -> Option<f64> {
    replies.get(i)?.as_deref().and_then(parse_number)
}

/// States in which the axis moves by itself.
pub(super) fn is_moving(state: State) -> bool {
    matches!(state, State::Moving | State::Homing(_) | State::Jogging(_))
}

/// A TS reading in words: the state, and the positioner error bits when any are set.
pub(super) fn ts_reason(ts: &Ts) -> String {
    let bits = describe_error_bits(ts.errors);
    if bits.is_empty() {
        ts.state.describe()
    } else {
        format!(
            "{}; positioner errors {:04X}: {}",
            ts.state.describe(),
            ts.errors,
            bits.join(", ")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reply_lines_split_into_address_command_value() {
        assert_eq!(parse_reply(b"1TP12.50000"), Some((1, *b"TP", "12.50000")));
        assert_eq!(parse_reply(b"12TS000033"), Some((12, *b"TS", "000033")));
        assert_eq!(parse_reply(b"2TE@"), Some((2, *b"TE", "@")));
        assert_eq!(parse_reply(b"0TS000033"), None); // address 0 does not exist
        assert_eq!(parse_reply(b"32TS000033"), None);
        assert_eq!(parse_reply(b"TS000033"), None);
        assert_eq!(parse_reply(b"1tp1"), None);
        assert_eq!(parse_reply(b"1T"), None);
        assert_eq!(parse_reply(b"1TP\xff"), None);
    }

    #[test]
    fn ts_decodes_error_bits_and_states() {
        let ts = parse_ts("000033").expect("valid");
        assert_eq!(
            ts,
            Ts {
                errors: 0,
                state: State::Ready(0x33)
            }
        );
        let ts = parse_ts("00203D").expect("valid");
        assert_eq!(ts.state, State::Disable(0x3D));
        assert_eq!(describe_error_bits(ts.errors), vec!["following error"]);
        assert_eq!(
            parse_ts("00000A").map(|t| t.state),
            Some(State::NotReferenced(0x0A))
        );
        assert_eq!(parse_ts("00001E").map(|t| t.state), Some(State::Homing(0x1E)));
        assert_eq!(parse_ts("000028").map(|t| t.state), Some(State::Moving));
        assert_eq!(parse_ts("00033"), None);
        assert_eq!(parse_ts("0000A8"), None); // no such state
        assert_eq!(parse_ts("800033"), None); // no such error bit
        assert_eq!(parse_ts("0000G3"), None);
        assert_eq!(
            describe_error_bits(0x0003),
            vec!["positive end of run", "negative end of run"]
        );
    }

    #[test]
    fn numbers_and_error_codes() {
        assert_eq!(parse_number("12.50000"), Some(12.5));
        assert_eq!(parse_number("-0.25"), Some(-0.25));
        assert_eq!(parse_number("1.5E-3"), Some(0.0015));
        assert_eq!(parse_number("nan"), None);
        assert_eq!(parse_number("1.2.3"), None);
        assert_eq!(parse_number(""), None);
        assert_eq!(parse_te("@"), Some('@'));
        assert_eq!(parse_te("H"), Some('H'));
        assert_eq!(parse_te("HH"), None);
        assert_eq!(parse_te("h"), None);
        assert_eq!(wire_number(-0.0000001), "0.000000");
        assert_eq!(wire_number(12.5), "12.500000");
    }
}
