//! gonio-daemon: the service that runs campaigns on the engine ([`gonio_engine`]) for its clients.
//!
//! Module map:
//! - [`service`]: the daemon's core: the campaign queue (one at a time, interrupted ones first), request routing,
//!   emergency stop, graceful shutdown, and the instrument handed to one owner at a time
//!   ([`service::InstrumentLease`]).
//! - [`api`]: the HTTP/JSON control API (axum) with server-sent events, the token rule, and the server loop.
//! - [`status_page`]: the live status page at `/` (embedded HTML/CSS/JS).
//!
//! The engine (rig, motion, acquisition, calibration, the run loop, the store) is the crate below; this one adds
//! what a service needs around it and nothing the engine needs.

pub mod api;
pub mod service;
pub mod status_page;
