//! Sweeps in the plan: the swept paths against every rule (checked here sample by sample through the forward
//! kinematics, independently of the path check's own scan), the time model against the trapezoid worked by
//! hand, the back-and-forth walk over the bands, and the errors of `[[plan.sweeps]]`.

use gonio_instrument::{AxisRole, Instrument};
use gonio_scheduler::constraints::{Constraints, Reason};
use gonio_scheduler::kinematics::{Kinematics, Pose};
use gonio_scheduler::plan::{PlanError, PlanSpec};
use gonio_scheduler::sweep::{
    EDGE_TOLERANCE_DEG, SweepPlan, SweptArm, build_sweeps, schedule_sweeps, sweep_reading_period_s,
};
use gonio_scheduler::timing::{TimeModel, trapezoid_time_s};
use proptest::prelude::*;

use crate::common::{random_instrument, simulated};

fn sweeps(text: &str, inst: &Instrument, bands: &[f64]) -> Result<SweepPlan, PlanError> {
    let spec = PlanSpec::from_toml(text, "test.toml")?;
    build_sweeps(&spec.sweeps, inst, &TimeModel::new(inst), None, bands, None, &[])
}

/// Every rule at one pose, by the forward kinematics: what the pose really points at.
fn pose_violates(inst: &Instrument, pose: &Pose) -> Option<&'static str> {
    let kin = Kinematics::new(inst);
    let (wi, wo) = kin.forward(pose);
    if let Err(r) = Constraints::new(inst, None).check_directions(&wi, &wo) {
        return Some(r.name());
    }
    for role in [AxisRole::LightArm, AxisRole::DetectorArm] {
        if let Some(a) = inst.axis(role) {
            let x = pose.get(role);
            if x < a.min_deg - 1e-9 || x > a.max_deg + 1e-9 {
                return Some("axis-limits");
            }
        }
    }
    if pose.arm_separation_deg() < inst.safety.min_arm_separation_deg - 1e-9 {
        return Some("arm-separation");
    }
    None
}

/// The pose at fraction `u` of a piece (every axis linear between the ends: only the swept one moves).
fn along(from: &Pose, to: &Pose, u: f64) -> Pose {
    let l = |a: f64, b: f64| a + (b - a) * u;
    Pose::new(
        l(from.light_deg, to.light_deg),
        l(from.detector_deg, to.detector_deg),
        l(from.tilt_deg, to.tilt_deg),
        l(from.rotation_deg, to.rotation_deg),
    )
}

/// Pieces are safe along their whole length, hold every axis but the swept one, and keep the arms' order.
fn check_pieces(inst: &Instrument, plan: &SweepPlan) -> Result<(), String> {
    let mut side = None;
    for (k, arc) in plan.arcs.iter().enumerate() {
        let (a, b) = (&arc.piece.from_pose, &arc.piece.to_pose);
        let swept = match arc.request.arm {
            SweptArm::Detector => AxisRole::DetectorArm,
            SweptArm::Light => AxisRole::LightArm,
        };
        for role in [
            AxisRole::LightArm,
            AxisRole::DetectorArm,
            AxisRole::SampleTilt,
            AxisRole::SampleRotation,
        ] {
            if role != swept && (a.get(role) - b.get(role)).abs() > 1e-9 {
                return Err(format!("arc {k}: {role:?} moves during the sweep"));
            }
        }
        let travel = (b.get(swept) - a.get(swept)).abs();
        if (travel - arc.length_deg()).abs() > 1e-9 {
            return Err(format!(
                "arc {k}: the axis travels {travel} for {} degrees of arc",
                arc.length_deg()
            ));
        }
        let n = (arc.length_deg() / 0.01).ceil() as usize;
        for i in 0..=n {
            let p = along(a, b, i as f64 / n as f64);
            if let Some(rule) = pose_violates(inst, &p) {
                return Err(format!("arc {k} at {:?}: {rule}", p));
            }
        }
        let s = a.light_deg < a.detector_deg;
        if *side.get_or_insert(s) != s {
            return Err(format!("arc {k}: the arms are on the other side"));
        }
    }
    Ok(())
}

#[test]
fn a_detector_sweep_through_the_source_is_cut_at_the_separation_and_resumed_beyond_it() {
    let inst = simulated();
    let plan = sweeps(
        "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -80.0, to = 80.0 }\nspeed_deg_s = 2.0\n",
        &inst,
        &[550.0],
    )
    .unwrap();
    // The simulated instrument keeps 10 degrees between the arms, plus twice its 0.01-degree backlash for the
    // overshoots of an approach: the detector may not come within 10.02 degrees of the source at -30.
    assert_eq!(plan.arcs.len(), 2, "{:#?}", plan.arcs);
    let sep = inst.safety.min_arm_separation_deg + 2.0 * 0.01;
    let (p0, p1) = (&plan.arcs[0].piece, &plan.arcs[1].piece);
    assert!((p0.from_deg + 80.0).abs() < 1e-12 && (p1.to_deg - 80.0).abs() < 1e-12);
    assert!(
        (p0.to_deg - (-30.0 - sep)).abs() < 2.0 * EDGE_TOLERANCE_DEG,
        "{}",
        p0.to_deg
    );
    assert!(
        (p1.from_deg - (-30.0 + sep)).abs() < 2.0 * EDGE_TOLERANCE_DEG,
        "{}",
        p1.from_deg
    );
    // Never beyond the boundary: the ends are on the allowed side.
    assert!(p0.to_deg <= -30.0 - sep && p1.from_deg >= -30.0 + sep);
    let skipped: f64 = plan.skipped_deg.values().sum();
    assert!((skipped - 2.0 * sep).abs() < 1e-4, "{:?}", plan.skipped_deg);
    assert!(
        plan.skipped_deg.contains_key(&Reason::ArmSeparation)
            || plan.skipped_deg.contains_key(&Reason::RetroBlock)
    );
    check_pieces(&inst, &plan).unwrap();
    // The far piece is swept with the mirror solution: the light arm is on the other side of the normal.
    assert!(
        p0.from_pose.light_deg * p1.from_pose.light_deg < 0.0,
        "{:?} {:?}",
        p0.from_pose,
        p1.from_pose
    );
}

#[test]
fn an_isotropic_arc_through_the_source_holds_the_sample_and_measures_the_far_stretch_turned() {
    let inst = simulated();
    let entry = "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -80.0, to = 80.0 }\nspeed_deg_s = 2.0\n";
    let plain = sweeps(entry, &inst, &[550.0]).unwrap();
    let iso = sweeps(&format!("{entry}isotropic = true\n"), &inst, &[550.0]).unwrap();
    assert_eq!(iso.arcs.len(), 2, "{:#?}", iso.arcs);
    check_pieces(&inst, &iso).unwrap();
    // The same stretches of the arc, the same degrees cut.
    for (a, b) in plain.arcs.iter().zip(&iso.arcs) {
        assert!(
            (a.piece.from_deg - b.piece.from_deg).abs() < 1e-9
                && (a.piece.to_deg - b.piece.to_deg).abs() < 1e-9
        );
    }
    assert!((plain.swept_deg() - iso.swept_deg()).abs() < 1e-9);
    // Without the declaration the far stretch turns the sample half a turn; with it the sample holds at the
    // plane's azimuth and the far stretch measures the arc turned about the normal.
    let rotations = |p: &SweepPlan| {
        p.arcs
            .iter()
            .map(|a| a.piece.from_pose.rotation_deg)
            .collect::<Vec<_>>()
    };
    assert!(
        rotations(&plain).iter().any(|r| (r.abs() - 180.0).abs() < 1e-9),
        "{:?}",
        rotations(&plain)
    );
    assert!(
        rotations(&iso).iter().all(|r| r.abs() < 1e-9),
        "{:?}",
        rotations(&iso)
    );
    let turned: Vec<_> = iso.arcs.iter().filter(|a| a.piece.turned).collect();
    assert_eq!(turned.len(), 1);
    let kin = Kinematics::new(&inst);
    let original = plain.arcs[0].request;
    for arc in &iso.arcs {
        for (s, pose) in [
            (arc.piece.from_deg, &arc.piece.from_pose),
            (arc.piece.to_deg, &arc.piece.to_pose),
        ] {
            // What the pose points at (the forward kinematics) is the geometry its readings carry ...
            let (wi, wo) = kin.forward(pose);
            let (ei, eo) = arc.request.geometry_at(s).directions();
            assert!(
                wi.angle_to(&ei).to_degrees() < 1e-6 && wo.angle_to(&eo).to_degrees() < 1e-6,
                "{arc:?} at {s}"
            );
            // ... with the requested theta_i, theta_o and azimuth difference at that swept angle.
            let (g, r) = (arc.request.geometry_at(s), original.geometry_at(s));
            let dphi =
                |g: &gonio_scheduler::kinematics::Geometry| (g.phi_o_deg - g.phi_i_deg).rem_euclid(360.0);
            assert!(
                (g.theta_i_deg - r.theta_i_deg).abs() < 1e-9 && (g.theta_o_deg - r.theta_o_deg).abs() < 1e-9
            );
            assert!((dphi(&g) - dphi(&r)).abs() < 1e-9, "{g:?} against {r:?}");
        }
    }
    assert!(
        turned[0].request.plane_phi_deg.abs() == 180.0,
        "{:?}",
        turned[0].request
    );
    // Only the light arm changes sides between the stretches: the whole sweep is shorter by the sample's half
    // turn (180 deg at 30 deg/s, 6.25 s) less the light arm's 60 deg (3.25 s), both arms moving at once.
    let time = TimeModel::new(&inst);
    let (a, b) = (
        schedule_sweeps(&plain, &time, None, None).breakdown.total_s(),
        schedule_sweeps(&iso, &time, None, None).breakdown.total_s(),
    );
    assert!(a - b > 2.5, "{a} s against {b} s");
}

#[test]
fn sweeps_stop_at_the_grazing_limit_and_light_sweeps_mirror_detector_sweeps() {
    let inst = simulated();
    let detector = sweeps(
        "[[plan.sweeps]]\ntheta_i_deg = [20.0]\ntheta_o_deg = { from = 0.0, to = 89.0 }\nspeed_deg_s = 5.0\n",
        &inst,
        &[550.0],
    )
    .unwrap();
    assert_eq!(detector.arcs.len(), 1);
    let grazing = inst.safety.grazing_limit_deg;
    assert!((detector.arcs[0].piece.to_deg - grazing).abs() < 2.0 * EDGE_TOLERANCE_DEG);
    assert!((detector.skipped_deg[&Reason::GrazingLimit] - (89.0 - grazing)).abs() < 1e-4);
    let light = sweeps(
        "[[plan.sweeps]]\narm = \"light\"\ntheta_o_deg = [20.0]\ntheta_i_deg = { from = 0.0, to = 89.0 }\n\
         speed_deg_s = 5.0\n",
        &inst,
        &[550.0],
    )
    .unwrap();
    assert_eq!(light.arcs.len(), 1);
    // Not the mirror image: the beam's footprint grows as 1 / cos theta_i and must stay inside the sample and
    // the detector's field, so the light arm may stop short of the grazing limit.
    let end = light.arcs[0].piece.to_deg;
    assert!(end <= grazing + 1e-9 && end > 60.0, "{:?}", light.arcs[0].piece);
    if end < grazing - 1e-3 {
        let k = &light.skipped_deg;
        assert!(
            k.contains_key(&Reason::SampleOverfill) || k.contains_key(&Reason::FieldOfViewOverfill),
            "{k:?}"
        );
    }
    check_pieces(&inst, &light).unwrap();
    check_pieces(&inst, &detector).unwrap();
}

#[test]
fn a_sweep_takes_its_trapezoid_and_reads_throughout_back_and_forth_over_the_bands() {
    let inst = simulated();
    let bands = [450.0, 550.0, 650.0];
    let plan = sweeps(
        "[[plan.sweeps]]\ntheta_i_deg = [45.0]\ntheta_o_deg = { from = 0.0, to = 60.0 }\nspeed_deg_s = 2.0\n\
         averaging = 2\n",
        &inst,
        &bands,
    )
    .unwrap();
    assert_eq!(plan.arcs.len(), 1);
    let time = TimeModel::new(&inst);
    let sched = schedule_sweeps(&plan, &time, None, None);
    assert_eq!(sched.steps.len(), 3);
    // 60 degrees at 2 deg/s with 80 deg/s^2: 30 s at cruise plus v/a = 0.025 s for the two ramps.
    let motion = 60.0 / 2.0 + 2.0 / 80.0;
    let det = inst.axis(AxisRole::DetectorArm).unwrap();
    assert!((trapezoid_time_s(60.0, 2.0, det.accel_deg_s2) - motion).abs() < 1e-12);
    let period = 2.0 * 0.003 + 0.001;
    assert!((sweep_reading_period_s(2) - period).abs() < 1e-15);
    let mut bands_seen = Vec::new();
    for (k, step) in sched.steps.iter().enumerate() {
        assert!((step.motion_s - motion).abs() < 1e-9, "{}", step.motion_s);
        // Around the motion, by hand from the drivers' exchanges (SMC100 at 57600 baud: 2 ms an exchange, a
        // 65 ms pause after a set command; Zaber at 115200: 3 ms): VA and AC set on the first sweep, VA alone on
        // the others (the driver knows the acceleration is the axis's), 67 ms each; the axis's own VA restored
        // once, after the last (each band starts where the last ended); nothing before PA (the driver knows where
        // the axis came to rest). After the motion:
        // no reading is asked for that would run more than half its 6 ms past the end, so the last ends within
        // (-3, 4] ms of it. Before it (3 of 7), the driver's wait sees the stop 1 ms after the end and three
        // exchanges later, 7 ms; after it (4 of 7), 2 ms on average, then TS TP TP, 6 ms, and PT TS TP TP, 8 ms
        // (its TP TP the read-back; no other axis is asked).
        let set = if k == 0 { 2.0 * 0.067 } else { 0.067 };
        let restore = if k + 1 == sched.steps.len() { 0.067 } else { 0.0 };
        let tail = 3.0 / 7.0 * 0.007 + 4.0 / 7.0 * (0.002 + 0.006 + 0.008);
        let overhead = set + restore + tail;
        assert!(
            (step.sweep_s - step.motion_s - overhead).abs() < 1e-9,
            "{}",
            step.sweep_s - step.motion_s
        );
        assert_eq!(step.readings, (motion / period).floor() as u64);
        assert!((step.smear_deg - 2.0 * 2.0 * 0.003).abs() < 1e-15);
        // Back and forth: each band starts where the last ended, so no move between them.
        assert_eq!(step.forward, k % 2 == 0);
        if k > 0 {
            assert!(step.movement.phases.is_empty(), "{:?}", step.movement);
            assert!(step.wheel_s > 0.0);
        }
        bands_seen.push(step.band_nm.unwrap());
    }
    bands_seen.sort_by(f64::total_cmp);
    assert_eq!(bands_seen, bands);
    let total: f64 = sched.steps.iter().map(|s| s.total_s()).sum();
    // Every step's time, and the wheel's last turn to its blank (no step's).
    let b = sched.breakdown;
    assert!((b.total_s() - b.closing_s - total).abs() < 1e-9);
    assert!((b.closing_s - time.wheel_time_s(sched.steps[2].wheel_position, Some(6))).abs() < 1e-12);
    assert!((sched.steps[2].start_s - sched.steps[0].total_s() - sched.steps[1].total_s()).abs() < 1e-9);
    assert_eq!(
        sched.readings,
        sched.steps.iter().map(|s| s.readings).sum::<u64>()
    );
}

#[test]
fn sweep_entries_that_cannot_be_swept_are_refused_with_their_key() {
    let inst = simulated();
    let cases = [
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = -80.0, to = 80.0 }\nspeed_deg_s = 50.0",
            "speed_deg_s",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = -80.0, to = 80.0 }\nspeed_deg_s = 0.0",
            "speed_deg_s",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = [10.0, 20.0]\nspeed_deg_s = 1.0",
            "theta_o_deg",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = 40.0, to = 10.0 }\nspeed_deg_s = 1.0",
            "theta_o_deg",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = 0.0, to = 95.0 }\nspeed_deg_s = 1.0",
            "theta_o_deg",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = 0.0, to = 50.0, step = 1.0 }\nspeed_deg_s = 1.0",
            "theta_o_deg",
        ),
        (
            "theta_i_deg = [95.0]\ntheta_o_deg = { from = 0.0, to = 50.0 }\nspeed_deg_s = 1.0",
            "theta_i_deg",
        ),
        (
            "theta_i_deg = [30.0]\ntheta_o_deg = { from = 0.0, to = 50.0 }\nspeed_deg_s = 1.0\naveraging = 0",
            "averaging",
        ),
        (
            "arm = \"light\"\ntheta_o_deg = [30.0]\ntheta_i_deg = [1.0]\nspeed_deg_s = 1.0",
            "theta_i_deg",
        ),
    ];
    for (body, key) in cases {
        let text = format!("[[plan.sweeps]]\n{body}\n");
        match sweeps(&text, &inst, &[550.0]) {
            Err(e @ PlanError::Invalid { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.starts_with(&format!("[plan.sweeps #1] {key}:")),
                    "{body}: {msg}"
                );
            }
            other => panic!("{body}: {other:?}"),
        }
    }
    // An unknown key or arm is a parse error naming it.
    for body in ["arm = \"tilt\"", "speed = 1.0"] {
        let text = format!(
            "[[plan.sweeps]]\n{body}\ntheta_i_deg = [30.0]\ntheta_o_deg = {{ from = 0.0, to = 50.0 }}\nspeed_deg_s = 1.0\n"
        );
        let e = sweeps(&text, &inst, &[550.0]).unwrap_err();
        assert!(matches!(e, PlanError::Parse { .. }), "{e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    /// On random instruments (offsets, directions, limits, separations, in-plane or not): every piece is safe
    /// along its whole length, and what was cut really breaks a rule (checked between the pieces, away from
    /// their ends by more than the edge tolerance and the backlash margin).
    #[test]
    fn swept_paths_are_safe_and_what_is_cut_is_forbidden(
        ri in random_instrument(),
        held in 0.0..70.0f64,
        from in -85.0..0.0f64,
        to in 5.0..85.0f64,
        light in any::<bool>(),
        plane in prop_oneof![Just(0.0), Just(90.0), Just(-135.0)],
    ) {
        let inst = ri.build();
        let (arm, held_key, swept_key) = if light {
            ("light", "theta_o_deg", "theta_i_deg")
        } else {
            ("detector", "theta_i_deg", "theta_o_deg")
        };
        let text = format!(
            "[[plan.sweeps]]\narm = \"{arm}\"\n{held_key} = [{held}]\n{swept_key} = {{ from = {from}, to = {to} }}\n\
             plane_phi_deg = [{plane}]\nspeed_deg_s = 1.0\n"
        );
        let plan = sweeps(&text, &inst, &[550.0]).map_err(|e| TestCaseError::fail(e.to_string()))?;
        check_pieces(&inst, &plan).map_err(TestCaseError::fail)?;
        let covered = plan.swept_deg();
        let skipped: f64 = plan.skipped_deg.values().sum();
        prop_assert!(covered <= to - from + 1e-9);
        prop_assert!(covered + skipped <= to - from + 1e-6, "{covered} + {skipped} > {}", to - from);
        // What the pieces leave of the requested arc: sampled every 0.25 degrees, 0.1 degree in from the ends
        // of each gap, no angle there has a safe pose on the plan's side of the arms.
        let kin = Kinematics::new(&inst);
        let constraints = Constraints::new(&inst, None);
        let request = gonio_scheduler::sweep::requests(&PlanSpec::from_toml(&text, "t").unwrap().sweeps, |_| Some(20.0))
            .unwrap()[0];
        let mut edges = vec![from];
        for arc in &plan.arcs {
            edges.push(arc.piece.from_deg);
            edges.push(arc.piece.to_deg);
        }
        edges.push(to);
        let side = plan.arcs.first().map(|a| a.piece.from_pose.light_deg < a.piece.from_pose.detector_deg);
        let hint = plan.arcs.first().map_or(Pose::new(0.0, 0.0, 0.0, plane), |a| a.piece.from_pose);
        let mut gaps = Vec::new();
        for w in edges.chunks(2) {
            let (a, b) = (w[0] + 0.1, w[1] - 0.1);
            let mut s = a;
            while s <= b {
                gaps.push(s);
                s += 0.25;
            }
        }
        for s in gaps {
            let g = request.geometry_at(s);
            let (wi, wo) = g.directions();
            let static_ok = constraints.check_directions(&wi, &wo).is_ok();
            let safe_pose = kin.solutions(&wi, &wo, &hint).map(|poses| {
                poses.iter().any(|p| {
                    pose_violates(&inst, p).is_none()
                        && side.is_none_or(|side| (p.light_deg < p.detector_deg) == side)
                        && p.arm_separation_deg() > inst.safety.min_arm_separation_deg + 1.0
                })
            });
            prop_assert!(!static_ok || !matches!(safe_pose, Ok(true)),
                "the angle {s} is sweepable but not swept: {g:?}, pieces {:?}", plan.arcs.iter().map(|a| (a.piece.from_deg, a.piece.to_deg)).collect::<Vec<_>>());
        }
    }
}
