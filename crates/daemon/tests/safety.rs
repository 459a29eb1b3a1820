//! Safety invariants of the real engine, as property tests over random plans and random interleavings of pause,
//! abort and emergency stop.
//!
//! Each case runs [`run_campaign`] on the in-process simulated instrument under tokio's paused clock (simulated
//! time at scale 1, no wall time spent waiting), resuming after every pause or emergency stop until the campaign
//! completes or is aborted. The simulator records every motion command its device emulators received over the
//! wire and every axis's exact trajectory (`gonio_simulator::recording`); the checks read only that record:
//! - the arms never come closer than `safety.min_arm_separation_deg` at any instant, motor and load (backlash)
//!   alike, computed exactly on the quadratic pieces of both trajectories. The simulator powers up with both arms
//!   at zero (closer than allowed); until they are first apart their separation may only grow;
//! - no axis is ever commanded to a target beyond its limits, and no trajectory leaves them;
//! - an emergency stop reaches every axis over the wire within 50 ms of the request (simulated clock), and no
//!   axis is commanded to move again until the campaign is resumed;
//! - every measured point's read-back pose passes the scheduler's own constraint checks (`Constraints`,
//!   `Pose::arm_separation_deg`): the independent reference for what is measured.
//!
//! Cases: `GONIO_SAFETY_CASES` (default 6; e.g. `GONIO_SAFETY_CASES=200 cargo test --release -p gonio-daemon
//! --test safety` for a large run).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_daemon::engine::{Control, Rig, prepare_campaign, run_campaign};
use gonio_daemon::store::{CampaignState, Store};
use gonio_instrument::{Axis, AxisRole, InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Kinematics, Pose};
use gonio_simulator::recording::{MotionCommand, MotionRecord, Piece};
use proptest::prelude::*;

/// Longest time from an emergency-stop request to the stop command at every axis (simulated seconds).
const ESTOP_DEADLINE_S: f64 = 0.050;
/// Slack on angle comparisons (floating-point rounding of degree arithmetic).
const EPS_DEG: f64 = 1e-9;

fn cases() -> u32 {
    std::env::var("GONIO_SAFETY_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(6)
}

// ---------------------------------------------------------------- random campaigns

#[derive(Debug, Clone, Copy, PartialEq)]
enum Act {
    Pause,
    Abort,
    Estop,
}

/// A request made `after_s` simulated seconds after the previous one (or after the run started).
#[derive(Debug, Clone)]
struct Interruption {
    after_s: f64,
    act: Act,
    /// Simulated seconds before a paused campaign is resumed.
    resume_after_s: f64,
}

/// Injected device faults (the simulator's): stalled moves, garbled and lost replies.
#[derive(Debug, Clone, Copy)]
struct FaultLevel {
    seed: u64,
    stall_rate: f64,
    garble_rate: f64,
    drop_rate: f64,
}

impl FaultLevel {
    fn any(&self) -> bool {
        self.stall_rate > 0.0 || self.garble_rate > 0.0 || self.drop_rate > 0.0
    }
}

#[derive(Debug, Clone)]
struct Case {
    campaign: String,
    interruptions: Vec<Interruption>,
    faults: FaultLevel,
}

fn round1(x: f64) -> f64 {
    (x * 10.0).round() / 10.0
}

/// A plan of one of three kinds: explicit geometries (tilt and rotation move), an in-plane sweep, or a small
/// isotropic grid; always at least one geometry that every constraint allows.
fn plan_table() -> impl Strategy<Value = String> {
    let points = proptest::collection::vec((0.0..70.0f64, 0.0..360.0f64, 0.0..80.0f64, 0.0..360.0f64), 1..8)
        .prop_map(|pts| {
            let mut list = vec!["[30.0, 0.0, 30.0, 180.0]".to_string()];
            list.extend(pts.into_iter().map(|(ti, pi, to, po)| {
                format!("[{}, {}, {}, {}]", round1(ti), round1(pi), round1(to), round1(po))
            }));
            format!("kind = \"points\"\npoints = [{}]\n", list.join(", "))
        });
    let in_plane = (0.0..60.0f64, 5.0..40.0f64, -70.0..0.0f64, 0.0..180.0f64).prop_map(|(ti, step, from, plane)| {
        format!(
            "kind = \"in-plane\"\ntheta_i_deg = [{}, 30.0]\ntheta_o_deg = {{ from = {}, to = 70.0, step = {} }}\n\
             plane_phi_deg = [{}]\n",
            round1(ti),
            round1(from),
            round1(step),
            round1(plane)
        )
    });
    let isotropic = (10.0..60.0f64, 20.0..90.0f64).prop_map(|(step, dphi)| {
        format!(
            "kind = \"isotropic\"\ntheta_i_deg = {{ from = 0.0, to = 60.0, step = {} }}\n\
             theta_o_deg = [20.0, 50.0]\ndelta_phi_deg = {{ from = 0.0, to = 180.0, step = {} }}\n",
            round1(step),
            round1(dphi)
        )
    });
    prop_oneof![points, in_plane, isotropic]
}

fn campaign_text() -> impl Strategy<Value = String> {
    let bands = proptest::sample::subsequence(vec![450.0, 550.0, 650.0], 1..=2);
    (
        plan_table(),
        bands,
        1u32..=2,
        (1u32..6, 2u32..9),
        -99.0..-81.0f64,
        (1u32..4, 0.0..0.2f64),
        prop::bool::ANY,
    )
        .prop_map(
            |(grid, bands, repeats, (dark, reference), light, (averaging, settle), plastic)| {
                let bands: Vec<String> = bands.iter().map(|b: &f64| format!("{b:.1}")).collect();
                format!(
                    r#"[campaign]
id = "safety"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [{bands}]
repeats = {repeats}
reciprocity = false
[plan.grid]
{grid}
[plan.calibration]
dark_every_points = {dark}
reference_every_points = {reference}
reference_pose_deg = {{ light = {light}, detector = {detector} }}
[calibration]
method = "absolute"
simulate_operator = true
[acquisition]
averaging = {averaging}
settle_s = {settle}
[material]
preset = "{material}"
"#,
                    bands = bands.join(", "),
                    // The detector faces the source: the direct beam.
                    light = round1(light),
                    detector = round1(light) + 180.0,
                    settle = round1(settle),
                    material = if plastic { "coloured-plastic" } else { "spectralon" },
                )
            },
        )
}

fn interruption() -> impl Strategy<Value = Interruption> {
    let act = prop_oneof![2 => Just(Act::Pause), 1 => Just(Act::Abort), 4 => Just(Act::Estop)];
    // Mostly within the first tens of seconds of a run, sometimes at once (start-up, homing, calibration).
    let after = prop_oneof![1 => 0.0..0.5f64, 4 => 0.5..40.0f64];
    (after, act, 0.0..5.0f64).prop_map(|(after_s, act, resume_after_s)| Interruption {
        after_s,
        act,
        resume_after_s,
    })
}

fn faults() -> impl Strategy<Value = FaultLevel> {
    let none = Just(FaultLevel {
        seed: 0,
        stall_rate: 0.0,
        garble_rate: 0.0,
        drop_rate: 0.0,
    });
    let some = (
        any::<u64>(),
        prop_oneof![Just(0.0), Just(0.05), Just(0.2)],
        prop_oneof![Just(0.0), Just(0.01)],
    )
        .prop_map(|(seed, stall_rate, garble_rate)| FaultLevel {
            seed,
            stall_rate,
            garble_rate,
            drop_rate: garble_rate / 2.0,
        });
    prop_oneof![2 => none, 1 => some]
}

fn case() -> impl Strategy<Value = Case> {
    (
        campaign_text(),
        proptest::collection::vec(interruption(), 0..6),
        faults(),
    )
        .prop_map(|(campaign, interruptions, faults)| Case {
            campaign,
            interruptions,
            faults,
        })
}

// ---------------------------------------------------------------- running a case

/// What happened during a case, for the checks.
struct Outcome {
    file: InstrumentFile,
    records: Vec<(Axis, MotionRecord)>,
    end_s: f64,
    /// Emergency stops: (requested at, next run started at, or the end).
    estops: Vec<(f64, f64)>,
    points: Vec<gonio_daemon::store::PointRecord>,
    final_state: CampaignState,
}

async fn run_case(case: &Case) -> Result<Outcome, TestCaseError> {
    let mut file = InstrumentFile::simulated();
    let f = &mut file.simulator.faults;
    (f.seed, f.stall_rate, f.garble_rate, f.drop_rate) = (
        case.faults.seed,
        case.faults.stall_rate,
        case.faults.garble_rate,
        case.faults.drop_rate,
    );
    let dir = tempfile::tempdir().map_err(|e| TestCaseError::fail(format!("tempdir: {e}")))?;
    let prepared = prepare_campaign(&case.campaign, "safety.toml", dir.path(), &file)
        .map_err(|e| TestCaseError::fail(format!("generated campaign refused: {e}\n{}", case.campaign)))?;
    let mut store = Store::open(dir.path()).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let id = store
        .create_campaign(&prepared.new_campaign(&case.campaign, SIMULATED_INSTRUMENT_TOML))
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(&file, None, 1.0)
        .await
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
    let sim = rig.sim().expect("the simulated instrument").clone();
    sim.start_motion_recording();
    let control = Control::new();
    let clock = sim.clock();

    let mut pending = case.interruptions.iter();
    let mut estops: Vec<(f64, f64)> = Vec::new();
    let mut open_estop: Option<f64> = None;
    let mut final_state = None;
    // Faults may pause a campaign by themselves (three failed points in a row): resume it a few times.
    let runs = case.interruptions.len() + if case.faults.any() { 6 } else { 2 };
    let mut state = CampaignState::Queued;
    for _run in 0..runs {
        if let Some(t) = open_estop.take() {
            estops.push((t, sim.now_s()));
        }
        let mut task = {
            let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
            tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
        };
        let mut resume_after_s = 0.0;
        let joined = loop {
            let Some(next) = pending.next() else {
                break (&mut task).await;
            };
            tokio::select! {
                r = &mut task => break r,
                _ = clock.sleep_s(next.after_s) => {
                    resume_after_s = next.resume_after_s;
                    match next.act {
                        Act::Pause => control.pause(),
                        Act::Abort => control.abort(),
                        Act::Estop => {
                            open_estop.get_or_insert(sim.now_s());
                            control.estop();
                        }
                    }
                }
            }
        };
        state = joined
            .map_err(|e| TestCaseError::fail(format!("engine task: {e}")))?
            .map_err(|e| TestCaseError::fail(format!("engine error: {e}")))?;
        if std::env::var("GONIO_SAFETY_DEBUG").is_ok() {
            let c = store.lock().expect("store").campaign(id).ok();
            eprintln!(
                "run ended {state} at {} s: {:?}",
                sim.now_s(),
                c.map(|c| (c.points_done, c.last_error))
            );
        }
        match state {
            CampaignState::Completed | CampaignState::Aborted => {
                final_state = Some(state);
                break;
            }
            CampaignState::Paused => {
                clock.sleep_s(resume_after_s).await;
                control.resume();
            }
            other => {
                let last = store
                    .lock()
                    .expect("store")
                    .campaign(id)
                    .ok()
                    .and_then(|c| c.last_error);
                return Err(TestCaseError::fail(format!("run ended {other}: {last:?}")));
            }
        }
    }
    let final_state = match final_state {
        Some(s) => s,
        // Under injected faults a campaign may still be paused by them: the motion checks apply all the same.
        None if case.faults.any() && state == CampaignState::Paused => state,
        None => {
            return Err(TestCaseError::fail(
                "the campaign neither completed nor was aborted",
            ));
        }
    };
    let end_s = sim.now_s();
    if let Some(t) = open_estop.take() {
        estops.push((t, end_s));
    }
    let points = store
        .lock()
        .expect("store")
        .points(id)
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
    Ok(Outcome {
        file,
        records: sim.motion_records(),
        end_s,
        estops,
        points,
        final_state,
    })
}

// ---------------------------------------------------------------- the checks

/// Pieces in physical degrees: `a = direction * (p - zero_offset)`.
fn physical(axis: &Axis, pieces: Vec<Piece>) -> Vec<Piece> {
    let dir = f64::from(axis.direction);
    pieces
        .into_iter()
        .map(|p| Piece {
            p0_deg: dir * (p.p0_deg - axis.zero_offset_deg),
            v0_deg_s: dir * p.v0_deg_s,
            a_deg_s2: dir * p.a_deg_s2,
            ..p
        })
        .collect()
}

/// Position and velocity of a piece at `t` (inside it).
fn state_at(p: &Piece, t: f64) -> (f64, f64) {
    (p.position_at(t), p.v0_deg_s + p.a_deg_s2 * (t - p.t0_s))
}

/// One interval between the breakpoints of both trajectories, with `f = l - d` at its ends and its extremes.
#[derive(Debug, Clone, Copy)]
struct Stretch {
    ta: f64,
    tb: f64,
    fa: f64,
    lo: f64,
    hi: f64,
}

/// `l(t) - d(t)` on each interval between the breakpoints of both trajectories: on each such interval the
/// difference is one quadratic, whose extremes lie at its ends or at its vertex.
fn difference_extremes(l: &[Piece], d: &[Piece]) -> Vec<Stretch> {
    let mut breaks: Vec<f64> = l.iter().chain(d.iter()).flat_map(|p| [p.t0_s, p.t1_s]).collect();
    breaks.sort_by(f64::total_cmp);
    breaks.dedup();
    let covering = |pieces: &[Piece], t: f64| pieces.iter().find(|p| p.t0_s <= t && t <= p.t1_s).copied();
    let mut out = Vec::new();
    for w in breaks.windows(2) {
        let (ta, tb) = (w[0], w[1]);
        if tb <= ta {
            continue;
        }
        let mid = 0.5 * (ta + tb);
        let (Some(lp), Some(dp)) = (covering(l, mid), covering(d, mid)) else {
            continue;
        };
        let ((l0, lv), (d0, dv)) = (state_at(&lp, ta), state_at(&dp, ta));
        let (c0, c1, c2) = (l0 - d0, lv - dv, 0.5 * (lp.a_deg_s2 - dp.a_deg_s2));
        let f = |t: f64| c0 + c1 * (t - ta) + c2 * (t - ta) * (t - ta);
        let (fa, fb) = (f(ta), f(tb));
        let (mut lo, mut hi) = (fa.min(fb), fa.max(fb));
        if c2 != 0.0 {
            let tv = ta - c1 / (2.0 * c2);
            if tv > ta && tv < tb {
                lo = lo.min(f(tv));
                hi = hi.max(f(tv));
            }
        }
        out.push(Stretch { ta, tb, fa, lo, hi });
    }
    out
}

/// The separation rule on the arms' trajectories: `Err` names the first stretch where they were too close.
/// Returns the smallest separation seen once apart.
fn check_separation(l: &[Piece], d: &[Piece], constraints: &Constraints) -> Result<f64, String> {
    let sep = constraints.min_arm_separation_deg;
    let mut apart = false;
    let mut min_seen = f64::INFINITY;
    for Stretch { ta, tb, fa, lo, hi } in difference_extremes(l, d) {
        // The arms are within 200 degrees of each other (axis limits +-100): |l - d| is their separation
        // whenever it is below 180, which is all that matters here.
        let nearest = if lo > 0.0 {
            lo
        } else if hi < 0.0 {
            -hi
        } else {
            0.0
        };
        let farthest = lo.abs().max(hi.abs());
        apart |= constraints.separation_ok(fa.abs());
        if apart {
            min_seen = min_seen.min(nearest);
            if !constraints.separation_ok(nearest) {
                return Err(format!(
                    "arms {nearest:.6} deg apart between t = {ta:.4} s and {tb:.4} s (minimum {sep} deg)"
                ));
            }
        } else {
            // Before the arms are first apart (power-up), their separation may only grow.
            if nearest + EPS_DEG < fa.abs() {
                return Err(format!(
                    "before the arms were apart their separation shrank from {:.6} to {nearest:.6} deg between \
                     t = {ta:.4} s and {tb:.4} s",
                    fa.abs()
                ));
            }
            apart = constraints.separation_ok(farthest);
            if apart {
                min_seen = min_seen.min(farthest);
            }
        }
    }
    Ok(min_seen)
}

fn check(case: &Case, o: &Outcome) -> Result<(), TestCaseError> {
    let inst = &o.file.instrument;
    let constraints = Constraints::new(inst, Some(12.5));
    let role = |r: AxisRole| o.records.iter().find(|(a, _)| a.role == r);

    // Limits: every commanded target and every trajectory.
    for (axis, record) in &o.records {
        prop_assert!(!record.truncated, "record of {} truncated", axis.name);
        for c in &record.commands {
            if let MotionCommand::MoveTo { target_deg } = c.command {
                let phys = axis.physical_from_controller_deg(target_deg);
                prop_assert!(
                    phys >= axis.min_deg - EPS_DEG && phys <= axis.max_deg + EPS_DEG,
                    "{} commanded to {phys} deg at t = {} s, limits [{}, {}]",
                    axis.name,
                    c.t_s,
                    axis.min_deg,
                    axis.max_deg
                );
            }
        }
        for p in physical(axis, record.motor_pieces(o.end_s)) {
            let mut values = vec![p.position_at(p.t0_s), p.position_at(p.t1_s)];
            if p.a_deg_s2 != 0.0 {
                let tv = p.t0_s - p.v0_deg_s / p.a_deg_s2;
                if tv > p.t0_s && tv < p.t1_s {
                    values.push(p.position_at(tv));
                }
            }
            for v in values {
                prop_assert!(
                    v >= axis.min_deg - EPS_DEG && v <= axis.max_deg + EPS_DEG,
                    "{} at {v} deg around t = {} s, limits [{}, {}]",
                    axis.name,
                    p.t0_s,
                    axis.min_deg,
                    axis.max_deg
                );
            }
        }
    }

    // Arm separation at every instant, for the motors and for the loads (what really swings).
    let (Some((la, lr)), Some((da, dr))) = (role(AxisRole::LightArm), role(AxisRole::DetectorArm)) else {
        return Err(TestCaseError::fail("no arm axes"));
    };
    let motor = check_separation(
        &physical(la, lr.motor_pieces(o.end_s)),
        &physical(da, dr.motor_pieces(o.end_s)),
        &constraints,
    );
    prop_assert!(motor.is_ok(), "motors: {}\n{case:#?}", motor.unwrap_err());
    let load = check_separation(
        &physical(la, lr.load_pieces(la.backlash_deg, o.end_s)),
        &physical(da, dr.load_pieces(da.backlash_deg, o.end_s)),
        &constraints,
    );
    prop_assert!(load.is_ok(), "loads: {}\n{case:#?}", load.unwrap_err());
    if std::env::var("GONIO_SAFETY_DEBUG").is_ok() {
        let moves: usize = o
            .records
            .iter()
            .map(|(_, r)| {
                r.commands
                    .iter()
                    .filter(|c| matches!(c.command, MotionCommand::MoveTo { .. }))
                    .count()
            })
            .sum();
        eprintln!(
            "checked: {moves} move commands, {} emergency stops, {} points; closest arms: motors {:?}, loads {:?}",
            o.estops.len(),
            o.points.len(),
            motor,
            load
        );
    }

    // Emergency stops: a stop on the wire at every axis within the deadline, then no move until resumed.
    for &(requested, resumed) in &o.estops {
        for (axis, record) in &o.records {
            let stop = record.commands.iter().find(|c| {
                matches!(c.command, MotionCommand::Stop { .. })
                    && c.t_s >= requested - EPS_DEG
                    && c.t_s <= requested + ESTOP_DEADLINE_S
            });
            let Some(stop) = stop else {
                let next = record
                    .commands
                    .iter()
                    .find(|c| c.t_s >= requested - EPS_DEG)
                    .map(|c| format!("{:?} at {} s", c.command, c.t_s));
                return Err(TestCaseError::fail(format!(
                    "emergency stop at t = {requested} s: no stop reached {} within {} ms (next command: {next:?})",
                    axis.name,
                    ESTOP_DEADLINE_S * 1e3
                )));
            };
            let moved = record.commands.iter().find(|c| {
                matches!(c.command, MotionCommand::MoveTo { .. } | MotionCommand::Home)
                    && c.t_s >= stop.t_s
                    && c.t_s < resumed
            });
            prop_assert!(
                moved.is_none(),
                "{} commanded {:?} after the emergency stop at {requested} s, before the resume at {resumed} s",
                axis.name,
                moved
            );
        }
    }

    // Every measured point, by the scheduler's own rules: read-back within limits, arms apart, and the
    // geometry it measured (forward kinematics of the read-back) allowed.
    let kinematics = Kinematics::new(inst);
    for p in o
        .points
        .iter()
        .filter(|p| p.flags.iter().all(|f| !f.starts_with("failed")))
    {
        let mut pose = Pose::new(0.0, 0.0, 0.0, 0.0);
        for (name, value) in &p.readback_deg {
            let axis = inst.axes.iter().find(|a| &a.name == name);
            prop_assert!(axis.is_some(), "read-back of unknown axis {name}");
            if let Some(axis) = axis {
                prop_assert!(
                    (axis.min_deg..=axis.max_deg).contains(value),
                    "{name} read back at {value}"
                );
                pose.set(axis.role, *value);
            }
        }
        prop_assert!(
            constraints.separation_ok(pose.arm_separation_deg()),
            "point {} measured with the arms {} deg apart",
            p.index,
            pose.arm_separation_deg()
        );
        let (wi, wo) = kinematics.forward(&pose);
        let allowed = constraints.check_directions(&wi, &wo);
        // Positioning tolerance can push a point sitting exactly on a limit a hair over it: only a clear
        // violation counts (the arm-separation rule is checked exactly above).
        if let Err(reason) = allowed {
            let nominal = gonio_brdf::geometry::Direction::from_spherical_deg(p.theta_i_deg, p.phi_i_deg);
            let nominal_o = gonio_brdf::geometry::Direction::from_spherical_deg(p.theta_o_deg, p.phi_o_deg);
            prop_assert!(
                constraints.check_directions(&nominal, &nominal_o).is_ok(),
                "point {} ({}, {}, {}, {}) violates {reason}",
                p.index,
                p.theta_i_deg,
                p.phi_i_deg,
                p.theta_o_deg,
                p.phi_o_deg
            );
        }
    }
    prop_assert!(
        matches!(o.final_state, CampaignState::Completed | CampaignState::Aborted) || case.faults.any(),
        "{:?}",
        o.final_state
    );
    Ok(())
}

fn run_and_check(case: &Case) -> Result<(), TestCaseError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(|e| TestCaseError::fail(format!("runtime: {e}")))?;
    rt.block_on(async {
        // Under the paused clock a hang turns into this timeout at once.
        let outcome = tokio::time::timeout(Duration::from_secs(7 * 24 * 3600), run_case(case))
            .await
            .map_err(|_| TestCaseError::fail("no end within a simulated week"))??;
        check(case, &outcome)
    })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        max_shrink_iters: 24,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn arms_apart_within_limits_and_estop_in_time_over_random_plans_and_interruptions(c in case()) {
        run_and_check(&c)?;
    }
}

// ---------------------------------------------------------------- the checker itself

fn piece(t0_s: f64, t1_s: f64, p0_deg: f64, v0_deg_s: f64, a_deg_s2: f64) -> Piece {
    Piece {
        t0_s,
        t1_s,
        p0_deg,
        v0_deg_s,
        a_deg_s2,
    }
}

#[test]
fn the_separation_check_finds_a_brief_approach_between_samples() {
    let c = Constraints::new(&InstrumentFile::simulated().instrument, None);
    // Both arms apart at every breakpoint, but the detector swings (quadratic) to within 9.5 deg of the
    // light arm in between: the vertex must be found.
    let light = vec![piece(0.0, 2.0, 0.0, 0.0, 0.0)];
    // d(t) = 20 - 10.5 * 4 t (1 - t)... as one quadratic: d(t) = 20 - 42 t + 42 t^2 on [0, 1], min 9.5 at 0.5.
    let detector = vec![
        piece(0.0, 1.0, 20.0, -42.0, 84.0),
        piece(1.0, 2.0, 20.0, 0.0, 0.0),
    ];
    let err = check_separation(&light, &detector, &c).expect_err("too close at t = 0.5");
    assert!(err.contains("9.5"), "{err}");
    // The same swing kept at 10.5 deg at its closest is fine, and the minimum is reported.
    let detector = vec![
        piece(0.0, 1.0, 20.0, -38.0, 76.0),
        piece(1.0, 2.0, 20.0, 0.0, 0.0),
    ];
    let min = check_separation(&light, &detector, &c).expect("apart");
    assert!((min - 10.5).abs() < 1e-9, "{min}");
    // Arms that start together may only separate until they are apart.
    let detector = vec![piece(0.0, 1.0, 0.0, 12.0, 0.0), piece(1.0, 2.0, 12.0, -4.0, 0.0)];
    let err = check_separation(&light, &detector, &c).expect_err("came back");
    assert!(err.contains("8.0"), "{err}");
}

/// Cases the property found, kept as regressions.
fn regression(campaign_edit: &[(&str, &str)], faults: FaultLevel, interruptions: Vec<Interruption>) -> Case {
    let mut campaign = r#"[campaign]
id = "safety"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [650.0]
repeats = 1
reciprocity = false
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 10 }
theta_o_deg = [20.0, 50.0]
delta_phi_deg = { from = 0.0, to = 180.0, step = 20 }

[plan.calibration]
dark_every_points = 1
reference_every_points = 2
reference_pose_deg = { light = -81, detector = 99 }
[calibration]
method = "absolute"
simulate_operator = true
[acquisition]
averaging = 1
settle_s = 0
[material]
preset = "spectralon"
"#
    .to_string();
    for (from, to) in campaign_edit {
        campaign = campaign.replace(from, to);
    }
    Case {
        campaign,
        interruptions,
        faults,
    }
}

#[test]
fn regression_a_stalled_move_keeps_the_arms_apart() {
    let case = regression(
        &[],
        FaultLevel {
            seed: 5329611950739166726,
            stall_rate: 0.05,
            garble_rate: 0.0,
            drop_rate: 0.0,
        },
        Vec::new(),
    );
    if std::env::var("GONIO_SAFETY_DEBUG").is_ok() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .expect("rt");
        let o = rt.block_on(run_case(&case)).expect("ran");
        for (axis, r) in &o.records {
            if !matches!(axis.role, AxisRole::LightArm | AxisRole::DetectorArm) {
                continue;
            }
            for c in r.commands.iter().filter(|c| c.t_s < 8.0) {
                eprintln!("{} cmd {:.4} {:?}", axis.name, c.t_s, c.command);
            }
            for c in r.changes.iter().filter(|c| c.t_s < 8.0) {
                eprintln!(
                    "{} chg {:.4} {:?} motor {:.4} rest {:.4} end {:?} segs {:?}",
                    axis.name,
                    c.t_s,
                    c.kind,
                    c.motor_deg,
                    c.rest_deg,
                    c.end,
                    c.segments
                        .iter()
                        .map(|s| (s.t0_s, s.end_s(), s.p0_deg))
                        .collect::<Vec<_>>()
                );
            }
        }
    }
    run_and_check(&case).unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn the_planner_keeps_a_stopping_margin_between_arms_that_move_together() {
    let inst = InstrumentFile::simulated().instrument;
    let time = gonio_scheduler::timing::TimeModel::new(&inst);
    // 20 deg/s and 80 deg/s^2: one 50 ms status poll at full speed, then v^2 / 2a of braking.
    let margin = time.arm_stopping_margin_deg();
    assert!((margin - (20.0 * 0.05 + 400.0 / 160.0)).abs() < 1e-12, "{margin}");
    // The move the safety property caught: the detector following the light arm 12.5 deg behind. Had the light
    // arm stalled, the detector would have come within 10 deg: it is now two phases (one arm at a time).
    let from = Pose::new(-6.25, 6.25, 0.0, 0.0);
    let to = Pose::new(-60.0, -20.0, 0.0, 0.0);
    let m = time.plan_move(&from, &to).expect("a safe move");
    assert_eq!(m.phases.len(), 2, "{m:?}");
    assert!(
        m.phases
            .iter()
            .all(|p| p.iter().filter(|a| a.axis_index < 2).count() == 1),
        "{m:?}"
    );
    // Arms far enough apart still move together.
    let m = time
        .plan_move(
            &Pose::new(-30.0, 30.0, 0.0, 0.0),
            &Pose::new(-50.0, 50.0, 0.0, 0.0),
        )
        .expect("move");
    assert_eq!(m.phases.len(), 1, "{m:?}");
}
