//! The port of one daisy chain: paced exchanges (queries one at a time, a pause after each set command), set
//! commands checked with `TE`, and the stop on the priority path.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use super::first_ts::FirstTs;
use super::protocol::{Ts, describe_te, parse_number, parse_reply, parse_te, parse_ts};
use super::{ATTEMPTS, MAX_SET_GAP, REPLY_TIMEOUT, SET_GAP};
use crate::error::DriverError;
use crate::transport::{LinePort, TransportError, escape_bytes};

/// An exchange that failed, and whether its failure was a controller not answering its first TS (see
/// [`FirstTs`]): expected, so not a warning.
#[derive(Debug)]
struct Failed {
    error: TransportError,
    first_ts: bool,
}

impl From<TransportError> for Failed {
    fn from(error: TransportError) -> Failed {
        Failed {
            error,
            first_ts: false,
        }
    }
}

/// When the next command to each controller may go out, and the pause a set command needs.
#[derive(Debug)]
struct Pacing {
    next_send: std::collections::BTreeMap<u8, Instant>,
    /// When the last set command to each controller was written.
    last_set: std::collections::BTreeMap<u8, Instant>,
    gap: Duration,
    /// The pause configured: widening starts from it and stops at the same multiple of it as [`MAX_SET_GAP`] is
    /// of [`SET_GAP`] (so a chain pausing in a faster clock widens in that clock too).
    base: Duration,
}

/// One SMC100 daisy chain: the port owner.
#[derive(Debug)]
pub struct Smc100Chain {
    pub(super) name: String,
    pub(super) port: Arc<LinePort>,
    pacing: Mutex<Pacing>,
    first_ts: FirstTs,
}

impl Smc100Chain {
    pub fn new(name: impl Into<String>, port: Arc<LinePort>) -> Arc<Smc100Chain> {
        Smc100Chain::with_set_gap(name, port, SET_GAP)
    }

    /// A chain pausing `gap` after each set command (widened on its own, up to `gap` x [`MAX_SET_GAP`] /
    /// [`SET_GAP`], when that is not enough). For a simulated controller running `k` times faster than real time,
    /// `SET_GAP / k` is the same pause in the controller's time, and so is its widening.
    pub fn with_set_gap(name: impl Into<String>, port: Arc<LinePort>, gap: Duration) -> Arc<Smc100Chain> {
        let gap = gap.min(MAX_SET_GAP);
        Arc::new(Smc100Chain {
            name: name.into(),
            port,
            pacing: Mutex::new(Pacing {
                next_send: Default::default(),
                last_set: Default::default(),
                gap,
                base: gap,
            }),
            first_ts: FirstTs::default(),
        })
    }

    pub fn port(&self) -> &Arc<LinePort> {
        &self.port
    }

    /// The pause after a set command in use now.
    pub fn set_gap(&self) -> Duration {
        self.pacing.lock().map(|p| p.gap).unwrap_or(SET_GAP)
    }

    /// When controller `addr` can take a command again by our pacing (`None`: no set command went to it yet).
    fn ready_at(&self, addr: u8) -> Option<Instant> {
        self.pacing
            .lock()
            .ok()
            .and_then(|p| p.next_send.get(&addr).copied())
    }

    /// A set command to `addr` has just been written: the controller is busy from now, whatever delayed the
    /// write (waiting for the port, the scheduler), so the next command waits the whole gap from now.
    fn sent_set(&self, addr: u8) {
        if let Ok(mut p) = self.pacing.lock() {
            let now = Instant::now();
            p.last_set.insert(addr, now);
            let after = now + p.gap;
            let next = p.next_send.entry(addr).or_insert(after);
            *next = (*next).max(after);
        }
    }

    /// When the last set command to controller `addr` was written (`None`: none yet). A move starts when its
    /// `PA` arrives, not when the exchange carrying it began: the queries before it in the same exchange take
    /// their own time on the line.
    pub(super) fn last_set_sent(&self, addr: u8) -> Option<Instant> {
        self.pacing
            .lock()
            .ok()
            .and_then(|p| p.last_set.get(&addr).copied())
    }

    /// The line after a set command went unanswered: perhaps the controller was still busy. Pause longer.
    fn widen_gap(&self) {
        if let Ok(mut p) = self.pacing.lock() {
            let widest = p
                .base
                .mul_f64(MAX_SET_GAP.as_secs_f64() / SET_GAP.as_secs_f64())
                .min(MAX_SET_GAP);
            let wider = (p.gap * 2).clamp(p.base, widest.max(p.base));
            if wider > p.gap {
                tracing::warn!(chain = %self.name, from_ms = p.gap.as_millis() as u64, to_ms = wider.as_millis() as u64, "no reply after a set command: pausing longer after set commands");
                p.gap = wider;
            }
        }
    }

    fn dev(&self, addr: u8) -> String {
        format!("{}/{}", self.name, addr)
    }

    /// The port was opened again: every controller's next TS may go unanswered (see [`FirstTs`]).
    pub(super) fn port_reopened(&self) {
        self.first_ts.port_opened();
    }

    /// Whether the latest exchange with `addr` went without a TS reply that real controllers are recorded to
    /// leave unanswered (see [`FirstTs`]): a caller that sees the value missing then asks again quietly.
    pub(super) fn lost_first_ts(&self, addr: u8) -> bool {
        self.first_ts.lost_in_last_exchange(addr)
    }

    /// Log at info, once, how many first TSs controller `addr` left unanswered since the last report: the count
    /// an operator may want, without a warning for what real controllers are recorded to do.
    pub(super) fn report_first_ts(&self, addr: u8) {
        let n = self.first_ts.take_count(addr);
        if n > 0 {
            tracing::info!(device = %self.dev(addr), unanswered = n, "first TS after power-up or homing went unanswered, as recorded for real SMC100s; retried");
        }
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

    /// One exchange: `lines` (each `<addr><cc><arg>`; terminators added here) go out one at a time, never as a
    /// burst (see the module notes): a line whose code is the next one in `expect` is a query, sent once the
    /// previous reply is in and answered before the next line; any other line is a set command, followed by the
    /// pause the controller needs. Returns each expected reply's value in order, `None` for one that did not come
    /// while a later one did; the exchange fails when its last reply does not come.
    async fn exchange(
        &self,
        lines: &[String],
        addr: u8,
        expect: &[&str],
    ) -> Result<Vec<Option<String>>, Failed> {
        self.first_ts.exchange_begins(addr);
        let mut s = self.port.session().await;
        s.discard_stale().await?;
        let mut values: Vec<Option<String>> = vec![None; expect.len()];
        let mut next = 0;
        let mut after_set = false;
        for line in lines {
            let code = line
                .trim_start_matches(|c: char| c.is_ascii_digit())
                .get(..2)
                .unwrap_or_default();
            let query = expect.get(next).is_some_and(|e| *e == code);
            // While the controller is still in its pause after a set command, free the port, so that the other
            // controllers on the chain are not held up, and take it again for the rest of the exchange. Looked at
            // again once the port is ours: a stop on the priority path may have started a new pause meanwhile.
            // (Each controller on the chain has its own processor: only its own set commands make it wait.)
            while let Some(at) = self.ready_at(addr).filter(|at| *at > Instant::now()) {
                drop(s);
                tokio::time::sleep_until(at).await;
                s = self.port.session().await;
                s.discard_stale().await?;
            }
            let deadline = Instant::now() + REPLY_TIMEOUT;
            s.send(format!("{line}\r\n").as_bytes(), deadline).await?;
            if !query {
                self.sent_set(addr);
                if matches!(code, "OR" | "RS") {
                    self.first_ts.reset(addr);
                }
                after_set = true;
                continue;
            }
            match read_reply(&mut s, addr, code, deadline).await {
                Ok(v) => {
                    if code == "TS"
                        && let Some(ts) = parse_ts(&v)
                    {
                        self.first_ts.answered(addr, ts.state);
                    }
                    if let Some(cell) = values.get_mut(next) {
                        *cell = Some(v);
                    }
                }
                Err(TransportError::Timeout) => {
                    if after_set {
                        self.widen_gap();
                    }
                    let first_ts = code == "TS" && self.first_ts.unanswered(addr);
                    if next + 1 >= expect.len() {
                        return Err(Failed {
                            error: TransportError::Timeout,
                            first_ts,
                        });
                    }
                    tracing::debug!(chain = %self.name, %line, first_ts, "no reply; going on with the exchange");
                }
                Err(e) => return Err(e.into()),
            }
            after_set = false;
            next += 1;
        }
        Ok(values)
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
                Err(Failed {
                    error: TransportError::Disconnected(d),
                    ..
                }) => {
                    return Err(self.transport_error(addr, &request, TransportError::Disconnected(d)));
                }
                // Real controllers are recorded to leave this TS unanswered: counted, reported at info by the
                // axis once homed (`report_first_ts`), and asked again.
                Err(Failed {
                    error,
                    first_ts: true,
                }) => {
                    tracing::debug!(device = %self.dev(addr), %request, attempt, error = %error, "first TS unanswered, as recorded for real SMC100s; asking again");
                    last = Some(error);
                }
                Err(Failed { error, .. }) => {
                    tracing::warn!(device = %self.dev(addr), %request, attempt, error = %error, "query failed; retrying");
                    last = Some(error);
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
            match self.exchange(&lines, addr, &expect).await.map_err(|f| f.error) {
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

    /// Stop the given controllers now, on the priority path (does not wait for exchanges in flight): every `ST`
    /// at once, then each once more. A controller still in its pause after a set command may lose the first
    /// `ST`: it gets the second the moment that pause is over, so a stop waits at most one pause ([`SET_GAP`])
    /// for it; the others get theirs one pause after the first, in case a controller needed longer than our
    /// pause (a second `ST` is harmless: it stops nothing more).
    pub async fn stop_all(&self, addrs: &[u8]) -> Result<(), DriverError> {
        let mut line = Vec::new();
        for a in addrs {
            line.extend_from_slice(format!("{a}ST\r\n").as_bytes());
        }
        let first = addrs.first().copied().unwrap_or(0);
        let now = Instant::now();
        let ready: Vec<Option<Instant>> = addrs.iter().map(|a| self.ready_at(*a)).collect();
        self.port
            .send_priority(&line, Instant::now() + REPLY_TIMEOUT)
            .await
            .map_err(|e| self.transport_error(first, "ST", e))?;
        let sent = Instant::now();
        for a in addrs {
            self.sent_set(*a);
        }
        tracing::info!(chain = %self.name, ?addrs, "stop sent");
        let gap = self.set_gap();
        let mut again: Vec<(Instant, u8)> = addrs
            .iter()
            .zip(ready)
            .map(|(a, ready)| match ready {
                Some(r) if r > now => (r, *a),
                _ => (sent + gap, *a),
            })
            .collect();
        again.sort_unstable();
        for (at, a) in again {
            tokio::time::sleep_until(at).await;
            self.port
                .send_priority(format!("{a}ST\r\n").as_bytes(), Instant::now() + REPLY_TIMEOUT)
                .await
                .map_err(|e| self.transport_error(a, "ST", e))?;
            self.sent_set(a);
        }
        Ok(())
    }
}

/// Read the reply of `addr` to the query `code`: lines from other controllers or for other commands (late
/// replies to earlier questions) are stale and dropped with a trace.
async fn read_reply(
    s: &mut crate::transport::line::Session<'_>,
    addr: u8,
    code: &str,
    deadline: Instant,
) -> Result<String, TransportError> {
    loop {
        let line = s.read_line(deadline).await?;
        match parse_reply(&line) {
            Some((a, c, v)) if a == addr && c == code.as_bytes() => return Ok(v.to_string()),
            _ => {
                tracing::debug!(line = %escape_bytes(&line), expected = %format!("{addr}{code}"), "unexpected line discarded")
            }
        }
    }
}
