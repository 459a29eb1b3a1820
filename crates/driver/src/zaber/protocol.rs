//! The Zaber ASCII wire format: checksums, command lines, reply/alert/info parsing, warning flags, numbers.

/// The LRC checksum of the bytes between the start character and the `:`.
pub fn checksum(body: &[u8]) -> u8 {
    let sum = body.iter().fold(0u8, |s, b| s.wrapping_add(*b));
    (!sum).wrapping_add(1)
}

/// A command line with message id and checksum: `/<device> <axis> <id> <command>:<CC>\n`.
pub fn encode_command(device: u8, axis: u8, id: Option<u8>, command: &str) -> String {
    let body = match id {
        Some(id) => format!("{device} {axis} {id} {command}"),
        None => format!("{device} {axis} {command}"),
    };
    let body = body.trim_end().to_string();
    format!("/{body}:{:02X}\n", checksum(body.as_bytes()))
}

/// Reply flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flag {
    Ok,
    Rejected,
}

/// A decoded reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    pub device: u8,
    pub axis: u8,
    pub id: Option<u8>,
    pub flag: Flag,
    pub busy: bool,
    /// Highest-priority warning flag, `None` for `--`.
    pub warning: Option<String>,
    pub data: String,
    /// The data continues in `cont` info lines.
    pub continues: bool,
    /// The reply carried a checksum, and it was right (a reply with a wrong one is not parsed at all).
    pub checksummed: bool,
}

impl Reply {
    /// Bytes the reply took on the line: rebuilt from its fields in the manual's layout
    /// (`@DD A [ID] FL STATUS WW DATA[:CC]\r\n`), for dating what it reports.
    pub fn line_len(&self) -> usize {
        let id = self.id.map_or(0, |id| format!(" {id}").len());
        let warning = self.warning.as_deref().map_or(2, str::len);
        let data = if self.data.is_empty() {
            0
        } else {
            1 + self.data.len()
        };
        let checksum = if self.checksummed { 3 } else { 0 };
        // "@DD" + " A" + id + " FL" + " BUSY" + " WW" + data + checksum + "\r\n"
        3 + format!(" {}", self.axis).len() + id + 3 + 5 + 1 + warning + data + checksum + 2
    }
}

/// A decoded alert (`!DD A STATUS WW [data]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Alert {
    pub device: u8,
    pub axis: u8,
    pub busy: bool,
    pub warning: Option<String>,
    pub data: String,
}

/// A decoded info line (`#DD A [id] data`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Info {
    pub device: u8,
    pub axis: u8,
    pub id: Option<u8>,
    pub data: String,
    pub continues: bool,
}

/// Any message a device sends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Message {
    Reply(Reply),
    Alert(Alert),
    Info(Info),
}

/// Why a line is not a valid message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("not ASCII text")]
    NotText,
    #[error("unknown message type")]
    Type,
    #[error("checksum mismatch")]
    Checksum,
    #[error("malformed {0}")]
    Field(&'static str),
}

pub(super) fn is_warning(s: &str) -> bool {
    s == "--" || (s.len() == 2 && s.bytes().all(|b| b.is_ascii_uppercase()))
}

/// Parse an integer as devices may write it: decimal, or hexadecimal `0x...`; optionally negative. Never panics.
pub fn parse_int(text: &str) -> Option<i64> {
    let t = text.trim();
    let (neg, digits) = match t.strip_prefix('-') {
        Some(d) => (true, d),
        None => (false, t),
    };
    let n = match digits.strip_prefix("0x").or_else(|| digits.strip_prefix("0X")) {
        Some(hex) if !hex.is_empty() && hex.len() <= 16 => i64::from_str_radix(hex, 16).ok()?,
        Some(_) => return None,
        None if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) => {
            digits.parse::<i64>().ok()?
        }
        None => return None,
    };
    if neg { n.checked_neg() } else { Some(n) }
}

/// Parse one line (without its `\r\n`). Verifies the checksum when present. Never panics.
pub fn parse_message(line: &[u8]) -> Result<Message, ParseError> {
    if !line.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
        return Err(ParseError::NotText);
    }
    let text = std::str::from_utf8(line).map_err(|_| ParseError::NotText)?;
    let kind = text.chars().next().ok_or(ParseError::Type)?;
    if !matches!(kind, '@' | '!' | '#') {
        return Err(ParseError::Type);
    }
    let rest = text.get(1..).ok_or(ParseError::Type)?;
    // A trailing ":CC" (two hex digits) is a checksum over everything between the start character and the colon.
    let mut checksummed = false;
    let body = match rest.rfind(':') {
        Some(at)
            if rest.len() == at + 3
                && rest
                    .get(at + 1..)
                    .is_some_and(|h| h.bytes().all(|b| b.is_ascii_hexdigit())) =>
        {
            let body = rest.get(..at).ok_or(ParseError::Checksum)?;
            let cs = u8::from_str_radix(rest.get(at + 1..).ok_or(ParseError::Checksum)?, 16)
                .map_err(|_| ParseError::Checksum)?;
            let sum = body.bytes().fold(0u8, |s, b| s.wrapping_add(b));
            if sum.wrapping_add(cs) != 0 {
                return Err(ParseError::Checksum);
            }
            checksummed = true;
            body
        }
        _ => rest,
    };
    let mut tokens = body.split(' ').filter(|t| !t.is_empty()).peekable();
    let device = tokens
        .next()
        .filter(|t| t.len() == 2 && t.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|t| t.parse::<u8>().ok())
        .ok_or(ParseError::Field("device number"))?;
    let axis = tokens
        .next()
        .filter(|t| t.len() <= 2 && t.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|t| t.parse::<u8>().ok())
        .ok_or(ParseError::Field("axis number"))?;
    let parse_id = |t: &str| -> Option<u8> {
        if t.len() <= 2 && t.bytes().all(|b| b.is_ascii_digit()) {
            t.parse().ok()
        } else {
            None
        }
    };
    match kind {
        '@' => {
            let mut id = None;
            let mut next = tokens.next().ok_or(ParseError::Field("reply flag"))?;
            if let Some(v) = parse_id(next) {
                id = Some(v);
                next = tokens.next().ok_or(ParseError::Field("reply flag"))?;
            }
            let flag = match next {
                "OK" => Flag::Ok,
                "RJ" => Flag::Rejected,
                _ => return Err(ParseError::Field("reply flag")),
            };
            let busy = parse_status(tokens.next())?;
            let warning = parse_warning(tokens.next())?;
            let (data, continues) = join_data(tokens);
            if data.is_empty() {
                return Err(ParseError::Field("reply data"));
            }
            Ok(Message::Reply(Reply {
                device,
                axis,
                id,
                flag,
                busy,
                warning,
                data,
                continues,
                checksummed,
            }))
        }
        '!' => {
            let busy = parse_status(tokens.next())?;
            let warning = parse_warning(tokens.next())?;
            let (data, _) = join_data(tokens);
            Ok(Message::Alert(Alert {
                device,
                axis,
                busy,
                warning,
                data,
            }))
        }
        _ => {
            let mut id = None;
            if let Some(t) = tokens.peek()
                && let Some(v) = parse_id(t)
            {
                id = Some(v);
                tokens.next();
            }
            let (data, continues) = join_data(tokens);
            Ok(Message::Info(Info {
                device,
                axis,
                id,
                data,
                continues,
            }))
        }
    }
}

fn parse_status(t: Option<&str>) -> Result<bool, ParseError> {
    match t {
        Some("BUSY") => Ok(true),
        Some("IDLE") => Ok(false),
        _ => Err(ParseError::Field("status")),
    }
}

fn parse_warning(t: Option<&str>) -> Result<Option<String>, ParseError> {
    match t {
        Some("--") => Ok(None),
        Some(w) if is_warning(w) => Ok(Some(w.to_string())),
        _ => Err(ParseError::Field("warning flag")),
    }
}

fn join_data<'a>(tokens: impl Iterator<Item = &'a str>) -> (String, bool) {
    let mut data = tokens.collect::<Vec<_>>().join(" ");
    let continues = data.ends_with('\\');
    if continues {
        data.pop();
        data = data.trim_end().to_string();
    }
    (data, continues)
}

/// What a warning flag means (Zaber's list; unknown flags are named by their letters).
pub fn describe_warning(flag: &str) -> String {
    let text = match flag {
        "FD" => "driver disabled",
        "FQ" => "encoder error",
        "FS" => "stalled and stopped",
        "FT" => "excessive twist",
        "FB" => "stream bounds error",
        "FP" => "interpolated path deviation",
        "FE" => "limit error",
        "FM" => "peripheral mismatch",
        "FO" => "overdrive limit exceeded",
        "WH" => "device not homed",
        "WL" => "unexpected limit trigger",
        "WP" => "invalid calibration type",
        "WV" => "voltage out of range",
        "WT" => "system temperature high",
        "WS" => "stalled (recovered)",
        "WM" => "displaced when stationary",
        "WR" => "no reference position",
        "NC" => "manual control",
        "NI" => "command interrupted",
        "ND" => "stream discontinuity",
        "NR" => "value rounded",
        "NU" => "setting update pending",
        "NJ" => "joystick calibrating",
        _ => "undocumented flag",
    };
    format!("{flag} ({text})")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_in_decimal_or_hexadecimal() {
        assert_eq!(parse_int("60281"), Some(60281));
        assert_eq!(parse_int("-12"), Some(-12));
        assert_eq!(parse_int("0x2710"), Some(10000));
        assert_eq!(parse_int("-0X1f"), Some(-31));
        assert_eq!(parse_int("0x"), None);
        assert_eq!(parse_int("+5"), None);
        assert_eq!(parse_int("1e3"), None);
        assert_eq!(parse_int("0x8000000000000000"), None);
    }

    #[test]
    fn the_manuals_unhomed_relative_move_is_a_rejection_with_wr() {
        let Ok(Message::Reply(r)) = parse_message(b"@01 0 RJ IDLE WR BADDATA") else {
            panic!("not a reply");
        };
        assert_eq!((r.device, r.axis, r.flag), (1, 0, Flag::Rejected));
        assert_eq!((r.warning.as_deref(), r.data.as_str()), (Some("WR"), "BADDATA"));
    }

    #[test]
    fn a_replys_length_on_the_line_is_rebuilt_from_its_fields() {
        let body = "01 1 12 OK BUSY -- 123456";
        let with_checksum = format!("@{body}:{:02X}", checksum(body.as_bytes()));
        for line in [
            "@01 0 OK IDLE -- 0",
            "@01 1 OK BUSY -- -60281",
            "@02 1 7 OK IDLE FZ 5",
            "@01 0 RJ IDLE WR BADDATA",
            with_checksum.as_str(),
        ] {
            let Ok(Message::Reply(r)) = parse_message(line.as_bytes()) else {
                panic!("not a reply: {line}");
            };
            assert_eq!(r.line_len(), line.len() + 2, "{line}");
        }
    }

    #[test]
    fn checksums_match_the_manual_examples() {
        assert_eq!(checksum(b"1"), 0xCF);
        assert_eq!(checksum(b"2 0 5 get maxspeed"), 0x52);
        assert_eq!(checksum(b"1 tools echo"), 0xBF);
    }

    #[test]
    fn commands_carry_id_and_checksum() {
        assert_eq!(
            encode_command(2, 0, Some(5), "get maxspeed"),
            "/2 0 5 get maxspeed:52\n"
        );
        assert_eq!(
            encode_command(1, 1, None, "stop"),
            format!("/1 1 stop:{:02X}\n", checksum(b"1 1 stop"))
        );
    }

    #[test]
    fn replies_parse_with_and_without_id_and_checksum() {
        let r = parse_message(b"@01 0 OK IDLE -- 0").expect("valid");
        assert_eq!(
            r,
            Message::Reply(Reply {
                device: 1,
                axis: 0,
                id: None,
                flag: Flag::Ok,
                busy: false,
                warning: None,
                data: "0".into(),
                continues: false,
                checksummed: false
            })
        );
        let body = "01 2 17 RJ BUSY WR BADDATA";
        let line = format!("@{body}:{:02X}", checksum(body.as_bytes()));
        match parse_message(line.as_bytes()).expect("valid") {
            Message::Reply(r) => {
                assert_eq!(
                    (r.device, r.axis, r.id, r.flag, r.busy),
                    (1, 2, Some(17), Flag::Rejected, true)
                );
                assert_eq!(r.warning.as_deref(), Some("WR"));
                assert_eq!(r.data, "BADDATA");
                assert!(r.checksummed);
            }
            other => panic!("not a reply: {other:?}"),
        }
        // One flipped character breaks the checksum.
        let bad = line.replacen("17", "18", 1);
        assert_eq!(parse_message(bad.as_bytes()), Err(ParseError::Checksum));
    }

    #[test]
    fn alerts_info_and_continuations() {
        assert_eq!(
            parse_message(b"!01 1 IDLE FS").expect("alert"),
            Message::Alert(Alert {
                device: 1,
                axis: 1,
                busy: false,
                warning: Some("FS".into()),
                data: String::new()
            })
        );
        match parse_message(b"#01 0 3 cont 1 more data").expect("info") {
            Message::Info(i) => {
                assert_eq!(i.id, Some(3));
                assert_eq!(i.data, "cont 1 more data");
            }
            other => panic!("{other:?}"),
        }
        match parse_message(b"@01 0 3 OK IDLE -- part one\\").expect("reply") {
            Message::Reply(r) => assert!(r.continues && r.data == "part one"),
            other => panic!("{other:?}"),
        }
        assert!(parse_message(b"@01 0 OK IDLE --").is_err()); // no data
        assert!(parse_message(b"@1 0 OK IDLE -- 0").is_err()); // device must be 2 digits
        assert!(parse_message(b"@01 0 OK HALT -- 0").is_err());
        assert!(parse_message(b"hello").is_err());
    }
}
