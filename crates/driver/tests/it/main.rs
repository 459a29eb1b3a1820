//! Integration tests of gonio-driver: one test binary (the simulator is linked once).
//!
//! - `usbtmc`: framing against the documented byte vectors, bTags, partial transfers, stale replies, recovery.
//! - `scripted`: the serial drivers against scripted in-memory peers (reply matching, stale lines, priority stop,
//!   disconnect and reconnect).
//! - `fuzz`: every reply parser fed random bytes.
//! - `garbled`: a digit garbled inside a well-formed number never becomes a wrong position (issue 8).
//! - `conformance_*`: each device's recorded real-device behaviour (issue 17), byte-level with the exchanges
//!   quoted from vendor references and real-device reports, and against every simulator variant.
//! - `first_ts`: the SMC100's recorded first-TS loss logged at debug with a count at info; faults still warn.
//! - `sim`: every driver against the simulator's emulators, in process and through pseudo-terminals.

mod common;
mod conformance_fw102c;
mod conformance_pm100;
mod conformance_smc100;
mod conformance_zaber;
mod first_ts;
mod fuzz;
mod garbled;
mod logcap;
mod scripted;
mod sim;
mod usbtmc;
