//! Disk trouble (issue #8): the store becomes genuinely full in the middle of a campaign (SQLite's
//! `max_page_count`, so that SQLITE_FULL comes from SQLite itself, whoever runs the test). The campaign pauses
//! with a reason naming the store file and SQLite's error, nothing moves any more, every committed point is kept,
//! and once there is room again it resumes from the first point not committed: every planned point exactly once.

use crate::common;

use std::sync::Arc;
use std::time::Duration;

use gonio_engine::store::{CampaignState, STORE_FILE};
use gonio_engine::{Control, Event, run_campaign};

const CAMPAIGN: &str = r#"[campaign]
id = "disk-full"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [550.0]
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [30.0]
theta_o_deg = { from = 10.0, to = 70.0, step = 1.0 }

[calibration]
simulate_operator = true

[acquisition]
averaging = 2

[material]
preset = "white-styrofoam"
"#;

#[tokio::test(start_paused = true)]
async fn a_full_store_pauses_the_campaign_and_it_resumes_once_there_is_room() {
    let campaign = common::stored_campaign(CAMPAIGN, "disk.toml").await;
    let (store, id, rig, dir) = (&campaign.store, campaign.id, &campaign.rig, &campaign.dir);
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = campaign.spawn_run(&control);

    // After a few points, the store may not grow by a single page any more.
    loop {
        if let Event::Point { point, .. } = rx.recv().await.expect("event")
            && point.index >= 3
        {
            break;
        }
    }
    let before = {
        let mut s = store.lock().expect("lock");
        let pages = s.page_count().expect("page count");
        assert_eq!(s.set_max_pages(Some(pages)).expect("cap"), pages);
        s.points(id).expect("points")
    };

    let state = task
        .await
        .expect("join")
        .expect("the engine returns, it does not fail");
    assert_eq!(state, CampaignState::Paused);
    let mut reason = None;
    while let Ok(event) = rx.try_recv() {
        if let Event::State {
            state: CampaignState::Paused,
            message,
            ..
        } = event
        {
            reason = message;
        }
    }
    let reason = reason.expect("a paused event with its reason");
    let store_path = dir.path().join(STORE_FILE).display().to_string();
    assert!(
        reason.contains(&store_path) && reason.contains("database or disk is full"),
        "the reason names the store and SQLite's error: {reason}"
    );
    let (record, at_pause) = {
        let s = store.lock().expect("lock");
        (s.campaign(id).expect("campaign"), s.points(id).expect("points"))
    };
    assert_eq!(
        record.state,
        CampaignState::Paused,
        "status requests see the pause"
    );
    assert_eq!(record.last_error.as_deref(), Some(reason.as_str()));
    assert!(
        (at_pause.len() as u64) < campaign.total_points,
        "the store filled up before the end ({} points)",
        at_pause.len()
    );
    assert_eq!(
        &at_pause[..before.len()],
        &before[..],
        "committed points are untouched"
    );
    for (i, p) in at_pause.iter().enumerate() {
        assert_eq!(p.index, i as u64, "no hole");
    }

    // Motion stopped: nothing moves while the campaign waits for room.
    let sim = rig.sim().expect("simulator");
    let pose = sim.pose();
    tokio::time::sleep(Duration::from_secs(120)).await;
    assert_eq!(sim.pose(), pose);

    // Room again: resuming measures the point that could not be committed and goes on to the end.
    store
        .lock()
        .expect("lock")
        .set_max_pages(None)
        .expect("lift the cap");
    let state = run_campaign(Arc::clone(store), id, rig, Control::new())
        .await
        .expect("resume");
    assert_eq!(state, CampaignState::Completed);
    // As committed: a completed campaign's corrections are read apart from the rows (gonio_engine::budget).
    let all = store.lock().expect("lock").committed_points(id).expect("points");
    assert_eq!(all.len() as u64, campaign.total_points);
    for (i, p) in all.iter().enumerate() {
        assert_eq!(p.index, i as u64, "every planned point exactly once");
    }
    assert_eq!(
        &all[..at_pause.len()],
        &at_pause[..],
        "nothing committed was lost or changed"
    );
    let record = store.lock().expect("lock").campaign(id).expect("campaign");
    assert_eq!(record.state, CampaignState::Completed);
}
