//! Unit tests of the service: the queue, requests by campaign state, the emergency stop and shutdown, with a
//! scripted runner.

use std::sync::atomic::{AtomicUsize, Ordering};

use tokio::sync::mpsc;

use super::*;
use gonio_engine::EngineError;
use gonio_engine::store::PointRecord;

/// A stand-in engine: one point per simulated second, obeying pause/abort/estop at safe points like the
/// real one, and recording which campaigns ran and how many at once.
#[derive(Default)]
struct FakeRunner {
    active: Arc<AtomicUsize>,
    max_active: Arc<AtomicUsize>,
    started: Arc<Mutex<Vec<CampaignId>>>,
}

fn fake_point(index: u64) -> PointRecord {
    PointRecord {
        index,
        band_nm: 550.0,
        theta_i_deg: 10.0,
        phi_i_deg: 0.0,
        theta_o_deg: 20.0,
        phi_o_deg: 180.0,
        signal_w: 1e-6,
        dark_w: 0.0,
        incident_w: 1e-3,
        brdf_sr: Some(0.3),
        brdf_u_sr: Some(0.01),
        flags: vec![],
        t_s: index as f64,
        readback_deg: vec![],
        truth_point_sr: None,
        truth_aperture_sr: None,
        truth_effects_json: None,
        brdf_aperture_sr: None,
        budget: Default::default(),
    }
}

impl CampaignRunner for FakeRunner {
    fn prepare(&self, campaign_toml: &str, origin: &str) -> Result<Submission, ServiceError> {
        let points: u64 = campaign_toml
            .strip_prefix("points = ")
            .and_then(|n| n.trim().parse().ok())
            .ok_or_else(|| {
                ServiceError::Invalid(format!("{origin}:1: key `points`: expected `points = N`"))
            })?;
        Ok(Submission {
            campaign: NewCampaign {
                name: format!("fake {points}"),
                campaign_toml: campaign_toml.into(),
                instrument_toml: String::new(),
                total_points: points,
                dry_run: true,
                software_version: "test".into(),
                predicted_instrument_s: None,
                alignment_toml: None,
                calibration_id: None,
            },
            prepared: None,
        })
    }

    fn run(
        &self,
        store: Arc<Mutex<Store>>,
        id: CampaignId,
        control: Control,
        _prepared: Option<Arc<PreparedCampaign>>,
    ) -> RunFuture {
        let (active, max_active, started) =
            (self.active.clone(), self.max_active.clone(), self.started.clone());
        Box::pin(async move {
            control.clear_requests();
            lock(&started).push(id);
            let now = active.fetch_add(1, Ordering::SeqCst) + 1;
            max_active.fetch_max(now, Ordering::SeqCst);
            let set = |state, msg: Option<&str>| {
                lock(&store)
                    .set_state(id, state, msg)
                    .map_err(EngineError::from)?;
                control.emit(Event::State {
                    campaign: id,
                    state,
                    message: msg.map(str::to_string),
                });
                Ok::<_, EngineError>(state)
            };
            let result = async {
                set(CampaignState::Running, None)?;
                let (next, total) = {
                    let s = lock(&store);
                    (
                        s.next_index(id).map_err(EngineError::from)?,
                        s.campaign(id).map_err(EngineError::from)?.total_points,
                    )
                };
                for index in next..total {
                    if control.estop_requested() {
                        return set(CampaignState::Paused, Some("emergency stop"));
                    }
                    if control.abort_requested() {
                        return set(CampaignState::Aborted, None);
                    }
                    if control.pause_requested() {
                        return set(CampaignState::Paused, None);
                    }
                    tokio::time::sleep(Duration::from_secs(1)).await;
                    lock(&store)
                        .commit_point(id, &fake_point(index))
                        .map_err(EngineError::from)?;
                    control.emit(Event::Progress {
                        campaign: id,
                        done: index + 1,
                        total,
                        eta_s: Some((total - index - 1) as f64),
                    });
                }
                set(CampaignState::Completed, None)
            }
            .await;
            active.fetch_sub(1, Ordering::SeqCst);
            result
        })
    }

    fn points_csv(&self, store: &Store, record: &CampaignRecord) -> Result<String, StoreError> {
        let points = store.points(record.id)?;
        Ok(gonio_engine::export::points_csv(record, &points))
    }
}

struct Harness {
    service: Service,
    runner: Arc<FakeRunner>,
    trigger: ShutdownTrigger,
    queue: tokio::task::JoinHandle<()>,
    _dir: tempfile::TempDir,
}

fn start_with(dir: tempfile::TempDir, setup: impl FnOnce(&mut Store)) -> Harness {
    let mut store = Store::open(dir.path()).expect("store");
    setup(&mut store);
    let runner = Arc::new(FakeRunner::default());
    let service = Service::new(store, runner.clone(), Control::new()).expect("service");
    let trigger = ShutdownTrigger::new();
    let (tx, _rx) = mpsc::channel(1);
    let queue = {
        let (service, shutdown) = (service.clone(), trigger.subscribe());
        tokio::spawn(async move { service.run_queue(shutdown, tx).await })
    };
    Harness {
        service,
        runner,
        trigger,
        queue,
        _dir: dir,
    }
}

fn start() -> Harness {
    start_with(tempfile::tempdir().expect("tempdir"), |_| {})
}

impl Harness {
    fn state(&self, id: CampaignId) -> CampaignState {
        self.service.campaign(id).expect("campaign").state
    }

    /// Advance (paused) time until `id` is in `state`; at most `limit_s` simulated seconds.
    async fn wait_for(&self, id: CampaignId, state: CampaignState, limit_s: u64) {
        for _ in 0..limit_s * 10 {
            if self.state(id) == state {
                return;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!(
            "campaign {id} is {} after {limit_s} s, expected {state}",
            self.state(id)
        );
    }

    fn started(&self) -> Vec<CampaignId> {
        lock(&self.runner.started).clone()
    }
}

#[tokio::test(start_paused = true)]
async fn campaigns_run_one_at_a_time_in_submission_order() {
    let h = start();
    let ids: Vec<_> = [3, 2, 4]
        .iter()
        .map(|n| h.service.submit(&format!("points = {n}"), "t").expect("submit"))
        .collect();
    h.wait_for(ids[2], CampaignState::Completed, 30).await;
    for &id in &ids {
        let c = h.service.campaign(id).expect("c");
        assert_eq!(
            (c.state, c.points_done),
            (CampaignState::Completed, c.total_points)
        );
    }
    assert_eq!(h.started(), ids);
    assert_eq!(h.runner.max_active.load(Ordering::SeqCst), 1);
}

#[tokio::test(start_paused = true)]
async fn invalid_submission_is_refused_with_the_runner_message() {
    let h = start();
    let err = h.service.submit("nonsense", "bad.toml").expect_err("invalid");
    assert!(
        matches!(&err, ServiceError::Invalid(m) if m.contains("bad.toml:1") && m.contains("points")),
        "{err}"
    );
    assert!(h.service.campaigns().expect("list").is_empty());
}

#[tokio::test(start_paused = true)]
async fn pause_at_a_safe_point_then_resume_completes_without_duplicates() {
    let h = start();
    let id = h.service.submit("points = 10", "t").expect("submit");
    h.wait_for(id, CampaignState::Running, 5).await;
    tokio::time::sleep(Duration::from_millis(3500)).await;
    h.service.pause(id).expect("pause");
    h.wait_for(id, CampaignState::Paused, 5).await;
    let done = h.service.campaign(id).expect("c").points_done;
    assert!(done > 0 && done < 10, "{done}");
    // Paused: it does not move on its own.
    tokio::time::sleep(Duration::from_secs(20)).await;
    assert_eq!(h.service.campaign(id).expect("c").points_done, done);
    assert!(matches!(h.service.pause(id), Err(ServiceError::Conflict(_))));
    h.service.resume(id).expect("resume");
    h.wait_for(id, CampaignState::Completed, 30).await;
    let store_points = lock(&h.service.shared.store).points(id).expect("points");
    assert_eq!(
        store_points.iter().map(|p| p.index).collect::<Vec<_>>(),
        (0..10).collect::<Vec<_>>()
    );
}

#[tokio::test(start_paused = true)]
async fn a_paused_queued_campaign_is_skipped_and_resume_puts_it_back() {
    let h = start();
    let a = h.service.submit("points = 3", "t").expect("a");
    let b = h.service.submit("points = 2", "t").expect("b");
    let c = h.service.submit("points = 2", "t").expect("c");
    assert_eq!(h.service.pause(b).expect("pause b").state, CampaignState::Paused);
    h.wait_for(c, CampaignState::Completed, 30).await;
    assert_eq!(h.state(b), CampaignState::Paused);
    assert_eq!(h.started(), vec![a, c]);
    assert_eq!(h.service.resume(b).expect("resume").state, CampaignState::Queued);
    h.wait_for(b, CampaignState::Completed, 30).await;
    assert_eq!(h.started(), vec![a, c, b]);
}

#[tokio::test(start_paused = true)]
async fn abort_running_and_queued_and_refuse_wrong_states() {
    let h = start();
    let a = h.service.submit("points = 50", "t").expect("a");
    let b = h.service.submit("points = 2", "t").expect("b");
    h.wait_for(a, CampaignState::Running, 5).await;
    assert_eq!(h.service.abort(b).expect("abort b").state, CampaignState::Aborted);
    h.service.abort(a).expect("abort a");
    h.wait_for(a, CampaignState::Aborted, 5).await;
    assert!(h.service.campaign(a).expect("a").points_done < 50);
    // Final campaigns refuse everything; confirm needs waiting-operator; unknown ids are not found.
    for result in [
        h.service.abort(a),
        h.service.pause(b),
        h.service.resume(a),
        h.service.confirm(a),
    ] {
        assert!(matches!(result, Err(ServiceError::Conflict(_))), "{result:?}");
    }
    assert!(matches!(
        h.service.pause(CampaignId(99)),
        Err(ServiceError::NotFound(CampaignId(99)))
    ));
    tokio::time::sleep(Duration::from_secs(10)).await;
    assert_eq!(h.started(), vec![a]);
}

#[tokio::test(start_paused = true)]
async fn estop_halts_the_running_campaign_and_holds_the_queue() {
    let h = start();
    let a = h.service.submit("points = 50", "t").expect("a");
    let b = h.service.submit("points = 2", "t").expect("b");
    h.wait_for(a, CampaignState::Running, 5).await;
    tokio::time::sleep(Duration::from_millis(2500)).await;
    h.service.estop().expect("estop");
    h.wait_for(a, CampaignState::Paused, 5).await;
    assert_eq!(h.state(b), CampaignState::Paused);
    assert!(
        h.service
            .campaign(b)
            .expect("b")
            .last_error
            .is_some_and(|m| m.contains("emergency stop"))
    );
    tokio::time::sleep(Duration::from_secs(30)).await;
    assert_eq!(h.started(), vec![a], "nothing may start after an emergency stop");
    h.service.resume(a).expect("resume a");
    h.wait_for(a, CampaignState::Completed, 80).await;
    assert_eq!(h.state(b), CampaignState::Paused);
}

#[tokio::test(start_paused = true)]
async fn interrupted_campaigns_are_resumed_first_from_their_first_missing_point() {
    let dir = tempfile::tempdir().expect("tempdir");
    let new = |n| NewCampaign {
        name: "x".into(),
        campaign_toml: String::new(),
        instrument_toml: String::new(),
        total_points: n,
        dry_run: true,
        software_version: "test".into(),
        predicted_instrument_s: None,
        alignment_toml: None,
        calibration_id: None,
    };
    let mut ids = Vec::new();
    let h = start_with(dir, |store| {
        let queued = store.create_campaign(&new(2)).expect("queued");
        let interrupted = store.create_campaign(&new(5)).expect("interrupted");
        store
            .set_state(interrupted, CampaignState::Running, None)
            .expect("state");
        for i in 0..3 {
            store.commit_point(interrupted, &fake_point(i)).expect("point");
        }
        ids = vec![queued, interrupted];
    });
    h.wait_for(ids[0], CampaignState::Completed, 30).await;
    assert_eq!(h.started(), vec![ids[1], ids[0]]);
    let points = lock(&h.service.shared.store).points(ids[1]).expect("points");
    assert_eq!(
        points.iter().map(|p| p.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3, 4]
    );
}

#[tokio::test(start_paused = true)]
async fn shutdown_stops_at_a_safe_point_and_leaves_the_campaign_interrupted() {
    let h = start();
    let id = h.service.submit("points = 100", "t").expect("submit");
    h.wait_for(id, CampaignState::Running, 5).await;
    tokio::time::sleep(Duration::from_secs(5)).await;
    h.trigger.trigger();
    tokio::time::timeout(Duration::from_secs(60), h.queue)
        .await
        .expect("queue stops")
        .expect("join");
    let c = h.service.campaign(id).expect("c");
    assert_eq!(c.state, CampaignState::Running, "left as interrupted");
    assert!(c.points_done >= 4 && c.points_done < 100, "{}", c.points_done);
    assert_eq!(
        lock(&h.service.shared.store)
            .interrupted_campaigns()
            .expect("list"),
        vec![id]
    );
}

#[tokio::test(start_paused = true)]
async fn without_an_instrument_there_is_nothing_to_align_nor_to_calibrate() {
    let h = start();
    for err in [
        h.service
            .start_alignment("loopback", None, true, Default::default())
            .expect_err("no instrument"),
        h.service
            .use_calibration_file("[calibration]\n", "cal.toml")
            .expect_err("no instrument"),
    ] {
        assert!(
            matches!(&err, ServiceError::Conflict(m) if m.contains("no instrument of its own")),
            "{err}"
        );
    }
    assert_eq!(h.service.alignment_status().state, AlignPhase::Idle);
    assert!(h.service.calibrations().expect("list").is_empty());
    assert_eq!(h.service.current_calibration(), None);
    // The queue is not held: a campaign still runs.
    let id = h.service.submit("points = 2", "t").expect("submit");
    h.wait_for(id, CampaignState::Completed, 30).await;
    assert_eq!(h.service.campaign(id).expect("c").calibration_id, None);
}
