//! [`MoveEnd`]: why an axis's last move ended.
//!
//! Its own module because two layers speak it: the motion physics decides it ([`crate::motion`]) and the record
//! of every move keeps it ([`crate::recording`]), which the physics writes to; the device emulators read it to set
//! their controller states.

/// Why the last move ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveEnd {
    /// Reached its target.
    Arrived,
    /// Decelerated to rest on request (stop).
    Stopped,
    /// Stopped instantly on request (emergency stop).
    Halted,
    /// Stopped short: stall (following error).
    Stalled,
    /// Ran into the negative or positive limit switch.
    LimitNegative,
    LimitPositive,
}
