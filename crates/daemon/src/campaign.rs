//! The campaign file: what to measure and how, validated with messages that name the file, the line, the key
//! and what was expected.
//!
//! Tables (see config/campaigns/demo.toml, relative.toml and template.toml for commented examples):
//! - `[campaign]` `id` (the sample id; names the run), `description`.
//! - `[sample]` `radius_mm`.
//! - `[plan]` the scheduler's schema (grid, bands, repeats, `[plan.calibration]` cadence of darks and
//!   normalisation readings: direct-beam readings for the absolute method, reference-sample readings for the
//!   relative one).
//! - `[calibration]` `method` ("absolute": direct-beam readings; "relative": against a reference sample),
//!   `reference` (relative: a material preset name or a material file), `reference_rel_std` (relative standard
//!   uncertainty of the reference's BRDF, default 0.005), `reference_geometry_deg` (relative: the geometry
//!   `[theta_i, phi_i, theta_o, phi_o]` the reference is read at, default `[0.0, 0.0, 45.0, 180.0]`, the 0/45
//!   geometry of reflectance standards), `simulate_operator` (dry-runs: the simulated operator swaps samples;
//!   default true).
//! - `[acquisition]` `averaging` (samples per reading), `range` ("auto" or a full-scale power in W),
//!   `settle_s` (extra settling after arrival, on top of each axis' own), `retries` (per device operation).
//! - `[material]` the simulated sample for dry-runs: a material table as in config/materials/, or
//!   `preset = "<name>"`.
//! - `[resolved]` is not written by people: gonio appends it when it stores a campaign (see [`sources`]).
//!
//! Material and reference names resolve by [`Sources`]: against the campaign file's directory for a local file,
//! inside the daemon's data directory only for a submitted one, and from the stored `[resolved]` table (never
//! the file system) when a stored campaign is read back to run or resume.

pub mod sources;

use std::path::{Path, PathBuf};

use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Wavelength};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::adaptive::Adaptive;
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_scheduler::plan::{self, BuildContext, CampaignDoc, Plan, PlanError, SampleTraits};
use gonio_scheduler::schedule::{self, Schedule};
use gonio_scheduler::timing::TimeModel;
use serde::Deserialize;

pub use sources::Sources;
use sources::{Resolved, is_preset};

/// The default reference geometry of the relative method: normal incidence, detector at 45 degrees (0/45).
pub const DEFAULT_REFERENCE_GEOMETRY_DEG: [f64; 4] = [0.0, 0.0, 45.0, 180.0];

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
    #[serde(default)]
    reference_geometry_deg: Option<toml::Value>,
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

/// The relative method's reference sample.
#[derive(Debug, Clone)]
pub struct Reference {
    /// As written in the campaign (`[calibration] reference`): a preset name or a file name.
    pub name: String,
    /// Its BRDF, angular shape included.
    pub material: Material,
    /// Where it is read: a geometry every band's reading of the reference is taken at.
    pub geometry: Geometry,
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
    /// The materials as resolved: what [`sources::resolved_trailer`] stores with the campaign.
    pub resolved: Resolved,
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
/// `sources` says how material and reference names resolve (module doc).
pub fn parse(
    text: &str,
    origin: &str,
    sources: &Sources,
    file: &InstrumentFile,
) -> Result<Campaign, CampaignError> {
    let instrument = &file.instrument;
    // Syntax and unknown tables first, with the line of the offender.
    let raw: toml::Table = toml::from_str(text)
        .map_err(|e| CampaignError(format!("{origin}: not valid TOML: {}", e.to_string().trim())))?;
    for key in raw.keys() {
        if key == "resolved" {
            continue;
        }
        if !TABLES.contains(&key.as_str()) {
            return Err(CampaignError(format!(
                "{origin}{}: unknown table or key `{key}`: expected one of {}",
                top_level_line(text, key),
                TABLES.join(", ")
            )));
        }
    }
    // `[resolved]`: only in a stored campaign (gonio wrote it). A stored campaign without it predates it: its
    // names resolve as they always did, against the current directory.
    let stored: Option<Resolved> = match (sources, raw.get("resolved")) {
        (Sources::Stored, Some(v)) => Some(v.clone().try_into::<Resolved>().map_err(|e| {
            CampaignError(format!(
                "{origin}{}: [resolved]: {}",
                top_level_line(text, "resolved"),
                e.to_string().trim()
            ))
        })?),
        (_, Some(_)) => {
            return Err(CampaignError(format!(
                "{origin}{}: unknown table `resolved`: gonio adds it when it stores a campaign; remove it (the \
                 [material] and [calibration] reference it was made from are resolved again)",
                top_level_line(text, "resolved")
            )));
        }
        _ => None,
    };
    let sources = match (sources, &stored) {
        (Sources::Stored, None) => Sources::Local(PathBuf::from(".")),
        (s, _) => s.clone(),
    };
    let base = sources::base_dir(&sources).map_err(|e| CampaignError(format!("{origin}: {e}")))?;

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
    let material = match &stored {
        Some(r) => r
            .material
            .as_ref()
            .map(sources::material_from_stored)
            .transpose()
            .map_err(|e| CampaignError(format!("{origin}: [resolved] material: {e}")))?,
        None => sample_material(&raw, text, origin, &sources, &base)?,
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
        reference_geometry_deg: None,
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
            let m = match &stored {
                Some(s) => s
                    .reference
                    .as_ref()
                    .ok_or_else(|| "the stored campaign has no [resolved] reference".to_string())
                    .and_then(sources::material_from_stored),
                None => reference_material(r, &sources, &base),
            }
            .map_err(|e| err(origin, text, "calibration", "reference", e))?;
            let geometry = reference_geometry(cal.reference_geometry_deg.as_ref())
                .map_err(|e| err(origin, text, "calibration", "reference_geometry_deg", e))?;
            Some(Reference {
                name: r.clone(),
                material: m,
                geometry,
            })
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
    if cal.method == Method::Absolute && cal.reference_geometry_deg.is_some() {
        return Err(err(
            origin,
            text,
            "calibration",
            "reference_geometry_deg",
            "only used with method = \"relative\" (the absolute method reads the direct beam at \
             [plan.calibration] reference_pose_deg)",
        ));
    }
    if cal.method == Method::Relative && doc.plan.calibration.reference_pose_deg.is_some() {
        return Err(err(
            origin,
            text,
            "plan.calibration",
            "reference_pose_deg",
            "is the direct-beam pose of the absolute method; with method = \"relative\" the reference sample is \
             read at [calibration] reference_geometry_deg",
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
    if let Some(r) = &reference {
        let mut bands = built.bands_nm.clone();
        if bands.is_empty() {
            bands.extend(instrument.source.wavelength_nm);
        }
        check_reference(r, &bands, instrument, sample_radius_mm)
            .map_err(|(key, e)| err(origin, text, "calibration", key, e))?;
    }
    let resolved = Resolved {
        material: material.as_ref().map(Material::spec),
        reference: reference.as_ref().map(|r| r.material.spec()),
    };
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
        resolved,
    })
}

/// The `: LINE` of the first line that opens top-level table or key `key`, or nothing.
fn top_level_line(text: &str, key: &str) -> String {
    text.lines()
        .position(|l| {
            let l = l.trim();
            l.starts_with(&format!("[{key}"))
                || l.starts_with(&format!("{key} "))
                || l.starts_with(&format!("{key}="))
                || l.starts_with(&format!("{key}."))
        })
        .map(|i| format!(":{}", i + 1))
        .unwrap_or_default()
}

/// The `[material]` table (the simulated sample), with its names resolved under `sources`.
fn sample_material(
    raw: &toml::Table,
    text: &str,
    origin: &str,
    sources: &Sources,
    base: &Path,
) -> Result<Option<Material>, CampaignError> {
    match raw.get("material") {
        None => Ok(None),
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
            Ok(Some(
                Material::preset(name).map_err(|e| err(origin, text, "material", "preset", e))?,
            ))
        }
        Some(t) => {
            // A measured material reads its data file: check the name against the policy first.
            if let Some(f) = t.get("file").and_then(|v| v.as_str()) {
                sources::file_path(sources, base, f).map_err(|e| err(origin, text, "material", "file", e))?;
            }
            Ok(Some(
                Material::from_document(text, origin, base).map_err(|e| CampaignError(e.to_string()))?,
            ))
        }
    }
}

/// `[calibration] reference`: a preset name or a material file (whose own data file, for a measured material,
/// resolves against its directory), under `sources`.
fn reference_material(name: &str, sources: &Sources, base: &Path) -> Result<Material, String> {
    let is_file = match sources {
        // Nothing outside the data directory may be probed: a name is a preset, or a path to confine.
        Sources::Confined(_) => !is_preset(name),
        _ => name.ends_with(".toml") || base.join(name).is_file(),
    };
    if !is_file {
        return Material::preset(name).map_err(|e| e.to_string());
    }
    let path = sources::file_path(sources, base, name).map_err(|e| {
        if name.ends_with(".toml") || name.contains(['/', '\\']) {
            e
        } else {
            format!(
                "{e} (nor is it a preset: {})",
                Material::preset_names().join(", ")
            )
        }
    })?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("cannot read the reference material file {}: {e}", path.display()))?;
    if let Some(f) = sources::material_data_file(&text) {
        sources::file_path(sources, &dir, &f)
            .map_err(|e| format!("{}: [material] file: {e}", path.display()))?;
    }
    Material::from_document(&text, &path.display().to_string(), &dir).map_err(|e| e.to_string())
}

/// `[calibration] reference_geometry_deg = [theta_i, phi_i, theta_o, phi_o]`, default 0/45.
fn reference_geometry(v: Option<&toml::Value>) -> Result<Geometry, String> {
    let Some(v) = v else {
        let [ti, pi, to, po] = DEFAULT_REFERENCE_GEOMETRY_DEG;
        return Ok(Geometry::new(ti, pi, to, po));
    };
    let expected = "expected [theta_i, phi_i, theta_o, phi_o] in degrees";
    let items = v.as_array().ok_or_else(|| format!("{expected}, got {v}"))?;
    let numbers: Vec<f64> = items
        .iter()
        .map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
        .collect::<Option<Vec<f64>>>()
        .filter(|n| n.len() == 4 && n.iter().all(|x| x.is_finite()))
        .ok_or_else(|| format!("{expected}, got {v}"))?;
    match numbers.as_slice() {
        [ti, pi, to, po] => Ok(Geometry::new(*ti, *pi, *to, *po)),
        _ => Err(format!("{expected}, got {v}")),
    }
}

/// The reference can be read where it is asked to be, and normalises every band: the geometry passes the
/// instrument's rules and has an axis solution, the material covers every band, and its BRDF there is positive.
/// Err: (key, message).
fn check_reference(
    r: &Reference,
    bands_nm: &[f64],
    instrument: &gonio_instrument::Instrument,
    sample_radius_mm: f64,
) -> Result<(), (&'static str, String)> {
    let (wi, wo) = r.geometry.directions();
    Constraints::new(instrument, Some(sample_radius_mm))
        .check_directions(&wi, &wo)
        .map_err(|reason| {
            (
                "reference_geometry_deg",
                format!(
                    "the reference cannot be read at {:?} on instrument {:?}: {}",
                    r.geometry,
                    instrument.name,
                    reason.name()
                ),
            )
        })?;
    let poses = Kinematics::new(instrument)
        .solutions(&wi, &wo, &Pose::new(0.0, 0.0, 0.0, 0.0))
        .map_err(|e| ("reference_geometry_deg", format!("no axis solution: {e}")))?;
    if poses.is_empty() {
        return Err(("reference_geometry_deg", "no axis solution".into()));
    }
    for nm in bands_nm {
        let wl = Wavelength::from_nm(*nm).map_err(|e| ("reference", e.to_string()))?;
        let f = r
            .material
            .eval(&wi, &wo, wl)
            .map_err(|e| ("reference", format!("{:?} at {nm} nm: {e}", r.name)))?;
        if !(f.is_finite() && f > 0.0) {
            return Err((
                "reference",
                format!(
                    "{:?} has BRDF {f} 1/sr at the reference geometry at {nm} nm: a reference must reflect \
                     there to normalise",
                    r.name
                ),
            ));
        }
    }
    Ok(())
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
