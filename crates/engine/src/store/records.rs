//! The records the store reads and writes: campaign identifiers and states, a new campaign, a stored campaign,
//! a measured point, a calibration reading, an instrument calibration (a `gonio align` file kept in the store),
//! and the durability level a campaign's writes get.

use std::fmt;
use std::str::FromStr;

use gonio_results::budget::Budget;
use serde::{Deserialize, Serialize};

use super::StoreError;

/// Campaign identifier: a positive integer assigned by the store.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct CampaignId(pub i64);

impl fmt::Display for CampaignId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Lifecycle of a campaign.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CampaignState {
    Queued,
    Running,
    Pausing,
    Paused,
    WaitingOperator,
    Completed,
    Aborted,
    Failed,
}

impl CampaignState {
    pub const ALL: [CampaignState; 8] = [
        CampaignState::Queued,
        CampaignState::Running,
        CampaignState::Pausing,
        CampaignState::Paused,
        CampaignState::WaitingOperator,
        CampaignState::Completed,
        CampaignState::Aborted,
        CampaignState::Failed,
    ];

    pub fn as_str(&self) -> &'static str {
        match self {
            CampaignState::Queued => "queued",
            CampaignState::Running => "running",
            CampaignState::Pausing => "pausing",
            CampaignState::Paused => "paused",
            CampaignState::WaitingOperator => "waiting-operator",
            CampaignState::Completed => "completed",
            CampaignState::Aborted => "aborted",
            CampaignState::Failed => "failed",
        }
    }

    /// A finished campaign never runs again.
    pub fn is_final(&self) -> bool {
        matches!(
            self,
            CampaignState::Completed | CampaignState::Aborted | CampaignState::Failed
        )
    }

    /// States that mean "was in the middle of running" when found after a restart.
    pub fn was_interrupted(&self) -> bool {
        matches!(
            self,
            CampaignState::Running | CampaignState::Pausing | CampaignState::WaitingOperator
        )
    }
}

impl fmt::Display for CampaignState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for CampaignState {
    type Err = StoreError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        CampaignState::ALL
            .iter()
            .copied()
            .find(|st| st.as_str() == s)
            .ok_or_else(|| StoreError::Corrupt(format!("unknown campaign state {s:?}")))
    }
}

/// What is stored when a campaign is submitted: enough to reproduce the run.
#[derive(Debug, Clone, PartialEq)]
pub struct NewCampaign {
    pub name: String,
    /// The campaign file as submitted (TOML text).
    pub campaign_toml: String,
    /// The instrument file in force (TOML text).
    pub instrument_toml: String,
    /// Number of planned points.
    pub total_points: u64,
    /// True when the instrument is the simulator.
    pub dry_run: bool,
    pub software_version: String,
    /// The time model's prediction of the campaign's instrument time (s), made once when it was prepared (an
    /// adaptive plan: its whole budget).
    pub predicted_instrument_s: Option<f64>,
    /// The alignment calibration applied to every point's pose (a `gonio align` file's text), if any: stored so
    /// that a resumed run applies the same one.
    pub alignment_toml: Option<String>,
    /// The stored instrument calibration that text is (the daemon's), if it is one.
    pub calibration_id: Option<InstrumentCalibrationId>,
}

/// A campaign as stored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CampaignRecord {
    pub id: CampaignId,
    pub name: String,
    pub state: CampaignState,
    pub campaign_toml: String,
    pub instrument_toml: String,
    pub total_points: u64,
    pub points_done: u64,
    pub dry_run: bool,
    pub software_version: String,
    pub created_unix_s: f64,
    pub last_error: Option<String>,
    /// Message shown while waiting for the operator.
    pub operator_message: Option<String>,
    /// The prediction made when the campaign was prepared (s); None for campaigns stored before version 4.
    pub predicted_instrument_s: Option<f64>,
    /// The alignment calibration applied (a `gonio align` file's text); None when none was (and for campaigns
    /// stored before version 5).
    pub alignment_toml: Option<String>,
    /// Which stored instrument calibration that is; None when none was applied or it was not a stored one (and
    /// for campaigns stored before version 6).
    pub calibration_id: Option<InstrumentCalibrationId>,
    /// Instrument time (s) at which the campaign's last run ended: after its closing calibration's last turn of
    /// the wheel and operator step, which no reading records. None before a run ended (and for campaigns stored
    /// before version 10).
    pub ended_instrument_s: Option<f64>,
}

/// What a campaign's completion (crate::budget::complete) records for one point: read in place of the
/// committed row's columns.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCompletion {
    pub index: u64,
    /// The completed budget; its total is the point's `brdf_u_sr`.
    pub budget: Budget,
    /// The value corrected to the nominal geometry (1/sr); `None`: the committed value stands.
    pub brdf_sr: Option<f64>,
    /// The aperture average `brdf_sr` was corrected from (1/sr).
    pub brdf_aperture_sr: Option<f64>,
    /// The point's flags, when the completion added one; `None`: the committed flags stand.
    pub flags: Option<Vec<String>>,
}

/// One measured (or failed) point with everything needed to recompute it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointRecord {
    pub index: u64,
    pub band_nm: f64,
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    /// Raw detector reading (W).
    pub signal_w: f64,
    /// Dark reading subtracted from it (W).
    pub dark_w: f64,
    /// Incident power from the direct-beam calibration, interpolated in time (W); or the reference signal
    /// for the relative method.
    pub incident_w: f64,
    /// The BRDF (1/sr); `None` for a failed or flagged point that has no valid value.
    pub brdf_sr: Option<f64>,
    /// Standard uncertainty of the BRDF (1/sr).
    pub brdf_u_sr: Option<f64>,
    /// Empty for a valid point, else reasons (saturated, overfilled, failed: ...).
    pub flags: Vec<String>,
    /// Seconds since the campaign started (instrument time).
    pub t_s: f64,
    /// Read-back positions per axis, in the instrument file's axis order (name, physical degrees).
    pub readback_deg: Vec<(String, f64)>,
    /// Dry-runs only: the simulator's ground truth at the nominal geometry and averaged over the aperture.
    pub truth_point_sr: Option<f64>,
    pub truth_aperture_sr: Option<f64>,
    /// Dry-runs on an imperfect simulated instrument only: what each imperfection did to this point's reading
    /// (JSON: the simulator's `OpticsEffects` and `MeterEffects`, simulator/src/imperfections/effects.rs,
    /// plus the relative effects derived from them; crates/engine/src/rig/dry_run.rs).
    #[serde(default)]
    pub truth_effects_json: Option<String>,
    /// The aperture average `brdf_sr` was corrected from (1/sr); `None` when no correction was made.
    #[serde(default)]
    pub brdf_aperture_sr: Option<f64>,
    /// The uncertainty budget (`brdf_u_sr` is its total); empty for points stored before version 7.
    #[serde(default)]
    pub budget: Budget,
}

/// A committed point's geometry and BRDF only: what an adaptive planner reads back (`Store::point_values`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointValue {
    pub index: u64,
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    /// `None` for a failed or flagged point.
    pub brdf_sr: Option<f64>,
}

/// A calibration reading (direct beam, reference sample, dark) taken during a campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// "direct-beam", "reference" or "dark".
    pub kind: String,
    pub band_nm: Option<f64>,
    pub t_s: f64,
    pub value_w: f64,
    pub u_w: f64,
}

/// Identifier of a stored instrument calibration: a positive integer assigned by the store.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct InstrumentCalibrationId(pub i64);

impl fmt::Display for InstrumentCalibrationId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// An instrument calibration to keep: a `gonio align` file's text with the header fields the store is searched
/// by (the caller reads them from the file's header; the store does not parse the text).
#[derive(Debug, Clone, PartialEq)]
pub struct NewInstrumentCalibration {
    /// The instrument's name, as the file's header gives it.
    pub instrument: String,
    /// SHA-256 of the instrument file it was made for (the file's header).
    pub instrument_sha256: String,
    /// When it was made (the file's header, ISO 8601 UTC).
    pub created_utc: String,
    pub software: String,
    pub method: String,
    /// Where it came from: "alignment by the daemon (loopback)", "gonio daemon --calibration FILE".
    pub source: String,
    /// The calibration file's text, as written.
    pub calibration_toml: String,
    /// The alignment's whole report (JSON), when the daemon made it.
    pub report_json: Option<String>,
}

/// A stored instrument calibration: never overwritten.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InstrumentCalibration {
    pub id: InstrumentCalibrationId,
    /// When the store received it (unix s).
    pub stored_unix_s: f64,
    pub instrument: String,
    pub instrument_sha256: String,
    pub created_utc: String,
    pub software: String,
    pub method: String,
    pub source: String,
    pub calibration_toml: String,
    pub report_json: Option<String>,
}

/// How far a commit survives (module doc): the store picks it from the campaign written to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// `synchronous = FULL`: survives a crash of the process or the operating system and a power cut (campaigns
    /// on the real instrument, and writes that belong to no campaign).
    PowerLoss,
    /// `synchronous = NORMAL` (WAL): survives a crash or `kill -9` of the process, not of the operating system
    /// (dry-runs).
    ProcessCrash,
}

impl Durability {
    /// The level a campaign's writes get.
    pub fn for_campaign(dry_run: bool) -> Durability {
        if dry_run {
            Durability::ProcessCrash
        } else {
            Durability::PowerLoss
        }
    }

    pub(super) fn pragma(self) -> &'static str {
        match self {
            Durability::PowerLoss => "PRAGMA synchronous = FULL",
            Durability::ProcessCrash => "PRAGMA synchronous = NORMAL",
        }
    }
}
