//! gonio-daemon: running measurement campaigns.
//!
//! Module map:
//! - [`store`]: the durable SQLite store (campaigns, configuration, devices, calibrations, points) and resume.

pub mod store;
