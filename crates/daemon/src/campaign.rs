//! The campaign file: what to measure and how, validated with messages that name the file, the line, the key
//! and what was expected.
//!
//! Tables (see config/campaigns/demo.toml and template.toml for commented examples):
//! - `[campaign]` `id` (the sample id; names the run), `description`.
//! - `[sample]` `radius_mm`.
//! - `[plan]` the scheduler's schema (grid, bands, repeats, `[plan.calibration]` cadence of darks and
//!   direct-beam readings).
//! - `[calibration]` `method` ("absolute": direct-beam readings; "relative": against a reference sample),
//!   `reference` (relative: a material preset name or file), `reference_rel_std`, `simulate_operator`
//!   (dry-runs: the simulated operator removes and remounts the sample; default true).
//! - `[acquisition]` `averaging` (samples per reading), `range` ("auto" or a full-scale power in W),
//!   `settle_s` (extra settling after arrival, on top of each axis' own), `retries` (per device operation).
//! - `[material]` the simulated sample for dry-runs: a material table as in config/materials/, or
//!   `preset = "<name>"`.

use std::path::Path;

use gonio_brdf::Brdf;
use gonio_brdf::material::Material;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::adaptive::Adaptive;
use gonio_scheduler::plan::{self, BuildContext, CampaignDoc, Plan, PlanError, SampleTraits};
use gonio_scheduler::schedule::{self, Schedule};
use gonio_scheduler::timing::TimeModel;
use serde::Deserialize;

/// Top-level tables a campaign file may hold.
const TABLES: [&str; 6] = [
    "campaign",
    "sample",
    "plan",
    "calibration",
    "acquisition",
    "material",
];

/// A campaign file that did not validate. The message names file, line, key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct CampaignError(pub String);

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct CampaignSection {
    id: String,
    #[serde(default)]
    description: Option<String>,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    #[default]
    Absolute,
    Relative,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct CalibrationSection {
    #[serde(default)]
    method: Method,
    #[serde(default)]
    reference: Option<String>,
    #[serde(default)]
    reference_rel_std: Option<f64>,
    #[serde(default = "yes")]
    simulate_operator: bool,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct AcquisitionSection {
    #[serde(default)]
    averaging: Option<u32>,
    #[serde(default)]
    range: Option<toml::Value>,
    #[serde(default)]
    settle_s: Option<f64>,
    #[serde(default)]
    retries: Option<u32>,
}

#[derive(Debug, Clone, Deserialize)]
struct Sections {
    #[serde(default)]
    campaign: Option<CampaignSection>,
    #[serde(default)]
    calibration: Option<CalibrationSection>,
    #[serde(default)]
    acquisition: Option<AcquisitionSection>,
}

fn yes() -> bool {
    true
}

/// Detector range for the readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    Auto,
    FixedW(f64),
}

/// Acquisition settings, defaults applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acquisition {
    pub averaging: u32,
    pub range: Range,
    pub extra_settle_s: f64,
    /// Attempts per device operation after the first (transient errors only).
    pub retries: u32,
}

/// Calibration settings, defaults applied.
#[derive(Debug, Clone)]
pub struct CalibrationSettings {
    pub method: Method,
    /// Relative method: the reference sample's BRDF and the relative uncertainty of its calibration.
    pub reference: Option<(String, Material)>,
    pub reference_rel_std: f64,
    pub simulate_operator: bool,
}

/// A validated campaign, with its plan and schedule.
#[derive(Debug, Clone)]
pub struct Campaign {
    pub id: String,
    pub description: Option<String>,
    pub sample_radius_mm: f64,
    pub material: Option<Material>,
    pub calibration: CalibrationSettings,
    pub acquisition: Acquisition,
    pub plan: Plan,
    pub schedule: Schedule,
    pub time: TimeModel,
    /// True when every device of the instrument is simulated.
    pub dry_run: bool,
}

impl Campaign {
    /// Number of points (measure steps) in run order.
    pub fn total_points(&self) -> u64 {
        self.schedule.measure_steps().count() as u64
    }
}

/// The 1-based line of the first `key = ` inside `[table]` (dotted tables like `plan.grid` allowed), else the
/// table header's line, else None.
pub fn line_of(text: &str, table: &str, key: Option<&str>) -> Option<usize> {
    let mut current = String::new();
    let mut header = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if let Some(rest) = line.strip_prefix('[') {
            let name = rest
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            current = name;
            if current == table && header.is_none() {
                header = Some(i + 1);
            }
            continue;
        }
        if current == table
            && let Some(k) = key
            && let Some(rest) = line.strip_prefix(k)
            && (rest.trim_start().starts_with('=') || rest.trim_start().starts_with('.'))
        {
            return Some(i + 1);
        }
    }
    header
}

fn at(origin: &str, text: &str, table: &str, key: Option<&str>) -> String {
    match line_of(text, table, key) {
        Some(l) => format!("{origin}:{l}"),
        None => origin.to_string(),
    }
}

fn err(origin: &str, text: &str, table: &str, key: &str, message: impl std::fmt::Display) -> CampaignError {
    CampaignError(format!(
        "{}: [{table}] {key}: {message}",
        at(origin, text, table, Some(key))
    ))
}

/// Parse and validate a campaign file against an instrument; builds its plan and schedule (deterministic:
/// the same texts always give the same points in the same order, which is what resuming relies on).
pub fn parse(
    text: &str,
    origin: &str,
    base_dir: &Path,
    file: &InstrumentFile,
) -> Result<Campaign, CampaignError> {
    let instrument = &file.instrument;
    // Syntax and unknown tables first, with the line of the offender.
    let raw: toml::Table = toml::from_str(text)
        .map_err(|e| CampaignError(format!("{origin}: not valid TOML: {}", e.to_string().trim())))?;
    for key in raw.keys() {
        if !TABLES.contains(&key.as_str()) {
            let line = text
                .lines()
                .position(|l| {
                    let l = l.trim();
                    l.starts_with(&format!("[{key}"))
                        || l.starts_with(&format!("{key} "))
                        || l.starts_with(&format!("{key}="))
                })
                .map(|i| format!(":{}", i + 1))
                .unwrap_or_default();
            return Err(CampaignError(format!(
                "{origin}{line}: unknown table or key `{key}`: expected one of {}",
                TABLES.join(", ")
            )));
        }
    }
    let sections: Sections =
        toml::from_str(text).map_err(|e| CampaignError(format!("{origin}: {}", e.to_string().trim())))?;
    let Some(campaign) = sections.campaign else {
        return Err(CampaignError(format!(
            "{origin}: missing the [campaign] table (with `id`, the sample id)"
        )));
    };
    let id = campaign.id.trim().to_string();
    if id.is_empty()
        || !id.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        || id.starts_with('.')
    {
        return Err(err(
            origin,
            text,
            "campaign",
            "id",
            format!(
                "expected a sample id of letters, digits, '-', '_' or '.' (it names the output directory), got {:?}",
                campaign.id
            ),
        ));
    }

    let doc = CampaignDoc::parse(text, origin).map_err(|e| CampaignError(plan_error(&e, origin, text)))?;

    let dry_run = instrument.devices.iter().all(|d| d.is_simulated());
    let material = match raw.get("material") {
        None => None,
        Some(toml::Value::Table(t)) if t.contains_key("preset") => {
            if t.len() != 1 {
                return Err(err(
                    origin,
                    text,
                    "material",
                    "preset",
                    "expected `preset` alone (a preset is a complete material)",
                ));
            }
            let name = t.get("preset").and_then(|v| v.as_str()).unwrap_or_default();
            Some(Material::preset(name).map_err(|e| err(origin, text, "material", "preset", e))?)
        }
        Some(_) => {
            Some(Material::from_document(text, origin, base_dir).map_err(|e| CampaignError(e.to_string()))?)
        }
    };
    if dry_run && material.is_none() {
        return Err(CampaignError(format!(
            "{origin}: the instrument {:?} is simulated, so the campaign is a dry-run and needs a [material] table \
             (the simulated sample: a material table or `preset = \"gold\"`)",
            instrument.name
        )));
    }

    let radius = doc.sample.as_ref().and_then(|s| s.radius_mm);
    let max_r = instrument.sample_holder.max_sample_radius_mm;
    if let Some(r) = radius
        && !(r.is_finite() && r > 0.0 && r <= max_r)
    {
        return Err(err(
            origin,
            text,
            "sample",
            "radius_mm",
            format!("expected a radius in (0, {max_r}] mm (the holder's largest), got {r}"),
        ));
    }
    let sample_radius_mm = radius.unwrap_or(max_r);

    let cal = sections.calibration.unwrap_or(CalibrationSection {
        method: Method::Absolute,
        reference: None,
        reference_rel_std: None,
        simulate_operator: true,
    });
    let reference = match (cal.method, &cal.reference) {
        (Method::Relative, None) => {
            return Err(err(
                origin,
                text,
                "calibration",
                "method",
                "\"relative\" needs `reference`: the reference sample's material (a preset name or a material file)",
            ));
        }
        (Method::Relative, Some(r)) => {
            let path = base_dir.join(r);
            let m = if r.ends_with(".toml") || path.is_file() {
                Material::load(&path)
            } else {
                Material::preset(r)
            }
            .map_err(|e| err(origin, text, "calibration", "reference", e))?;
            Some((r.clone(), m))
        }
        (Method::Absolute, Some(_)) => {
            return Err(err(
                origin,
                text,
                "calibration",
                "reference",
                "only used with method = \"relative\"",
            ));
        }
        (Method::Absolute, None) => None,
    };
    if cal.method == Method::Relative {
        // Parsed and checked above so the schema is stable; the engine does not run it yet.
        return Err(err(
            origin,
            text,
            "calibration",
            "method",
            "\"relative\" is not supported by this engine yet; expected \"absolute\"",
        ));
    }
    let reference_rel_std = cal.reference_rel_std.unwrap_or(0.005);
    if !(reference_rel_std.is_finite() && (0.0..1.0).contains(&reference_rel_std)) {
        return Err(err(
            origin,
            text,
            "calibration",
            "reference_rel_std",
            format!("expected a relative uncertainty in [0, 1), got {reference_rel_std}"),
        ));
    }

    let acq = sections.acquisition.unwrap_or(AcquisitionSection {
        averaging: None,
        range: None,
        settle_s: None,
        retries: None,
    });
    let averaging = acq.averaging.unwrap_or(instrument.detector.averaging);
    if averaging == 0 || averaging > 100_000 {
        return Err(err(
            origin,
            text,
            "acquisition",
            "averaging",
            format!("expected 1..=100000 samples, got {averaging}"),
        ));
    }
    let range = match &acq.range {
        None => Range::Auto,
        Some(toml::Value::String(s)) if s == "auto" => Range::Auto,
        Some(v) => match v.as_float().or_else(|| v.as_integer().map(|i| i as f64)) {
            Some(w) if w.is_finite() && w > 0.0 => Range::FixedW(w),
            _ => {
                return Err(err(
                    origin,
                    text,
                    "acquisition",
                    "range",
                    format!("expected \"auto\" or a full-scale power in W > 0, got {v}"),
                ));
            }
        },
    };
    let extra_settle_s = acq.settle_s.unwrap_or(0.0);
    if !(extra_settle_s.is_finite() && (0.0..=600.0).contains(&extra_settle_s)) {
        return Err(err(
            origin,
            text,
            "acquisition",
            "settle_s",
            format!("expected seconds in [0, 600], got {extra_settle_s}"),
        ));
    }
    let retries = acq.retries.unwrap_or(2);
    if retries > 10 {
        return Err(err(
            origin,
            text,
            "acquisition",
            "retries",
            format!("expected 0..=10, got {retries}"),
        ));
    }

    let traits = match &material {
        Some(m) => SampleTraits {
            isotropic: m.is_isotropic(),
            spectrally_flat: m.is_spectrally_flat(),
        },
        None => SampleTraits {
            isotropic: false,
            spectrally_flat: false,
        },
    };
    let ctx = BuildContext {
        instrument,
        traits,
        sample_radius_mm: Some(sample_radius_mm),
        start: None,
    };
    let built = if let Some(spec) = &doc.plan.adaptive {
        let adaptive = Adaptive::new(spec, &ctx).map_err(|e| CampaignError(plan_error(&e, origin, text)))?;
        let first = adaptive.first_pass();
        let mut iso = doc.plan.clone();
        iso.adaptive = None;
        plan::build_from_geometries(&iso, &ctx, &first, true)
    } else {
        plan::build(&doc.plan, &ctx)
    }
    .map_err(|e| CampaignError(plan_error(&e, origin, text)))?;
    let mut time = TimeModel::new(instrument);
    // The engine reads with the campaign's averaging (not the instrument file's default) and waits the
    // campaign's extra settling after every move: the prediction must use the same numbers.
    time.reading_s = gonio_scheduler::timing::reading_time_s(averaging);
    for axis in time.axes.iter_mut().flatten() {
        axis.settle_s += extra_settle_s;
    }
    let sched = schedule::schedule(&built, &time, None);
    if sched.measure_steps().next().is_none() {
        return Err(CampaignError(format!(
            "{}: [plan]: no point of the plan can be measured on instrument {:?} (all were skipped: {:?})",
            at(origin, text, "plan", None),
            instrument.name,
            built.skipped
        )));
    }
    Ok(Campaign {
        id,
        description: campaign.description,
        sample_radius_mm,
        material,
        calibration: CalibrationSettings {
            method: cal.method,
            reference,
            reference_rel_std,
            simulate_operator: cal.simulate_operator,
        },
        acquisition: Acquisition {
            averaging,
            range,
            extra_settle_s,
            retries,
        },
        plan: built,
        schedule: sched,
        time,
        dry_run,
    })
}

/// A scheduler error with the file and line of its key.
fn plan_error(e: &PlanError, origin: &str, text: &str) -> String {
    match e {
        PlanError::Parse { message, .. } => format!("{origin}: {}", message.trim()),
        PlanError::Invalid { table, key, message } => {
            let t = format!("plan{table}");
            // Keys may be dotted or indexed ("grid.theta_i_deg"); look up the first component.
            let k = key.split(['.', '[']).next().unwrap_or(key);
            format!("{}: [{t}] {key}: {message}", at(origin, text, &t, Some(k)))
        }
    }
}
