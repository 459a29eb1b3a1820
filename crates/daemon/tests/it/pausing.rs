//! The `pausing` state: a pause request shows at once (event, store, HTTP status) while the point in progress
//! finishes; the campaign is `paused` at the next safe point; a pause withdrawn before then goes back to
//! `running`. Points take 30 s of extra settling here, so a request always lands mid-point.

use crate::common;

use std::time::Duration;

use axum::http::StatusCode;
use common::next_point;
use gonio_engine::store::CampaignState;
use gonio_engine::{Control, Event};
use tokio::sync::broadcast::Receiver;

const CAMPAIGN: &str = r#"[campaign]
id = "pausing"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [550.0]
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [30.0]
theta_o_deg = { from = 10.0, to = 60.0, step = 10.0 }

[calibration]
simulate_operator = true

[acquisition]
averaging = 2
settle_s = 30.0

[material]
preset = "white-styrofoam"
"#;

async fn next_state(rx: &mut Receiver<Event>) -> (CampaignState, Option<String>) {
    loop {
        if let Event::State { state, message, .. } = rx.recv().await.expect("event") {
            return (state, message);
        }
    }
}

#[tokio::test(start_paused = true)]
async fn pausing_is_announced_at_once_and_can_be_withdrawn() {
    let campaign = common::stored_campaign(CAMPAIGN, "pausing.toml").await;
    let (store, id) = (&campaign.store, campaign.id);
    let state_in_store = || store.lock().expect("lock").campaign(id).expect("campaign").state;
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = campaign.spawn_run(&control);
    assert_eq!(next_point(&mut rx).await, 0);

    // A pause withdrawn before the safe point: pausing, then running again, and the run goes on.
    control.pause();
    let (state, message) = next_state(&mut rx).await;
    assert_eq!(state, CampaignState::Pausing);
    assert!(message.is_some_and(|m| m.contains("next safe point")));
    assert_eq!(state_in_store(), CampaignState::Pausing);
    control.resume();
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Running);
    assert_eq!(state_in_store(), CampaignState::Running);
    assert_eq!(
        next_point(&mut rx).await,
        1,
        "the withdrawn pause did not stop the run"
    );

    // A pause kept: pausing at once, the point in progress still committed, then paused.
    control.pause();
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Pausing);
    let done_when_asked = store.lock().expect("lock").next_index(id).expect("next");
    assert_eq!(state_in_store(), CampaignState::Pausing);
    assert_eq!(
        next_point(&mut rx).await,
        done_when_asked,
        "the point in progress finishes"
    );
    assert_eq!(next_state(&mut rx).await.0, CampaignState::Paused);
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    assert_eq!(state_in_store(), CampaignState::Paused);
    assert_eq!(
        store.lock().expect("lock").next_index(id).expect("next"),
        done_when_asked + 1
    );
}

#[tokio::test(start_paused = true)]
async fn the_api_reports_pausing_then_paused() {
    let app = common::app(tempfile::tempdir().expect("tempdir")).await;
    let (status, body) = app.json("POST", "/api/campaigns", CAMPAIGN).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let id = body["id"].as_u64().expect("id");
    let done = |v: &serde_json::Value| v["points_done"].as_u64().expect("points_done");
    let mut view = serde_json::Value::Null;
    for _ in 0..600 {
        view = app.json("GET", &format!("/api/campaigns/{id}"), "").await.1;
        if done(&view) >= 1 {
            break;
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    assert_eq!(view["state"], "running", "{view}");
    let before = done(&view);

    let (status, body) = app.json("POST", &format!("/api/campaigns/{id}/pause"), "").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    // Let the engine see the request (well within the 30 s settle of the point in progress).
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (_, view) = app.json("GET", &format!("/api/campaigns/{id}"), "").await;
    assert_eq!(view["state"], "pausing", "{view}");
    assert_eq!(done(&view), before, "still on the same point");
    let (status, _) = app.json("POST", &format!("/api/campaigns/{id}/pause"), "").await;
    assert_eq!(status, StatusCode::CONFLICT, "already pausing");

    for _ in 0..600 {
        if app.state(id).await == "paused" {
            break;
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    let (_, view) = app.json("GET", &format!("/api/campaigns/{id}"), "").await;
    assert_eq!(view["state"], "paused", "{view}");
    assert_eq!(
        done(&view),
        before + 1,
        "the point in progress was committed, no other"
    );
}
