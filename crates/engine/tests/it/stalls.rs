//! Stall injection in a dry-run (issue #3/#8): with `[simulator.faults] stall_rate > 0` the simulator stalls
//! moves, and every stall ends as a flagged failed point or a retried-then-good point, never a wrong value.

use std::sync::{Arc, Mutex};

use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, Rig, prepare_campaign, run_campaign};
use gonio_instrument::InstrumentFile;

const CAMPAIGN: &str = r#"
[campaign]
id = "stall-test"
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
simulate_operator = true
[material]
preset = "spectralon"
"#;

#[tokio::test(start_paused = true)]
async fn stalled_moves_are_injected_and_never_give_a_wrong_value() {
    let mut file = InstrumentFile::simulated();
    file.simulator.faults.stall_rate = 0.3;
    file.simulator.faults.seed = 5;
    let text = toml::to_string(&file).expect("toml");
    let dir = tempfile::tempdir().expect("tempdir");
    let prepared = prepare_campaign(CAMPAIGN, "c.toml", dir.path(), &file).expect("valid");
    let mut store = Store::open(dir.path()).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(CAMPAIGN, &text))
        .expect("create");
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let state = tokio::time::timeout(
        std::time::Duration::from_secs(24 * 3600),
        run_campaign(Arc::clone(&store), id, &rig, Control::new()),
    )
    .await
    .expect("no hang")
    .expect("run");
    let counts = rig.sim().expect("sim").fault_counts();
    assert!(counts.stalls > 0, "stall_rate 0.3 injected no stall: {counts:?}");
    assert_eq!(
        state,
        CampaignState::Completed,
        "a stalled move is recovered (or its point fails), it does not stop the campaign: {:?}",
        store.lock().expect("lock").campaign(id).expect("c").last_error
    );
    let points = store.lock().expect("lock").points(id).expect("points");
    assert_eq!(points.len() as u64, prepared.total_points);
    let mut good = 0;
    for p in &points {
        match (p.brdf_sr, p.truth_aperture_sr, p.brdf_u_sr) {
            (Some(f), Some(t), Some(u)) => {
                assert!(p.flags.is_empty(), "point {}: {:?}", p.index, p.flags);
                assert!(
                    (f - t).abs() <= 5.0 * u + 1e-6 * t,
                    "point {}: {f} vs truth {t} (u {u})",
                    p.index
                );
                good += 1;
            }
            (None, _, _) => {
                // A failed point carries the device's own reason (the controller state after the stall).
                assert!(
                    p.flags.iter().any(|f| f.starts_with("failed:")),
                    "point {} has no value and no failure reason: {:?}",
                    p.index,
                    p.flags
                );
            }
            other => panic!("point {}: {other:?}", p.index),
        }
    }
    eprintln!(
        "stalls injected {}, points {}, valid {good}",
        counts.stalls,
        points.len()
    );
    assert!(good > 0, "no valid point at all");
}
