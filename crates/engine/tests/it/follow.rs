//! A sweep whose speed follows the BRDF, run by the engine on the simulated instrument (tokio's paused clock): a
//! first pass over the coloured plastic's plane of incidence, its readings written as a run writes them
//! (sweeps.csv), then the campaign that follows them. Its pieces are swept at their speeds, each reading's
//! smearing (the truth averaged over the arc it covered, from the first pass's dense truth column, against the
//! truth at its middle) stays within the tolerance where a constant top speed does not, the readings of short
//! pieces and of their ramps are placed where the arm was, and the run takes the time the plan predicted.

use std::sync::{Arc, Mutex};

use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, Rig, prepare_campaign, run_campaign};
use gonio_instrument::InstrumentFile;
use gonio_results::sweeps::{SweepReading, truth_summary, write_sweeps_csv};

const FIRST: &str = r#"
[campaign]
id = "first"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [550.0]
[[plan.sweeps]]
theta_i_deg = [30.0]
theta_o_deg = { from = 0.0, to = 70.0 }
speed_deg_s = 4.0
[calibration]
simulate_operator = true
[material]
preset = "coloured-plastic"
"#;

const TOLERANCE: f64 = 1e-3;

/// Run `campaign` (its file names resolved against `base`) with its store in `dir`, to completion: its readings,
/// the instrument time it took and the time predicted. The engine reads the campaign back as stored (its
/// `[resolved]` table, never the first pass).
async fn run(dir: &std::path::Path, base: &std::path::Path, campaign: &str) -> (Vec<SweepReading>, f64, f64) {
    std::fs::create_dir_all(dir).expect("dir");
    let file = InstrumentFile::simulated();
    let prepared = prepare_campaign(campaign, "c.toml", base, &file).expect("valid campaign");
    let predicted = prepared.predicted_s;
    let text = toml::to_string(&file).expect("toml");
    let store = Arc::new(Mutex::new(Store::open(dir).expect("store")));
    let id = store
        .lock()
        .expect("lock")
        .create_campaign(&prepared.new_campaign(campaign, &text))
        .expect("create");
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let state = run_campaign(Arc::clone(&store), id, &rig, Control::new())
        .await
        .expect("run");
    assert_eq!(state, CampaignState::Completed);
    let store = store.lock().expect("lock");
    let took = store
        .campaign(id)
        .expect("campaign")
        .ended_instrument_s
        .expect("the run's end is recorded");
    (store.sweep_readings(id).expect("readings"), took, predicted)
}

/// The truth along the arc (signed angle, BRDF) from the first pass's readings, and the mean of it over `[a, b]`
/// against its value at the middle, minus one: the smearing of a reading that covered that arc.
fn smearing(truth: &[(f64, f64)], a: f64, b: f64) -> Option<f64> {
    let f = |s: f64| {
        let i = truth.partition_point(|(x, _)| *x < s);
        let (l, r) = (truth.get(i.checked_sub(1)?)?, truth.get(i)?);
        Some(l.1 + (r.1 - l.1) * (s - l.0) / (r.0 - l.0))
    };
    let (lo, hi) = (a.min(b), a.max(b));
    let n = 200;
    let mut sum = 0.0;
    for k in 0..n {
        sum += f(lo + (hi - lo) * (k as f64 + 0.5) / n as f64)?;
    }
    Some(sum / n as f64 / f(0.5 * (a + b))? - 1.0)
}

#[tokio::test(start_paused = true)]
async fn a_sweep_that_follows_the_brdf_keeps_every_reading_within_its_smearing_tolerance() {
    let dir = tempfile::tempdir().expect("tempdir");
    let first_dir = dir.path().join("first");
    let (first, _, _) = run(&first_dir, dir.path(), FIRST).await;
    std::fs::write(first_dir.join("sweeps.csv"), write_sweeps_csv(&first, true)).expect("write");
    let mut truth: Vec<(f64, f64)> = first
        .iter()
        .filter_map(|r| Some((0.5 * (r.arc_from_deg + r.arc_to_deg), r.truth_point_sr?)))
        .collect();
    truth.sort_by(|a, b| a.0.total_cmp(&b.0));

    let fast = FIRST
        .replace("id = \"first\"", "id = \"follow\"")
        .replace("speed_deg_s = 4.0", "speed_deg_s = 16.0\naveraging = 30");
    let following = fast.replace(
        "averaging = 30",
        &format!("averaging = 30\nfollow = {{ first_pass = \"first\", tolerance_rel = {TOLERANCE} }}"),
    );
    let file = InstrumentFile::simulated();
    let prepared = gonio_campaign::load_and_prepare(
        &following,
        "c.toml",
        &gonio_campaign::Sources::Local(dir.path().to_path_buf()),
        &file,
    )
    .expect("follows");
    let speeds: Vec<f64> = prepared
        .sweeps
        .as_ref()
        .expect("sweeps")
        .plan
        .arcs
        .iter()
        .map(|a| a.request.speed_deg_s)
        .collect();
    // The lobe's side slower than the rest, none faster than the request (pieces merged, at the slower speed,
    // where a piece of its own costs more in ramps and exchanges than it saves: whether the tail beyond the lobe
    // keeps a piece at the top speed is that margin's call).
    let (slowest, fastest) = speeds
        .iter()
        .fold((f64::INFINITY, 0.0_f64), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
    assert!(
        speeds.len() >= 2 && fastest <= 16.0 && fastest > 1.2 * slowest,
        "{speeds:?}"
    );
    assert!(slowest < 12.0, "{speeds:?}");

    let (followed, took, predicted) = run(&dir.path().join("follow"), dir.path(), &following).await;
    let (constant, _, _) = run(&dir.path().join("constant"), dir.path(), &fast).await;

    // Every reading within the arc the first pass covered: its smearing within the tolerance (1.2 x: the
    // profile's leading order) when it follows; at the constant top speed the lobe's flanks exceed it.
    let worst = |readings: &[SweepReading]| {
        readings
            .iter()
            .filter_map(|r| smearing(&truth, r.arc_from_deg, r.arc_to_deg))
            .map(f64::abs)
            .fold(0.0, f64::max)
    };
    let (w_follow, w_constant) = (worst(&followed), worst(&constant));
    eprintln!("largest smearing: {w_follow:.2e} following, {w_constant:.2e} at 16 deg/s throughout");
    assert!(w_follow <= 1.2 * TOLERANCE, "{w_follow:.2e}");
    assert!(w_constant > 1.5 * TOLERANCE, "{w_constant:.2e}");
    // The readings of the short pieces and of their ramps are where the arm was: the values agree with the
    // truth at their middles and the stated uncertainties cover it.
    let summary = truth_summary(&followed).expect("summary");
    eprintln!("following: {summary:?}");
    assert!(summary.readings > 50, "{summary:?}");
    assert!(
        summary.cos_weighted_relative_rms.expect("rms") < 2e-3,
        "{summary:?}"
    );
    assert!(summary.coverage_k2 >= 0.9, "{summary:?}");
    // The time the plan predicted.
    eprintln!("instrument time {took:.2} s, predicted {predicted:.2} s");
    assert!(
        (took / predicted - 1.0).abs() < 0.02,
        "{took} s against {predicted} s"
    );
}
