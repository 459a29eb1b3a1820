//! A quiet first run (issue 26): the SMC100's first TS after power-up and after homing, which real controllers
//! are recorded to leave unanswered (`smc100_drop_first_ts`), is retried at debug and counted once at info per
//! axis; any other lost reply stays a warning.

use std::sync::Arc;

use gonio_driver::Axis;
use gonio_driver::smc100::{SET_GAP, Smc100Axis, Smc100Chain};
use tracing::Level;

use crate::common::{sim_axis, sim_file, sim_port};
use crate::logcap::capture;

const COUNT: &str = "first TS after power-up or homing went unanswered";

/// Read both arms' status at power-up (as the engine does before homing), home them and move each once, under
/// the quirks and faults `f` sets.
async fn home_and_move(
    f: impl FnOnce(&mut gonio_instrument::InstrumentFile),
) -> Vec<Result<f64, gonio_driver::DriverError>> {
    let sim = sim_file(f, 1.0);
    let chain = Smc100Chain::with_set_gap("arms", sim_port(&sim, "arms"), SET_GAP);
    let light = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    let detector = Smc100Axis::new(chain, sim_axis("detector"));
    let mut results = Vec::new();
    for (axis, target) in [(&light, 20.0), (&detector, -30.0)] {
        if let Err(e) = axis.status().await {
            results.push(Err(e));
            continue;
        }
        match axis.home().await {
            Ok(()) => results.push(axis.move_to(target).await),
            Err(e) => results.push(Err(e)),
        }
    }
    results
}

#[tokio::test(start_paused = true)]
async fn the_recorded_first_ts_loss_is_no_warning_and_one_count_per_axis() {
    let (log, _guard) = capture();
    let results = home_and_move(|f| {
        f.simulator.quirks.smc100_drop_first_ts = true;
        f.simulator.quirks.smc100_min_command_gap_ms = 60.0;
    })
    .await;
    assert!(results.iter().all(|r| r.is_ok()), "{results:?}");
    assert_eq!(log.lines(Level::WARN, ""), Vec::<String>::new(), "no warning");
    assert!(log.lines(Level::ERROR, "").is_empty());
    // Each controller lost its first TS after power-up and its first after homing: retried at debug...
    let retried = log.lines(Level::DEBUG, "first TS unanswered");
    assert_eq!(retried.len(), 4, "{retried:?}");
    // ...and counted once per axis at info.
    let counts = log.lines(Level::INFO, COUNT);
    assert_eq!(counts.len(), 2, "{counts:?}");
    for (count, dev) in counts.iter().zip(["arms/1", "arms/2"]) {
        assert!(count.contains(dev) && count.contains("unanswered=2"), "{count}");
    }
}

#[tokio::test(start_paused = true)]
async fn the_manuals_controller_answers_every_ts_and_nothing_is_counted() {
    let (log, _guard) = capture();
    let results = home_and_move(|f| {
        f.simulator.quirks.smc100_drop_first_ts = false;
        f.simulator.quirks.smc100_min_command_gap_ms = 0.0;
    })
    .await;
    assert!(results.iter().all(|r| r.is_ok()), "{results:?}");
    assert!(
        log.lines(Level::WARN, "").is_empty(),
        "{:?}",
        log.lines(Level::WARN, "")
    );
    assert!(log.lines(Level::DEBUG, "first TS unanswered").is_empty());
    assert!(log.lines(Level::INFO, COUNT).is_empty());
}

#[tokio::test(start_paused = true)]
async fn replies_lost_to_faults_still_warn() {
    for drop_first_ts in [true, false] {
        let (log, _guard) = capture();
        home_and_move(|f| {
            f.simulator.quirks.smc100_drop_first_ts = drop_first_ts;
            f.simulator.quirks.smc100_min_command_gap_ms = 60.0;
            f.simulator.faults.seed = 7;
            f.simulator.faults.drop_rate = 0.2;
        })
        .await;
        let warned = log.lines(Level::WARN, "");
        assert!(
            warned
                .iter()
                .any(|w| w.contains("query failed; retrying") || w.contains("no TE reply")),
            "drop_first_ts={drop_first_ts}: a lost reply warns: {warned:?}"
        );
    }
}
