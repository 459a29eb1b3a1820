//! Newport SMC100CC/PP motion controllers on one daisy-chained RS-232 port, written from the SMC100 user manual.
//!
//! Wire format: `<addr><CC><arg>\r\n`. Queries answer `<addr><CC><value>\r\n`; set commands are silent, so every
//! set command is followed, in the same exchange, by `<addr>TE` (last command error, `@` = none). Status `TS`
//! answers 4 hex digits of positioner error bits and 2 hex digits of controller state. `PA` is idempotent and may
//! be retried; `OR` (home) and `PR` are never retried blindly. A wait loop treats DISABLE (3C..3E) and the NOT
//! REFERENCED states as terminal.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use crate::error::{DriverError, ErrorKind};
use crate::motion::{approach_waypoints, check_speed, move_deadline, trapezoid_time_s};
use crate::traits::{Axis, AxisLimits, AxisStatus};
use crate::transport::{BoxFuture, LinePort, TransportError, escape_bytes};

/// Time allowed for one query's reply.
const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
/// Attempts for idempotent requests (queries, PA).
const ATTEMPTS: usize = 3;
/// Status polling interval while waiting for a move.
const POLL: Duration = Duration::from_millis(50);

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

    /// Send a query `<addr><cc><arg>` and return the value of the matching reply. Lines from other addresses or
    /// commands are discarded (traced). Queries are idempotent: retried on timeout or garbage, bounded.
    pub async fn query(&self, addr: u8, cc: &str, arg: &str) -> Result<String, DriverError> {
        let request = format!("{addr}{cc}{arg}");
        let mut last = None;
        for attempt in 1..=ATTEMPTS {
            let mut s = self.port.session().await;
            let r = async {
                s.discard_stale().await?;
                let deadline = Instant::now() + REPLY_TIMEOUT;
                s.send(format!("{request}\r\n").as_bytes(), deadline).await?;
                read_matching(&mut s, addr, cc, deadline).await
            }
            .await;
            match r {
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

    /// Send a set command and read `TE` in the same exchange. `idempotent` commands are retried when the TE reply
    /// is lost; others (OR, PR, ST) are sent once, and a lost TE is reported as a timeout.
    pub async fn command(&self, addr: u8, cc: &str, arg: &str, idempotent: bool) -> Result<(), DriverError> {
        let request = format!("{addr}{cc}{arg}");
        let attempts = if idempotent { ATTEMPTS } else { 1 };
        let mut last = TransportError::Timeout;
        let mut refused = None;
        for attempt in 1..=attempts {
            let mut s = self.port.session().await;
            let r = async {
                s.discard_stale().await?;
                let deadline = Instant::now() + REPLY_TIMEOUT;
                s.send(format!("{request}\r\n{addr}TE\r\n").as_bytes(), deadline)
                    .await?;
                read_matching(&mut s, addr, "TE", deadline).await
            }
            .await;
            match r {
                Ok(v) => {
                    // A code the controller does not have is a garbled reply, not a refusal.
                    let code = parse_te(&v)
                        .filter(|c| *c == '@' || describe_te(*c) != describe_te('?'))
                        .ok_or_else(|| DriverError::Protocol {
                            device: self.dev(addr),
                            request: format!("{addr}TE"),
                            detail: format!("not an error code: {v:?}"),
                        })?;
                    if code == '@' {
                        return Ok(());
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

/// Read lines until one from `addr` answering `cc`; other lines are stale and dropped with a trace.
async fn read_matching(
    s: &mut crate::transport::line::Session<'_>,
    addr: u8,
    cc: &str,
    deadline: Instant,
) -> Result<String, TransportError> {
    loop {
        let line = s.read_line(deadline).await?;
        match parse_reply(&line) {
            Some((a, c, v)) if a == addr && c == cc.as_bytes() => return Ok(v.to_string()),
            _ => {
                tracing::debug!(line = %escape_bytes(&line), expected = %format!("{addr}{cc}"), "unexpected line discarded")
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

    /// Status with the position converted to physical degrees.
    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let ts = self.chain.ts(self.addr).await?;
        let pos = self.chain.number(self.addr, "TP", "").await?;
        let fault = match ts.state {
            State::Disable(_) | State::Unknown(_) => Some(ts_reason(&ts)),
            _ if ts.errors != 0 => Some(ts_reason(&ts)),
            _ => None,
        };
        Ok(AxisStatus {
            position_deg: self.cfg.physical_from_controller_deg(pos),
            moving: matches!(ts.state, State::Moving | State::Homing(_) | State::Jogging(_)),
            referenced: !matches!(ts.state, State::NotReferenced(_) | State::Configuration),
            fault,
            raw: format!("TS errors {:04X}, {}", ts.errors, ts.state.describe()),
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
                self.wait_state(|s| matches!(s, State::Ready(_)), Duration::from_secs(5), None)
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
                self.wait_state(|s| matches!(s, State::Ready(_)), deadline, None)
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

    /// Poll TS until `done(state)`. DISABLE, NOT REFERENCED (unless awaited), CONFIGURATION and unknown states
    /// end the wait with the device's reason. Returns the final TS.
    async fn wait_state(
        &self,
        done: impl Fn(State) -> bool,
        timeout: Duration,
        target_deg: Option<f64>,
    ) -> Result<Ts, DriverError> {
        let deadline = Instant::now() + timeout;
        loop {
            let ts = self.chain.ts(self.addr).await?;
            if done(ts.state) {
                return Ok(ts);
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
            if Instant::now() >= deadline {
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
            tokio::time::sleep(POLL).await;
        }
    }

    /// Send `PA` for a physical target (idempotent, retried when its TE is lost).
    pub async fn do_start_move(&self, target_deg: f64) -> Result<(), DriverError> {
        self.check_limits(target_deg)?;
        let controller = self.cfg.controller_from_physical_deg(target_deg);
        let start = self.chain.number(self.addr, "TP", "").await.ok();
        if let Ok(mut g) = self.last_start.lock() {
            *g = start;
        }
        tracing::info!(axis = %self.dev(), target_deg, controller, "move absolute");
        match self
            .chain
            .command(self.addr, "PA", &wire_number(controller), true)
            .await
        {
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
                    .wait_state(|s| matches!(s, State::Ready(_)), timeout, Some(target_deg))
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
            other => other,
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
        let mut timeout = move_deadline(distance, v, a);
        // The controller's own estimate (PT) can only lengthen the deadline: it knows its real profile.
        if let Ok(pt) = self.chain.number(self.addr, "PT", &wire_number(distance)).await
            && pt.is_finite()
            && (0.0..600.0).contains(&pt)
        {
            timeout = timeout.max(Duration::from_secs_f64(2.0 * pt + 2.0));
        }
        let ts = self
            .wait_state(|s| matches!(s, State::Ready(_)), timeout, Some(target_deg))
            .await?;
        // READY: verify the read-back; a garbled number is re-read rather than trusted.
        let mut read = f64::NAN;
        for _ in 0..ATTEMPTS {
            let pos = self.chain.number(self.addr, "TP", "").await?;
            read = self.cfg.physical_from_controller_deg(pos);
            if (read - target_deg).abs() <= tolerance_deg {
                tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
                return Ok(read);
            }
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
        let current = self.chain.number(self.addr, "TP", "").await?;
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
    fn position_deg(&self) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(async move {
            let pos = self.chain.number(self.addr, "TP", "").await?;
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
