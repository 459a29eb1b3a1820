//! The instrument's calibrations (`gonio align` files) as the daemon keeps and applies them.
//!
//! Every calibration the daemon is given (`gonio daemon --calibration FILE`) or makes (the alignment action,
//! `align`) is kept in the store, dated and never overwritten. One of them is current: the one applied to every
//! campaign submitted (stored with it as its `alignment_toml`, with its id) and to the console's moves by
//! geometry. At start-up that is the `--calibration` file if one is given, else the store's latest calibration
//! made for this very instrument file (by SHA-256), else none; a calibration the alignment action makes becomes
//! current for the campaigns submitted after it. A calibration made for another instrument file is never
//! current: `--calibration` refuses it, and the store's are looked up by this file's SHA-256 (and checked again).

use serde::{Deserialize, Serialize};

use super::{CampaignRunner, Service, ServiceError, lock};
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::store::{InstrumentCalibrationId, NewInstrumentCalibration, Store};
use gonio_results::provenance_summary::sha256_hex;

/// The calibration the daemon applies now.
#[derive(Debug, Clone, PartialEq)]
pub struct CurrentCalibration {
    pub id: InstrumentCalibrationId,
    /// The calibration file's text, stored with each campaign it is applied to.
    pub toml: String,
}

/// A stored calibration as the API lists it (the texts are fetched one at a time).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationView {
    pub id: InstrumentCalibrationId,
    pub created_utc: String,
    pub stored_unix_s: f64,
    pub instrument: String,
    pub instrument_sha256: String,
    /// Made for the instrument file this daemon runs (only those can be applied).
    pub for_this_instrument: bool,
    /// The one applied to campaigns submitted now.
    pub current: bool,
    pub software: String,
    pub method: String,
    pub source: String,
    /// The alignment's whole report is kept with it (`GET /api/calibrations/{id}/report.json`).
    pub has_report: bool,
}

/// `text` read as a calibration file made for the runner's instrument file (`origin` names it in messages).
fn checked(runner: &dyn CampaignRunner, text: &str, origin: &str) -> Result<CalibrationFile, ServiceError> {
    let instrument = runner
        .instrument_toml()
        .ok_or_else(|| ServiceError::Conflict("this daemon has no instrument of its own".into()))?;
    let file = CalibrationFile::parse(text, origin).map_err(|e| ServiceError::Invalid(e.to_string()))?;
    file.check_instrument(instrument, origin)
        .map_err(|e| ServiceError::Invalid(e.to_string()))?;
    Ok(file)
}

/// The store's latest calibration made for the runner's instrument file, if any (module doc). One that cannot be
/// read any more is not applied, and the log says why.
pub(super) fn latest_for_instrument(
    store: &Store,
    runner: &dyn CampaignRunner,
) -> Result<Option<CurrentCalibration>, ServiceError> {
    let Some(instrument) = runner.instrument_toml() else {
        return Ok(None);
    };
    let Some(latest) = store.latest_instrument_calibration(&sha256_hex(instrument.as_bytes()))? else {
        tracing::info!("no stored calibration for this instrument file: campaigns are not aligned");
        return Ok(None);
    };
    let origin = format!("stored calibration {}", latest.id);
    match checked(runner, &latest.calibration_toml, &origin) {
        Ok(_) => {
            tracing::info!(
                calibration = %latest.id,
                made = %latest.created_utc,
                "applying the store's latest calibration of this instrument file"
            );
            Ok(Some(CurrentCalibration {
                id: latest.id,
                toml: latest.calibration_toml,
            }))
        }
        Err(e) => {
            tracing::warn!("{e}: no calibration is applied");
            Ok(None)
        }
    }
}

impl Service {
    /// The calibration applied to campaigns submitted now, if any.
    pub fn current_calibration(&self) -> Option<CurrentCalibration> {
        lock(&self.shared.calibration).clone()
    }

    /// Apply the calibration file `text` (`gonio daemon --calibration`, `origin` its path) from now on: refused
    /// unless it was made for this instrument file; kept in the store (once, however often it is given).
    pub fn use_calibration_file(
        &self,
        text: &str,
        origin: &str,
    ) -> Result<InstrumentCalibrationId, ServiceError> {
        let file = checked(self.shared.runner.as_ref(), text, origin)?;
        let known = lock(&self.shared.store).instrument_calibration_with_text(text)?;
        let id = match known {
            Some(c) => c.id,
            None => {
                self.keep_calibration(&file, text, &format!("gonio daemon --calibration {origin}"), None)?
            }
        };
        self.make_current(id, text);
        Ok(id)
    }

    /// Store `file` (whose text is `text`), made or given by `source`, with the alignment's report if any.
    pub(super) fn keep_calibration(
        &self,
        file: &CalibrationFile,
        text: &str,
        source: &str,
        report_json: Option<String>,
    ) -> Result<InstrumentCalibrationId, ServiceError> {
        let h = &file.calibration;
        let id = lock(&self.shared.store).add_instrument_calibration(&NewInstrumentCalibration {
            instrument: h.instrument.clone(),
            instrument_sha256: h.instrument_sha256.clone(),
            created_utc: h.created_utc.clone(),
            software: h.software.clone(),
            method: h.method.clone(),
            source: source.to_string(),
            calibration_toml: text.to_string(),
            report_json,
        })?;
        tracing::info!(calibration = %id, made = %h.created_utc, %source, "calibration stored");
        Ok(id)
    }

    /// From now on campaigns submitted are given calibration `id` (text `text`).
    pub(super) fn make_current(&self, id: InstrumentCalibrationId, text: &str) {
        *lock(&self.shared.calibration) = Some(CurrentCalibration {
            id,
            toml: text.to_string(),
        });
        tracing::info!(calibration = %id, "calibration applied to the campaigns submitted from now on");
    }

    /// Every stored calibration, oldest first.
    pub fn calibrations(&self) -> Result<Vec<CalibrationView>, ServiceError> {
        let all = lock(&self.shared.store).instrument_calibrations()?;
        let this = self
            .shared
            .runner
            .instrument_toml()
            .map(|t| sha256_hex(t.as_bytes()));
        let current = self.current_calibration().map(|c| c.id);
        Ok(all
            .into_iter()
            .map(|c| CalibrationView {
                for_this_instrument: this.as_deref() == Some(c.instrument_sha256.as_str()),
                current: current == Some(c.id),
                has_report: c.report_json.is_some(),
                id: c.id,
                created_utc: c.created_utc,
                stored_unix_s: c.stored_unix_s,
                instrument: c.instrument,
                instrument_sha256: c.instrument_sha256,
                software: c.software,
                method: c.method,
                source: c.source,
            })
            .collect())
    }

    /// One stored calibration's file text.
    pub fn calibration_toml(&self, id: InstrumentCalibrationId) -> Result<String, ServiceError> {
        Ok(lock(&self.shared.store)
            .instrument_calibration(id)?
            .calibration_toml)
    }

    /// The alignment report kept with a stored calibration (None for one that came from a file).
    pub fn calibration_report(&self, id: InstrumentCalibrationId) -> Result<Option<String>, ServiceError> {
        Ok(lock(&self.shared.store).instrument_calibration(id)?.report_json)
    }
}
