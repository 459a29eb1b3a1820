//! Integration tests of gonio-simulator: one test binary.
//!
//! - `faults`: fault injection seen from the host.
//! - `fuzz`: the device emulators' command parsers fed random input.
//! - `horizon`: aperture integrals over cones that cross the horizon, against references written here.
//! - `imperfections`: the imperfect instrument against independent expectations, one effect at a time.
//! - `optics`: the simulated optics against closed forms and brute-force references.
//! - `pm100`: PM100USB over USBTMC.
//! - `pm100_scpi`: PM100 conformance with the vendor's SCPI references and recorded real-meter behaviour.
//! - `smc100`: SMC100 conformance.
//! - `smc100_quirks`: SMC100 conformance beyond the manual's motion subset.
//! - `stress`: the numerical stability stress suite for the simulated optics (`cargo test -p gonio-simulator
//!   --test it stress`).
//! - `zaber`: Zaber ASCII conformance.

mod common;

mod faults;
mod fuzz;
mod horizon;
mod imperfections;
mod optics;
mod pm100;
mod pm100_scpi;
mod smc100;
mod smc100_quirks;
mod stress;
mod zaber;
