//! gonio-simulator: the simulated gonioreflectometer.
//!
//! Module map:
//! - [`scene`]: the seam between devices and optics (`Scene`, `Pose`, `Band`).
//! - [`kinematics`]: forward kinematics of the reference geometry (axis angles -> wi, wo in the sample frame).
//! - [`optics`]: the faithful scene: power on the photodiode for a pose, band and sample, with ground truth and
//!   an integration error estimate (footprint, aperture integral, delta lobes, retro-blocking, source drift/noise).
//! - [`imperfections`]: the instrument's hidden imperfections (`[simulator.imperfections]` magnitudes, actual
//!   values drawn from the seed) and the true geometry they make; never visible to the engine.
//! - [`instrument`]: [`SimInstrument`], the whole simulated instrument and its in-process API (serial streams,
//!   the USB power meter, pose/band/clock/faults for tests and the daemon).
//! - `world`: the physical state every device shares (clock, axes, filter wheel, scene).
//! - [`clock`]: the simulated clock (tokio time x time scale).
//! - [`motion`]: per-axis motion physics (trapezoidal profiles, backlash, limits, encoder, stalls).
//! - [`move_end`]: why an axis's last move ended (arrived, stopped, stalled, at a limit).
//! - [`recording`]: what each axis was commanded and its exact trajectory, for safety audits.
//! - [`smc100`], [`zaber`], [`fw102c`], [`pm100`]: the device emulators, speaking the real wire protocols.
//! - [`pty`]: a serial device served on a real pseudo-terminal ([`pty::PtyDevice`]).
//! - [`usb_socket`]: the USB power meter served on a Unix socket, for hosts in another process.
//! - [`ffs`]: the USB power meter as a real USB device, behind a Linux FunctionFS gadget function.
//! - [`session`]: the byte-stream session between a host and a serial emulator ([`SerialStream`], the host's end,
//!   stamps each write with when it was sent).
//! - [`faults`]: seeded fault injection and its counters.

pub mod clock;
pub mod faults;
pub mod ffs;
pub mod fw102c;
pub mod imperfections;
pub mod instrument;
pub mod kinematics;
pub mod motion;
pub mod move_end;
pub mod optics;
pub mod pm100;
pub mod pty;
pub mod recording;
pub mod responsivity;
pub mod scene;
pub mod session;
pub mod smc100;
pub mod usb_socket;
pub(crate) mod world;
pub mod zaber;

pub use faults::FaultCounts;
pub use instrument::{SimError, SimInstrument};
pub use pm100::{SimUsbDevice, UsbSimError};
pub use session::SerialStream;
