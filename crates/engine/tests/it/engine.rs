//! The engine in process on the simulated instrument under tokio's paused clock: operator confirmation, pause,
//! resume, abort and emergency stop through `Control`, and a device fault.

use std::sync::{Arc, Mutex};

use gonio_engine::store::{CampaignId, CampaignState, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_campaign};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};

const CAMPAIGN: &str = r#"
[campaign]
id = "engine-test"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [550.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 30.0 }
theta_o_deg = { from = 0.0, to = 60.0, step = 30.0 }
delta_phi_deg = { from = 0.0, to = 180.0, step = 90.0 }
[calibration]
simulate_operator = false
[material]
preset = "spectralon"
"#;

fn setup(file: &InstrumentFile, dir: &std::path::Path) -> (Arc<Mutex<Store>>, CampaignId, u64) {
    let prepared = prepare_campaign(CAMPAIGN, "engine-test.toml", dir, file).expect("valid campaign");
    let mut store = Store::open(dir).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(CAMPAIGN, SIMULATED_INSTRUMENT_TOML))
        .expect("create");
    (Arc::new(Mutex::new(store)), id, prepared.total_points)
}

async fn next_state(rx: &mut tokio::sync::broadcast::Receiver<Event>) -> (CampaignState, Option<String>) {
    loop {
        match rx.recv().await.expect("event") {
            Event::State { state, message, .. } => return (state, message),
            _ => continue,
        }
    }
}

async fn wait_points(rx: &mut tokio::sync::broadcast::Receiver<Event>, n: u64) {
    loop {
        if let Event::Point { point, .. } = rx.recv().await.expect("event")
            && point.index + 1 >= n
        {
            return;
        }
    }
}

#[tokio::test(start_paused = true)]
async fn confirm_pause_resume_abort_and_estop_through_control() {
    // Under the paused clock a hang becomes this timeout at once.
    tokio::time::timeout(std::time::Duration::from_secs(24 * 3600), control_sequence())
        .await
        .expect("no hang");
}

async fn control_sequence() {
    let file = InstrumentFile::simulated();
    let dir = tempfile::tempdir().expect("tempdir");
    let (store, id, total) = setup(&file, dir.path());
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let control = Control::new();
    let mut rx = control.subscribe();

    let task = {
        let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Running);
    // Remove the sample: the engine waits, the sample is still mounted, nothing is measured.
    let (state, message) = next_state(&mut rx).await;
    assert_eq!(state, CampaignState::WaitingOperator);
    assert!(message.unwrap_or_default().contains("remove the sample"));
    let optics = rig.optics().expect("dry-run optics");
    assert!(optics.sample_mounted());
    assert_eq!(
        store.lock().expect("lock").campaign(id).expect("c").state,
        CampaignState::WaitingOperator
    );
    control.confirm();
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Running);
    let second = next_state(&mut rx).await;
    assert_eq!(second.0, CampaignState::WaitingOperator, "{second:?}");
    assert!(
        !optics.sample_mounted(),
        "the simulated operator's removal follows the confirmation"
    );
    control.confirm();
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Running);
    assert!(optics.sample_mounted());

    wait_points(&mut rx, 2).await;
    control.pause();
    let state = task.await.expect("join").expect("run");
    assert_eq!(state, CampaignState::Paused);
    let done = store.lock().expect("lock").next_index(id).expect("next");
    assert!(done >= 2 && done < total, "{done} of {total}");

    // Resume: calibration again (two confirmations), then an emergency stop once a new point is in.
    let task = {
        let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    loop {
        match rx.recv().await.expect("event") {
            Event::State {
                state: CampaignState::WaitingOperator,
                ..
            } => control.confirm(),
            Event::Point { point, .. } if point.index >= done => break,
            _ => {}
        }
    }
    control.estop();
    let state = task.await.expect("join").expect("run");
    assert_eq!(state, CampaignState::Paused);
    let rec = store.lock().expect("lock").campaign(id).expect("c");
    assert_eq!(rec.last_error.as_deref(), Some("emergency stop"));
    let after_estop = rec.points_done;
    assert!(after_estop > done);

    // Abort while waiting for the operator: final, nothing more measured.
    let task = {
        let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    loop {
        if next_state(&mut rx).await.0 == CampaignState::WaitingOperator {
            break;
        }
    }
    control.abort();
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Aborted);
    let rec = store.lock().expect("lock").campaign(id).expect("c");
    assert_eq!(rec.state, CampaignState::Aborted);
    assert_eq!(rec.points_done, after_estop);
    // Points are contiguous and unique.
    let points = store.lock().expect("lock").points(id).expect("points");
    for (i, p) in points.iter().enumerate() {
        assert_eq!(p.index, i as u64);
    }
}

#[tokio::test(start_paused = true)]
async fn garbled_replies_give_failed_points_or_a_pause_never_a_wrong_value() {
    let mut file = InstrumentFile::simulated();
    file.simulator.faults.garble_rate = 0.05;
    file.simulator.faults.seed = 3;
    let text = toml::to_string(&file).expect("toml");
    let dir = tempfile::tempdir().expect("tempdir");
    let campaign = CAMPAIGN.replace("simulate_operator = false", "simulate_operator = true");
    let prepared = prepare_campaign(&campaign, "c.toml", dir.path(), &file).expect("valid");
    let mut store = Store::open(dir.path()).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(&campaign, &text))
        .expect("create");
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let state = run_campaign(Arc::clone(&store), id, &rig, Control::new())
        .await
        .expect("run");
    assert!(
        matches!(state, CampaignState::Completed | CampaignState::Paused),
        "{state}"
    );
    let points = store.lock().expect("lock").points(id).expect("points");
    for p in &points {
        match (p.brdf_sr, p.truth_aperture_sr, p.brdf_u_sr) {
            (Some(f), Some(t), Some(u)) => {
                assert!(p.flags.is_empty());
                assert!(
                    (f - t).abs() <= 5.0 * u + 1e-6 * t,
                    "point {}: {f} vs {t}",
                    p.index
                );
            }
            (None, _, _) => assert!(!p.flags.is_empty(), "point {} has no value and no flag", p.index),
            other => panic!("point {}: {other:?}", p.index),
        }
    }
    if state == CampaignState::Paused {
        let rec = store.lock().expect("lock").campaign(id).expect("c");
        assert!(rec.last_error.is_some_and(|e| !e.is_empty()));
    }
    assert!(
        rig.sim().expect("sim").fault_counts() != Default::default(),
        "no fault was injected"
    );
}
