//! Zaber motion devices over the ASCII protocol, written from Zaber's ASCII protocol manual.
//!
//! Every command carries a message id (0..=99) and a checksum: `/<dev> <axis> <id> <command>:<CC>\n`. Replies
//! `@DD A [id] FL STATUS WW data[:CC]` are matched by device, axis and id; their checksum is verified when present,
//! and the driver turns a device's reply checksums on (`set comm.checksum 1`) whenever a reply comes without one;
//! an idle axis's position is only taken from a checksummed reply or confirmed by a second read (see
//! [`ZaberChain`]). Alerts (`!`) and info lines (`#`) interleaved with replies are handled, and a
//! reply or info line ending in `\` continues in the next `#... cont` info line. `move abs`, `get`, `stop` and
//! `warnings` are idempotent and retried (bounded); `home` is sent once. Positions are integer microsteps,
//! converted to degrees with the axis's `microstep_deg`. A wait for a move asks at once, then on a
//! [`PollSchedule`](crate::motion::PollSchedule).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use crate::error::DriverError;
use crate::motion::{PollSchedule, approach_waypoints, check_speed, move_deadline, trapezoid_time_s};
use crate::traits::{Axis, AxisLimits, AxisStatus};
use crate::transport::{BoxFuture, LinePort, TransportError, escape_bytes};

const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
const ATTEMPTS: usize = 3;
/// Shortest pause between two status questions to one device. The manual sets no minimum (a device answers each
/// command before the next is sent, as this driver waits for every reply); 10 ms leaves the shared chain free for
/// the other axes between questions.
const POLL_MIN: Duration = Duration::from_millis(10);
/// Longest pause between two status questions while a move runs: bounds how late a stall is noticed.
const POLL_MAX: Duration = Duration::from_millis(50);
/// Zaber's speed data unit: microsteps/s x 1.6384.
const SPEED_UNIT: f64 = 1.6384;
/// Zaber's acceleration data unit: microsteps/s^2 x 1.6384 / 10000.
const ACCEL_UNIT: f64 = 1.6384 / 10_000.0;

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

fn is_warning(s: &str) -> bool {
    s == "--" || (s.len() == 2 && s.bytes().all(|b| b.is_ascii_uppercase()))
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

/// Whether a device's replies carry checksums (the device setting `comm.checksum`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Checksums {
    /// Its replies carry them.
    On,
    /// A reply came without one: ask the device to add them before the next request.
    Enable,
    /// The device refused the setting: positions for decisions are confirmed by a second read instead.
    Unsupported,
}

/// One Zaber daisy chain: the port owner, the message-id counter, and the checksum state of each device.
///
/// Replies are only trusted with a checksum: a digit garbled inside a position (`@01 1 7 OK IDLE -- 60281`) parses
/// like a good one, and the LRC catches every single corrupted byte. Devices send checksums once their setting
/// `comm.checksum` is 1; the driver sets it whenever a device's reply comes without one (first contact, or a
/// device that lost the setting in a power cycle) and carries on.
#[derive(Debug)]
pub struct ZaberChain {
    name: String,
    port: Arc<LinePort>,
    next_id: AtomicU8,
    checksums: Mutex<BTreeMap<u8, Checksums>>,
}

impl ZaberChain {
    pub fn new(name: impl Into<String>, port: Arc<LinePort>) -> Arc<ZaberChain> {
        Arc::new(ZaberChain {
            name: name.into(),
            port,
            next_id: AtomicU8::new(0),
            checksums: Mutex::new(BTreeMap::new()),
        })
    }

    pub fn port(&self) -> &Arc<LinePort> {
        &self.port
    }

    fn take_id(&self) -> u8 {
        // 0..=99, wrapping; an id is never reused before 99 other requests have been made.
        self.next_id
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| Some((v + 1) % 100))
            .unwrap_or(0)
    }

    fn dev(&self, device: u8, axis: u8) -> String {
        format!("{}/{device}.{axis}", self.name)
    }

    fn transport_error(&self, device: u8, axis: u8, request: &str, e: TransportError) -> DriverError {
        let dev = self.dev(device, axis);
        match e {
            TransportError::Timeout => DriverError::Timeout {
                device: dev,
                request: request.into(),
                timeout: REPLY_TIMEOUT,
            },
            TransportError::Disconnected(detail) => DriverError::Disconnected { device: dev, detail },
            TransportError::Garbled(detail) => DriverError::Protocol {
                device: dev,
                request: request.into(),
                detail,
            },
        }
    }

    fn checksum_state(&self, device: u8) -> Option<Checksums> {
        self.checksums.lock().ok().and_then(|m| m.get(&device).copied())
    }

    fn set_checksum_state(&self, device: u8, state: Checksums) {
        if let Ok(mut m) = self.checksums.lock() {
            m.insert(device, state);
        }
    }

    /// Ask `device` to checksum its replies (`set comm.checksum 1`, idempotent). A refusal marks the device as
    /// without checksums; no reply leaves the request for the next exchange.
    async fn enable_checksums(&self, device: u8) {
        match self.request_raw(device, 0, "set comm.checksum 1", true).await {
            Ok(r) if r.flag == Flag::Ok => {
                tracing::info!(chain = %self.name, device, "reply checksums enabled");
                self.set_checksum_state(device, Checksums::On);
            }
            Ok(r) => {
                tracing::warn!(chain = %self.name, device, reason = %r.data, "the device refuses reply checksums; positions will be read twice");
                self.set_checksum_state(device, Checksums::Unsupported);
            }
            Err(e) => {
                tracing::warn!(chain = %self.name, device, error = %e, "could not enable reply checksums; will ask again")
            }
        }
    }

    /// Send `command` to `device`/`axis` and return its reply (OK or RJ; the caller decides). Idempotent commands
    /// are retried on a lost or garbled reply, with a fresh message id each time. Keeps the device's reply
    /// checksums on (see [`ZaberChain`]); [`Reply::checksummed`] says whether this reply had one.
    pub async fn request(
        &self,
        device: u8,
        axis: u8,
        command: &str,
        idempotent: bool,
    ) -> Result<Reply, DriverError> {
        if device != 0 && self.checksum_state(device) == Some(Checksums::Enable) {
            self.enable_checksums(device).await;
        }
        let reply = self.request_raw(device, axis, command, idempotent).await?;
        if device != 0 {
            match (reply.checksummed, self.checksum_state(device)) {
                (true, Some(Checksums::On)) => {}
                (true, _) => self.set_checksum_state(device, Checksums::On),
                (false, Some(Checksums::Unsupported)) => {}
                (false, state) => {
                    if state == Some(Checksums::On) {
                        tracing::warn!(chain = %self.name, device, "a reply without checksum from a device that sends them (restarted?)");
                    }
                    self.set_checksum_state(device, Checksums::Enable);
                }
            }
        }
        Ok(reply)
    }

    /// [`ZaberChain::request`] without the checksum bookkeeping.
    async fn request_raw(
        &self,
        device: u8,
        axis: u8,
        command: &str,
        idempotent: bool,
    ) -> Result<Reply, DriverError> {
        let attempts = if idempotent { ATTEMPTS } else { 1 };
        let mut last = TransportError::Timeout;
        for attempt in 1..=attempts {
            let id = self.take_id();
            let line = encode_command(device, axis, Some(id), command);
            let mut s = self.port.session().await;
            let r = async {
                s.discard_stale().await?;
                let deadline = Instant::now() + REPLY_TIMEOUT;
                s.send(line.as_bytes(), deadline).await?;
                self.read_reply(&mut s, device, axis, id, deadline).await
            }
            .await;
            match r {
                Ok(reply) => return Ok(reply),
                Err(TransportError::Disconnected(d)) => {
                    return Err(self.transport_error(device, axis, command, TransportError::Disconnected(d)));
                }
                Err(e) => {
                    if idempotent {
                        tracing::warn!(device = %self.dev(device, axis), command, attempt, error = %e, "no valid reply; retrying");
                    }
                    last = e;
                }
            }
        }
        Err(self.transport_error(device, axis, command, last))
    }

    async fn read_reply(
        &self,
        s: &mut crate::transport::line::Session<'_>,
        device: u8,
        axis: u8,
        id: u8,
        deadline: Instant,
    ) -> Result<Reply, TransportError> {
        let mut reply: Option<Reply> = None;
        loop {
            let line = s.read_line(deadline).await?;
            match parse_message(&line) {
                Ok(Message::Reply(r)) if r.device == device && r.axis == axis && r.id == Some(id) => {
                    if !r.continues {
                        return Ok(r);
                    }
                    reply = Some(r);
                }
                Ok(Message::Info(info)) if info.device == device && info.id == Some(id) => {
                    // `#DD A id cont N data`: the continuation of a reply that ended in `\`.
                    if let Some(r) = reply.as_mut() {
                        let data = info
                            .data
                            .strip_prefix("cont")
                            .map(str::trim_start)
                            .unwrap_or(&info.data);
                        let data = data
                            .split_once(' ')
                            .filter(|(n, _)| n.bytes().all(|b| b.is_ascii_digit()))
                            .map(|(_, d)| d)
                            .unwrap_or(data);
                        r.data.push(' ');
                        r.data.push_str(data);
                        if !info.continues {
                            r.continues = false;
                            return Ok(r.clone());
                        }
                    } else {
                        tracing::debug!(info = %info.data, "info line");
                    }
                }
                Ok(Message::Alert(a)) => {
                    tracing::info!(chain = %self.name, device = a.device, axis = a.axis, warning = ?a.warning, data = %a.data, "alert");
                }
                Ok(other) => tracing::debug!(?other, "message for another request discarded"),
                Err(e) => {
                    tracing::warn!(chain = %self.name, line = %escape_bytes(&line), error = %e, "bad line discarded")
                }
            }
        }
    }

    /// Stop every device on the chain now (priority path; replies are discarded by whichever exchange reads them).
    pub async fn stop_all(&self) -> Result<(), DriverError> {
        // Addressed to every device: `/stop`, checksummed like any other command.
        let line = format!("/stop:{:02X}\n", checksum(b"stop"));
        self.port
            .send_priority(line.as_bytes(), Instant::now() + REPLY_TIMEOUT)
            .await
            .map_err(|e| self.transport_error(0, 0, "stop", e))
    }
}

/// One Zaber rotary axis.
#[derive(Debug)]
pub struct ZaberAxis {
    chain: Arc<ZaberChain>,
    device: u8,
    axis: u8,
    microstep_deg: f64,
    cfg: gonio_instrument::Axis,
    motion: Mutex<(f64, f64)>,
    last_start: Mutex<Option<f64>>,
}

impl ZaberAxis {
    /// `cfg.microstep_deg` is required (the instrument file validation guarantees it for Zaber axes).
    pub fn new(chain: Arc<ZaberChain>, cfg: gonio_instrument::Axis) -> Result<ZaberAxis, DriverError> {
        let microstep_deg = cfg
            .microstep_deg
            .filter(|m| m.is_finite() && *m > 0.0)
            .ok_or_else(|| DriverError::OutOfRange {
                device: cfg.name.clone(),
                what: "microstep_deg".into(),
                value: cfg.microstep_deg.unwrap_or(f64::NAN),
                min: 0.0,
                max: f64::INFINITY,
            })?;
        let motion = Mutex::new((cfg.max_speed_deg_s, cfg.accel_deg_s2));
        Ok(ZaberAxis {
            device: cfg.address,
            axis: cfg.zaber_axis,
            chain,
            microstep_deg,
            cfg,
            motion,
            last_start: Mutex::new(None),
        })
    }

    fn dev(&self) -> String {
        format!(
            "{} ({}/{}.{})",
            self.cfg.name, self.chain.name, self.device, self.axis
        )
    }

    fn steps_from_deg(&self, physical_deg: f64) -> i64 {
        (self.cfg.controller_from_physical_deg(physical_deg) / self.microstep_deg).round() as i64
    }

    fn deg_from_steps(&self, steps: i64) -> f64 {
        self.cfg
            .physical_from_controller_deg(steps as f64 * self.microstep_deg)
    }

    async fn ok(&self, command: &str, idempotent: bool) -> Result<Reply, DriverError> {
        let r = self
            .chain
            .request(self.device, self.axis, command, idempotent)
            .await?;
        if r.flag == Flag::Rejected {
            if matches!(r.warning.as_deref(), Some("WR") | Some("WH")) {
                return Err(DriverError::NotReferenced {
                    device: self.dev(),
                    state: format!(
                        "{command:?} rejected ({}), {}",
                        r.data,
                        describe_warning(r.warning.as_deref().unwrap_or(""))
                    ),
                });
            }
            return Err(DriverError::Rejected {
                device: self.dev(),
                request: command.into(),
                reason: r.data,
            });
        }
        Ok(r)
    }

    /// `get pos`: (microsteps, busy, warning). The position of an idle axis decides things (arrival, where a
    /// move starts, where the engine plans from), and a digit garbled inside the number parses like a good one:
    /// it is taken from a checksummed reply, or else confirmed by a second read that agrees within the encoder
    /// resolution. (A busy axis's position decides nothing; only its busy flag and warning do, which a single
    /// garbled byte cannot turn into another valid value.) Bounded; a typed Protocol error otherwise.
    async fn get_pos(&self) -> Result<(i64, bool, Option<String>), DriverError> {
        let tolerance_steps = (self.cfg.encoder_resolution_deg / self.microstep_deg)
            .round()
            .clamp(0.0, 1e9) as i64;
        let mut seen = Vec::new();
        let mut unconfirmed: Vec<i64> = Vec::new();
        for _ in 0..ATTEMPTS {
            let r = self.ok("get pos", true).await?;
            let Ok(steps) = r.data.trim().parse::<i64>() else {
                seen.push(r.data);
                continue;
            };
            if r.checksummed || r.busy {
                return Ok((steps, r.busy, r.warning));
            }
            // Confirmed by any earlier read: one garbled read among good ones is outvoted.
            if unconfirmed.iter().any(|p| (p - steps).abs() <= tolerance_steps) {
                return Ok((steps, r.busy, r.warning));
            }
            tracing::debug!(axis = %self.dev(), steps, "position without checksum; reading it again");
            unconfirmed.push(steps);
            seen.push(r.data);
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: "get pos".into(),
            detail: format!("no trustworthy position: {seen:?}"),
        })
    }

    /// All active warning flags (`warnings` answers a count then the flags).
    pub async fn warnings(&self) -> Result<Vec<String>, DriverError> {
        let r = self.ok("warnings", true).await?;
        let mut it = r.data.split(' ').filter(|t| !t.is_empty());
        let count: usize = it
            .next()
            .and_then(|c| c.parse().ok())
            .ok_or_else(|| DriverError::Protocol {
                device: self.dev(),
                request: "warnings".into(),
                detail: format!("{:?}", r.data),
            })?;
        let flags: Vec<String> = it.filter(|f| is_warning(f)).map(str::to_string).collect();
        if flags.len() != count {
            return Err(DriverError::Protocol {
                device: self.dev(),
                request: "warnings".into(),
                detail: format!("{:?}", r.data),
            });
        }
        Ok(flags)
    }

    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let (steps, busy, warning) = self.get_pos().await?;
        let flags = self.warnings().await?;
        let referenced = !flags.iter().any(|f| f == "WR" || f == "WH");
        let faults: Vec<String> = flags
            .iter()
            .filter(|f| f.starts_with('F'))
            .map(|f| describe_warning(f))
            .collect();
        Ok(AxisStatus {
            position_deg: self.deg_from_steps(steps),
            moving: busy,
            referenced,
            fault: if faults.is_empty() {
                None
            } else {
                Some(faults.join(", "))
            },
            raw: format!(
                "pos {steps}, {}, warning {}",
                if busy { "BUSY" } else { "IDLE" },
                warning.as_deref().unwrap_or("--")
            ),
        })
    }

    pub async fn do_home(&self) -> Result<(), DriverError> {
        tracing::info!(axis = %self.dev(), "homing");
        // Sent once: a lost reply is resolved by polling, not by homing again.
        match self.ok("home", false).await {
            Ok(_) | Err(DriverError::Timeout { .. }) => {}
            Err(e) => return Err(e),
        }
        let (v, a) = self.speed_accel();
        let span = self.cfg.max_deg - self.cfg.min_deg;
        let deadline = Instant::now() + move_deadline(span, v, a) + Duration::from_secs(5);
        let mut schedule = PollSchedule::new(Instant::now(), POLL_MIN, POLL_MAX);
        loop {
            let (_, busy, _) = self.get_pos().await?;
            if !busy {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                let _ = self.ok("stop", true).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: "home".into(),
                    timeout: move_deadline(span, v, a),
                });
            }
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
        }
        let flags = self.warnings().await?;
        if let Some(f) = flags.iter().find(|f| f.starts_with('F')) {
            return Err(DriverError::MotionFault {
                device: self.dev(),
                target_deg: f64::NAN,
                reason: format!("homing ended with {}", describe_warning(f)),
            });
        }
        if flags.iter().any(|f| f == "WR" || f == "WH") {
            return Err(DriverError::NotReferenced {
                device: self.dev(),
                state: format!("after homing: {}", flags.join(" ")),
            });
        }
        tracing::info!(axis = %self.dev(), "homed");
        Ok(())
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

    pub async fn do_start_move(&self, target_deg: f64) -> Result<(), DriverError> {
        self.check_limits(target_deg)?;
        let (start, _, _) = self.get_pos().await?;
        if let Ok(mut g) = self.last_start.lock() {
            *g = Some(self.deg_from_steps(start));
        }
        let steps = self.steps_from_deg(target_deg);
        tracing::info!(axis = %self.dev(), target_deg, steps, "move abs");
        let r = self.ok(&format!("move abs {steps}"), true).await?;
        if let Some(w) = r.warning.as_deref().filter(|w| w.starts_with('F')) {
            // A fault flag set before the move: the move may not happen. Report it rather than wait in vain.
            tracing::warn!(axis = %self.dev(), warning = %describe_warning(w), "fault flag active at move start");
        }
        Ok(())
    }

    pub async fn do_wait_arrived(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.wait_arrived_within(target_deg, self.cfg.tolerance_deg).await
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    async fn wait_arrived_within(&self, target_deg: f64, tolerance_deg: f64) -> Result<f64, DriverError> {
        let (v, a) = self.speed_accel();
        let start = self.last_start.lock().ok().and_then(|g| *g);
        let distance = start
            .map(|s| (target_deg - s).abs())
            .unwrap_or(self.cfg.max_deg - self.cfg.min_deg);
        let timeout = move_deadline(distance, v, a);
        let predicted = trapezoid_time_s(distance, v, a);
        let now = Instant::now();
        let deadline = now + timeout;
        // The first question at once (the reply to `get pos` says busy or idle and where, in one exchange).
        let mut schedule = PollSchedule::new(
            now + Duration::from_secs_f64(if predicted.is_finite() {
                predicted.clamp(0.0, 600.0)
            } else {
                0.0
            }),
            POLL_MIN,
            POLL_MAX,
        );
        let (mut steps, mut warning);
        loop {
            let (s, busy, w) = self.get_pos().await?;
            steps = s;
            warning = w;
            if let Some(f) = warning.as_deref().filter(|w| w.starts_with('F')) {
                let flags = self.warnings().await.unwrap_or_else(|_| vec![f.to_string()]);
                let _ = self.ok("warnings clear", true).await;
                return Err(DriverError::MotionFault {
                    device: self.dev(),
                    target_deg,
                    reason: format!(
                        "{}; stopped at {} deg",
                        flags
                            .iter()
                            .map(|f| describe_warning(f))
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.deg_from_steps(steps)
                    ),
                });
            }
            if !busy {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                tracing::warn!(axis = %self.dev(), "deadline passed while moving; stopping the axis");
                let _ = self.ok("stop", true).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: format!("move to {target_deg} deg"),
                    timeout,
                });
            }
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
        }
        let read = self.deg_from_steps(steps);
        if (read - target_deg).abs() <= tolerance_deg.max(self.microstep_deg) {
            tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
            return Ok(read);
        }
        let flags = self.warnings().await.unwrap_or_default();
        let why = if flags.is_empty() {
            warning
                .map(|w| describe_warning(&w))
                .unwrap_or_else(|| "no warning flag".into())
        } else {
            flags
                .iter()
                .map(|f| describe_warning(f))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = self.ok("warnings clear", true).await;
        Err(DriverError::MotionFault {
            device: self.dev(),
            target_deg,
            reason: format!(
                "idle at {read} deg, {} deg from the target: {why}",
                read - target_deg
            ),
        })
    }

    pub async fn do_move_to(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.check_limits(target_deg)?;
        let (steps, _, _) = self.get_pos().await?;
        let current_c = steps as f64 * self.microstep_deg;
        let mut read = f64::NAN;
        for (step_deg, tolerance) in approach_waypoints(&self.cfg, current_c, target_deg) {
            self.do_start_move(step_deg).await?;
            read = self.wait_arrived_within(step_deg, tolerance).await?;
        }
        Ok(read)
    }

    pub async fn do_set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
        check_speed(self.dev(), speed_deg_s, accel_deg_s2)?;
        let speed = (speed_deg_s / self.microstep_deg * SPEED_UNIT).round().max(1.0) as i64;
        let accel = (accel_deg_s2 / self.microstep_deg * ACCEL_UNIT).round().max(1.0) as i64;
        self.ok(&format!("set maxspeed {speed}"), true).await?;
        self.ok(&format!("set accel {accel}"), true).await?;
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

    /// Stop this axis now on the priority path.
    pub async fn stop_now(&self) -> Result<(), DriverError> {
        let line = encode_command(self.device, self.axis, None, "stop");
        self.chain
            .port
            .send_priority(line.as_bytes(), Instant::now() + REPLY_TIMEOUT)
            .await
            .map_err(|e| self.chain.transport_error(self.device, self.axis, "stop", e))
    }
}

impl Axis for ZaberAxis {
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
        Box::pin(async move { self.get_pos().await.map(|(s, _, _)| self.deg_from_steps(s)) })
    }
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.read_status())
    }
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.stop_now())
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
