//! gonio-engine: running measurement campaigns on a connected instrument, without the service around it.
//!
//! Module map, from the bottom up (no module uses one above it; no two files import each other):
//! - [`store`]: the durable SQLite store (campaigns, configuration, devices, calibrations, points, sweep
//!   readings a sweep per transaction) and resume.
//! - [`error`]: [`error::EngineError`], why the engine could not run a campaign.
//! - [`rig`]: the connected instrument (drivers for every device; the in-process simulator for dry-runs). Only
//!   the rig names the simulator.
//! - [`control`]: the seam to whoever drives a run: [`control::Control`] requests in, [`control::Event`]s out.
//! - [`motion`]: the axes and the supervision of every device, without a campaign or a store (safe multi-axis
//!   moves, homing, retries and reconnection); a campaign and a person at a console drive the same layer.
//! - [`console`]: a person's hands on the instrument (state, safe moves by axis or geometry, jog, homing, the
//!   wheel, meter readings), on `motion`.
//! - [`acquisition`]: the meter's configuration, one reading with its uncertainty, the measurement equation as a
//!   pure function.
//! - [`calibration`]: darks and normalisation readings per band, the source's drift extrapolated in time.
//! - [`prepare`]: a campaign file validated, planned and ordered for the store ([`prepare::PreparedCampaign`]).
//! - `runner`: the run loop over a campaign's steps (calibration, per-point acquisition committed, faults,
//!   resume), then its sweeps (one arm turning while the meter reads), on `motion` and `acquisition`: [`run_campaign`], [`run_prepared_campaign`].
//! - [`selftest`]: what the instrument file claims measured on the hardware (speeds, accelerations, the
//!   wheel's time, latencies, the meter's dark and noise), on `motion`.
//! - [`budget`]: a point's uncertainty budget from the measurement equation's parts, the characterisation and
//!   the signature; `budget::complete` adds what needs the campaign's other points when it completes (the drift
//!   between references, the aperture correction, pointing, the finite band), kept apart from the committed rows.
//! - [`align`]: the instrument's geometric errors from its own scans (the engine's own model of the instrument,
//!   fitted with priors; what cannot be observed stays at nominal), the calibration file, and the pose correction
//!   a campaign applies; [`characterise`]: the detector and the source from their own readings, run inside the
//!   alignment (ranges, signature and NEBRDF, warm-up).
//! - [`export`]: the points CSV and the run record (shared by `gonio run`, the exports and the HTTP API), and a
//!   run's report.
//!
//! The service (queue, ownership, HTTP API, status page) is `gonio-daemon`, above this crate: nothing here can
//! reach up into it.

pub mod acquisition;
pub mod align;
pub mod budget;
pub mod calibration;
pub mod characterise;
pub mod console;
pub mod control;
pub mod error;
pub mod export;
pub mod motion;
pub mod prepare;
pub mod rig;
mod runner;
pub mod selftest;
pub mod store;

pub use control::{Control, Event};
pub use error::EngineError;
pub use prepare::{
    PreparedCampaign, prepare_campaign, prepare_campaign_with, prepare_submitted_campaign, software_version,
};
pub use rig::Rig;
pub use runner::{run_campaign, run_prepared_campaign};
