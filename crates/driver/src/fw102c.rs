//! Thorlabs FW102C / FW212C filter wheel, written from the FW102C manual (chapter "Software Control").
//!
//! Commands end in `\r`. The wheel echoes each command, prints the answer to a query, and then a `> ` prompt;
//! lines end in `\r`. A position command returns its prompt when the wheel has turned, so the host waits for the
//! prompt with a deadline that follows from the distance. A bad keyword or argument answers an error string
//! (the manual does not fix its text; known firmware says `Command error ...`), reported verbatim.
//!
//! Protocol notes, and where each comes from:
//! - Timing: users of real wheels report about 1 s per position at speed 1 and about 2 s at speed 0. The
//!   instrument file gives the time per position at its `speed`, and the driver sets that speed before the
//!   first turn (a wheel may have been saved in the other mode), so the turn deadline (twice the predicted
//!   time plus 2 s) follows from the speed in use.
//! - Before the first turn the driver also sets `sensors=0`: with the sensors on, the wheel's position sensors
//!   stay lit while it is idle and add stray light (real-hardware drivers do the same).
//! - Right after the port opens, NUL bytes and a `Command error CMD_NOT_DEFINED` can arrive (users of real
//!   wheels report it): NUL bytes are dropped, and an error with no echo before it is the port's noise, not
//!   an answer: the driver reads on to its own echo.
//!
//! Both settings are applied again after every reconnect (a power cycle restores the saved modes).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::time::Instant;

use crate::error::DriverError;
use crate::traits::FilterWheel;
use crate::transport::{BoxFuture, LinePort, TransportError};

const REPLY_TIMEOUT: Duration = Duration::from_millis(500);
const ATTEMPTS: usize = 3;
const PROMPT: &[u8] = b"> ";

/// What came back for one command: the echo was checked and removed; the remaining lines.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    Lines(Vec<String>),
    /// The wheel answered an error string.
    Error(String),
}

/// Split what preceded the prompt into the echo and the answer lines. `None` when the echo is not the command
/// (a garbled or stale exchange). Never panics.
pub fn parse_answer(command: &str, before_prompt: &[u8]) -> Option<Answer> {
    let text = std::str::from_utf8(before_prompt).ok()?;
    if !text
        .chars()
        .all(|c| c.is_ascii_graphic() || c == ' ' || c == '\r' || c == '\n')
    {
        return None;
    }
    let mut lines = text.split(['\r', '\n']).map(str::trim).filter(|l| !l.is_empty());
    let echo = lines.next()?;
    if echo != command {
        return None;
    }
    let rest: Vec<String> = lines.map(str::to_string).collect();
    if let Some(err) = rest
        .iter()
        .find(|l| l.to_ascii_lowercase().contains("error") || l.starts_with("CMD_"))
    {
        return Some(Answer::Error(err.clone()));
    }
    Some(Answer::Lines(rest))
}

/// What a freshly opened port may say before any command: an error line with no echo before it (NUL bytes
/// already dropped).
pub fn is_open_noise(before_prompt: &[u8]) -> bool {
    let text = String::from_utf8_lossy(before_prompt);
    let text = text.trim();
    text.is_empty() || (text.starts_with("Command error") && !text.contains(['\r', '\n']))
}

/// Parse a single integer answer line.
pub fn parse_int(lines: &[String]) -> Option<u32> {
    match lines {
        [one] if !one.is_empty() && one.len() <= 3 && one.bytes().all(|b| b.is_ascii_digit()) => {
            one.parse().ok()
        }
        _ => None,
    }
}

/// One filter wheel on its own port.
#[derive(Debug)]
pub struct Fw102c {
    name: String,
    port: Arc<LinePort>,
    seconds_per_position: f64,
    speed: u8,
    /// `speed` and `sensors=0` were set since the port (re)opened.
    prepared: AtomicBool,
}

impl Fw102c {
    /// `seconds_per_position`: time to turn by one position (from the instrument file) at speed 1, the speed set
    /// unless [`Fw102c::with_speed`] says otherwise; for deadlines.
    pub fn new(name: impl Into<String>, port: Arc<LinePort>, seconds_per_position: f64) -> Fw102c {
        let s = if seconds_per_position.is_finite() && seconds_per_position > 0.0 {
            seconds_per_position
        } else {
            1.0
        };
        Fw102c {
            name: name.into(),
            port,
            seconds_per_position: s,
            speed: 1,
            prepared: AtomicBool::new(false),
        }
    }

    /// The speed mode to set (0 slow, 1 fast; anything else is taken as 1); `seconds_per_position` is the time
    /// per position at this speed.
    pub fn with_speed(mut self, speed: u8) -> Fw102c {
        self.speed = if speed == 0 { 0 } else { 1 };
        self
    }

    /// Set the speed and turn the position sensors off, once per opening of the port.
    async fn prepare(&self) -> Result<(), DriverError> {
        if self.prepared.load(Ordering::SeqCst) {
            return Ok(());
        }
        self.exchange(&format!("speed={}", self.speed), REPLY_TIMEOUT, true)
            .await?;
        self.exchange("sensors=0", REPLY_TIMEOUT, true).await?;
        self.prepared.store(true, Ordering::SeqCst);
        tracing::info!(wheel = %self.name, speed = self.speed, "speed set, position sensors off");
        Ok(())
    }

    fn error(&self, request: &str, e: TransportError, timeout: Duration) -> DriverError {
        match e {
            TransportError::Timeout => DriverError::Timeout {
                device: self.name.clone(),
                request: request.into(),
                timeout,
            },
            TransportError::Disconnected(detail) => DriverError::Disconnected {
                device: self.name.clone(),
                detail,
            },
            TransportError::Garbled(detail) => DriverError::Protocol {
                device: self.name.clone(),
                request: request.into(),
                detail,
            },
        }
    }

    /// Send a command and collect its answer lines (echo checked). Retried (bounded) only when `idempotent`.
    pub async fn exchange(
        &self,
        command: &str,
        timeout: Duration,
        idempotent: bool,
    ) -> Result<Vec<String>, DriverError> {
        let attempts = if idempotent { ATTEMPTS } else { 1 };
        let mut last = TransportError::Timeout;
        for attempt in 1..=attempts {
            let mut s = self.port.session().await;
            let r = async {
                s.discard_stale().await?;
                let deadline = Instant::now() + timeout;
                s.send(format!("{command}\r").as_bytes(), deadline).await?;
                loop {
                    let mut raw = s.read_until(PROMPT, deadline).await?;
                    // NUL bytes come with the noise of a freshly opened port; they are never part of an answer.
                    raw.retain(|b| *b != 0);
                    if let Some(answer) = parse_answer(command, &raw) {
                        return Ok(answer);
                    }
                    if is_open_noise(&raw) {
                        tracing::debug!(wheel = %self.name, noise = %crate::transport::escape_bytes(&raw), "noise of a freshly opened port skipped");
                        continue;
                    }
                    return Err(TransportError::Garbled(format!(
                        "echo does not match {command:?}: {}",
                        crate::transport::escape_bytes(&raw)
                    )));
                }
            }
            .await;
            match r {
                Ok(Answer::Lines(lines)) => return Ok(lines),
                Ok(Answer::Error(text)) => {
                    return Err(DriverError::Rejected {
                        device: self.name.clone(),
                        request: command.into(),
                        reason: text,
                    });
                }
                Err(TransportError::Disconnected(d)) => {
                    return Err(self.error(command, TransportError::Disconnected(d), timeout));
                }
                Err(e) => {
                    if idempotent {
                        tracing::warn!(wheel = %self.name, command, attempt, error = %e, "exchange failed; retrying");
                    }
                    last = e;
                }
            }
        }
        Err(self.error(command, last, timeout))
    }

    /// A numeric query; a garbled answer is asked again (queries are idempotent), boundedly.
    async fn query_int(&self, command: &str) -> Result<u32, DriverError> {
        let mut last = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let lines = self.exchange(command, REPLY_TIMEOUT, true).await?;
            if let Some(n) = parse_int(&lines) {
                return Ok(n);
            }
            tracing::warn!(wheel = %self.name, command, attempt, ?lines, "not a number; asking again");
            last = lines;
        }
        Err(DriverError::Protocol {
            device: self.name.clone(),
            request: command.into(),
            detail: format!("not a number: {last:?}"),
        })
    }

    pub async fn do_position_count(&self) -> Result<u8, DriverError> {
        let n = self.query_int("pcount?").await?;
        match n {
            6 | 12 => Ok(n as u8),
            other => Err(DriverError::Protocol {
                device: self.name.clone(),
                request: "pcount?".into(),
                detail: format!("{other} positions"),
            }),
        }
    }

    pub async fn do_position(&self) -> Result<u8, DriverError> {
        let p = self.query_int("pos?").await?;
        u8::try_from(p)
            .ok()
            .filter(|p| (1..=12).contains(p))
            .ok_or_else(|| DriverError::Protocol {
                device: self.name.clone(),
                request: "pos?".into(),
                detail: format!("position {p}"),
            })
    }

    /// The position after a turn decides whether the right filter is in the beam. Its answer is one bare digit
    /// without a checksum, so a garbled digit would confirm a turn that did not happen: two reads must agree.
    /// Bounded; a typed Protocol error when they never do.
    async fn verified_position(&self) -> Result<u8, DriverError> {
        let mut seen: Vec<u8> = Vec::new();
        for _ in 0..=ATTEMPTS {
            let p = self.do_position().await?;
            // Confirmed by any earlier read: one garbled answer among good ones is outvoted.
            if seen.contains(&p) {
                return Ok(p);
            }
            if !seen.is_empty() {
                tracing::warn!(wheel = %self.name, ?seen, now = p, "position reads disagree; reading again");
            }
            seen.push(p);
        }
        Err(DriverError::Protocol {
            device: self.name.clone(),
            request: "pos?".into(),
            detail: format!("consecutive reads never agreed: {seen:?}"),
        })
    }

    pub async fn do_go_to(&self, position: u8) -> Result<(), DriverError> {
        self.prepare().await?;
        let count = self.do_position_count().await?;
        if !(1..=count).contains(&position) {
            return Err(DriverError::OutOfRange {
                device: self.name.clone(),
                what: "position".into(),
                value: f64::from(position),
                min: 1.0,
                max: f64::from(count),
            });
        }
        let current = self.do_position().await?;
        // The wheel may turn either way; at worst half a turn. Margin: twice that plus two seconds, at the speed
        // set by `prepare` (the time per position is the configured speed's).
        // (Saturating: a garbled `pos?` can report a position beyond a 6-position wheel's count.)
        let apart = current.abs_diff(position);
        let steps = f64::from(apart.min(count.saturating_sub(apart)));
        let timeout = Duration::from_secs_f64(2.0 * self.seconds_per_position * steps.max(1.0) + 2.0);
        tracing::info!(wheel = %self.name, from = current, to = position, "turning");
        // `pos=N` is idempotent: retried on a lost prompt.
        self.exchange(&format!("pos={position}"), timeout, true).await?;
        let now = self.verified_position().await?;
        if now != position {
            return Err(DriverError::MotionFault {
                device: self.name.clone(),
                target_deg: f64::NAN,
                reason: format!("wheel reports position {now} after pos={position}"),
            });
        }
        Ok(())
    }

    pub async fn identify(&self) -> Result<String, DriverError> {
        let lines = self.exchange("*idn?", REPLY_TIMEOUT, true).await?;
        Ok(lines.join(" "))
    }
}

impl FilterWheel for Fw102c {
    fn name(&self) -> &str {
        &self.name
    }
    fn position_count(&self) -> BoxFuture<'_, Result<u8, DriverError>> {
        Box::pin(self.do_position_count())
    }
    fn go_to(&self, position: u8) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_go_to(position))
    }
    fn position(&self) -> BoxFuture<'_, Result<u8, DriverError>> {
        Box::pin(self.do_position())
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move {
            self.port
                .reconnect()
                .await
                .map_err(|e| DriverError::Unavailable {
                    device: self.name.clone(),
                    detail: e.to_string(),
                })?;
            // A power cycle restores the saved speed and sensor modes: set them again.
            self.prepared.store(false, Ordering::SeqCst);
            self.prepare().await?;
            self.do_position().await.map(|_| ())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn echo_answer_and_errors() {
        assert_eq!(
            parse_answer("pos?", b"pos?\r3\r"),
            Some(Answer::Lines(vec!["3".into()]))
        );
        assert_eq!(parse_answer("pos=2", b"pos=2\r"), Some(Answer::Lines(vec![])));
        assert_eq!(parse_answer("pos?", b"pos=\r3\r"), None);
        assert_eq!(
            parse_answer("bogus", b"bogus\rCommand error CMD_NOT_DEFINED\r"),
            Some(Answer::Error("Command error CMD_NOT_DEFINED".into()))
        );
        assert_eq!(parse_answer("pos?", b"pos?\r\xff\r"), None);
        assert_eq!(parse_int(&["12".into()]), Some(12));
        assert_eq!(parse_int(&["1".into(), "2".into()]), None);
        assert_eq!(parse_int(&["-1".into()]), None);
    }

    #[test]
    fn noise_of_a_fresh_port_is_told_from_answers() {
        assert!(is_open_noise(b"Command error CMD_NOT_DEFINED\r"));
        assert!(is_open_noise(b""));
        assert!(!is_open_noise(b"pos?\rCommand error CMD_NOT_DEFINED\r"));
        assert!(!is_open_noise(b"pos?\r3\r"));
    }
}
