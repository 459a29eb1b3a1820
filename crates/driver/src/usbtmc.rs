//! USBTMC 1.0 (USB Test and Measurement Class) message framing and session, written from the class
//! specification: Bulk-OUT/IN headers, bTag sequencing, EOM, padding, multi-transfer replies, stale-reply discard,
//! abort of a bulk transfer and INITIATE_CLEAR recovery, and halted endpoints.
//!
//! Header (12 bytes): MsgID, bTag (1..=255), !bTag, 0, TransferSize (u32 LE), then 4 message-specific bytes:
//! DEV_DEP_MSG_OUT (1): bmTransferAttributes bit0 = EOM; REQUEST_DEV_DEP_MSG_IN (2): bit1 = TermChar enabled,
//! then TermChar; DEV_DEP_MSG_IN (2, from the device): bit0 = EOM. Every transfer is zero-padded to a multiple
//! of 4 bytes.

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use crate::transport::escape_bytes;
use crate::transport::usb::{UsbError, UsbPipe};

pub const DEV_DEP_MSG_OUT: u8 = 1;
pub const REQUEST_DEV_DEP_MSG_IN: u8 = 2;
pub const DEV_DEP_MSG_IN: u8 = 2;
pub const HEADER_LEN: usize = 12;

/// Class-specific control requests (USBTMC 1.0 table 15).
pub mod request {
    pub const INITIATE_ABORT_BULK_OUT: u8 = 1;
    pub const CHECK_ABORT_BULK_OUT_STATUS: u8 = 2;
    pub const INITIATE_ABORT_BULK_IN: u8 = 3;
    pub const CHECK_ABORT_BULK_IN_STATUS: u8 = 4;
    pub const INITIATE_CLEAR: u8 = 5;
    pub const CHECK_CLEAR_STATUS: u8 = 6;
    pub const GET_CAPABILITIES: u8 = 7;
}

/// USBTMC_status values (USBTMC 1.0 table 16).
pub mod status {
    pub const SUCCESS: u8 = 0x01;
    pub const PENDING: u8 = 0x02;
    pub const FAILED: u8 = 0x80;
    pub const TRANSFER_NOT_IN_PROGRESS: u8 = 0x81;
}

/// bmRequestType for class requests to the interface / to an endpoint (device-to-host).
pub const REQUEST_TYPE_INTERFACE: u8 = 0xA1;
pub const REQUEST_TYPE_ENDPOINT: u8 = 0xA2;

fn pad4(v: &mut Vec<u8>) {
    while v.len() % 4 != 0 {
        v.push(0);
    }
}

/// A DEV_DEP_MSG_OUT transfer carrying `payload`.
pub fn encode_dev_dep_msg_out(btag: u8, payload: &[u8], eom: bool) -> Vec<u8> {
    let size = u32::try_from(payload.len()).unwrap_or(u32::MAX);
    let mut v = Vec::with_capacity(HEADER_LEN + payload.len() + 3);
    v.extend_from_slice(&[DEV_DEP_MSG_OUT, btag, !btag, 0]);
    v.extend_from_slice(&size.to_le_bytes());
    v.extend_from_slice(&[u8::from(eom), 0, 0, 0]);
    v.extend_from_slice(payload);
    pad4(&mut v);
    v
}

/// A REQUEST_DEV_DEP_MSG_IN transfer asking for up to `max_len` bytes, optionally ending at `term_char`.
pub fn encode_request_dev_dep_msg_in(btag: u8, max_len: u32, term_char: Option<u8>) -> Vec<u8> {
    let mut v = Vec::with_capacity(HEADER_LEN);
    v.extend_from_slice(&[REQUEST_DEV_DEP_MSG_IN, btag, !btag, 0]);
    v.extend_from_slice(&max_len.to_le_bytes());
    match term_char {
        Some(t) => v.extend_from_slice(&[0x02, t, 0, 0]),
        None => v.extend_from_slice(&[0, 0, 0, 0]),
    }
    v
}

/// The header of a DEV_DEP_MSG_IN transfer from the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InHeader {
    pub btag: u8,
    /// Bytes of message data that follow the header in this transfer (and possibly the next ones).
    pub transfer_size: u32,
    pub eom: bool,
}

/// Why a Bulk-IN transfer is not a valid DEV_DEP_MSG_IN.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("transfer of {0} bytes is shorter than the 12-byte header")]
    Short(usize),
    #[error("MsgID {0} is not DEV_DEP_MSG_IN")]
    MsgId(u8),
    #[error("bTag {btag} and its inverse {inverse} do not match")]
    TagInverse { btag: u8, inverse: u8 },
    #[error("bTag 0 is not allowed")]
    ZeroTag,
    #[error("reserved header byte is {0:#04x}, not 0")]
    Reserved(u8),
}

/// Parse the 12-byte header of a Bulk-IN transfer. Never panics.
pub fn decode_in_header(transfer: &[u8]) -> Result<InHeader, FrameError> {
    let h: &[u8; HEADER_LEN] = transfer
        .get(..HEADER_LEN)
        .and_then(|s| s.try_into().ok())
        .ok_or(FrameError::Short(transfer.len()))?;
    if h[0] != DEV_DEP_MSG_IN {
        return Err(FrameError::MsgId(h[0]));
    }
    if h[1] == 0 {
        return Err(FrameError::ZeroTag);
    }
    if h[2] != !h[1] {
        return Err(FrameError::TagInverse {
            btag: h[1],
            inverse: h[2],
        });
    }
    if h[3] != 0 {
        return Err(FrameError::Reserved(h[3]));
    }
    let transfer_size = u32::from_le_bytes([h[4], h[5], h[6], h[7]]);
    Ok(InHeader {
        btag: h[1],
        transfer_size,
        eom: h[8] & 0x01 != 0,
    })
}

/// The next bTag after `tag`: 1..=255, wrapping 255 -> 1, never 0.
pub fn next_btag(tag: u8) -> u8 {
    if tag == 255 { 1 } else { tag + 1 }
}

/// USBTMC failures.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsbtmcError {
    #[error("{0}")]
    Usb(#[from] UsbError),
    #[error("no complete reply within the deadline")]
    Timeout,
    #[error("bad Bulk-IN transfer: {0}")]
    Frame(#[from] FrameError),
    #[error("reply longer than {0} bytes")]
    TooLong(usize),
    #[error("the device refused {what}: status {status:#04x}")]
    Refused { what: &'static str, status: u8 },
}

/// One USBTMC session on a pipe. Not shareable: wrap it in a mutex (one request at a time on a device).
#[derive(Debug)]
pub struct Usbtmc {
    pipe: Arc<dyn UsbPipe>,
    /// Last bTag used (0 = none yet).
    btag: u8,
    /// Largest reply accepted per REQUEST_DEV_DEP_MSG_IN.
    pub max_chunk: u32,
    /// Largest whole reply accepted.
    pub max_reply: usize,
    name: String,
}

/// Bounded polling for the CHECK_*_STATUS requests.
const STATUS_POLLS: usize = 50;
const STATUS_POLL_INTERVAL: Duration = Duration::from_millis(20);
const CONTROL_TIMEOUT: Duration = Duration::from_millis(500);

impl Usbtmc {
    pub fn new(name: impl Into<String>, pipe: Arc<dyn UsbPipe>) -> Usbtmc {
        Usbtmc {
            pipe,
            btag: 0,
            max_chunk: 1024,
            max_reply: 64 * 1024,
            name: name.into(),
        }
    }

    pub fn pipe(&self) -> &Arc<dyn UsbPipe> {
        &self.pipe
    }

    /// The bTag the last transfer used.
    pub fn last_btag(&self) -> u8 {
        self.btag
    }

    /// The size of every Bulk-IN read: room for a header, `max_chunk` bytes and padding, rounded up to a
    /// multiple of 512 bytes, the bulk packet size at high speed (a multiple of full speed's 64 too). libusb
    /// and the kernel report an overflow when a packet does not fit what is left of the buffer, so a read that
    /// is not a whole number of packets can fail on a device that sends one packet more than asked; a whole
    /// number never does, and the transfer still ends at its short (or zero-length) packet.
    fn in_buffer_len(&self) -> usize {
        (HEADER_LEN + self.max_chunk as usize + 3).div_ceil(512) * 512
    }

    fn take_btag(&mut self) -> u8 {
        self.btag = next_btag(self.btag);
        self.btag
    }

    fn remaining(deadline: Instant) -> Result<Duration, UsbtmcError> {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            Err(UsbtmcError::Timeout)
        } else {
            Ok(left)
        }
    }

    /// Send one whole message (EOM set). On a timeout the transfer is aborted; on a halt the endpoint is cleared.
    pub async fn write(&mut self, message: &[u8], deadline: Instant) -> Result<(), UsbtmcError> {
        let tag = self.take_btag();
        let frame = encode_dev_dep_msg_out(tag, message, true);
        tracing::debug!(device = %self.name, btag = tag, tx = %escape_bytes(message), "USBTMC DEV_DEP_MSG_OUT");
        self.bulk_out_checked(&frame, tag, deadline).await
    }

    async fn bulk_out_checked(
        &mut self,
        frame: &[u8],
        tag: u8,
        deadline: Instant,
    ) -> Result<(), UsbtmcError> {
        let timeout = Self::remaining(deadline)?;
        match self.pipe.bulk_out(frame, timeout).await {
            Ok(n) if n == frame.len() => Ok(()),
            Ok(n) => {
                tracing::warn!(device = %self.name, btag = tag, written = n, "short Bulk-OUT; aborting it");
                self.abort_bulk_out(tag).await?;
                Err(UsbtmcError::Timeout)
            }
            Err(UsbError::Timeout { transferred }) => {
                tracing::warn!(device = %self.name, btag = tag, transferred, "Bulk-OUT timed out; aborting it");
                self.abort_bulk_out(tag).await?;
                Err(UsbtmcError::Timeout)
            }
            Err(UsbError::Pipe) => {
                tracing::warn!(device = %self.name, "Bulk-OUT halted; clearing the halt");
                self.pipe.clear_halt(self.pipe.bulk_out_endpoint()).await?;
                Err(UsbtmcError::Usb(UsbError::Pipe))
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Read one whole reply: REQUEST_DEV_DEP_MSG_IN, then Bulk-IN transfers until EOM. Transfers whose bTag is not
    /// the one requested are stale and discarded. A transfer cut short by a timeout is never taken as a reply.
    pub async fn read(&mut self, deadline: Instant) -> Result<Vec<u8>, UsbtmcError> {
        let mut message = Vec::new();
        loop {
            let tag = self.take_btag();
            let request = encode_request_dev_dep_msg_in(tag, self.max_chunk, None);
            tracing::debug!(device = %self.name, btag = tag, "USBTMC REQUEST_DEV_DEP_MSG_IN");
            self.bulk_out_checked(&request, tag, deadline).await?;
            let eom = self.read_chunk(tag, &mut message, deadline).await?;
            if message.len() > self.max_reply {
                return Err(UsbtmcError::TooLong(self.max_reply));
            }
            if eom {
                tracing::debug!(device = %self.name, rx = %escape_bytes(&message), "USBTMC reply");
                return Ok(message);
            }
        }
    }

    /// Read the Bulk-IN transfers answering request `tag`; append the data; return EOM.
    async fn read_chunk(
        &mut self,
        tag: u8,
        message: &mut Vec<u8>,
        deadline: Instant,
    ) -> Result<bool, UsbtmcError> {
        let buf_len = self.in_buffer_len();
        loop {
            let transfer = self.bulk_in_checked(buf_len, tag, deadline).await?;
            let header = match decode_in_header(&transfer) {
                Ok(h) => h,
                Err(e) => {
                    // Not a header: a fragment of an old reply, or garbage. The stream is out of step: abort.
                    tracing::warn!(device = %self.name, error = %e, rx = %escape_bytes(&transfer), "bad Bulk-IN header");
                    self.abort_bulk_in(tag).await?;
                    return Err(e.into());
                }
            };
            let size = header.transfer_size as usize;
            if size > self.max_chunk as usize {
                self.abort_bulk_in(tag).await?;
                return Err(UsbtmcError::TooLong(self.max_chunk as usize));
            }
            // The data may continue in further Bulk-IN transfers (without a header) until `size` bytes arrived.
            let mut data: Vec<u8> = transfer.get(HEADER_LEN..).unwrap_or_default().to_vec();
            while data.len() < size {
                let more = self.bulk_in_checked(buf_len, tag, deadline).await?;
                if more.is_empty() {
                    self.abort_bulk_in(tag).await?;
                    return Err(UsbtmcError::Timeout);
                }
                data.extend_from_slice(&more);
            }
            data.truncate(size); // drop the alignment padding
            if header.btag != tag {
                tracing::warn!(device = %self.name, expected = tag, got = header.btag, stale = %escape_bytes(&data),
                    "stale Bulk-IN reply discarded");
                continue;
            }
            message.extend_from_slice(&data);
            return Ok(header.eom);
        }
    }

    async fn bulk_in_checked(
        &mut self,
        len: usize,
        tag: u8,
        deadline: Instant,
    ) -> Result<Vec<u8>, UsbtmcError> {
        let timeout = Self::remaining(deadline)?;
        match self.pipe.bulk_in(len, timeout).await {
            Ok(v) => Ok(v),
            Err(UsbError::Timeout { transferred }) => {
                tracing::warn!(device = %self.name, btag = tag, transferred, "Bulk-IN timed out; aborting it");
                self.abort_bulk_in(tag).await?;
                Err(UsbtmcError::Timeout)
            }
            Err(UsbError::Pipe) => {
                tracing::warn!(device = %self.name, "Bulk-IN halted; clearing the halt");
                self.pipe.clear_halt(self.pipe.bulk_in_endpoint()).await?;
                Err(UsbtmcError::Usb(UsbError::Pipe))
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Write a message and read its reply, as text without the trailing newline.
    pub async fn query(&mut self, message: &str, deadline: Instant) -> Result<String, UsbtmcError> {
        self.write(message.as_bytes(), deadline).await?;
        let reply = self.read(deadline).await?;
        Ok(String::from_utf8_lossy(&reply)
            .trim_end_matches(['\n', '\r'])
            .to_string())
    }

    /// Abort the Bulk-OUT transfer `tag` (INITIATE_ABORT_BULK_OUT, poll CHECK_ABORT_BULK_OUT_STATUS), then clear
    /// the endpoint's halt as the specification requires.
    pub async fn abort_bulk_out(&mut self, tag: u8) -> Result<(), UsbtmcError> {
        let ep = u16::from(self.pipe.bulk_out_endpoint());
        let reply = self
            .pipe
            .control_in(
                REQUEST_TYPE_ENDPOINT,
                request::INITIATE_ABORT_BULK_OUT,
                u16::from(tag),
                ep,
                2,
                CONTROL_TIMEOUT,
            )
            .await?;
        let st = reply.first().copied().unwrap_or(status::FAILED);
        tracing::info!(device = %self.name, btag = tag, status = st, "INITIATE_ABORT_BULK_OUT");
        if st != status::SUCCESS {
            // FAILED / TRANSFER_NOT_IN_PROGRESS: nothing (left) to abort.
            return Ok(());
        }
        for _ in 0..STATUS_POLLS {
            let reply = self
                .pipe
                .control_in(
                    REQUEST_TYPE_ENDPOINT,
                    request::CHECK_ABORT_BULK_OUT_STATUS,
                    0,
                    ep,
                    8,
                    CONTROL_TIMEOUT,
                )
                .await?;
            match reply.first().copied() {
                Some(status::PENDING) => tokio::time::sleep(STATUS_POLL_INTERVAL).await,
                Some(status::SUCCESS) => {
                    self.pipe.clear_halt(self.pipe.bulk_out_endpoint()).await?;
                    return Ok(());
                }
                other => {
                    return Err(UsbtmcError::Refused {
                        what: "CHECK_ABORT_BULK_OUT_STATUS",
                        status: other.unwrap_or(0),
                    });
                }
            }
        }
        Err(UsbtmcError::Timeout)
    }

    /// Abort the Bulk-IN transfer `tag` (INITIATE_ABORT_BULK_IN, drain, poll CHECK_ABORT_BULK_IN_STATUS).
    pub async fn abort_bulk_in(&mut self, tag: u8) -> Result<(), UsbtmcError> {
        let ep = u16::from(self.pipe.bulk_in_endpoint());
        let reply = self
            .pipe
            .control_in(
                REQUEST_TYPE_ENDPOINT,
                request::INITIATE_ABORT_BULK_IN,
                u16::from(tag),
                ep,
                2,
                CONTROL_TIMEOUT,
            )
            .await?;
        let st = reply.first().copied().unwrap_or(status::FAILED);
        tracing::info!(device = %self.name, btag = tag, status = st, "INITIATE_ABORT_BULK_IN");
        if st != status::SUCCESS {
            return Ok(());
        }
        for _ in 0..STATUS_POLLS {
            let reply = self
                .pipe
                .control_in(
                    REQUEST_TYPE_ENDPOINT,
                    request::CHECK_ABORT_BULK_IN_STATUS,
                    0,
                    ep,
                    8,
                    CONTROL_TIMEOUT,
                )
                .await?;
            match reply.first().copied() {
                Some(status::PENDING) => {
                    // bmAbortBulkIn bit0: the device still has data queued; read it out (and throw it away).
                    if reply.get(1).is_some_and(|b| b & 1 != 0) {
                        self.drain_in().await?;
                    } else {
                        tokio::time::sleep(STATUS_POLL_INTERVAL).await;
                    }
                }
                Some(status::SUCCESS) => return Ok(()),
                other => {
                    return Err(UsbtmcError::Refused {
                        what: "CHECK_ABORT_BULK_IN_STATUS",
                        status: other.unwrap_or(0),
                    });
                }
            }
        }
        Err(UsbtmcError::Timeout)
    }

    /// Read and discard one Bulk-IN transfer, if any.
    async fn drain_in(&mut self) -> Result<(), UsbtmcError> {
        match self
            .pipe
            .bulk_in(self.in_buffer_len(), Duration::from_millis(100))
            .await
        {
            Ok(v) => {
                tracing::debug!(device = %self.name, drained = %escape_bytes(&v), "drained Bulk-IN");
                Ok(())
            }
            Err(UsbError::Timeout { .. }) => Ok(()),
            Err(UsbError::Pipe) => Ok(self.pipe.clear_halt(self.pipe.bulk_in_endpoint()).await?),
            Err(e) => Err(e.into()),
        }
    }

    /// Reset the device's I/O: INITIATE_CLEAR, poll CHECK_CLEAR_STATUS (draining Bulk-IN while it reports data),
    /// then clear the halt on Bulk-OUT.
    pub async fn clear(&mut self) -> Result<(), UsbtmcError> {
        let iface = u16::from(self.pipe.interface_number());
        let reply = self
            .pipe
            .control_in(
                REQUEST_TYPE_INTERFACE,
                request::INITIATE_CLEAR,
                0,
                iface,
                1,
                CONTROL_TIMEOUT,
            )
            .await?;
        let st = reply.first().copied().unwrap_or(0);
        tracing::info!(device = %self.name, status = st, "INITIATE_CLEAR");
        if st != status::SUCCESS {
            return Err(UsbtmcError::Refused {
                what: "INITIATE_CLEAR",
                status: st,
            });
        }
        for _ in 0..STATUS_POLLS {
            let reply = self
                .pipe
                .control_in(
                    REQUEST_TYPE_INTERFACE,
                    request::CHECK_CLEAR_STATUS,
                    0,
                    iface,
                    2,
                    CONTROL_TIMEOUT,
                )
                .await?;
            match reply.first().copied() {
                Some(status::PENDING) => {
                    if reply.get(1).is_some_and(|b| b & 1 != 0) {
                        self.drain_in().await?;
                    } else {
                        tokio::time::sleep(STATUS_POLL_INTERVAL).await;
                    }
                }
                Some(status::SUCCESS) => {
                    self.pipe.clear_halt(self.pipe.bulk_out_endpoint()).await?;
                    return Ok(());
                }
                other => {
                    return Err(UsbtmcError::Refused {
                        what: "CHECK_CLEAR_STATUS",
                        status: other.unwrap_or(0),
                    });
                }
            }
        }
        Err(UsbtmcError::Timeout)
    }
}
