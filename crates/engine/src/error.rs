//! The engine's error: why it could not run a campaign. Beneath every part that can fail that way (the rig,
//! preparing, the run loop), so none of them needs another to name it.

use gonio_campaign::CampaignError;

use crate::store::{CampaignId, StoreError};

/// Why the engine could not run a campaign (as opposed to a campaign that ended `failed`, which is a state).
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// The campaign file is invalid (the message names file, line and key).
    #[error(transparent)]
    Campaign(#[from] CampaignError),
    /// The instrument file or its simulator cannot be used.
    #[error("instrument: {0}")]
    Instrument(String),
    /// A device cannot be opened or used.
    #[error("device: {0}")]
    Device(String),
    /// The store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The stored campaign cannot be run (already final, its stored configuration no longer valid, ...).
    #[error("campaign {id}: {message}")]
    NotRunnable { id: CampaignId, message: String },
}
