//! The device traits the daemon programs against: small, object-safe (`Box<dyn Axis>`), async through boxed
//! futures, one error type with a coarse [`ErrorKind`](crate::ErrorKind). All angles are physical degrees.

use std::time::SystemTime;

use crate::error::DriverError;
use crate::transport::BoxFuture;

/// What an axis reports about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisStatus {
    /// Read-back position, physical degrees.
    pub position_deg: f64,
    /// The controller is executing a move (or homing).
    pub moving: bool,
    /// The axis knows its reference (homed).
    pub referenced: bool,
    /// A fault the controller reports (stall, limit, disabled, ...), in its own words.
    pub fault: Option<String>,
    /// The raw status as the device gave it (for logs).
    pub raw: String,
}

/// Travel and motion limits of an axis, physical degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisLimits {
    pub min_deg: f64,
    pub max_deg: f64,
    pub max_speed_deg_s: f64,
    pub accel_deg_s2: f64,
}

/// One read of an axis's position while it moves, with the size of its exchange on the line, so that the caller
/// can date it: the controller took the position after the request had crossed the line and before its reply
/// started back (a reply of `reply_bytes` at the line's baud rate ends the exchange).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionReport {
    /// Physical degrees.
    pub position_deg: f64,
    /// Bytes of the request, terminator included.
    pub request_bytes: usize,
    /// Bytes of the reply, terminator included.
    pub reply_bytes: usize,
}

/// A motorised rotation axis.
pub trait Axis: Send + Sync + std::fmt::Debug {
    /// Name used in messages ("light", "tilt").
    fn name(&self) -> &str;
    /// Configured limits.
    fn limits(&self) -> AxisLimits;
    /// Home (reference) the axis and wait, with a deadline, until it is referenced.
    fn home(&self) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Move to `target_deg` and wait for a verified arrival (controller idle AND read-back within tolerance),
    /// approaching from below when the axis has backlash. Returns the read-back position.
    fn move_to(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>>;
    /// Start an absolute move without waiting (no backlash approach); pair with [`Axis::wait_arrived`].
    fn start_move(&self, target_deg: f64) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Wait until the move to `target_deg` is over and verify the arrival. Returns the read-back position.
    fn wait_arrived(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>>;
    /// Like [`Axis::wait_arrived`] for a via point of a longer move (a backlash overshoot): there the load may
    /// lag the motor by the backlash, so the arrival is verified within the tolerance plus twice the backlash.
    fn wait_passed_via(&self, via_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>>;
    /// Read-back position.
    fn position_deg(&self) -> BoxFuture<'_, Result<f64, DriverError>>;
    /// One unverified position read in a single exchange, for placing readings in time while the axis moves
    /// (a garbled read is the caller's to outvote; [`Axis::position_deg`] is the verified read).
    fn position_report(&self) -> BoxFuture<'_, Result<PositionReport, DriverError>>;
    /// Full status.
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>>;
    /// Stop now, even while other requests on the same port are in flight.
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Set the speed and acceleration used for moves.
    fn set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Reopen the port after a disconnect and re-verify the axis: returns its status, or
    /// [`DriverError::NotReferenced`] when it lost its reference (power cycle) and must be homed again.
    fn reconnect(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>>;
}

/// How the detector picks its measurement range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PowerRange {
    Auto,
    /// Fixed full-scale power (W); the meter picks the smallest range that holds it.
    Fixed {
        full_scale_w: f64,
    },
}

/// Detector settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorConfig {
    pub wavelength_nm: f64,
    /// Samples averaged per reading.
    pub averaging: u32,
    pub range: PowerRange,
}

/// One power reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerReading {
    pub power_w: f64,
    /// Full scale of the range in use (W).
    pub range_w: f64,
    /// The reading is at or beyond full scale: not a valid measurement.
    pub overload: bool,
    /// When the reading was returned.
    pub timestamp: SystemTime,
}

/// An optical power meter.
pub trait Detector: Send + Sync + std::fmt::Debug {
    fn name(&self) -> &str;
    /// Apply the settings and verify them (the device's error queue must be empty afterwards).
    fn configure(&self, config: DetectorConfig) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Take one reading.
    fn read_power(&self) -> BoxFuture<'_, Result<PowerReading, DriverError>>;
    /// Identification string (`*IDN?`).
    fn identify(&self) -> BoxFuture<'_, Result<String, DriverError>>;
    /// Reset the I/O after a fault or reopen a vanished device, then check it answers.
    fn reconnect(&self) -> BoxFuture<'_, Result<(), DriverError>>;
}

/// A filter wheel.
pub trait FilterWheel: Send + Sync + std::fmt::Debug {
    fn name(&self) -> &str;
    /// Number of positions (6 or 12).
    fn position_count(&self) -> BoxFuture<'_, Result<u8, DriverError>>;
    /// Turn to `position` (1-based) and verify it.
    fn go_to(&self, position: u8) -> BoxFuture<'_, Result<(), DriverError>>;
    /// Current position (1-based).
    fn position(&self) -> BoxFuture<'_, Result<u8, DriverError>>;
    /// Reopen after a disconnect and check it answers.
    fn reconnect(&self) -> BoxFuture<'_, Result<(), DriverError>>;
}
