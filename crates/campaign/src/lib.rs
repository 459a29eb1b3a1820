//! gonio-campaign: what a campaign is, read one way and prepared one way.
//!
//! Module map:
//! - [`model`]: the campaign file as typed data ([`CampaignFile`], `Serialize` and `Deserialize`): its tables.
//! - [`load`]: the one loader: text to a validated [`Campaign`], with messages that name the file, the line, the
//!   key and what was expected ([`CampaignError`]).
//! - [`sources`]: where the materials a campaign names come from ([`Sources`]) and the `[resolved]` table a
//!   stored campaign carries.
//! - `follow`: the first pass of sweeps whose speed follows the BRDF, read into each arc's speed profile.
//! - `materials`: resolving the sample and the reference, and checking the reference can normalise.
//! - [`prepare`]: the one prepare: plan, schedule and time model ([`Prepared`]), used by `gonio plan`,
//!   `gonio run`, the daemon, the exports and the benchmarks.
//! - [`passes`]: adaptive plans at run time: each later pass from the points measured so far ([`AdaptivePlan`]).
//! - [`rehearsal`]: an adaptive plan's duration before it runs: its passes rehearsed on a stand-in sample
//!   ([`Rehearsal`]).

pub mod error;
mod follow;
pub mod load;
mod materials;
pub mod model;
pub mod passes;
pub mod prepare;
pub mod rehearsal;
pub mod sources;

pub use error::{CampaignError, line_of};
pub use gonio_scheduler::adaptive::{Measured, StopReason};
pub use load::{Acquisition, CalibrationSettings, Campaign, Range, load};
pub use materials::{DEFAULT_REFERENCE_GEOMETRY_DEG, Reference};
pub use model::{
    AcquisitionSection, CalibrationSection, CampaignFile, CampaignSection, Method, SampleSection,
};
pub use passes::{AdaptivePlan, NextPass, measured_geometries};
pub use prepare::{Prepared, Sweeps, campaign_time_model, load_and_prepare, prepare, sample_traits};
pub use rehearsal::Rehearsal;
pub use sources::{Resolved, Sources};
