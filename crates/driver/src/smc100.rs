//! Newport SMC100CC/PP motion controllers on one daisy-chained RS-232 port, written from the SMC100 user manual.
//!
//! Wire format: `<addr><CC><arg>\r\n`. Queries answer `<addr><CC><value>\r\n`; set commands are silent, so every
//! set command is followed, in the same exchange, by `<addr>TE` (last command error, `@` = none). Status `TS`
//! answers 4 hex digits of positioner error bits and 2 hex digits of controller state. `PA` is idempotent and may
//! be retried; `OR` (home) and `PR` are never retried blindly. A wait loop treats DISABLE (3C..3E) and the NOT
//! REFERENCED states as terminal (once a second TS confirms them).
//!
//! Replies carry no checksum, so a position the driver acts on is read twice in one exchange and the two reads
//! must agree within the encoder resolution ([`Smc100Axis::verified_position`]). Several queries share one
//! exchange where the manual allows it (one command per line): a move is `TP TP PA TE`, then `PT TS` (plus
//! `TP TP` once the move should be over) on a [`PollSchedule`](crate::motion::PollSchedule).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use crate::error::{DriverError, ErrorKind};
use crate::motion::{PollSchedule, approach_waypoints, check_speed, move_deadline, trapezoid_time_s};
use crate::traits::{Axis, AxisLimits, AxisStatus};
use crate::transport::{BoxFuture, LinePort, TransportError, escape_bytes};

/// Time allowed for one query's reply.
const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
/// Attempts for idempotent requests (queries, PA).
const ATTEMPTS: usize = 3;
/// Shortest pause between two status questions to one controller: the manual (section 6.4, "Command Execution
/// Time") gives about 10 ms for a controller to execute a TP query, so asking faster only queues questions.
const POLL_MIN: Duration = Duration::from_millis(10);
/// Longest pause between two status questions while a move runs: bounds how late a stall is noticed.
const POLL_MAX: Duration = Duration::from_millis(50);
/// Span of two position reads in one exchange of a moving axis (two TP executions and their replies), for the
/// agreement allowed between them: what the axis travels at full speed in that time.
const MOVING_READ_WINDOW_S: f64 = 0.05;

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
fn wire_number(x: f64) -> String {
    let s = format!("{x:.6}");
    if s == "-0.000000" { "0.000000".into() } else { s }
}

/// One SMC100 daisy chain: the port owner.
#[derive(Debug)]
pub struct Smc100Chain {
    name: String,
    port: Arc<LinePort>,
}

impl Smc100Chain {
    pub fn new(name: impl Into<String>, port: Arc<LinePort>) -> Arc<Smc100Chain> {
        Arc::new(Smc100Chain {
            name: name.into(),
            port,
        })
    }

    pub fn port(&self) -> &Arc<LinePort> {
        &self.port
    }

    fn dev(&self, addr: u8) -> String {
        format!("{}/{}", self.name, addr)
    }

    fn transport_error(&self, addr: u8, request: &str, e: TransportError) -> DriverError {
        match e {
            TransportError::Timeout => DriverError::Timeout {
                device: self.dev(addr),
                request: request.into(),
                timeout: REPLY_TIMEOUT,
            },
            TransportError::Disconnected(detail) => DriverError::Disconnected {
                device: self.dev(addr),
                detail,
            },
            TransportError::Garbled(detail) => DriverError::Protocol {
                device: self.dev(addr),
                request: request.into(),
                detail,
            },
        }
    }

    /// One exchange: write `lines` (each `<addr><cc><arg>`; terminators added here) in one go, then read the
    /// replies to the commands named in `expect`, in order (see [`read_replies`]). Several short lines may go out
    /// together: the controller takes them one after the other, and XON/XOFF flow control lets it pause the host
    /// should its input fill. (One command per line: the manual forbids several commands on one line.)
    async fn exchange(
        &self,
        lines: &[String],
        addr: u8,
        expect: &[&str],
    ) -> Result<Vec<Option<String>>, TransportError> {
        let mut s = self.port.session().await;
        s.discard_stale().await?;
        let deadline = Instant::now() + REPLY_TIMEOUT;
        let mut bytes = String::new();
        for line in lines {
            bytes.push_str(line);
            bytes.push_str("\r\n");
        }
        s.send(bytes.as_bytes(), deadline).await?;
        read_replies(&mut s, addr, expect, deadline).await
    }

    /// Several queries `(cc, arg)` to one controller in one exchange: the value of each reply, in order; `None`
    /// for one that never came (lost or garbled beyond recognition) while a later one did. Queries are
    /// idempotent: the exchange is retried, boundedly, when the last reply does not come.
    pub async fn queries(
        &self,
        addr: u8,
        queries: &[(&str, &str)],
    ) -> Result<Vec<Option<String>>, DriverError> {
        let lines: Vec<String> = queries
            .iter()
            .map(|(cc, arg)| format!("{addr}{cc}{arg}"))
            .collect();
        let expect: Vec<&str> = queries.iter().map(|(cc, _)| *cc).collect();
        let request = lines.join(" ");
        let mut last = None;
        for attempt in 1..=ATTEMPTS {
            match self.exchange(&lines, addr, &expect).await {
                Ok(v) => return Ok(v),
                Err(TransportError::Disconnected(d)) => {
                    return Err(self.transport_error(addr, &request, TransportError::Disconnected(d)));
                }
                Err(e) => {
                    tracing::warn!(device = %self.dev(addr), %request, attempt, error = %e, "query failed; retrying");
                    last = Some(e);
                }
            }
        }
        Err(self.transport_error(addr, &request, last.unwrap_or(TransportError::Timeout)))
    }

    /// Send a query `<addr><cc><arg>` and return the value of the matching reply. Lines from other addresses or
    /// commands are discarded (traced). Queries are idempotent: retried on timeout or garbage, bounded.
    pub async fn query(&self, addr: u8, cc: &str, arg: &str) -> Result<String, DriverError> {
        self.queries(addr, &[(cc, arg)])
            .await?
            .pop()
            .flatten()
            // Unreachable in practice: the exchange ends only with its last reply.
            .ok_or_else(|| DriverError::Protocol {
                device: self.dev(addr),
                request: format!("{addr}{cc}{arg}"),
                detail: "no reply value".into(),
            })
    }

    /// Send a set command and read `TE` in the same exchange. `idempotent` commands are retried when the TE reply
    /// is lost; others (OR, PR, ST) are sent once, and a lost TE is reported as a timeout.
    pub async fn command(&self, addr: u8, cc: &str, arg: &str, idempotent: bool) -> Result<(), DriverError> {
        self.command_after(addr, &[], cc, arg, idempotent)
            .await
            .map(|_| ())
    }

    /// Like [`Smc100Chain::command`], with `queries` answered just before the command runs, in the same exchange
    /// (e.g. the position a move starts from). Returns the queries' values in order, `None` for a lost one.
    pub async fn command_after(
        &self,
        addr: u8,
        queries: &[(&str, &str)],
        cc: &str,
        arg: &str,
        idempotent: bool,
    ) -> Result<Vec<Option<String>>, DriverError> {
        let request = format!("{addr}{cc}{arg}");
        let mut lines: Vec<String> = queries.iter().map(|(q, a)| format!("{addr}{q}{a}")).collect();
        lines.push(request.clone());
        lines.push(format!("{addr}TE"));
        let mut expect: Vec<&str> = queries.iter().map(|(q, _)| *q).collect();
        expect.push("TE");
        let attempts = if idempotent { ATTEMPTS } else { 1 };
        let mut last = TransportError::Timeout;
        let mut refused = None;
        for attempt in 1..=attempts {
            match self.exchange(&lines, addr, &expect).await {
                Ok(mut values) => {
                    let v = values.pop().flatten().unwrap_or_default();
                    // A code the controller does not have is a garbled reply, not a refusal.
                    let code = parse_te(&v)
                        .filter(|c| *c == '@' || describe_te(*c) != describe_te('?'))
                        .ok_or_else(|| DriverError::Protocol {
                            device: self.dev(addr),
                            request: format!("{addr}TE"),
                            detail: format!("not an error code: {v:?}"),
                        })?;
                    if code == '@' {
                        return Ok(values);
                    }
                    let e = if code == 'H' {
                        DriverError::NotReferenced {
                            device: self.dev(addr),
                            state: format!("{request} refused: {}", describe_te(code)),
                        }
                    } else {
                        DriverError::Rejected {
                            device: self.dev(addr),
                            request: request.clone(),
                            reason: format!("error {code}: {}", describe_te(code)),
                        }
                    };
                    // The TE reply may have been garbled into another documented code ('@' into 'H' sends the
                    // caller homing a moving axis): an idempotent command is sent once more, and only a repeated
                    // refusal counts. (MOVING is left to the caller: a resent move meets it whenever the first
                    // copy got through.)
                    if idempotent && code != 'M' && attempt < attempts && refused.is_none() {
                        tracing::warn!(device = %self.dev(addr), %request, error = %e, "refused; asking again to confirm");
                        refused = Some(e);
                        continue;
                    }
                    return Err(e);
                }
                Err(TransportError::Disconnected(d)) => {
                    return Err(self.transport_error(addr, &request, TransportError::Disconnected(d)));
                }
                Err(e) => {
                    if idempotent {
                        tracing::warn!(device = %self.dev(addr), %request, attempt, error = %e, "no TE reply; retrying");
                    }
                    last = e;
                }
            }
        }
        Err(refused.unwrap_or_else(|| self.transport_error(addr, &request, last)))
    }

    /// Controller status.
    pub async fn ts(&self, addr: u8) -> Result<Ts, DriverError> {
        let mut last = String::new();
        for _ in 0..ATTEMPTS {
            let v = self.query(addr, "TS", "").await?;
            if let Some(ts) = parse_ts(&v) {
                return Ok(ts);
            }
            tracing::warn!(device = %self.dev(addr), value = %v, "malformed TS reply; asking again");
            last = v;
        }
        Err(DriverError::Protocol {
            device: self.dev(addr),
            request: format!("{addr}TS"),
            detail: format!("{last:?}"),
        })
    }

    /// A numeric query (`TP`, `VA?`, ...).
    pub async fn number(&self, addr: u8, cc: &str, arg: &str) -> Result<f64, DriverError> {
        let mut last = String::new();
        for _ in 0..ATTEMPTS {
            let v = self.query(addr, cc, arg).await?;
            if let Some(x) = parse_number(&v) {
                return Ok(x);
            }
            tracing::warn!(device = %self.dev(addr), value = %v, "malformed numeric reply; asking again");
            last = v;
        }
        Err(DriverError::Protocol {
            device: self.dev(addr),
            request: format!("{addr}{cc}{arg}"),
            detail: format!("{last:?}"),
        })
    }

    /// Stop the given controllers now, on the priority path (does not wait for exchanges in flight).
    pub async fn stop_all(&self, addrs: &[u8]) -> Result<(), DriverError> {
        let mut line = Vec::new();
        for a in addrs {
            line.extend_from_slice(format!("{a}ST\r\n").as_bytes());
        }
        self.port
            .send_priority(&line, Instant::now() + REPLY_TIMEOUT)
            .await
            .map_err(|e| self.transport_error(addrs.first().copied().unwrap_or(0), "ST", e))?;
        tracing::info!(chain = %self.name, ?addrs, "stop sent");
        Ok(())
    }
}

/// Read the replies from `addr` to the commands `expect` (two-letter codes), which come in the order the
/// commands were sent: each reply fills the first open slot at or after the last one filled that names its
/// command. Ends when the last slot is filled; a slot skipped on the way (its reply lost, or garbled in its address
/// or code) stays `None`. Lines from other controllers or for other commands are stale and dropped with a trace.
async fn read_replies(
    s: &mut crate::transport::line::Session<'_>,
    addr: u8,
    expect: &[&str],
    deadline: Instant,
) -> Result<Vec<Option<String>>, TransportError> {
    let mut values: Vec<Option<String>> = vec![None; expect.len()];
    if expect.is_empty() {
        return Ok(values);
    }
    let mut next = 0;
    loop {
        let line = s.read_line(deadline).await?;
        let slot = parse_reply(&line).and_then(|(a, c, v)| {
            let at = (next..expect.len()).find(|i| expect.get(*i).is_some_and(|e| e.as_bytes() == c))?;
            (a == addr).then_some((at, v))
        });
        match slot {
            Some((at, v)) => {
                if let Some(cell) = values.get_mut(at) {
                    *cell = Some(v.to_string());
                }
                next = at + 1;
                if next >= expect.len() {
                    return Ok(values);
                }
            }
            None => {
                tracing::debug!(line = %escape_bytes(&line), expected = %format!("{addr}{expect:?}"), "unexpected line discarded")
            }
        }
    }
}

/// One SMC100 axis.
#[derive(Debug)]
pub struct Smc100Axis {
    chain: Arc<Smc100Chain>,
    addr: u8,
    cfg: gonio_instrument::Axis,
    /// Speed and acceleration in use (controller units per s, per s^2), for deadlines.
    motion: Mutex<(f64, f64)>,
    /// Controller position where the last move started.
    last_start: Mutex<Option<f64>>,
    /// The last move was already over at its first status question (a move that was tiny, or a controller much
    /// faster than its configured motion, like the simulator at a large time scale): the first question of the
    /// next move then asks for the read-back at once, saving an exchange.
    early_finish: AtomicBool,
}

impl Smc100Axis {
    pub fn new(chain: Arc<Smc100Chain>, cfg: gonio_instrument::Axis) -> Smc100Axis {
        let motion = Mutex::new((cfg.max_speed_deg_s, cfg.accel_deg_s2));
        Smc100Axis {
            chain,
            addr: cfg.address,
            cfg,
            motion,
            last_start: Mutex::new(None),
            early_finish: AtomicBool::new(false),
        }
    }

    pub fn address(&self) -> u8 {
        self.addr
    }

    fn dev(&self) -> String {
        format!("{} ({}/{})", self.cfg.name, self.chain.name, self.addr)
    }

    fn speed_accel(&self) -> (f64, f64) {
        self.motion
            .lock()
            .map(|g| *g)
            .unwrap_or((self.cfg.max_speed_deg_s, self.cfg.accel_deg_s2))
    }

    fn check_limits(&self, target_deg: f64) -> Result<(), DriverError> {
        if !(target_deg.is_finite() && target_deg >= self.cfg.min_deg && target_deg <= self.cfg.max_deg) {
            return Err(DriverError::OutOfRange {
                device: self.dev(),
                what: "target (deg)".into(),
                value: target_deg,
                min: self.cfg.min_deg,
                max: self.cfg.max_deg,
            });
        }
        Ok(())
    }

    /// Whether two position reads (controller units) agree: within the encoder resolution for an axis at rest;
    /// for a moving axis, within what it travels at full speed between the two reads.
    fn reads_agree(&self, a: f64, b: f64, moving: bool) -> bool {
        let mut tolerance = self.cfg.encoder_resolution_deg.max(1e-6) + 1e-9;
        if moving {
            let (v, _) = self.speed_accel();
            tolerance += v.abs() * MOVING_READ_WINDOW_S;
        }
        (a - b).abs() <= tolerance
    }

    /// The controller position (controller units), read for a decision: where a move starts from, where it
    /// ended, where the engine plans from. Why two reads: a reply garbled inside a well-formed number
    /// (`1TP12.345` with one digit changed) parses like a good one, and this protocol has no checksum. Two reads
    /// in one exchange must agree within the encoder resolution (one corrupted byte cannot make both wrong
    /// alike); a moving axis is allowed its travel between them. Retried, boundedly; a typed Protocol error
    /// when the reads never agree.
    pub async fn verified_position(&self) -> Result<f64, DriverError> {
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = self.chain.queries(self.addr, &[("TP", ""), ("TP", "")]).await?;
            let (a, b) = (number_at(&r, 0), number_at(&r, 1));
            if let (Some(a), Some(b)) = (a, b) {
                if self.reads_agree(a, b, false) {
                    return Ok(b);
                }
                // Reads of a moving axis differ by its travel: that is motion, not garbage.
                if let Ok(ts) = self.chain.ts(self.addr).await
                    && is_moving(ts.state)
                    && self.reads_agree(a, b, true)
                {
                    return Ok(b);
                }
            }
            tracing::warn!(axis = %self.dev(), attempt, replies = ?r, "two position reads disagree; reading again");
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: format!("{}TP (read twice)", self.addr),
            detail: format!(
                "the two reads never agreed within the encoder resolution ({} deg): {}",
                self.cfg.encoder_resolution_deg,
                seen.join(", ")
            ),
        })
    }

    /// A TS reading that would end a wait or report a fault (DISABLE, NOT REFERENCED, CONFIGURATION, and error
    /// bits when `errors_matter`) is confirmed by a second TS before anything acts on it: one garbled byte turns
    /// READY (33) into DISABLE (3C). Returns the latest reading (the second when a confirmation was asked).
    async fn confirmed(&self, ts: Ts, errors_matter: bool) -> Result<Ts, DriverError> {
        let alarming = (errors_matter && ts.errors != 0)
            || matches!(
                ts.state,
                State::Disable(_) | State::NotReferenced(_) | State::Configuration | State::Unknown(_)
            );
        if !alarming {
            return Ok(ts);
        }
        let again = self.chain.ts(self.addr).await?;
        if again != ts {
            tracing::warn!(axis = %self.dev(), first = %ts_reason(&ts), second = %ts_reason(&again), "status changed on a second look");
        }
        Ok(again)
    }

    /// Status with the position converted to physical degrees: TS and two TP reads in one exchange.
    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = self
                .chain
                .queries(self.addr, &[("TS", ""), ("TP", ""), ("TP", "")])
                .await?;
            let ts = r.first().and_then(|v| v.as_deref()).and_then(parse_ts);
            if let (Some(ts), Some(a), Some(b)) = (ts, number_at(&r, 1), number_at(&r, 2))
                && self.reads_agree(a, b, is_moving(ts.state))
            {
                let ts = self.confirmed(ts, true).await?;
                let fault = match ts.state {
                    State::Disable(_) | State::Unknown(_) => Some(ts_reason(&ts)),
                    _ if ts.errors != 0 => Some(ts_reason(&ts)),
                    _ => None,
                };
                return Ok(AxisStatus {
                    position_deg: self.cfg.physical_from_controller_deg(b),
                    moving: is_moving(ts.state),
                    referenced: !matches!(ts.state, State::NotReferenced(_) | State::Configuration),
                    fault,
                    raw: format!("TS errors {:04X}, {}", ts.errors, ts.state.describe()),
                });
            }
            tracing::warn!(axis = %self.dev(), attempt, replies = ?r, "status replies malformed or disagreeing; reading again");
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: format!("{0}TS {0}TP {0}TP", self.addr),
            detail: format!("no consistent status: {}", seen.join(", ")),
        })
    }

    /// Home: NOT REFERENCED -> `OR` and wait for READY; DISABLE -> `MM1` back to READY (reference kept);
    /// READY -> nothing to do. `OR` is sent once, never retried blindly.
    pub async fn do_home(&self) -> Result<(), DriverError> {
        let ts = self.chain.ts(self.addr).await?;
        match ts.state {
            State::Ready(_) => {
                tracing::info!(axis = %self.dev(), "already referenced");
                Ok(())
            }
            State::Disable(_) => {
                tracing::info!(axis = %self.dev(), state = %ts.state.describe(), "leaving DISABLE (MM1)");
                self.chain.command(self.addr, "MM", "1", true).await?;
                self.wait_state(
                    |s| matches!(s, State::Ready(_)),
                    Wait::plain(Duration::from_secs(5), Duration::ZERO),
                    None,
                )
                .await
                .map(|_| ())
            }
            State::NotReferenced(_) => {
                tracing::info!(axis = %self.dev(), "homing (OR)");
                if let Err(e) = self.chain.command(self.addr, "OR", "", false).await {
                    // OR is not resent blindly, but a lost or garbled TE reply says nothing about whether homing
                    // started: the controller's state does.
                    if !matches!(e.kind(), ErrorKind::Timeout | ErrorKind::Protocol) {
                        return Err(e);
                    }
                    match self.chain.ts(self.addr).await?.state {
                        State::Homing(_) | State::Ready(_) => {
                            tracing::warn!(axis = %self.dev(), error = %e, "no clear reply to OR, but homing is under way")
                        }
                        State::NotReferenced(_) => {
                            tracing::warn!(axis = %self.dev(), error = %e, "OR not taken; sending it again");
                            self.chain.command(self.addr, "OR", "", false).await?;
                        }
                        _ => return Err(e),
                    }
                }
                // Homing searches at reduced speed across at most the whole travel.
                let (v, a) = self.speed_accel();
                let span = self.cfg.max_deg - self.cfg.min_deg;
                let deadline = move_deadline(span, v * 0.25, a) + Duration::from_secs(10);
                self.wait_state(
                    |s| matches!(s, State::Ready(_)),
                    Wait::plain(deadline, Duration::ZERO),
                    None,
                )
                .await
                .map(|_| ())
            }
            other => Err(DriverError::Rejected {
                device: self.dev(),
                request: format!("{}OR", self.addr),
                reason: format!("cannot home in state {}", other.describe()),
            }),
        }
    }

    /// Poll TS until `done(state)`, on a [`PollSchedule`] (the first question at once). DISABLE, NOT REFERENCED
    /// (unless awaited), CONFIGURATION and unknown states end the wait with the device's reason, once confirmed
    /// (see [`Smc100Axis::confirmed`]). Returns the final TS and, when `wait.readback` asked for it and the final
    /// question carried two agreeing TP reads, the read-back position (controller units).
    async fn wait_state(
        &self,
        done: impl Fn(State) -> bool,
        wait: Wait,
        target_deg: Option<f64>,
    ) -> Result<(Ts, Option<f64>), DriverError> {
        let start = Instant::now();
        let mut timeout = wait.timeout;
        let mut schedule = PollSchedule::new(start + wait.predicted, POLL_MIN, POLL_MAX);
        let mut first = true;
        loop {
            let now = Instant::now();
            let pt_arg = wait.pt_distance.filter(|_| first).map(wire_number);
            // A question asked when the move should be over also asks for the read-back (two TP), so that the
            // arrival costs no further exchange.
            let readback = wait.readback
                && (schedule.expect_over(now) || (first && self.early_finish.load(Ordering::Relaxed)));
            let mut queries: Vec<(&str, &str)> = Vec::with_capacity(4);
            if let Some(arg) = pt_arg.as_deref() {
                queries.push(("PT", arg));
            }
            queries.push(("TS", ""));
            if readback {
                queries.extend([("TP", ""), ("TP", "")]);
            }
            let r = self.chain.queries(self.addr, &queries).await?;
            let mut at = 0;
            if pt_arg.is_some() {
                // The controller's own estimate of the move time can only lengthen the deadline: it knows its
                // real profile.
                if let Some(pt) = number_at(&r, 0)
                    && (0.0..600.0).contains(&pt)
                {
                    timeout = timeout.max(Duration::from_secs_f64(2.0 * pt + 2.0));
                }
                at = 1;
            }
            let (ts, read) = match r.get(at).and_then(|v| v.as_deref()).and_then(parse_ts) {
                Some(ts) => {
                    // (A wait acts on the state only; error bits are for the status report.)
                    let confirmed = self.confirmed(ts, false).await?;
                    // Read-back values count only when they followed this very TS (not a confirmation).
                    let read = match (number_at(&r, at + 1), number_at(&r, at + 2)) {
                        (Some(a), Some(b)) if confirmed == ts && self.reads_agree(a, b, false) => Some(b),
                        _ => None,
                    };
                    (confirmed, read)
                }
                None => {
                    tracing::warn!(axis = %self.dev(), replies = ?r, "malformed TS reply; asking again");
                    (
                        self.confirmed(self.chain.ts(self.addr).await?, false).await?,
                        None,
                    )
                }
            };
            if done(ts.state) {
                if wait.readback && first {
                    self.early_finish.store(true, Ordering::Relaxed);
                }
                return Ok((ts, read));
            }
            if wait.readback && first {
                self.early_finish.store(false, Ordering::Relaxed);
            }
            match ts.state {
                State::Moving | State::Homing(_) => {}
                State::NotReferenced(_) => {
                    return Err(DriverError::NotReferenced {
                        device: self.dev(),
                        state: ts_reason(&ts),
                    });
                }
                State::Ready(_) => {}
                _ => {
                    return Err(DriverError::MotionFault {
                        device: self.dev(),
                        target_deg: target_deg.unwrap_or(f64::NAN),
                        reason: ts_reason(&ts),
                    });
                }
            }
            let now = Instant::now();
            let deadline = start + timeout;
            if now >= deadline {
                tracing::warn!(axis = %self.dev(), "deadline passed while moving; stopping the axis");
                let _ = self.chain.stop_all(&[self.addr]).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: match target_deg {
                        Some(t) => format!("move to {t} deg"),
                        None => "homing".into(),
                    },
                    timeout,
                });
            }
            first = false;
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
        }
    }

    /// Send `PA` for a physical target (idempotent, retried when its TE is lost).
    pub async fn do_start_move(&self, target_deg: f64) -> Result<(), DriverError> {
        self.check_limits(target_deg)?;
        let controller = self.cfg.controller_from_physical_deg(target_deg);
        if let Ok(mut g) = self.last_start.lock() {
            *g = None;
        }
        tracing::info!(axis = %self.dev(), target_deg, controller, "move absolute");
        // The position the move starts from (read twice, see `verified_position`) goes out in the same exchange
        // as PA: the distance sets the deadline and when to ask whether the move is over. When the two reads do
        // not agree the start stays unknown and the wait assumes the whole travel (a longer deadline, no harm).
        match self
            .chain
            .command_after(
                self.addr,
                &[("TP", ""), ("TP", "")],
                "PA",
                &wire_number(controller),
                true,
            )
            .await
        {
            Ok(start) => {
                let start = match (number_at(&start, 0), number_at(&start, 1)) {
                    (Some(a), Some(b)) if self.reads_agree(a, b, false) => Some(b),
                    _ => None,
                };
                if let Ok(mut g) = self.last_start.lock() {
                    *g = start;
                }
                Ok(())
            }
            // A retried PA whose first copy got through (only its TE reply was lost) meets the axis already
            // MOVING: that is success if the controller's set-point is our target. During a move the set-point
            // (TH) is the profile generator's position, which reaches the target only at the end of the move:
            // when it does not match at once, wait (bounded) for the move in progress to end and look again.
            Err(e @ DriverError::Rejected { .. }) if e.to_string().contains("error M:") => {
                let on_target =
                    |th: f64| (th - controller).abs() <= self.cfg.encoder_resolution_deg.max(1e-6);
                if let Ok(th) = self.chain.number(self.addr, "TH", "").await
                    && on_target(th)
                {
                    tracing::info!(axis = %self.dev(), target_deg, "already moving to this target");
                    return Ok(());
                }
                let (v, a) = self.speed_accel();
                let timeout = move_deadline(self.cfg.max_deg - self.cfg.min_deg, v, a);
                match self
                    .wait_state(
                        |s| matches!(s, State::Ready(_)),
                        Wait::plain(timeout, Duration::ZERO),
                        Some(target_deg),
                    )
                    .await
                {
                    Ok(_) => {}
                    // The move in progress ended in a fault (a stall leaves DISABLE): that is the error to report.
                    Err(stalled) if stalled.kind() == ErrorKind::MotionFault => return Err(stalled),
                    Err(_) => return Err(e),
                }
                match self.chain.number(self.addr, "TH", "").await {
                    Ok(th) if on_target(th) => {
                        tracing::info!(axis = %self.dev(), target_deg, "the retried move had already run to this target");
                        Ok(())
                    }
                    _ => Err(e),
                }
            }
            // DISABLE is where a stall or a stop leaves the controller: a motion fault, which the caller recovers
            // from (reconnecting re-enables the axis), not a refusal to give up on.
            Err(DriverError::Rejected { reason, .. }) if reason.starts_with("error J:") => {
                Err(DriverError::MotionFault {
                    device: self.dev(),
                    target_deg,
                    reason: format!(
                        "the controller is in DISABLE after a fault and refused the move ({reason})"
                    ),
                })
            }
            Err(other) => Err(other),
        }
    }

    /// Wait for the move to end and verify the read-back against the target.
    pub async fn do_wait_arrived(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.wait_arrived_within(target_deg, self.cfg.tolerance_deg).await
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    async fn wait_arrived_within(&self, target_deg: f64, tolerance_deg: f64) -> Result<f64, DriverError> {
        let controller_target = self.cfg.controller_from_physical_deg(target_deg);
        let (v, a) = self.speed_accel();
        let start = self.last_start.lock().ok().and_then(|g| *g);
        let distance = match start {
            Some(s) => (controller_target - s).abs(),
            None => self.cfg.max_deg - self.cfg.min_deg,
        };
        let predicted = trapezoid_time_s(distance, v, a);
        let wait = Wait {
            timeout: move_deadline(distance, v, a),
            predicted: Duration::from_secs_f64(if predicted.is_finite() {
                predicted.clamp(0.0, 600.0)
            } else {
                0.0
            }),
            pt_distance: Some(distance),
            readback: true,
        };
        let (ts, read_c) = self
            .wait_state(|s| matches!(s, State::Ready(_)), wait, Some(target_deg))
            .await?;
        // READY: verify the read-back. The position decides whether the move arrived and becomes the point's
        // recorded position, hence two agreeing reads (see `verified_position`), never one.
        let mut read_c = match read_c {
            Some(p) => p,
            None => self.verified_position().await?,
        };
        let mut read = f64::NAN;
        for attempt in 1..=ATTEMPTS {
            read = self.cfg.physical_from_controller_deg(read_c);
            if (read - target_deg).abs() <= tolerance_deg {
                tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
                return Ok(read);
            }
            if attempt == ATTEMPTS {
                break;
            }
            // A servo may still settle into its deadband just after READY: look again, a little later.
            tokio::time::sleep(POLL_MIN).await;
            read_c = self.verified_position().await?;
        }
        Err(DriverError::MotionFault {
            device: self.dev(),
            target_deg,
            reason: format!(
                "stopped at {read} deg ({}), tolerance {} deg; {}",
                read - target_deg,
                tolerance_deg,
                ts_reason(&ts)
            ),
        })
    }

    /// Move with the backlash approach and verified arrival.
    pub async fn do_move_to(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.check_limits(target_deg)?;
        // Where the axis is decides whether the approach needs the backlash overshoot: a verified read.
        let current = self.verified_position().await?;
        let mut read = f64::NAN;
        for (step_deg, tolerance) in approach_waypoints(&self.cfg, current, target_deg) {
            self.do_start_move(step_deg).await?;
            read = self.wait_arrived_within(step_deg, tolerance).await?;
        }
        Ok(read)
    }

    pub async fn do_set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
        check_speed(self.dev(), speed_deg_s, accel_deg_s2)?;
        self.chain
            .command(self.addr, "VA", &wire_number(speed_deg_s), true)
            .await?;
        self.chain
            .command(self.addr, "AC", &wire_number(accel_deg_s2), true)
            .await?;
        if let Ok(mut g) = self.motion.lock() {
            *g = (speed_deg_s, accel_deg_s2);
        }
        Ok(())
    }

    pub async fn do_reconnect(&self) -> Result<AxisStatus, DriverError> {
        self.chain
            .port
            .reconnect()
            .await
            .map_err(|e| DriverError::Unavailable {
                device: self.dev(),
                detail: e.to_string(),
            })?;
        // A stall (following error) or a stop leaves the controller in DISABLE, where it refuses every move
        // (error J). Reconnecting means "ready to be commanded again": leave DISABLE with MM1, which keeps the
        // reference, so that the caller's retry of an absolute move is not refused.
        let ts = self.chain.ts(self.addr).await?;
        if let State::Disable(_) = ts.state {
            tracing::warn!(axis = %self.dev(), reason = %ts_reason(&ts), "controller in DISABLE after a fault; re-enabling");
            self.do_home().await?;
        }
        let status = self.read_status().await?;
        if !status.referenced {
            return Err(DriverError::NotReferenced {
                device: self.dev(),
                state: status.raw,
            });
        }
        tracing::info!(axis = %self.dev(), position_deg = status.position_deg, "re-verified after reconnect");
        Ok(status)
    }

    /// Expected duration of a move of `distance_deg` at the current settings (for planning).
    pub fn move_time_s(&self, distance_deg: f64) -> f64 {
        let (v, a) = self.speed_accel();
        trapezoid_time_s(distance_deg, v, a)
    }
}

/// How long to wait for a state, and what else to ask on the way (see [`Smc100Axis::wait_state`]).
#[derive(Debug, Clone, Copy)]
struct Wait {
    /// Deadline from the start of the wait (lengthened by the controller's PT estimate when asked).
    timeout: Duration,
    /// When the awaited state is predicted, from the start of the wait.
    predicted: Duration,
    /// Ask PT for this distance with the first question.
    pt_distance: Option<f64>,
    /// Ask for the read-back (two TP) with the questions made when the move should be over.
    readback: bool,
}

impl Wait {
    fn plain(timeout: Duration, predicted: Duration) -> Wait {
        Wait {
            timeout,
            predicted,
            pt_distance: None,
            readback: false,
        }
    }
}

/// The number in reply `i` of an exchange, if it came and parses.
fn number_at(replies: &[Option<String>], i: usize) -> Option<f64> {
    replies.get(i)?.as_deref().and_then(parse_number)
}

/// States in which the axis moves by itself.
fn is_moving(state: State) -> bool {
    matches!(state, State::Moving | State::Homing(_) | State::Jogging(_))
}

fn ts_reason(ts: &Ts) -> String {
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

impl Axis for Smc100Axis {
    fn name(&self) -> &str {
        &self.cfg.name
    }
    fn limits(&self) -> AxisLimits {
        AxisLimits {
            min_deg: self.cfg.min_deg,
            max_deg: self.cfg.max_deg,
            max_speed_deg_s: self.cfg.max_speed_deg_s,
            accel_deg_s2: self.cfg.accel_deg_s2,
        }
    }
    fn home(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_home())
    }
    fn move_to(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.do_move_to(target_deg))
    }
    fn start_move(&self, target_deg: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_start_move(target_deg))
    }
    fn wait_arrived(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.do_wait_arrived(target_deg))
    }
    fn wait_passed_via(&self, via_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.wait_arrived_within(via_deg, crate::motion::via_point_tolerance_deg(&self.cfg)))
    }
    fn position_deg(&self) -> BoxFuture<'_, Result<f64, DriverError>> {
        // The engine plans moves (and their collision safety) from this: a verified read.
        Box::pin(async move {
            let pos = self.verified_position().await?;
            Ok(self.cfg.physical_from_controller_deg(pos))
        })
    }
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.read_status())
    }
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.chain.stop_all(std::slice::from_ref(&self.addr)))
    }
    fn set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_set_speed(speed_deg_s, accel_deg_s2))
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.do_reconnect())
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
