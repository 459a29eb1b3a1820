//! [`EngineRunner`]: the [`CampaignRunner`] the daemon uses, the campaign engine on one connected instrument.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use gonio_instrument::InstrumentFile;

use super::{CampaignRunner, RunFuture, ServiceError, Submission};
use gonio_engine::align::correction::PoseCorrection;
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::control::Control;
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignId, CampaignRecord, Store, StoreError};
use gonio_engine::{PreparedCampaign, prepare_submitted_campaign, run_prepared_campaign};

/// The real runner: the campaign engine on one connected instrument.
#[derive(Debug)]
pub struct EngineRunner {
    instrument: InstrumentFile,
    instrument_toml: String,
    /// The daemon's data directory: submitted campaigns may name material presets or files inside it only, and
    /// relative names resolve against it.
    base_dir: PathBuf,
    rig: Rig,
}

impl EngineRunner {
    /// `instrument_toml` is the text of the instrument file in force, stored with every campaign.
    pub fn new(
        instrument: InstrumentFile,
        instrument_toml: String,
        base_dir: PathBuf,
        rig: Rig,
    ) -> EngineRunner {
        EngineRunner {
            instrument,
            instrument_toml,
            base_dir,
            rig,
        }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }
}

impl CampaignRunner for EngineRunner {
    fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<Submission, ServiceError> {
        let p = prepare_submitted_campaign(campaign_toml, origin, &self.base_dir, &self.instrument)
            .map_err(|e| ServiceError::Invalid(e.to_string()))?;
        // The service adds the current calibration (`Service::submit`).
        Ok(Submission {
            campaign: p.new_campaign(campaign_toml, &self.instrument_toml),
            prepared: Some(Arc::new(p)),
        })
    }

    fn run(
        &self,
        store: Arc<Mutex<Store>>,
        id: CampaignId,
        control: Control,
        prepared: Option<Arc<PreparedCampaign>>,
    ) -> RunFuture {
        let rig = self.rig.clone();
        Box::pin(async move {
            match &prepared {
                Some(p) => run_prepared_campaign(store, id, &rig, control, p).await,
                None => gonio_engine::run_campaign(store, id, &rig, control).await,
            }
        })
    }

    fn rig(&self) -> Option<Rig> {
        Some(self.rig.clone())
    }

    fn instrument_toml(&self) -> Option<&str> {
        Some(&self.instrument_toml)
    }

    fn pose_correction(&self, alignment_toml: &str) -> Option<PoseCorrection> {
        // Checked against the instrument file when it became the daemon's current calibration.
        let cal = CalibrationFile::parse(alignment_toml, "<the daemon's calibration>").ok()?;
        Some(PoseCorrection::new(
            &self.instrument.instrument,
            cal.params(&self.instrument.instrument),
        ))
    }

    fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, StoreError> {
        let points = store.points(record.id)?;
        Ok(gonio_engine::export::points_csv(record, &points))
    }
}
