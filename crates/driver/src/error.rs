//! Errors: one rich error type for every driver, plus a coarse [`ErrorKind`] that generic code (the daemon's
//! retry and recovery logic) can match without knowing which device spoke.

use std::time::Duration;

/// What kind of failure happened, independent of the device (in the style of embedded-hal's `ErrorKind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// No (complete) reply before the deadline. The device may still be there.
    Timeout,
    /// The port or USB device is gone (unplugged, closed, no permission any more); reconnect before use.
    Disconnected,
    /// A reply arrived but was malformed, garbled, failed its checksum, or answered something else.
    Protocol,
    /// The device refused the command (wrong state, bad argument, unknown command).
    Rejected,
    /// A move ended somewhere other than its target (stall, limit switch, following error, disabled, stopped).
    MotionFault,
    /// The axis has lost (or never had) its reference: it must be homed.
    NotReferenced,
    /// A requested value lies outside the configured or device limits; nothing was sent.
    OutOfRange,
    /// The device cannot be opened or found (absent, no permission, no bus).
    Unavailable,
}

/// A driver error. The messages say which device, what was asked and what the device answered.
#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// No complete reply in time.
    #[error("{device}: no reply to {request:?} within {} ms", timeout.as_millis())]
    Timeout {
        device: String,
        request: String,
        timeout: Duration,
    },
    /// The port or device disappeared.
    #[error("{device}: the connection is lost ({detail}); reconnect and re-verify before use")]
    Disconnected { device: String, detail: String },
    /// A malformed or unexpected reply.
    #[error("{device}: bad reply to {request:?}: {detail}")]
    Protocol {
        device: String,
        request: String,
        detail: String,
    },
    /// The device said no.
    #[error("{device}: {request:?} was rejected: {reason}")]
    Rejected {
        device: String,
        request: String,
        reason: String,
    },
    /// A move did not end at its target; `reason` is the device's own account.
    #[error("{device}: move to {target_deg} deg failed: {reason}")]
    MotionFault {
        device: String,
        target_deg: f64,
        reason: String,
    },
    /// The axis must be homed first.
    #[error("{device}: the axis is not referenced ({state}); home it first")]
    NotReferenced { device: String, state: String },
    /// A value outside the limits; nothing was sent to the device.
    #[error("{device}: {what} {value} is outside [{min}, {max}]")]
    OutOfRange {
        device: String,
        what: String,
        value: f64,
        min: f64,
        max: f64,
    },
    /// Cannot open or find the device.
    #[error("{device}: cannot open: {detail}")]
    Unavailable { device: String, detail: String },
}

impl DriverError {
    /// The coarse kind generic code matches on.
    pub fn kind(&self) -> ErrorKind {
        match self {
            DriverError::Timeout { .. } => ErrorKind::Timeout,
            DriverError::Disconnected { .. } => ErrorKind::Disconnected,
            DriverError::Protocol { .. } => ErrorKind::Protocol,
            DriverError::Rejected { .. } => ErrorKind::Rejected,
            DriverError::MotionFault { .. } => ErrorKind::MotionFault,
            DriverError::NotReferenced { .. } => ErrorKind::NotReferenced,
            DriverError::OutOfRange { .. } => ErrorKind::OutOfRange,
            DriverError::Unavailable { .. } => ErrorKind::Unavailable,
        }
    }

    /// True when repeating an idempotent request might succeed (a lost or garbled reply).
    pub fn is_transient(&self) -> bool {
        matches!(self.kind(), ErrorKind::Timeout | ErrorKind::Protocol)
    }
}
