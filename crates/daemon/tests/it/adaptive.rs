//! Adaptive campaigns through the engine (tokio's paused clock, the in-process simulator): the whole budget is
//! placed pass after pass, a campaign stops early at its target error with its total set to what it measured,
//! and progress follows the growing plan.

use crate::common;

use std::collections::HashSet;

use gonio_engine::store::CampaignState;
use gonio_engine::{Control, Event};

/// An adaptive campaign on `material`: one band, `budget` points in passes of 20, stopping at `target`.
fn adaptive(material: &str, budget: u32, target: f64) -> String {
    format!(
        r#"[campaign]
id = "adaptive-{material}"
[sample]
radius_mm = 12.5
[material]
preset = "{material}"
[plan]
bands_nm = [550.0]
[plan.adaptive]
budget_points = {budget}
batch_points = 20
target_error = {target}
first_pass_step_deg = 15.0
[plan.calibration]
dark_every_points = 50
[acquisition]
averaging = 2
"#
    )
}

/// Run to the end, collecting the progress events: (done, total, eta_s).
async fn run(c: &common::StoredCampaign) -> (CampaignState, Vec<(u64, u64, Option<f64>)>) {
    let control = Control::new();
    let mut rx = control.subscribe();
    let mut handle = c.spawn_run(&control);
    let mut progress = Vec::new();
    let state = loop {
        tokio::select! {
            r = rx.recv() => if let Ok(Event::Progress { done, total, eta_s, .. }) = r {
                progress.push((done, total, eta_s));
            },
            r = &mut handle => break r.expect("join").expect("run"),
        }
    };
    while let Ok(e) = rx.try_recv() {
        if let Event::Progress {
            done, total, eta_s, ..
        } = e
        {
            progress.push((done, total, eta_s));
        }
    }
    (state, progress)
}

#[tokio::test(start_paused = true)]
async fn an_adaptive_campaign_places_its_whole_budget_beyond_the_first_pass() {
    let c = common::stored_campaign(&adaptive("gold", 100, 0.0), "adaptive.toml").await;
    assert_eq!(c.total_points, 100);
    let (state, progress) = run(&c).await;
    assert_eq!(state, CampaignState::Completed);
    let points = c.store.lock().expect("store").points(c.id).expect("points");
    assert_eq!(points.len(), 100);
    let geometries: HashSet<[u64; 4]> = points
        .iter()
        .map(|p| [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg].map(f64::to_bits))
        .collect();
    assert_eq!(geometries.len(), 100, "every point a new geometry");
    // The first pass is in-plane sweeps (delta phi 0 or 180); later passes refine off the plane too.
    let off_plane = points
        .iter()
        .filter(|p| {
            let dphi = (p.phi_o_deg - p.phi_i_deg).rem_euclid(360.0);
            (dphi - 180.0).abs() > 1e-9 && dphi.abs() > 1e-9 && (dphi - 360.0).abs() > 1e-9
        })
        .count();
    assert!(off_plane > 0, "no point was placed off the plane of incidence");
    assert!(points.iter().all(|p| p.brdf_sr.is_some()), "every point measured");
    // Progress: the total is the budget throughout; the ETA is known while points remain and ends near 0.
    assert!(progress.iter().all(|p| p.1 == 100), "{progress:?}");
    let etas: Vec<f64> = progress.iter().filter_map(|p| p.2).collect();
    assert!(etas.len() > 50, "{progress:?}");
    let (first, last) = (etas[0], etas[etas.len() - 1]);
    assert!(
        first > 20.0 && last < first / 5.0,
        "ETA {first} s at the start, {last} s at the end"
    );
}

#[tokio::test(start_paused = true)]
async fn an_adaptive_campaign_stops_at_its_target_error_and_says_how_many_points_it_measured() {
    // A diffuse sample: the first pass already shows a smooth BRDF (largest local estimate well below 0.05).
    let c = common::stored_campaign(&adaptive("white-styrofoam", 400, 0.05), "adaptive.toml").await;
    let (state, progress) = run(&c).await;
    assert_eq!(state, CampaignState::Completed);
    let points = c.store.lock().expect("store").points(c.id).expect("points");
    assert!(
        !points.is_empty() && points.len() < 400,
        "{} points",
        points.len()
    );
    let record = c.store.lock().expect("store").campaign(c.id).expect("record");
    assert_eq!(
        record.total_points,
        points.len() as u64,
        "the total becomes what was measured"
    );
    assert_eq!(record.points_done, points.len() as u64);
    let last = progress.last().expect("progress");
    assert_eq!(
        (last.0, last.1),
        (points.len() as u64, points.len() as u64),
        "{progress:?}"
    );
    // Resuming a campaign that ended early is a no-op, not an error.
    let control = Control::new();
    let again = c.spawn_run(&control).await.expect("join").expect("run");
    assert_eq!(again, CampaignState::Completed);
}

/// An adaptive campaign on gold whose first pass sweeps the detector through the plane of incidence at 30 deg.
const SWEPT_FIRST: &str = r#"[campaign]
id = "adaptive-swept"
[sample]
radius_mm = 12.5
[material]
preset = "gold"
[plan]
bands_nm = [550.0]
[plan.adaptive]
budget_points = 60
batch_points = 20
target_error = 0.0
first_pass_theta_i_deg = [30.0]
first_pass_sweeps = { speed_deg_s = 10.0 }
[plan.calibration]
dark_every_points = 50
[acquisition]
averaging = 2
"#;

/// True when the isotropic geometry lies on the swept plane at 30 deg incidence (theta_i or theta_o 30 deg, in
/// the plane of incidence), within the finest spacing the planner refines to (an eighth of its 2.5 deg grid).
fn on_the_swept_arc(p: &gonio_engine::store::PointRecord) -> bool {
    let dphi = (p.phi_o_deg - p.phi_i_deg).rem_euclid(360.0);
    let in_plane = [0.0, 180.0, 360.0].iter().any(|d| (dphi - d).abs() < 1e-6);
    in_plane
        && [p.theta_i_deg, p.theta_o_deg]
            .iter()
            .any(|t| (t - 30.0).abs() < 0.16)
}

#[tokio::test(start_paused = true)]
async fn a_first_pass_of_sweeps_runs_before_the_points_and_the_planner_places_them_off_its_arcs() {
    let c = common::stored_campaign(SWEPT_FIRST, "adaptive.toml").await;
    assert_eq!(c.total_points, 60, "the budget counts points only");
    let (state, _) = run(&c).await;
    assert_eq!(state, CampaignState::Completed);
    let store = c.store.lock().expect("store");
    let points = store.points(c.id).expect("points");
    let readings = store.committed_sweep_readings(c.id).expect("readings");
    assert_eq!(points.len(), 60, "the whole budget in points, beside the sweeps");
    assert!(readings.len() > 1000, "{} sweep readings", readings.len());
    assert!(
        readings.iter().all(|r| r.brdf_sr.is_some()),
        "every reading valid"
    );
    // The sweeps first, then every point.
    let last_reading = readings.iter().map(|r| r.t_s).fold(0.0f64, f64::max);
    let first_point = points.iter().map(|p| p.t_s).fold(f64::INFINITY, f64::min);
    assert!(last_reading < first_point, "{last_reading} s, {first_point} s");
    // The readings cover the arc: no point of the budget is spent where the sweeps measured.
    let on_arc: Vec<_> = points.iter().filter(|p| on_the_swept_arc(p)).collect();
    assert!(on_arc.is_empty(), "points on the swept arc: {on_arc:?}");
    let geometries: HashSet<[u64; 4]> = points
        .iter()
        .map(|p| [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg].map(f64::to_bits))
        .collect();
    assert_eq!(geometries.len(), 60, "every point a new geometry");
}

#[tokio::test(start_paused = true)]
async fn a_campaign_paused_after_its_first_pass_of_sweeps_resumes_without_sweeping_again() {
    let c = common::stored_campaign(SWEPT_FIRST, "adaptive.toml").await;
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = c.spawn_run(&control);
    // Pause once the points have begun: the sweeps are all committed by then.
    assert_eq!(common::next_point(&mut rx).await, 0);
    control.pause();
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    let (segments, readings, before) = {
        let store = c.store.lock().expect("store");
        (
            store.sweep_segments_done(c.id).expect("segments"),
            store.committed_sweep_readings(c.id).expect("readings"),
            store.points(c.id).expect("points"),
        )
    };
    assert!(segments > 0 && !before.is_empty() && before.len() < 60);
    let control = Control::new();
    let state = c.spawn_run(&control).await.expect("join").expect("run");
    assert_eq!(state, CampaignState::Completed);
    let store = c.store.lock().expect("store");
    assert_eq!(store.sweep_segments_done(c.id).expect("segments"), segments);
    let after = store.committed_sweep_readings(c.id).expect("readings");
    assert_eq!(after.len(), readings.len(), "no sweep swept again");
    let points = store.points(c.id).expect("points");
    let indices: Vec<u64> = points.iter().map(|p| p.index).collect();
    assert_eq!(indices, (0..60).collect::<Vec<_>>(), "none lost, none twice");
    // (Their values are the completion's now: the aperture and the drift corrected when the campaign ended.)
    for (a, b) in before.iter().zip(&points) {
        assert_eq!(
            (
                a.index,
                a.theta_i_deg,
                a.phi_i_deg,
                a.theta_o_deg,
                a.phi_o_deg,
                a.signal_w
            ),
            (
                b.index,
                b.theta_i_deg,
                b.phi_i_deg,
                b.theta_o_deg,
                b.phi_o_deg,
                b.signal_w
            ),
            "a committed point changed"
        );
    }
    assert!(points.iter().all(|p| !on_the_swept_arc(p)));
}

#[tokio::test(start_paused = true)]
async fn a_campaign_paused_among_its_first_pass_sweeps_sweeps_the_rest_then_places_its_points() {
    // Three incidences: six sweeps, so that a pause lands between two of them.
    let text = SWEPT_FIRST.replace("[30.0]", "[30.0, 50.0, 65.0]");
    let c = common::stored_campaign(&text, "adaptive.toml").await;
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = c.spawn_run(&control);
    // Pause as the first sweep is committed: the campaign stops at the next safe point, between sweeps.
    loop {
        if let Event::Sweep { segment: 0, .. } = rx.recv().await.expect("event") {
            break;
        }
    }
    control.pause();
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    let (segments, points) = {
        let store = c.store.lock().expect("store");
        (
            store.sweep_segments_done(c.id).expect("segments"),
            store.points(c.id).expect("points").len(),
        )
    };
    assert_eq!(points, 0, "no point before the sweeps are all in");
    let whole = common::stored_campaign(&text, "adaptive.toml").await;
    let (state, _) = run(&whole).await;
    assert_eq!(state, CampaignState::Completed);
    let all = whole
        .store
        .lock()
        .expect("store")
        .sweep_segments_done(whole.id)
        .expect("segments");
    assert!(
        segments >= 1 && segments < all,
        "{segments} of {all} sweeps before the pause"
    );

    let state = c.spawn_run(&Control::new()).await.expect("join").expect("run");
    assert_eq!(state, CampaignState::Completed);
    let store = c.store.lock().expect("store");
    assert_eq!(store.sweep_segments_done(c.id).expect("segments"), all);
    let readings = store.committed_sweep_readings(c.id).expect("readings");
    let mut keys: Vec<(u32, u32)> = readings.iter().map(|r| (r.segment, r.k)).collect();
    let n = keys.len();
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(keys.len(), n, "no reading stored twice");
    let points = store.points(c.id).expect("points");
    assert_eq!(points.len(), 60);
    let first_point = points.iter().map(|p| p.t_s).fold(f64::INFINITY, f64::min);
    assert!(readings.iter().all(|r| r.t_s < first_point));
    assert!(points.iter().all(|p| !on_the_swept_arc(p)));
}
