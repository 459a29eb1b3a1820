//! The campaign file as typed data: what people write, and what gonio writes back (`Serialize`): the store keeps
//! the text as written; tools that generate campaigns (the benchmarks' and the soaks' generators) build them as
//! values ([`CampaignFile::new`] and the `with_` methods, the scheduler's `PlanSpec`/`GridSpec`) and write them
//! with [`CampaignFile::to_toml`] instead of formatting TOML by hand. Tests state campaigns as the text a person
//! writes (gonio-testkit's `CampaignText`), which is what they test.
//!
//! Tables (see config/campaigns/demo.toml, relative.toml and template.toml for commented examples):
//! - `[campaign]` `id` (the sample id; names the run), `description`.
//! - `[sample]` `radius_mm`, `non_uniformity`.
//! - `[plan]` the scheduler's schema ([`PlanSpec`]: grid or adaptive plan, bands, repeats, `[plan.calibration]`
//!   cadence of darks and normalisation readings: direct-beam readings for the absolute method,
//!   reference-sample readings for the relative one).
//! - `[calibration]` `method` ("absolute": direct-beam readings; "relative": against a reference sample),
//!   `reference` (relative: a material preset name or a material file), `reference_rel_std` (relative standard
//!   uncertainty of the reference's BRDF, default 0.005), `reference_geometry_deg` (relative: the geometry
//!   `[theta_i, phi_i, theta_o, phi_o]` the reference is read at, default `[0.0, 0.0, 45.0, 180.0]`, the 0/45
//!   geometry of reflectance standards), `simulate_operator` (dry-runs: the simulated operator swaps samples;
//!   default true).
//! - `[acquisition]` `averaging` (samples per reading), `calibration_averaging` (samples per dark and
//!   normalisation reading), `range` ("auto" or a full-scale power in W),
//!   `settle_s` (extra settling after arrival, on top of each axis' own), `retries` (per device operation).
//! - `[material]` the simulated sample for dry-runs: a material table as in config/materials/ (gonio-brdf's
//!   schema), or `preset = "<name>"`.
//! - `[resolved]` is not written by people: gonio appends it when it stores a campaign ([`crate::sources`]).

use gonio_scheduler::plan::PlanSpec;
use serde::{Deserialize, Serialize};

use crate::sources::Resolved;

/// Top-level tables a campaign file may hold (besides `[resolved]`, which only gonio writes).
pub const TABLES: [&str; 6] = [
    "campaign",
    "sample",
    "plan",
    "calibration",
    "acquisition",
    "material",
];

/// A whole campaign file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignFile {
    /// Required; optional here so that its absence gets a message of its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub campaign: Option<CampaignSection>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample: Option<SampleSection>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationSection>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acquisition: Option<AcquisitionSection>,
    pub plan: PlanSpec,
    /// A material description (gonio-brdf's `[material]` schema), read by gonio-brdf from the text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<toml::Table>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolved: Option<Resolved>,
}

impl CampaignFile {
    /// A campaign on sample `id` (`radius_mm` in radius) with `plan`; the other tables at their defaults (set
    /// them as values, or with the `with_` methods).
    pub fn new(id: &str, radius_mm: f64, plan: PlanSpec) -> CampaignFile {
        CampaignFile {
            campaign: Some(CampaignSection {
                id: id.to_string(),
                description: None,
            }),
            sample: Some(SampleSection {
                radius_mm: Some(radius_mm),
                non_uniformity: None,
            }),
            calibration: None,
            acquisition: None,
            plan,
            material: None,
            resolved: None,
        }
    }

    /// The file's text read as typed data; `Err` is TOML's message (the loader, [`crate::load`], says more).
    pub fn parse(text: &str) -> Result<CampaignFile, toml::de::Error> {
        toml::from_str(text)
    }

    /// `[campaign] id`, when given.
    pub fn id(&self) -> Option<&str> {
        self.campaign.as_ref().map(|c| c.id.as_str())
    }

    pub fn with_description(mut self, description: &str) -> CampaignFile {
        if let Some(c) = &mut self.campaign {
            c.description = Some(description.to_string());
        }
        self
    }

    /// `[material] preset = "<name>"`: a material preset as the simulated sample.
    pub fn with_material_preset(mut self, preset: &str) -> CampaignFile {
        let mut t = toml::Table::new();
        t.insert("preset".into(), toml::Value::String(preset.to_string()));
        self.material = Some(t);
        self
    }

    pub fn with_calibration(mut self, calibration: CalibrationSection) -> CampaignFile {
        self.calibration = Some(calibration);
        self
    }

    pub fn with_acquisition(mut self, acquisition: AcquisitionSection) -> CampaignFile {
        self.acquisition = Some(acquisition);
        self
    }

    /// The file as TOML text (what [`crate::load`] reads back to the same value).
    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }
}

/// `[campaign]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignSection {
    /// The sample id: names the run and its output directory.
    pub id: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
}

/// `[sample]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleSection {
    /// Sample radius (mm); default: the holder's largest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_mm: Option<f64>,
    /// How much the sample's reflectance may change from its centre to its edge (relative standard
    /// uncertainty, e.g. 0.003: a scan's or a certificate's figure), both across it and towards its rim; the
    /// budget's non-uniformity part. Absent: a sample taken as uniform (no such part).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub non_uniformity: Option<f64>,
}

/// `[calibration] method`.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Normalise by direct-beam readings (the operator removes the sample).
    #[default]
    Absolute,
    /// Normalise by readings of a reference sample of known BRDF.
    Relative,
}

/// `[calibration]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    #[serde(default)]
    pub method: Method,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_rel_std: Option<f64>,
    /// `[theta_i, phi_i, theta_o, phi_o]` in degrees (kept as written for the loader's messages).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_geometry_deg: Option<toml::Value>,
    #[serde(default = "yes")]
    pub simulate_operator: bool,
}

impl Default for CalibrationSection {
    fn default() -> Self {
        CalibrationSection {
            method: Method::Absolute,
            reference: None,
            reference_rel_std: None,
            reference_geometry_deg: None,
            simulate_operator: true,
        }
    }
}

fn yes() -> bool {
    true
}

/// `[acquisition]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcquisitionSection {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub averaging: Option<u32>,
    /// Samples a dark or normalisation reading averages (default: the larger of `averaging` and
    /// [`crate::load::MIN_CALIBRATION_AVERAGING`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_averaging: Option<u32>,
    /// `"auto"` or a full-scale power in W (kept as written for the loader's messages).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settle_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retries: Option<u32>,
}
