//! A daemon started with an alignment calibration (`gonio daemon --calibration`) stores it with every campaign
//! submitted to it, so that the run loop applies it (and a resume applies the same one). The calibration here is
//! a real one: `gonio align`'s procedure run on the same simulated instrument.

use gonio_brdf::material::Material;
use gonio_daemon::service::{CampaignRunner, EngineRunner};
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::align::{Placement, run_alignment};
use gonio_engine::control::Control;
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_scheduler::timing::TimeModel;

const DEMO: &str = include_str!("../../../config/campaigns/demo.toml");

#[tokio::test(start_paused = true)]
async fn a_daemon_with_an_alignment_stores_it_with_every_submitted_campaign() {
    let file = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let mirror = Material::preset("mirror").expect("mirror");
    let holder = rig
        .alignment_holder(&mirror, None, 25.0)
        .expect("holder")
        .expect("dry-run");
    let operator = |p: Placement| {
        holder.hold(p.held());
        Ok(())
    };
    let mut motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
    let report = run_alignment(&mut motion, &operator, Default::default())
        .await
        .expect("alignment");
    drop(motion);
    let text = CalibrationFile::from_report(&report, SIMULATED_INSTRUMENT_TOML, 1.8e9)
        .to_toml()
        .expect("toml");
    CalibrationFile::parse(&text, "cal")
        .expect("reads back")
        .check_instrument(SIMULATED_INSTRUMENT_TOML, "cal")
        .expect("made for this instrument file");

    let dir = tempfile::tempdir().expect("tempdir");
    let aligned = EngineRunner::new(
        file.clone(),
        SIMULATED_INSTRUMENT_TOML.to_string(),
        dir.path().to_path_buf(),
        rig.clone(),
    )
    .with_alignment(Some(text.clone()));
    let submission = aligned.prepare(DEMO, "demo.toml").expect("prepared");
    assert_eq!(submission.campaign.alignment_toml.as_deref(), Some(text.as_str()));

    let plain = EngineRunner::new(
        file,
        SIMULATED_INSTRUMENT_TOML.to_string(),
        dir.path().to_path_buf(),
        rig,
    );
    let submission = plain.prepare(DEMO, "demo.toml").expect("prepared");
    assert_eq!(submission.campaign.alignment_toml, None);
}
