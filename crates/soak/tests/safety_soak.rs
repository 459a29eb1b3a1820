//! CI-sized safety soak: a few random campaigns with random pause/abort/estop interleavings, checked on the
//! simulator's motion record (arm separation at every instant, limits, emergency-stop latency).

use gonio_soak::safety_soak::{ESTOP_DEADLINE_S, SafetySoakConfig, run_safety_soak};

#[test]
fn random_plans_and_interruptions_keep_the_arms_apart_within_limits_and_stop_in_time() {
    let r = run_safety_soak(&SafetySoakConfig { cases: 4, seed: 8 }).expect("the soak runs");
    for c in &r.cases {
        eprintln!("{c:?}");
    }
    assert_eq!(r.violations(), Vec::<String>::new());
    assert_eq!(r.cases.len(), 4);
    assert!(r.move_commands() > 0);
    // The measured margins agree with the verdict.
    assert!(
        r.closest_motor_deg() >= r.min_separation_deg - 1e-9,
        "{}",
        r.closest_motor_deg()
    );
    assert!(
        r.closest_load_deg() >= r.min_separation_deg - 1e-9,
        "{}",
        r.closest_load_deg()
    );
    assert!(r.command_margin_deg() >= -1e-9 && r.trajectory_margin_deg() >= -1e-9);
    for l in r.estop_latencies_s() {
        assert!((0.0..=ESTOP_DEADLINE_S).contains(&l), "{l}");
    }
    let [_, _, estops] = r.acts();
    // Every emergency stop is measured at every axis (4 axes on the simulated instrument).
    assert_eq!(r.estop_latencies_s().len() as u64, estops * 4);
}
