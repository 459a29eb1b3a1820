//! The port of one Zaber chain: requests matched by device, axis and message id, reply checksums, stop.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};

use tokio::time::Instant;

use super::protocol::{Flag, Message, Reply, checksum, encode_command, parse_message};
use super::{ATTEMPTS, REPLY_TIMEOUT};
use crate::error::DriverError;
use crate::transport::{LinePort, TransportError, escape_bytes};

/// What came back for one request.
#[derive(Debug)]
enum ReplyOrRefusal {
    Reply(Reply),
    /// Refused for a bad checksum: the command did not run.
    BadChecksum,
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
    pub(super) name: String,
    pub(super) port: Arc<LinePort>,
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

    pub(super) fn transport_error(
        &self,
        device: u8,
        axis: u8,
        request: &str,
        e: TransportError,
    ) -> DriverError {
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
        let mut attempt = 0;
        let mut refused_checksums = 0;
        while attempt < attempts {
            attempt += 1;
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
                Ok(ReplyOrRefusal::Reply(reply)) => return Ok(reply),
                Ok(ReplyOrRefusal::BadChecksum) => {
                    // Not run: safe to send again, even a command otherwise sent once (bounded).
                    refused_checksums += 1;
                    tracing::warn!(device = %self.dev(device, axis), command, "rejected for a bad checksum (the line was corrupted on its way); sending it again");
                    last = TransportError::Garbled(format!("{command:?} rejected for a bad checksum"));
                    if refused_checksums < ATTEMPTS {
                        attempt = attempt.min(attempts - 1);
                    }
                }
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
    ) -> Result<ReplyOrRefusal, TransportError> {
        let mut reply: Option<Reply> = None;
        let mut refused = false;
        loop {
            let line = match s.read_line(deadline).await {
                Ok(line) => line,
                // Every device on the chain refused the message for its checksum (ours may have said nothing
                // more, or its refusal came first): the command did not run.
                Err(TransportError::Timeout) if refused => return Ok(ReplyOrRefusal::BadChecksum),
                Err(e) => return Err(e),
            };
            match parse_message(&line) {
                // A rejection with this request's id from a device or axis it was not addressed to: the chain's
                // answer to a bad checksum (see the module notes). From the addressed device itself it ends the
                // wait at once.
                Ok(Message::Reply(r))
                    if r.id == Some(id)
                        && r.flag == Flag::Rejected
                        && r.data == "BADDATA"
                        && (r.device != device || r.axis != axis) =>
                {
                    if r.device == device {
                        return Ok(ReplyOrRefusal::BadChecksum);
                    }
                    refused = true;
                }
                Ok(Message::Reply(r)) if r.device == device && r.axis == axis && r.id == Some(id) => {
                    if !r.continues {
                        return Ok(ReplyOrRefusal::Reply(r));
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
                            return Ok(ReplyOrRefusal::Reply(r.clone()));
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
