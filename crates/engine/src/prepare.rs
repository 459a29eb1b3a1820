//! Preparing a campaign for the engine: validated, planned and ordered, with what the store keeps of it.
//!
//! Preparing a campaign ([`gonio_campaign::prepare`], through [`prepare_campaign`] for a local file or
//! [`prepare_submitted_campaign`] for one submitted to the daemon) resolves the materials it names once
//! ([`Sources`]). What is stored is the file's text with the resolved materials appended
//! ([`PreparedCampaign::new_campaign`]), so that running and resuming read no file.
//!
//! Start-up: preparing builds the plan and orders it (for a large plan most of the time before the first point).
//! A campaign run right after it was prepared (`gonio run`, the daemon's queue) need not be ordered a second
//! time: the [`PreparedCampaign`] value carries the prepared campaign to [`run_prepared_campaign`](crate::runner::run_prepared_campaign) when the
//! stored text provably parses to the very same campaign (see `reusable`). Anything else (another process, a
//! restart, a resume, a measured material whose data file the stored text names) parses and orders the stored
//! text again, which stays the source of truth.

use std::path::Path;
use std::sync::Arc;

use gonio_campaign::sources::{Resolved, material_from_stored, resolved_trailer};
use gonio_campaign::{Campaign, Prepared};

use crate::error::EngineError;
use crate::store::NewCampaign;
use gonio_campaign::Sources;
use gonio_instrument::InstrumentFile;

/// What the service needs to store a new campaign, and the prepared campaign for its first run.
#[derive(Debug, Clone)]
pub struct PreparedCampaign {
    /// The campaign (sample) id from `[campaign] id`.
    pub name: String,
    pub description: Option<String>,
    /// Points the campaign measures (an adaptive campaign: its budget, the most it measures).
    pub total_points: u64,
    /// Sweep segments the campaign measures after its points (`[[plan.sweeps]]`: each arc once per band, each a
    /// store transaction); 0 without sweeps.
    pub sweep_segments: u64,
    pub dry_run: bool,
    /// Predicted instrument time (s) from the time model (an adaptive campaign: its whole budget).
    pub predicted_s: f64,
    /// Appended to the campaign text when it is stored: the `[resolved]` materials (empty when it names none).
    pub resolved_toml: String,
    /// The prepared campaign, when the stored text provably parses to it (`reusable`), with the stored text and
    /// the instrument it was prepared for: the run takes it instead of planning and ordering again.
    kept: Option<Arc<Kept>>,
}

#[derive(Debug)]
struct Kept {
    stored_toml: String,
    instrument: gonio_instrument::Instrument,
    prepared: Prepared,
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
            predicted_instrument_s: Some(self.predicted_s),
            alignment_toml: None,
            calibration_id: None,
        }
    }

    /// The campaign text as it is stored: `campaign_toml` followed by the resolved materials.
    pub fn stored_campaign_toml(&self, campaign_toml: &str) -> String {
        format!("{campaign_toml}{}", self.resolved_toml)
    }

    /// The prepared campaign for a stored campaign with this text on this instrument, if it is the one this value
    /// carries: what parsing the stored text would give, without ordering its plan again.
    pub(crate) fn reuse_for(&self, stored_toml: &str, instrument: &InstrumentFile) -> Option<Prepared> {
        self.kept
            .as_ref()
            .filter(|k| k.stored_toml == stored_toml && k.instrument == instrument.instrument)
            .map(|k| k.prepared.clone())
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

/// Validate a campaign to run, with names resolving under `sources`.
pub fn prepare_campaign_with(
    text: &str,
    origin: &str,
    sources: &Sources,
    instrument: &InstrumentFile,
) -> Result<PreparedCampaign, EngineError> {
    let p = gonio_campaign::load_and_prepare(text, origin, sources, instrument)?;
    p.require_sample(&instrument.instrument)?;
    let c = &p.campaign;
    let resolved_toml = resolved_trailer(&c.resolved);
    let mut prepared = PreparedCampaign {
        name: c.id.clone(),
        description: c.description.clone(),
        total_points: p.total_points(),
        sweep_segments: p.sweeps.as_ref().map_or(0, |s| s.schedule.steps.len() as u64),
        dry_run: c.dry_run,
        predicted_s: p.predicted_s(),
        resolved_toml,
        kept: None,
    };
    if reusable(c, &prepared.resolved_toml) {
        prepared.kept = Some(Arc::new(Kept {
            stored_toml: prepared.stored_campaign_toml(text),
            instrument: instrument.instrument.clone(),
            prepared: p,
        }));
    }
    Ok(prepared)
}

/// True when parsing the stored text (the prepared text with `resolved_toml` appended, materials from its
/// `[resolved]` table) gives `c` again. The rest of the parse reads the same text against the same instrument
/// and is deterministic; only the materials come from elsewhere (the `[resolved]` table instead of the presets
/// and files named), so they must come back identical: the table read back from its text equals what was
/// resolved, and each material rebuilt from it equals the material prepared (their full debug forms, which hold
/// every parameter with its exact value). A measured material's data file is read again by the stored parse:
/// such campaigns are not reused.
fn reusable(c: &Campaign, resolved_toml: &str) -> bool {
    if resolved_toml.is_empty() {
        return c.material.is_none() && c.calibration.reference.is_none();
    }
    let Ok(table) = toml::from_str::<toml::Table>(resolved_toml) else {
        return false;
    };
    let Some(Ok(resolved)) = table.get("resolved").map(|v| v.clone().try_into::<Resolved>()) else {
        return false;
    };
    if resolved != c.resolved {
        return false;
    }
    let same = |spec: Option<&gonio_brdf::material::MaterialSpec>,
                m: Option<&gonio_brdf::material::Material>| {
        match (spec, m) {
            (None, None) => true,
            (Some(spec), Some(m)) if spec.file.is_none() => {
                material_from_stored(spec).is_ok_and(|back| format!("{back:?}") == format!("{m:?}"))
            }
            _ => false,
        }
    };
    same(resolved.material.as_ref(), c.material.as_ref())
        && same(
            resolved.reference.as_ref(),
            c.calibration.reference.as_ref().map(|r| &r.material),
        )
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_brdf::material::Material;

    const GRID: &str = r#"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [450.0, 650.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 20.0 }
theta_o_deg = { from = 0.0, to = 60.0, step = 20.0 }
delta_phi_deg = { from = 0.0, to = 180.0, step = 60.0 }
[plan.calibration]
dark_every_points = 20
"#;

    /// A GGX conductor written out in the campaign (no preset), with spectral tables.
    const INLINE_GOLDISH: &str = r#"
[material]
model = "conductor"
distribution = "ggx"
masking = "height-correlated"
alpha = 0.17
eta = { 450 = 1.3, 550 = 0.43, 650 = 0.17 }
k = { 450 = 1.9, 550 = 2.45, 650 = 3.6 }
"#;

    fn text(id: &str, rest: &str) -> String {
        format!("[campaign]\nid = \"{id}\"\n{GRID}{rest}")
    }

    /// Prepare `text`, then compare what the run would take from the prepared value with what parsing the
    /// stored text gives: the same campaign down to every step's time and pose (debug forms hold every value
    /// exactly) except the text itself and its origin.
    fn prepared_equals_stored_parse(text: &str, dir: &Path) {
        let file = InstrumentFile::simulated();
        let prepared = prepare_campaign(text, "campaign.toml", dir, &file).expect("prepare");
        let stored = prepared.stored_campaign_toml(text);
        let mut kept = prepared.reuse_for(&stored, &file).expect("kept for the run");
        let parsed = gonio_campaign::load_and_prepare(&stored, "<stored>", &Sources::Stored, &file)
            .expect("stored parse");
        assert!(kept.schedule.steps.len() > 10);
        // What differs by construction: where the text came from, and the stored `[resolved]` table.
        kept.campaign.origin = parsed.campaign.origin.clone();
        kept.campaign.text = parsed.campaign.text.clone();
        kept.campaign.file.resolved = parsed.campaign.file.resolved.clone();
        assert_eq!(format!("{kept:?}"), format!("{parsed:?}"));
    }

    #[test]
    fn a_prepared_campaign_is_what_its_stored_text_parses_to() {
        let dir = tempfile::tempdir().expect("tempdir");
        prepared_equals_stored_parse(
            &text("cache-preset", "[material]\npreset = \"coloured-plastic\"\n"),
            dir.path(),
        );
        prepared_equals_stored_parse(&text("cache-inline", INLINE_GOLDISH), dir.path());
        // Relative method: the reference from a material file next to the campaign.
        std::fs::write(
            dir.path().join("white.toml"),
            "[material]\nmodel = \"lambertian\"\nalbedo = { 400 = 0.98, 550 = 0.99, 700 = 0.987 }\n",
        )
        .expect("write");
        let relative = format!(
            "{}[calibration]\nmethod = \"relative\"\nreference = \"white.toml\"\n",
            text("cache-relative", "[material]\npreset = \"gold\"\n")
        );
        prepared_equals_stored_parse(&relative, dir.path());
    }

    #[test]
    fn only_provably_identical_campaigns_are_kept_and_only_for_their_instrument() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = InstrumentFile::simulated();
        let t = text("cache-instrument", "[material]\npreset = \"white-styrofoam\"\n");
        let prepared = prepare_campaign(&t, "campaign.toml", dir.path(), &file).expect("prepare");
        let stored = prepared.stored_campaign_toml(&t);
        // Another instrument description, or another text, does not match.
        let mut other = file.clone();
        other.instrument.name.push_str(" (modified)");
        assert!(prepared.reuse_for(&stored, &other).is_none());
        assert!(prepared.reuse_for(&t, &file).is_none());
        assert!(prepared.reuse_for(&stored, &file).is_some());

        // A material whose stored description names a data file is read again by the stored parse: not reusable.
        let mut c = gonio_campaign::load(&t, "campaign.toml", &Sources::Local(dir.path().into()), &file)
            .expect("parse");
        let trailer = resolved_trailer(&c.resolved);
        assert!(reusable(&c, &trailer));
        if let Some(spec) = c.resolved.material.as_mut() {
            spec.file = Some("/data/sample.binary".into());
        }
        let trailer = resolved_trailer(&c.resolved);
        assert!(!reusable(&c, &trailer));
        // A table that does not describe the prepared material (here: another albedo) is not reusable either.
        let mut c = gonio_campaign::load(&t, "campaign.toml", &Sources::Local(dir.path().into()), &file)
            .expect("parse");
        let honest = resolved_trailer(&c.resolved);
        c.resolved.material = Material::preset("spectralon").ok().map(|m| m.spec());
        assert!(!reusable(&c, &resolved_trailer(&c.resolved)));
        assert!(!reusable(&c, &honest));
    }
}
