//! A campaign's `last_error` says why it stopped; once it completed there is no error left to show: the reason of
//! a pause before the resume does not stay on the completed campaign (issue #8), in the store's record or the
//! API's view of it. In process on the simulated instrument under tokio's paused clock.

use crate::common;

use std::sync::Arc;
use std::time::Duration;

use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, run_campaign};
use gonio_testkit::CampaignText;

fn campaign() -> String {
    CampaignText::in_plane_grid("last-error", "[30.0]", "{ from = 10.0, to = 60.0, step = 10.0 }")
        .calibration("simulate_operator = true")
        .material("preset = \"spectralon\"")
        .to_string()
}

#[tokio::test(start_paused = true)]
async fn a_completed_campaign_no_longer_shows_the_reason_of_an_earlier_pause() {
    let campaign = common::stored_campaign(&campaign(), "last-error.toml").await;
    let (store, id, rig, dir) = (&campaign.store, campaign.id, &campaign.rig, &campaign.dir);
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = campaign.spawn_run(&control);
    tokio::time::timeout(Duration::from_secs(3600), common::next_point(&mut rx))
        .await
        .expect("a point");
    control.pause();
    let state = task.await.expect("join").expect("run");
    assert_eq!(state, CampaignState::Paused);
    let paused = store.lock().expect("lock").campaign(id).expect("campaign");
    assert_eq!(
        paused.last_error.as_deref(),
        Some("paused by request"),
        "the pause says why"
    );

    // Resumed: running, the earlier reason may stay (it is the last one there was); completed: gone.
    let state = tokio::time::timeout(
        Duration::from_secs(24 * 3600),
        run_campaign(Arc::clone(store), id, rig, Control::new()),
    )
    .await
    .expect("no hang")
    .expect("resume");
    assert_eq!(state, CampaignState::Completed);
    let done = store.lock().expect("lock").campaign(id).expect("campaign");
    assert_eq!(done.points_done, campaign.total_points);
    assert_eq!(done.last_error, None, "a completed campaign shows no error");
    // The same from a fresh open of the file (what a restarted daemon shows).
    let reopened = Store::open(dir.path()).expect("reopen");
    assert_eq!(reopened.campaign(id).expect("campaign").last_error, None);
}
