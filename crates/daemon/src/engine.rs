//! The campaign engine: runs one stored campaign on a connected [`Rig`], point by point, committing each point
//! durably, obeying [`Control`] requests at safe points, and resuming from the first uncommitted point.
//!
//! Preparing a campaign resolves the materials it names once ([`Sources`]): [`prepare_campaign`] for a local
//! file (`gonio run`: names relative to the file's directory), [`prepare_submitted_campaign`] for one submitted
//! to the daemon (presets and files inside its data directory only). What is stored is the file's text with the
//! resolved materials appended ([`PreparedCampaign::new_campaign`]), so that running and resuming read no file.

use std::path::Path;
use std::sync::{Arc, Mutex};

pub use crate::campaign::{CampaignError, Sources};
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
    /// Appended to the campaign text when it is stored: the `[resolved]` materials (empty when it names none).
    pub resolved_toml: String,
}

impl PreparedCampaign {
    /// The store record for this campaign with its texts: `campaign_toml` (the text that was prepared) followed
    /// by [`PreparedCampaign::resolved_toml`].
    pub fn new_campaign(&self, campaign_toml: &str, instrument_toml: &str) -> NewCampaign {
        NewCampaign {
            name: self.name.clone(),
            campaign_toml: self.stored_campaign_toml(campaign_toml),
            instrument_toml: instrument_toml.to_string(),
            total_points: self.total_points,
            dry_run: self.dry_run,
            software_version: software_version(),
        }
    }

    /// The campaign text as it is stored: `campaign_toml` followed by the resolved materials.
    pub fn stored_campaign_toml(&self, campaign_toml: &str) -> String {
        format!("{campaign_toml}{}", self.resolved_toml)
    }
}

/// The software version stored with each campaign.
pub fn software_version() -> String {
    format!("gonio {}", env!("CARGO_PKG_VERSION"))
}

/// Validate a local campaign file against an instrument: every error names file, line, key and what was
/// expected. Material and reference files resolve against `base_dir` (the campaign file's directory).
pub fn prepare_campaign(
    text: &str,
    origin: &str,
    base_dir: &Path,
    instrument: &InstrumentFile,
) -> Result<PreparedCampaign, EngineError> {
    prepare_campaign_with(text, origin, &Sources::Local(base_dir.to_path_buf()), instrument)
}

/// Validate a campaign submitted to the daemon: it may name material presets, or files inside `data_dir` only
/// (no `..`, no absolute path or symbolic link leading outside); anything else is refused with a message that
/// names file, line and key.
pub fn prepare_submitted_campaign(
    text: &str,
    origin: &str,
    data_dir: &Path,
    instrument: &InstrumentFile,
) -> Result<PreparedCampaign, EngineError> {
    prepare_campaign_with(
        text,
        origin,
        &Sources::Confined(data_dir.to_path_buf()),
        instrument,
    )
}

/// Validate a campaign with names resolving under `sources`.
pub fn prepare_campaign_with(
    text: &str,
    origin: &str,
    sources: &Sources,
    instrument: &InstrumentFile,
) -> Result<PreparedCampaign, EngineError> {
    let c = crate::campaign::parse(text, origin, sources, instrument)?;
    Ok(PreparedCampaign {
        name: c.id.clone(),
        description: c.description.clone(),
        total_points: c.total_points(),
        dry_run: c.dry_run,
        predicted_s: c.schedule.breakdown.total_s(),
        resolved_toml: crate::campaign::sources::resolved_trailer(&c.resolved),
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
