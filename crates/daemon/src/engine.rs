//! The campaign engine: runs one stored campaign on a connected [`Rig`], point by point, committing each point
//! durably, obeying [`Control`] requests at safe points, and resuming from the first uncommitted point.
//!
//! Preparing a campaign resolves the materials it names once ([`Sources`]): [`prepare_campaign`] for a local
//! file (`gonio run`: names relative to the file's directory), [`prepare_submitted_campaign`] for one submitted
//! to the daemon (presets and files inside its data directory only). What is stored is the file's text with the
//! resolved materials appended ([`PreparedCampaign::new_campaign`]), so that running and resuming read no file.
//!
//! Start-up: preparing builds the plan and orders it (for a large plan most of the time before the first point).
//! The engine runs the stored text, which must not be ordered a second time when the campaign runs right after it
//! was prepared in the same process (`gonio run`, the daemon's queue): prepared campaigns are kept, by their
//! stored text, in a small process-wide cache that the run takes them from (`take_prepared`). Only a campaign
//! whose stored text provably parses to the very same campaign is kept (see `reusable`); anything else (another
//! process, a restart, a resume after the entry was taken, a measured material whose data file the stored text
//! names) parses and orders the stored text again, which stays the source of truth.

use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::campaign::Campaign;
use crate::campaign::sources::{Resolved, material_from_stored};

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
    let prepared = PreparedCampaign {
        name: c.id.clone(),
        description: c.description.clone(),
        total_points: c.total_points(),
        dry_run: c.dry_run,
        predicted_s: c.schedule.breakdown.total_s(),
        resolved_toml: crate::campaign::sources::resolved_trailer(&c.resolved),
    };
    if reusable(&c, &prepared.resolved_toml) {
        keep_prepared(prepared.stored_campaign_toml(text), instrument, c);
    }
    Ok(prepared)
}

/// Prepared campaigns kept for their run (module doc), newest last.
static PREPARED: Mutex<Vec<Kept>> = Mutex::new(Vec::new());
/// How many prepared campaigns are kept: enough for a queue being filled while one runs; a schedule is a few
/// hundred bytes per point.
const KEEP_PREPARED: usize = 4;

struct Kept {
    stored_toml: String,
    instrument: gonio_instrument::Instrument,
    campaign: Campaign,
}

fn keep_prepared(stored_toml: String, instrument: &InstrumentFile, campaign: Campaign) {
    let mut kept = PREPARED.lock().unwrap_or_else(|e| e.into_inner());
    kept.retain(|k| k.stored_toml != stored_toml || k.instrument != instrument.instrument);
    if kept.len() >= KEEP_PREPARED {
        kept.remove(0);
    }
    kept.push(Kept {
        stored_toml,
        instrument: instrument.instrument.clone(),
        campaign,
    });
}

/// The campaign this process prepared with exactly this stored text for this instrument, if it is still kept:
/// what parsing the stored text would give (see `reusable`), without ordering its plan again. Taken out of the
/// cache: a later run of the same text (a resume) parses it.
pub(crate) fn take_prepared(stored_toml: &str, instrument: &InstrumentFile) -> Option<Campaign> {
    let mut kept = PREPARED.lock().unwrap_or_else(|e| e.into_inner());
    let at = kept
        .iter()
        .position(|k| k.stored_toml == stored_toml && k.instrument == instrument.instrument)?;
    Some(kept.remove(at).campaign)
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

/// Run (or resume from `store.next_index(id)`) one stored campaign to a final or paused state.
pub async fn run_campaign(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &Rig,
    control: Control,
) -> Result<CampaignState, EngineError> {
    crate::runner::run(store, id, rig, control).await
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

    /// Prepare `text`, then compare what the run would take from the cache with what parsing the stored text
    /// gives: the same campaign down to every step's time and pose (debug forms hold every value exactly).
    fn prepared_equals_stored_parse(text: &str, dir: &Path) {
        let file = InstrumentFile::simulated();
        let prepared = prepare_campaign(text, "campaign.toml", dir, &file).expect("prepare");
        let stored = prepared.stored_campaign_toml(text);
        let kept = take_prepared(&stored, &file).expect("kept for the run");
        let parsed =
            crate::campaign::parse(&stored, "<stored>", &Sources::Stored, &file).expect("stored parse");
        assert!(kept.schedule.steps.len() > 10);
        assert_eq!(format!("{kept:?}"), format!("{parsed:?}"));
        // Taken: a second run of the same text (a resume) parses the stored text.
        assert!(take_prepared(&stored, &file).is_none());
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
        assert!(take_prepared(&stored, &other).is_none());
        assert!(take_prepared(&t, &file).is_none());
        assert!(take_prepared(&stored, &file).is_some());

        // A material whose stored description names a data file is read again by the stored parse: not reusable.
        let mut c = crate::campaign::parse(&t, "campaign.toml", &Sources::Local(dir.path().into()), &file)
            .expect("parse");
        let trailer = crate::campaign::sources::resolved_trailer(&c.resolved);
        assert!(reusable(&c, &trailer));
        if let Some(spec) = c.resolved.material.as_mut() {
            spec.file = Some("/data/sample.binary".into());
        }
        let trailer = crate::campaign::sources::resolved_trailer(&c.resolved);
        assert!(!reusable(&c, &trailer));
        // A table that does not describe the prepared material (here: another albedo) is not reusable either.
        let mut c = crate::campaign::parse(&t, "campaign.toml", &Sources::Local(dir.path().into()), &file)
            .expect("parse");
        let honest = crate::campaign::sources::resolved_trailer(&c.resolved);
        c.resolved.material = Material::preset("spectralon").ok().map(|m| m.spec());
        assert!(!reusable(
            &c,
            &crate::campaign::sources::resolved_trailer(&c.resolved)
        ));
        assert!(!reusable(&c, &honest));
    }
}
