//! The service handing the instrument to one owner at a time: a person holding it keeps the queue waiting, and a
//! running campaign keeps the person waiting.

use std::sync::Arc;
use std::time::Duration;

use gonio_daemon::service::{EngineRunner, Service, ServiceError, ShutdownTrigger};
use gonio_engine::control::Control;
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;
use gonio_engine::store::{CampaignState, Store};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_scheduler::kinematics::Pose;
use gonio_testkit::CampaignText;

/// Under the paused clock a hang becomes this timeout at once.
const NO_HANG: Duration = Duration::from_secs(24 * 3600);

fn assert_at(motion: &Motion<'_>, target: &Pose) {
    let rig = motion.rig();
    for (a, read) in rig.axes().iter().zip(motion.readback_deg()) {
        let want = target.get(a.config.role);
        assert!(
            (read - want).abs() <= a.config.tolerance_deg,
            "{} reads {read} deg, target {want} deg",
            a.config.name
        );
    }
}

fn service_on(rig: &Rig, data: &std::path::Path) -> Service {
    let runner = Arc::new(EngineRunner::new(
        InstrumentFile::simulated(),
        SIMULATED_INSTRUMENT_TOML.to_string(),
        data.to_path_buf(),
        rig.clone(),
    ));
    Service::new(Store::open(data).expect("store"), runner, Control::new()).expect("service")
}

async fn wait_state(service: &Service, id: gonio_engine::store::CampaignId, want: CampaignState) {
    while service.campaign(id).expect("campaign").state != want {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(start_paused = true)]
async fn the_service_hands_the_instrument_to_one_owner_at_a_time() {
    tokio::time::timeout(NO_HANG, one_owner()).await.expect("no hang");
}

async fn one_owner() {
    let file = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let data = tempfile::tempdir().expect("tempdir");
    let service = service_on(&rig, data.path());
    let trigger = ShutdownTrigger::new();
    let (done_tx, _done_rx) = tokio::sync::mpsc::channel(1);
    let queue = {
        let (service, shutdown) = (service.clone(), trigger.subscribe());
        tokio::spawn(async move { service.run_queue(shutdown, done_tx).await })
    };

    // A person takes the instrument and moves the arms; a campaign submitted meanwhile waits in the queue.
    let lease = service
        .take_instrument("alignment console")
        .expect("nothing runs");
    assert_eq!(service.instrument_holder().as_deref(), Some("alignment console"));
    assert!(matches!(
        service.take_instrument("someone else"),
        Err(ServiceError::Conflict(_))
    ));
    let text = CampaignText::in_plane("handoff", 4).to_string();
    let id = service.submit(&text, "handoff.toml").expect("submitted");
    {
        let mut motion = lease.motion(2).expect("the daemon's instrument");
        motion.reference_all().await.expect("referenced");
        let target = Pose::new(-50.0, 35.0, 0.0, 0.0);
        motion.move_to(&target).await.expect("moved");
        motion.read_positions().await.expect("read back");
        assert_at(&motion, &target);
    }
    tokio::time::sleep(Duration::from_secs(30)).await;
    assert_eq!(
        service.campaign(id).expect("campaign").state,
        CampaignState::Queued
    );
    assert_eq!(service.campaign(id).expect("campaign").points_done, 0);

    // Handed back: the queue starts the campaign; while it runs, nobody can take the instrument.
    drop(lease);
    assert_eq!(service.instrument_holder(), None);
    wait_state(&service, id, CampaignState::Running).await;
    match service.take_instrument("alignment console") {
        Err(ServiceError::Conflict(why)) => assert!(why.contains("pause it first"), "{why}"),
        other => panic!("expected a conflict, got {other:?}"),
    }
    wait_state(&service, id, CampaignState::Completed).await;
    let view = service.campaign(id).expect("campaign");
    assert_eq!(view.points_done, view.total_points);
    // Free again once the campaign is done.
    drop(service.take_instrument("alignment console").expect("free again"));

    trigger.trigger();
    queue.await.expect("queue task");
}
