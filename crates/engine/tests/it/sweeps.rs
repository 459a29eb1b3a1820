//! Sweeps run by the engine on the simulated instrument (tokio's paused clock): the readings cover each planned
//! arc in order at the set speed, agree with the simulator's truth away from the specular peak, and a pause
//! between sweeps loses and duplicates nothing on resume.

use std::sync::{Arc, Mutex};

use gonio_engine::store::{CampaignId, CampaignState, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_campaign};
use gonio_instrument::InstrumentFile;
use gonio_results::sweeps::SweepReading;

const CAMPAIGN: &str = r#"
[campaign]
id = "sweep-test"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [450.0, 650.0]
[[plan.sweeps]]
theta_i_deg = [30.0]
theta_o_deg = { from = -10.0, to = 60.0 }
speed_deg_s = 5.0
[[plan.sweeps]]
arm = "light"
theta_o_deg = [20.0]
theta_i_deg = { from = 40.0, to = 70.0 }
speed_deg_s = 2.0
averaging = 3
[plan.calibration]
dark_every_s = 15.0
reference_every_s = 15.0
reference_pose_deg = { light = -90.0, detector = 90.0 }
[calibration]
simulate_operator = true
[material]
preset = "coloured-plastic"
"#;

struct Setup {
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: Rig,
    /// (segments, readings per segment predicted, the sweep's speed) of the schedule.
    steps: Vec<(u64, f64)>,
}

async fn setup(dir: &std::path::Path) -> Setup {
    setup_with(dir, CAMPAIGN).await
}

async fn setup_with(dir: &std::path::Path, campaign: &str) -> Setup {
    setup_on(dir, campaign, InstrumentFile::simulated()).await
}

async fn setup_on(dir: &std::path::Path, campaign: &str, file: InstrumentFile) -> Setup {
    let prepared = prepare_campaign(campaign, "sweep-test.toml", dir, &file).expect("valid campaign");
    let text = toml::to_string(&file).expect("toml");
    let mut store = Store::open(dir).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(campaign, &text))
        .expect("create");
    let planned = gonio_campaign::load_and_prepare(
        campaign,
        "sweep-test.toml",
        &gonio_campaign::Sources::Local(dir.to_path_buf()),
        &file,
    )
    .expect("prepare");
    let sweeps = planned.sweeps.expect("sweeps");
    let steps = sweeps
        .schedule
        .steps
        .iter()
        .map(|s| (s.readings, sweeps.plan.arcs[s.arc].request.speed_deg_s))
        .collect();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    Setup {
        store: Arc::new(Mutex::new(store)),
        id,
        rig,
        steps,
    }
}

/// Every segment's readings: numbered from 0, in time order, the arc advancing in one direction by about
/// speed x period per reading.
fn check_segments(readings: &[SweepReading], steps: &[(u64, f64)]) {
    let segments = readings.iter().map(|r| r.segment).max().map_or(0, |m| m + 1);
    assert_eq!(segments as usize, steps.len(), "every sweep of the schedule");
    for (segment, (predicted, speed)) in steps.iter().enumerate() {
        let rs: Vec<&SweepReading> = readings.iter().filter(|r| r.segment == segment as u32).collect();
        let n = rs.len() as f64;
        assert!(
            (n - *predicted as f64).abs() <= 0.15 * *predicted as f64,
            "segment {segment}: {n} readings, {predicted} predicted"
        );
        for (k, r) in rs.iter().enumerate() {
            assert_eq!(r.k as usize, k);
            assert!(r.flags.is_empty(), "segment {segment} reading {k}: {:?}", r.flags);
        }
        let direction = (rs[rs.len() - 1].arc_to_deg - rs[0].arc_from_deg).signum();
        for w in rs.windows(2) {
            assert!(w[1].t_s > w[0].t_s);
            let step = (w[1].arc_from_deg - w[0].arc_from_deg) * direction;
            // At cruise a reading is speed x (integration + exchanges) of arc; in the ramps less.
            assert!(
                step >= -1e-9 && step <= speed * 0.02,
                "segment {segment}: step {step}"
            );
        }
    }
}

#[tokio::test(start_paused = true)]
async fn sweeps_cover_their_arcs_and_agree_with_the_truth() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = setup(dir.path()).await;
    let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
        .await
        .expect("run");
    assert_eq!(state, CampaignState::Completed);
    let readings = s
        .store
        .lock()
        .expect("lock")
        .sweep_readings(s.id)
        .expect("readings");
    check_segments(&readings, &s.steps);
    // Calibrations opened the sweeps, fell due between arcs (every 15 s of instrument time), and closed them:
    // direct-beam readings of both bands after the last sweep, for the drift's interpolation.
    let calibrations = s
        .store
        .lock()
        .expect("lock")
        .calibrations(s.id)
        .expect("calibrations");
    let beams: Vec<f64> = calibrations
        .iter()
        .filter(|c| c.kind == "direct-beam")
        .map(|c| c.t_s)
        .collect();
    let segments = s
        .store
        .lock()
        .expect("lock")
        .sweep_segments(s.id)
        .expect("segments");
    let last_end = segments.last().map_or(0.0, |g| g.ended_s);
    assert!(beams.len() >= 3 * 2, "{beams:?}");
    assert_eq!(
        beams.iter().filter(|t| **t > last_end).count(),
        2,
        "{beams:?} after {last_end}"
    );
    assert!(
        beams.iter().any(|t| *t > segments[0].ended_s && *t < last_end),
        "none between the sweeps: {beams:?}"
    );
    // The detector's arc starts at -10, clear of the source at -30: one piece; the light's arc one piece; each
    // swept in both bands.
    assert_eq!(s.steps.len(), 4);
    // Away from the specular peak the readings are within 1 % of the BRDF at their arcs' middles, and the
    // median error is far smaller.
    let mut errors: Vec<f64> = Vec::new();
    for r in &readings {
        let (Some(f), Some(t)) = (r.brdf_sr, r.truth_point_sr) else {
            panic!("reading without a value or a truth: {r:?}");
        };
        let specular =
            (r.theta_o_deg - r.theta_i_deg).abs() < 8.0 && (r.phi_o_deg - r.phi_i_deg).abs() > 90.0;
        if !specular {
            assert!((f - t).abs() <= 0.01 * t, "{r:?}");
            errors.push(((f - t) / t).abs());
        }
    }
    errors.sort_by(f64::total_cmp);
    assert!(errors.len() > 1000, "{}", errors.len());
    assert!(
        errors[errors.len() / 2] < 2e-3,
        "median error {}",
        errors[errors.len() / 2]
    );
    // The completion corrected the readings to their nominal geometry: near the specular peak (where the
    // aperture's average falls below the peak) the corrected values are closer to the truth than the averages
    // they came from.
    let near: Vec<&SweepReading> = readings
        .iter()
        .filter(|r| (r.theta_o_deg - r.theta_i_deg).abs() < 3.0 && (r.phi_o_deg - r.phi_i_deg).abs() > 90.0)
        .collect();
    assert!(near.len() > 100, "{}", near.len());
    let mean_error = |value: &dyn Fn(&SweepReading) -> f64| {
        near.iter()
            .map(|r| {
                let t = r.truth_point_sr.unwrap_or(f64::NAN);
                ((value(r) - t) / t).abs()
            })
            .sum::<f64>()
            / near.len() as f64
    };
    let corrected = mean_error(&|r| r.brdf_sr.unwrap_or(f64::NAN));
    let average = mean_error(&|r| r.brdf_aperture_sr.or(r.brdf_sr).unwrap_or(f64::NAN));
    eprintln!("near the specular peak: mean |error| {corrected:.2e} corrected, {average:.2e} as averaged");
    assert!(
        corrected < 0.5 * average,
        "corrected {corrected:.2e}, averaged {average:.2e}"
    );
    let summary = gonio_results::sweeps::truth_summary(&readings).expect("summary");
    eprintln!(
        "k=2 coverage {:.3}, cos-weighted relative rms {:?}",
        summary.coverage_k2, summary.cos_weighted_relative_rms
    );
    // The stated uncertainties hold the truth at k=2 for at least 90 % of the readings here (the issue's
    // target; 56 % when the position reports were stamped when the reading beside them ended).
    assert!(
        summary.coverage_k2 >= 0.90,
        "k=2 coverage {:.3}",
        summary.coverage_k2
    );
    // So they do in each direction of travel, at 95 %: an arm swept down its controller's scale carries its
    // load a backlash (0.01 deg) further than the motor, which the attribution takes into account (97.8 % and
    // 97.4 % here; without it, 90.9 % on the coloured plastic's lobe flanks one way).
    for up in [true, false] {
        let way: Vec<SweepReading> = readings
            .iter()
            .filter(|r| (r.arc_to_deg > r.arc_from_deg) == up)
            .cloned()
            .collect();
        let s = gonio_results::sweeps::truth_summary(&way).expect("summary");
        eprintln!(
            "sweeps {}: k=2 coverage {:.3} of {}",
            if up { "up" } else { "down" },
            s.coverage_k2,
            s.readings
        );
        assert!(s.readings > 1000 && s.coverage_k2 >= 0.95, "{up}: {s:?}");
    }
}

#[tokio::test(start_paused = true)]
async fn a_pause_between_sweeps_loses_and_duplicates_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = setup(dir.path()).await;
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = {
        let (store, rig, control) = (Arc::clone(&s.store), s.rig.clone(), control.clone());
        let id = s.id;
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    loop {
        if let Event::Sweep { segment: 0, .. } = rx.recv().await.expect("event") {
            control.pause();
            break;
        }
    }
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    let done = s
        .store
        .lock()
        .expect("lock")
        .sweep_segments_done(s.id)
        .expect("done");
    assert!(done >= 1 && (done as usize) < s.steps.len(), "{done}");
    let before = s
        .store
        .lock()
        .expect("lock")
        .sweep_readings(s.id)
        .expect("readings");
    let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
        .await
        .expect("resume");
    assert_eq!(state, CampaignState::Completed);
    let after = s
        .store
        .lock()
        .expect("lock")
        .committed_sweep_readings(s.id)
        .expect("readings");
    // What was committed before the pause is untouched (the completion at the end is kept beside it); the rest
    // was swept after it.
    assert_eq!(&after[..before.len()], &before[..]);
    check_segments(&after, &s.steps);
}

#[tokio::test(start_paused = true)]
async fn an_emergency_stop_during_a_sweep_halts_it_at_once_and_keeps_nothing_of_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = setup(dir.path()).await;
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = {
        let (store, rig, control) = (Arc::clone(&s.store), s.rig.clone(), control.clone());
        let id = s.id;
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    loop {
        if let Event::Sweep { segment: 0, .. } = rx.recv().await.expect("event") {
            break;
        }
    }
    // The second sweep (the same 70-degree arc back in the other band, 14 s at 5 deg/s) is under way 6 s later.
    tokio::time::sleep(std::time::Duration::from_secs(6)).await;
    let before = s.rig.sim().expect("sim").pose();
    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    let moving = s.rig.sim().expect("sim").pose();
    assert_ne!(before, moving, "an arm sweeps");
    control.estop();
    // The arm is halted within 200 ms (the stop on its line, its deceleration), not at the end of the sweep.
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let halted = s.rig.sim().expect("sim").pose();
    tokio::time::sleep(std::time::Duration::from_secs(1)).await;
    assert_eq!(halted, s.rig.sim().expect("sim").pose(), "the arm stays halted");
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    let rec = s.store.lock().expect("lock").campaign(s.id).expect("campaign");
    assert_eq!(rec.last_error.as_deref(), Some("emergency stop"));
    // The interrupted sweep left nothing; resumed, it is swept again whole.
    assert_eq!(
        s.store
            .lock()
            .expect("lock")
            .sweep_segments_done(s.id)
            .expect("done"),
        1
    );
    let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
        .await
        .expect("resume");
    assert_eq!(state, CampaignState::Completed);
    let after = s
        .store
        .lock()
        .expect("lock")
        .sweep_readings(s.id)
        .expect("readings");
    check_segments(&after, &s.steps);
}

/// A fast sweep with long readings (10 deg/s, 30 meter samples: each reading averages the BRDF over 0.9 deg of
/// arc) across the coloured plastic's gloss lobe: each reading is attributed to the arc it really covered, the
/// completion takes it to its arc's middle (the aperture's and the smearing's corrections with the fitted
/// model), and the stated uncertainties hold the truth. (With the simulated meter seeing its whole window at
/// the window's end, as it did, the readings were 0.46 deg off and 3 % of them covered.)
/// Fast sweeps across the coloured plastic's specular lobe, with calibrations between them.
const FAST: &str = r#"
[campaign]
id = "fast-sweep"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [550.0]
[[plan.sweeps]]
theta_i_deg = [30.0]
theta_o_deg = { from = 5.0, to = 60.0 }
speed_deg_s = 10.0
averaging = 30
[plan.calibration]
dark_every_s = 60.0
reference_every_s = 60.0
reference_pose_deg = { light = -90.0, detector = 90.0 }
[calibration]
simulate_operator = true
[material]
preset = "coloured-plastic"
"#;

#[tokio::test(start_paused = true)]
async fn fast_sweeps_are_taken_to_their_arcs_middles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = setup_with(dir.path(), FAST).await;
    let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
        .await
        .expect("run");
    assert_eq!(state, CampaignState::Completed);
    let readings = s
        .store
        .lock()
        .expect("lock")
        .sweep_readings(s.id)
        .expect("readings");
    let summary = gonio_results::sweeps::truth_summary(&readings).expect("summary");
    // The readings as committed (before the completion), against the same truth.
    let raw: Vec<SweepReading> = readings
        .iter()
        .map(|r| SweepReading {
            brdf_sr: r.brdf_aperture_sr.or(r.brdf_sr),
            ..r.clone()
        })
        .collect();
    let before = gonio_results::sweeps::truth_summary(&raw).expect("summary");
    eprintln!(
        "{} readings: relative rms {:?} completed, {:?} as read; k=2 coverage {:.3}",
        summary.readings,
        summary.cos_weighted_relative_rms,
        before.cos_weighted_relative_rms,
        summary.coverage_k2
    );
    let (after, before) = (
        summary.cos_weighted_relative_rms.expect("rms"),
        before.cos_weighted_relative_rms.expect("rms"),
    );
    assert!(summary.readings > 50, "{summary:?}");
    assert!(after < 2e-3, "rms {after:.2e} completed");
    assert!(
        after < 0.5 * before,
        "rms {after:.2e} completed, {before:.2e} as read"
    );
    assert!(summary.coverage_k2 >= 0.90, "{summary:?}");
}

/// A controller that takes its time to answer (12 ms here; the SMC100 manual gives about 10 ms to execute a
/// position query) leaves open when, within each exchange, it took the position it reports: the run records that
/// window in each segment's timing uncertainty, the completion puts it in the readings' budgets, and their k=2
/// intervals still cover the truth. Without the delay the segments carry the meter's exchange alone.
#[tokio::test(start_paused = true)]
async fn a_slow_controllers_report_window_is_in_the_readings_uncertainty() {
    let mut runs = Vec::new();
    // The simulated controllers take the position as a query is sent; the third run's file says so. The
    // fourth's controllers answer 12 ms after a query and take the position 9 ms after it, as their file says.
    for (delay_ms, latency_ms, sampled_ms) in [
        (0.0, None, None),
        (12.0, None, None),
        (12.0, None, Some(0.0)),
        (0.0, Some(12.0), Some(9.0)),
    ] {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut file = InstrumentFile::simulated();
        file.simulator.faults.delay_ms = delay_ms;
        for d in &mut file.instrument.devices {
            d.position_sampled_ms = sampled_ms;
            d.reply_latency_ms = latency_ms;
        }
        let s = setup_on(dir.path(), FAST, file).await;
        let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
            .await
            .expect("run");
        assert_eq!(state, CampaignState::Completed);
        let store = s.store.lock().expect("lock");
        let segments = store.sweep_segments(s.id).expect("segments");
        let readings = store.sweep_readings(s.id).expect("readings");
        let summary = gonio_results::sweeps::truth_summary(&readings).expect("summary");
        let mut u_rel: Vec<f64> = readings
            .iter()
            .filter_map(|r| Some(r.brdf_u_sr? / r.brdf_sr?))
            .filter(|u| u.is_finite())
            .collect();
        u_rel.sort_by(f64::total_cmp);
        let p90 = u_rel[u_rel.len() * 9 / 10];
        let rms = summary.cos_weighted_relative_rms.expect("rms");
        eprintln!(
            "reply delay {delay_ms} ms, latency {latency_ms:?} ms, sampled {sampled_ms:?} ms: timing u {:?} s, k=2 coverage {:.3}, \
             p90 relative u {p90:.2e}, rms {rms:.2e}",
            segments.iter().map(|g| g.timing_u_s).collect::<Vec<_>>(),
            summary.coverage_k2
        );
        assert!(!segments.is_empty());
        assert!(summary.coverage_k2 >= 0.90, "{delay_ms} ms: {summary:?}");
        runs.push((segments, p90, rms));
    }
    let (quick, slow, told, late) = (&runs[0], &runs[1], &runs[2], &runs[3]);
    // Told when the position is taken, the run dates the reports there: no window, and the readings are placed
    // where the arm was (dated in the window's middle they were 5.5 ms late: 0.055 deg behind at 10 deg/s; the
    // coloured plastic's lobe then off by 6.4e-3 rms, told 8e-5).
    for g in told.0.iter().chain(&late.0) {
        assert_eq!(g.timing_u_s, Some(gonio_engine::budget::TIMING_U_S), "{g:?}");
    }
    for (what, run) in [("taken on sending", told), ("taken 9 ms after", late)] {
        assert!(
            run.2 < 0.2 * slow.2,
            "rms {:.2e} {what}, {:.2e} window",
            run.2,
            slow.2
        );
    }
    for g in &quick.0 {
        assert_eq!(g.timing_u_s, Some(gonio_engine::budget::TIMING_U_S), "{g:?}");
    }
    // 12 ms less the request's 0.9 ms on the line, uniform: 3.2 ms, with the meter's 1 ms.
    for g in &slow.0 {
        let u = g.timing_u_s.expect("recorded");
        assert!(u > 0.003 && u < 0.0036, "{g:?}");
    }
    assert!(
        slow.1 > quick.1,
        "p90 relative u {:.2e} slow, {:.2e} quick",
        slow.1,
        quick.1
    );
}

#[tokio::test(start_paused = true)]
async fn an_isotropic_samples_far_stretch_is_measured_turned_without_turning_the_sample() {
    // The arc through the source in two stretches: with `isotropic = true` the far one is measured on the arc
    // turned about the normal, the sample held, and only the light arm changes sides between them.
    let campaign = |isotropic: bool| {
        format!(
            "[campaign]\nid = \"iso\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [550.0]\n[[plan.sweeps]]\n\
             theta_i_deg = [30.0]\ntheta_o_deg = {{ from = -80.0, to = 80.0 }}\nspeed_deg_s = 10.0\n{}\
             [calibration]\nsimulate_operator = true\n[material]\npreset = \"coloured-plastic\"\n",
            if isotropic { "isotropic = true\n" } else { "" }
        )
    };
    let mut swept_s = Vec::new();
    for isotropic in [false, true] {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = setup_with(dir.path(), &campaign(isotropic)).await;
        let state = run_campaign(Arc::clone(&s.store), s.id, &s.rig, Control::new())
            .await
            .expect("run");
        assert_eq!(state, CampaignState::Completed);
        let store = s.store.lock().expect("lock");
        let readings = store.sweep_readings(s.id).expect("readings");
        let segments = store.sweep_segments(s.id).expect("segments");
        check_segments(&readings, &s.steps);
        assert_eq!(segments.len(), 2);
        swept_s.push(segments[1].ended_s - segments[0].started_s);
        let last_of = |seg: u32| {
            readings
                .iter()
                .filter(|r| r.segment == seg)
                .map(|r| r.t_s)
                .fold(f64::NAN, f64::max)
        };
        let first_of = |seg: u32| {
            readings
                .iter()
                .filter(|r| r.segment == seg)
                .map(|r| r.t_s)
                .fold(f64::NAN, f64::min)
        };
        // What docs/reference/campaign-file.md quotes: the stretches' gap from one's last reading to the next's first.
        eprintln!(
            "isotropic {isotropic}: {:.2} s between the stretches' readings",
            first_of(1) - last_of(0)
        );
        // Each stretch's readings carry the geometry measured: the near stretch's incidence at phi_i = 0, the
        // far one's at 0 (the sample turned) or 180 (the arc turned, the sample held).
        let far_phi: Vec<f64> = readings
            .iter()
            .filter(|r| r.arc_from_deg > -30.0)
            .map(|r| r.phi_i_deg.rem_euclid(360.0))
            .collect();
        assert!(!far_phi.is_empty());
        let expected = if isotropic { 180.0 } else { 0.0 };
        assert!(
            far_phi.iter().all(|p| (p - expected).abs() < 1e-6),
            "{isotropic}: {:?}",
            &far_phi[..3]
        );
        // Both stretches agree with the simulator's truth at the geometry each reading carries.
        let summary = gonio_results::sweeps::truth_summary(&readings).expect("summary");
        eprintln!(
            "isotropic {isotropic}: k=2 coverage {:.3} of {}",
            summary.coverage_k2, summary.readings
        );
        assert!(summary.coverage_k2 >= 0.90, "{isotropic}: {summary:?}");
        for r in readings
            .iter()
            .filter(|r| (r.theta_o_deg - r.theta_i_deg).abs() > 8.0)
        {
            let (f, t) = (r.brdf_sr.expect("value"), r.truth_point_sr.expect("truth"));
            assert!((f - t).abs() <= 0.01 * t, "{r:?}");
        }
    }
    // The move between the stretches: the sample's half turn (6.25 s at 30 deg/s) against the light arm's 60
    // degrees (3.25 s) with the detector moving at once.
    eprintln!(
        "from the first sweep's start to the last's end: {:.2} s, isotropic {:.2} s",
        swept_s[0], swept_s[1]
    );
    assert!(swept_s[0] - swept_s[1] > 2.5, "{swept_s:?}");
}
