//! gonio-daemon: running measurement campaigns.
//!
//! Module map:
//! - [`store`]: the durable SQLite store (campaigns, configuration, devices, calibrations, points) and resume.
//! - [`campaign`]: the campaign model (re-exported `gonio-campaign`: the typed file, the one loader, the one
//!   prepare).
//! - [`rig`]: the connected instrument (drivers for every device; the in-process simulator for dry-runs).
//! - [`control`]: the seam to whoever drives a run: [`control::Control`] requests in, [`control::Event`]s out.
//! - [`engine`]: [`engine::run_campaign`], [`engine::prepare_campaign`], [`engine::EngineError`].
//! - [`motion`]: the axes and the supervision of every device, without a campaign or a store (safe multi-axis
//!   moves, homing, retries and reconnection); a campaign and a person at a console drive the same layer.
//! - [`acquisition`]: the meter's configuration, one reading with its uncertainty, the measurement equation as a
//!   pure function.
//! - [`calibration`]: darks and normalisation readings per band, the source's drift extrapolated in time.
//! - `runner`: the run loop over a campaign's steps (calibration, per-point acquisition committed, faults,
//!   resume), on `motion` and `acquisition`.
//! - [`export`]: the points CSV (shared by `gonio run` and the HTTP API).
//! - [`service`]: the daemon's core: the campaign queue (one at a time, interrupted ones first), request routing,
//!   emergency stop, graceful shutdown, and the instrument handed to one owner at a time
//!   ([`service::InstrumentLease`]).
//! - [`api`]: the HTTP/JSON control API (axum) with server-sent events, the token rule, and the server loop.
//! - [`status_page`]: the live status page at `/` (embedded HTML/CSS/JS).

pub mod acquisition;
pub mod api;
pub mod calibration;
pub mod control;
pub mod engine;
pub mod export;
pub mod motion;
pub mod rig;
mod runner;
pub mod service;
pub mod status_page;
pub mod store;

pub use control::{Control, Event};
pub use engine::{EngineError, PreparedCampaign, prepare_campaign, run_campaign, run_prepared_campaign};
pub use gonio_campaign as campaign;
pub use rig::Rig;
