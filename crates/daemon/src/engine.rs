//! The campaign engine: runs one stored campaign on a connected [`Rig`], point by point, committing each point
//! durably, obeying [`Control`] requests at safe points, and resuming from the first uncommitted point.

use std::path::Path;
use std::sync::{Arc, Mutex};

pub use crate::campaign::CampaignError;
pub use crate::control::{Control, Event};
pub use crate::rig::Rig;
use crate::store::{CampaignId, CampaignState, NewCampaign, Store, StoreError};
use gonio_instrument::InstrumentFile;

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

/// What the service needs to store a new campaign.
#[derive(Debug, Clone, PartialEq)]
pub struct PreparedCampaign {
    /// The campaign (sample) id from `[campaign] id`.
    pub name: String,
    pub description: Option<String>,
    pub total_points: u64,
    pub dry_run: bool,
    /// Predicted instrument time (s) from the time model.
    pub predicted_s: f64,
}

impl PreparedCampaign {
    /// The store record for this campaign with its texts.
    pub fn new_campaign(&self, campaign_toml: &str, instrument_toml: &str) -> NewCampaign {
        NewCampaign {
            name: self.name.clone(),
            campaign_toml: campaign_toml.to_string(),
            instrument_toml: instrument_toml.to_string(),
            total_points: self.total_points,
            dry_run: self.dry_run,
            software_version: software_version(),
        }
    }
}

/// The software version stored with each campaign.
pub fn software_version() -> String {
    format!("gonio {}", env!("CARGO_PKG_VERSION"))
}

/// Validate a campaign file against an instrument: every error names file, line, key and what was expected.
pub fn prepare_campaign(
    text: &str,
    origin: &str,
    base_dir: &Path,
    instrument: &InstrumentFile,
) -> Result<PreparedCampaign, EngineError> {
    let c = crate::campaign::parse(text, origin, base_dir, instrument)?;
    Ok(PreparedCampaign {
        name: c.id.clone(),
        description: c.description.clone(),
        total_points: c.total_points(),
        dry_run: c.dry_run,
        predicted_s: c.schedule.breakdown.total_s(),
    })
}

/// Run (or resume from `store.next_index(id)`) one stored campaign to a final or paused state.
pub async fn run_campaign(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &Rig,
    control: Control,
) -> Result<CampaignState, EngineError> {
    crate::runner::run(store, id, rig, control).await
}
