//! gonio-driver: the hardware. Byte transports and one module per device protocol, behind small device traits.
//! It knows nothing about BRDFs; angles cross its boundary in physical degrees.
//!
//! Module map:
//! - [`error`]: [`DriverError`] (rich, per device and request) and [`ErrorKind`] (coarse, for generic code).
//! - [`traits`]: [`Axis`], [`Detector`], [`FilterWheel`]: object-safe, async through boxed futures.
//! - [`transport`]: [`transport::LinePort`] (one owner per serial port / pty / in-memory stream; requests
//!   serialised, stops on a priority path) and [`transport::UsbPipe`] (rusb, or in memory).
//! - [`motion`]: move durations and deadlines, the backlash approach. [`poll`]: waiting for a move to end.
//! - [`axis_driver`]: what the axis drivers share; [`Axis`] for each over a few protocol operations.
//! - [`smc100`]: Newport SMC100 chains. [`zaber`]: Zaber ASCII chains. [`fw102c`]: Thorlabs filter wheel.
//! - [`usbtmc`]: USBTMC framing and recovery. [`pm100`]: Thorlabs power meters over USBTMC + SCPI.
//! - [`discovery`]: what serial ports and USB instruments this machine can see (`gonio devices`).
//!
//! Invariants: every wait has a deadline; only idempotent requests are retried, and boundedly; "arrived" means
//! the controller finished AND the read-back is within tolerance; a position acted on comes from a checksummed
//! reply or from two reads that agree within the encoder resolution; parsers never panic on device bytes.

pub mod axis_driver;
pub mod discovery;
pub mod error;
pub mod fw102c;
pub mod motion;
pub mod pm100;
pub mod poll;
pub mod smc100;
pub mod traits;
pub mod transport;
pub mod usbtmc;
pub mod zaber;

pub use error::{DriverError, ErrorKind};
pub use traits::{
    Axis, AxisLimits, AxisStatus, Detector, DetectorConfig, FilterWheel, PositionReport, PowerRange,
    PowerReading,
};
