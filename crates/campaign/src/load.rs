//! The one loader: a campaign's text to a validated [`Campaign`], every error naming file, line, key and what
//! was expected. Material and reference names resolve by [`Sources`] (see [`crate::sources`]): against the
//! campaign file's directory for a local file, inside the daemon's data directory only for a submitted one, and
//! from the stored `[resolved]` table (never the file system) when a stored campaign is read back.

use std::path::PathBuf;

use gonio_brdf::material::Material;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan::PlanSpec;

use crate::error::{CampaignError, Located};
use crate::materials::{self, Reference};
use crate::model::{AcquisitionSection, CalibrationSection, CampaignFile, Method, TABLES};
use crate::sources::{self, Resolved, Sources};

/// Detector range for the readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    Auto,
    FixedW(f64),
}

/// Acquisition settings, defaults applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acquisition {
    /// Samples a point's reading averages.
    pub averaging: u32,
    /// Samples a dark or normalisation reading averages: their noise is shared by every value they correct
    /// (`[acquisition] calibration_averaging`).
    pub calibration_averaging: u32,
    pub range: Range,
    pub extra_settle_s: f64,
    /// Attempts per device operation after the first (transient errors only).
    pub retries: u32,
}

/// Calibration settings, defaults applied.
#[derive(Debug, Clone)]
pub struct CalibrationSettings {
    pub method: Method,
    /// Relative method: the reference sample.
    pub reference: Option<Reference>,
    /// Relative standard uncertainty of the reference's BRDF (its calibration certificate).
    pub reference_rel_std: f64,
    pub simulate_operator: bool,
}

/// A validated campaign: its settings with defaults applied and its materials resolved. [`crate::prepare`]
/// turns it into a plan, a schedule and a time model.
#[derive(Debug, Clone)]
pub struct Campaign {
    pub id: String,
    pub description: Option<String>,
    pub sample_radius_mm: f64,
    /// `[sample] non_uniformity`: the reflectance's relative change from centre to edge (standard
    /// uncertainty); 0 when the file does not state it.
    pub sample_non_uniformity: f64,
    /// The simulated sample (dry-runs need one: [`crate::Prepared::require_sample`]).
    pub material: Option<Material>,
    pub calibration: CalibrationSettings,
    pub acquisition: Acquisition,
    pub plan_spec: PlanSpec,
    /// The speed profiles of the sweeps that follow the BRDF (`follow`), one per arc.
    pub sweep_profiles: Vec<gonio_scheduler::sweep::ArcProfile>,
    /// True when every device of the instrument is simulated.
    pub dry_run: bool,
    /// The materials as resolved: what [`sources::resolved_trailer`] stores with the campaign.
    pub resolved: Resolved,
    /// The file as typed data.
    pub file: CampaignFile,
    /// Where the text came from, and the text (messages name its lines).
    pub origin: String,
    pub text: String,
}

impl Campaign {
    pub(crate) fn located(&self) -> Located<'_> {
        Located {
            origin: &self.origin,
            text: &self.text,
        }
    }
}

/// Read and validate a campaign's text against an instrument. `sources` says how material and reference names
/// resolve (module doc).
pub fn load(
    text: &str,
    origin: &str,
    sources: &Sources,
    file: &InstrumentFile,
) -> Result<Campaign, CampaignError> {
    let instrument = &file.instrument;
    let at = Located { origin, text };
    // Syntax and unknown tables first, with the line of the offender.
    let raw: toml::Table =
        toml::from_str(text).map_err(|e| at.plain(format!("not valid TOML: {}", e.to_string().trim())))?;
    for key in raw.keys() {
        if key != "resolved" && !TABLES.contains(&key.as_str()) {
            return Err(CampaignError(format!(
                "{origin}{}: unknown table or key `{key}`: expected one of {}",
                at.top_level_line(key),
                TABLES.join(", ")
            )));
        }
    }
    // `[resolved]`: only in a stored campaign (gonio wrote it). A stored campaign without it predates it: its
    // names resolve as they always did, against the current directory.
    if raw.contains_key("resolved") && *sources != Sources::Stored {
        return Err(CampaignError(format!(
            "{origin}{}: unknown table `resolved`: gonio adds it when it stores a campaign; remove it (the \
             [material] and [calibration] reference it was made from are resolved again)",
            at.top_level_line("resolved")
        )));
    }
    let doc: CampaignFile = toml::from_str(text).map_err(|e| {
        let message = e.to_string();
        if raw.contains_key("resolved") && message.contains("resolved") {
            CampaignError(format!(
                "{origin}{}: [resolved]: {}",
                at.top_level_line("resolved"),
                message.trim()
            ))
        } else {
            at.plain(message.trim())
        }
    })?;
    let stored = doc.resolved.clone();
    let sources = match (sources, &stored) {
        (Sources::Stored, None) => Sources::Local(PathBuf::from(".")),
        (s, _) => s.clone(),
    };
    let base = sources::base_dir(&sources).map_err(|e| at.plain(e))?;

    let Some(campaign) = &doc.campaign else {
        return Err(at.plain("missing the [campaign] table (with `id`, the sample id)"));
    };
    let id = campaign.id.trim().to_string();
    if id.is_empty()
        || !id.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        || id.starts_with('.')
    {
        return Err(at.err(
            "campaign",
            "id",
            format!(
                "expected a sample id of letters, digits, '-', '_' or '.' (it names the output directory), got {:?}",
                campaign.id
            ),
        ));
    }

    let dry_run = instrument.devices.iter().all(|d| d.is_simulated());
    let material = match &stored {
        Some(r) => r
            .material
            .as_ref()
            .map(sources::material_from_stored)
            .transpose()
            .map_err(|e| at.plain(format!("[resolved] material: {e}")))?,
        None => materials::sample_material(&raw, &at, &sources, &base)?,
    };

    let radius = doc.sample.as_ref().and_then(|s| s.radius_mm);
    let max_r = instrument.sample_holder.max_sample_radius_mm;
    if let Some(r) = radius
        && !(r.is_finite() && r > 0.0 && r <= max_r)
    {
        return Err(at.err(
            "sample",
            "radius_mm",
            format!("expected a radius in (0, {max_r}] mm (the holder's largest), got {r}"),
        ));
    }
    let sample_radius_mm = radius.unwrap_or(max_r);
    let sample_non_uniformity = doc.sample.as_ref().and_then(|s| s.non_uniformity).unwrap_or(0.0);
    if !(sample_non_uniformity.is_finite() && (0.0..1.0).contains(&sample_non_uniformity)) {
        return Err(at.err(
            "sample",
            "non_uniformity",
            format!(
                "expected a relative change of the reflectance from centre to edge in [0, 1) (0.003 for 0.3 %), got {sample_non_uniformity}"
            ),
        ));
    }

    let cal = doc.calibration.clone().unwrap_or_default();
    let calibration = calibration(&cal, &doc.plan, &at, &sources, &base, stored.as_ref())?;
    let acquisition = acquisition(
        &doc.acquisition.clone().unwrap_or_default(),
        instrument.detector.averaging,
        &at,
    )?;
    // The relative method reads its reference at a geometry: the schedule predicts that move, not the direct beam's.
    let mut plan_spec = doc.plan.clone();
    plan_spec.calibration.reference_geometry = calibration.reference.as_ref().map(|r| r.geometry);
    let sweep_profiles = match &stored {
        Some(r) => r.sweep_profiles.clone(),
        None => crate::follow::profiles(&plan_spec, instrument, &at, &sources, &base)?,
    };
    let resolved = Resolved {
        material: material.as_ref().map(Material::spec),
        reference: calibration.reference.as_ref().map(|r| r.material.spec()),
        sweep_profiles: sweep_profiles.clone(),
    };
    Ok(Campaign {
        id,
        description: campaign.description.clone(),
        sample_radius_mm,
        sample_non_uniformity,
        material,
        calibration,
        acquisition,
        plan_spec,
        sweep_profiles,
        dry_run,
        resolved,
        file: doc,
        origin: origin.to_string(),
        text: text.to_string(),
    })
}

/// `[calibration]` validated, the reference resolved.
fn calibration(
    cal: &CalibrationSection,
    plan: &PlanSpec,
    at: &Located,
    sources: &Sources,
    base: &std::path::Path,
    stored: Option<&Resolved>,
) -> Result<CalibrationSettings, CampaignError> {
    let reference = match (cal.method, &cal.reference) {
        (Method::Relative, None) => {
            return Err(at.err(
                "calibration",
                "method",
                "\"relative\" needs `reference`: the reference sample's material (a preset name or a material file)",
            ));
        }
        (Method::Relative, Some(r)) => {
            let m = match stored {
                Some(s) => s
                    .reference
                    .as_ref()
                    .ok_or_else(|| "the stored campaign has no [resolved] reference".to_string())
                    .and_then(|spec| sources::material_from_stored(spec).map_err(|e| e.to_string())),
                None => materials::reference_material(r, sources, base),
            }
            .map_err(|e| at.err("calibration", "reference", e))?;
            let geometry = materials::reference_geometry(cal.reference_geometry_deg.as_ref())
                .map_err(|e| at.err("calibration", "reference_geometry_deg", e))?;
            Some(Reference {
                name: r.clone(),
                material: m,
                geometry,
            })
        }
        (Method::Absolute, Some(_)) => {
            return Err(at.err("calibration", "reference", "only used with method = \"relative\""));
        }
        (Method::Absolute, None) => None,
    };
    if cal.method == Method::Absolute && cal.reference_geometry_deg.is_some() {
        return Err(at.err(
            "calibration",
            "reference_geometry_deg",
            "only used with method = \"relative\" (the absolute method reads the direct beam at \
             [plan.calibration] reference_pose_deg)",
        ));
    }
    if cal.method == Method::Relative && plan.calibration.reference_pose_deg.is_some() {
        return Err(at.err(
            "plan.calibration",
            "reference_pose_deg",
            "is the direct-beam pose of the absolute method; with method = \"relative\" the reference sample is \
             read at [calibration] reference_geometry_deg",
        ));
    }
    let reference_rel_std = cal.reference_rel_std.unwrap_or(0.005);
    if !(reference_rel_std.is_finite() && (0.0..1.0).contains(&reference_rel_std)) {
        return Err(at.err(
            "calibration",
            "reference_rel_std",
            format!("expected a relative uncertainty in [0, 1), got {reference_rel_std}"),
        ));
    }
    Ok(CalibrationSettings {
        method: cal.method,
        reference,
        reference_rel_std,
        simulate_operator: cal.simulate_operator,
    })
}

/// The fewest samples a dark or normalisation reading averages unless `[acquisition] calibration_averaging`
/// says otherwise: 0.3 s on a PM100 (3 ms a sample). A point's noise is its own, but a dark's or a direct-beam
/// reading's is shared by every value it corrects, so no number of points averages it away. Measured by hand
/// while this was built (no test repeats it; BENCHMARKS.md section 7 shows its effect): on the ideal instrument
/// (seeds 1 and 3), sweeps of white styrofoam normalised by one reading of 10 samples came out 7.5e-5 and
/// 2.5e-5 low on average; with readings of 100 samples, within 2e-5 (the lamp's drift apart), for a few tenths
/// of a second per band and calibration (the demo: 241 s of instrument time became 246 s, section 6).
pub const MIN_CALIBRATION_AVERAGING: u32 = 100;

/// `[acquisition]` validated, defaults applied (`averaging` defaults to the instrument's detector setting,
/// `calibration_averaging` to the larger of `averaging` and [`MIN_CALIBRATION_AVERAGING`]).
fn acquisition(
    acq: &AcquisitionSection,
    default_averaging: u32,
    at: &Located,
) -> Result<Acquisition, CampaignError> {
    let averaging = acq.averaging.unwrap_or(default_averaging);
    if averaging == 0 || averaging > 100_000 {
        return Err(at.err(
            "acquisition",
            "averaging",
            format!("expected 1..=100000 samples, got {averaging}"),
        ));
    }
    let calibration_averaging = acq
        .calibration_averaging
        .unwrap_or(averaging.max(MIN_CALIBRATION_AVERAGING));
    if calibration_averaging == 0 || calibration_averaging > 100_000 {
        return Err(at.err(
            "acquisition",
            "calibration_averaging",
            format!("expected 1..=100000 samples, got {calibration_averaging}"),
        ));
    }
    let range = match &acq.range {
        None => Range::Auto,
        Some(toml::Value::String(s)) if s == "auto" => Range::Auto,
        Some(v) => match v.as_float().or_else(|| v.as_integer().map(|i| i as f64)) {
            Some(w) if w.is_finite() && w > 0.0 => Range::FixedW(w),
            _ => {
                return Err(at.err(
                    "acquisition",
                    "range",
                    format!("expected \"auto\" or a full-scale power in W > 0, got {v}"),
                ));
            }
        },
    };
    let extra_settle_s = acq.settle_s.unwrap_or(0.0);
    if !(extra_settle_s.is_finite() && (0.0..=600.0).contains(&extra_settle_s)) {
        return Err(at.err(
            "acquisition",
            "settle_s",
            format!("expected seconds in [0, 600], got {extra_settle_s}"),
        ));
    }
    let retries = acq.retries.unwrap_or(2);
    if retries > 10 {
        return Err(at.err(
            "acquisition",
            "retries",
            format!("expected 0..=10, got {retries}"),
        ));
    }
    Ok(Acquisition {
        averaging,
        calibration_averaging,
        range,
        extra_settle_s,
        retries,
    })
}
