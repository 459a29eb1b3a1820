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
