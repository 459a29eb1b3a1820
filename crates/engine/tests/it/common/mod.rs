//! Shared by the engine's integration tests: `gonio align`'s procedure on a dry-run rig, the simulated operator
//! making each placement; a campaign run to its end on a dry-run rig.

use gonio_brdf::material::Material;
use gonio_engine::align::{AlignOptions, AlignmentReport, OperatorStep, Placement, run_alignment};
use gonio_engine::control::Control;
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::timing::TimeModel;

/// The alignment with `options` on `file`, the preset `mirror` as the alignment mirror and `sample` (a preset)
/// as the sample: the rig (its optics show what the holder holds at the end) and the report, or the refusal's
/// message.
pub async fn dry_run_alignment(
    file: &InstrumentFile,
    mirror: &str,
    sample: Option<&str>,
    options: AlignOptions,
) -> (Rig, Result<AlignmentReport, String>) {
    let rig = Rig::connect_with_time_scale(file, None, 1.0).await.expect("rig");
    let mirror = Material::preset(mirror).expect("preset");
    let sample = sample.map(|s| Material::preset(s).expect("preset"));
    let holder = rig
        .alignment_holder(&mirror, sample.as_ref(), 25.0)
        .expect("holder")
        .expect("dry-run");
    let operator = |p: Placement| -> OperatorStep<'_> {
        holder.hold(p.held());
        Box::pin(std::future::ready(Ok(())))
    };
    let mut motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
    let report = run_alignment(&mut motion, &operator, options)
        .await
        .map_err(|e| e.to_string());
    drop(motion);
    (rig, report)
}

/// `campaign` (its text) prepared on `file`, stored in `dir` and run on a dry-run rig to its end: the store, the
/// campaign's id and the state it ended in.
pub async fn run_campaign_text(
    dir: &std::path::Path,
    campaign: &str,
    file: &InstrumentFile,
) -> (
    std::sync::Arc<std::sync::Mutex<gonio_engine::store::Store>>,
    gonio_engine::store::CampaignId,
    gonio_engine::store::CampaignState,
) {
    let prepared = gonio_engine::prepare_campaign(campaign, "c.toml", dir, file).expect("valid campaign");
    let instrument_text = toml::to_string(file).expect("toml");
    let mut store = gonio_engine::store::Store::open(dir).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(campaign, &instrument_text))
        .expect("create");
    let store = std::sync::Arc::new(std::sync::Mutex::new(store));
    let rig = Rig::connect_with_time_scale(file, None, 1.0).await.expect("rig");
    let state = gonio_engine::run_campaign(std::sync::Arc::clone(&store), id, &rig, Control::new())
        .await
        .expect("run");
    (store, id, state)
}
