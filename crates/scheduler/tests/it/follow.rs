//! Sweeps whose speed follows the BRDF through the plan: a first pass's readings made into each arc's profile,
//! the path's pieces cut where the speed changes, the cut pieces still safe and contiguous, the time each
//! takes, and the errors of `follow = { ... }`.

use gonio_instrument::AxisRole;
use gonio_scheduler::plan::{PlanError, PlanSpec};
use gonio_scheduler::sweep::{
    ArcProfile, PassReading, SweepPlan, arc_profile, build_sweeps, requests, schedule_sweeps, swept_role,
};
use gonio_scheduler::timing::{TimeModel, trapezoid_time_s};

use crate::common::simulated;

const FOLLOWING: &str = "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -70.0, to = 70.0 }\n\
     speed_deg_s = 16.0\naveraging = 10\nfollow = { first_pass = \"first\", tolerance_rel = 1e-4 }\n";

/// The plastic-like lobe at the specular direction (30 deg), a few degrees wide, on a diffuse floor.
fn lobe(s: f64) -> f64 {
    0.1 + 5.0 * (-((s - 30.0) / 3.0).powi(2)).exp()
}

fn plan_with(text: &str, profiles: &[ArcProfile]) -> Result<SweepPlan, PlanError> {
    let inst = simulated();
    let spec = PlanSpec::from_toml(text, "test.toml")?;
    build_sweeps(
        &spec.sweeps,
        &inst,
        &TimeModel::new(&inst),
        None,
        &[550.0],
        None,
        profiles,
    )
}

/// The profiles of `text`'s arcs from a first pass read every 0.02 deg over the whole arc.
fn profiles(text: &str) -> Vec<ArcProfile> {
    let inst = simulated();
    let spec = PlanSpec::from_toml(text, "test.toml").unwrap();
    let reqs = requests(&spec.sweeps, |arm| {
        inst.axis(swept_role(arm)).map(|a| a.max_speed_deg_s)
    })
    .unwrap();
    reqs.iter()
        .map(|r| {
            let readings: Vec<PassReading> = (0..=7000)
                .map(|i| {
                    let s = -70.0 + i as f64 * 0.02;
                    PassReading {
                        geometry: r.geometry_at(s),
                        s_deg: s,
                        band_nm: 550.0,
                        value: lobe(s),
                    }
                })
                .collect();
            arc_profile(
                r,
                &readings,
                spec.sweeps[r.entry].follow.as_ref().unwrap(),
                &TimeModel::new(&inst),
            )
            .unwrap()
        })
        .collect()
}

#[test]
fn an_arc_that_follows_is_swept_in_pieces_slower_at_the_lobe_and_faster_in_time_than_its_slowest_speed() {
    let profiles = profiles(FOLLOWING);
    let plan = plan_with(FOLLOWING, &profiles).unwrap();
    assert!(plan.arcs.len() >= 3, "{:?}", plan.arcs);
    // The path's own pieces (the source's side and the specular side, split at the arms' separation), cut
    // where the speed changes: contiguous within each, every axis but the detector held, the detector on the
    // line between the path piece's ends.
    let speed_at = |s: f64| {
        plan.arcs
            .iter()
            .find(|a| a.piece.from_deg <= s && s <= a.piece.to_deg)
            .map(|a| a.request.speed_deg_s)
    };
    assert_eq!(speed_at(60.0), Some(16.0));
    assert_eq!(speed_at(-50.0), Some(16.0));
    // The first pass's bins reach the arc's ends: no stretch beyond it to sweep at the slowest speed.
    assert_eq!(speed_at(-69.9), Some(16.0));
    assert_eq!(speed_at(69.9), Some(16.0));
    let lobe_speed = speed_at(30.0).unwrap();
    assert!(lobe_speed < 4.0, "{lobe_speed}");
    for arc in &plan.arcs {
        let (a, b) = (&arc.piece.from_pose, &arc.piece.to_pose);
        assert_eq!(
            (a.light_deg, a.tilt_deg, a.rotation_deg),
            (b.light_deg, b.tilt_deg, b.rotation_deg)
        );
        let slope = (b.detector_deg - a.detector_deg) / (arc.piece.to_deg - arc.piece.from_deg);
        assert!((slope.abs() - 1.0).abs() < 1e-9, "{slope}");
        assert!(arc.length_deg() >= gonio_scheduler::sweep::MIN_PIECE_DEG);
    }
    let swept: f64 = plan.arcs.iter().map(|a| a.length_deg()).sum();
    let constant_text = FOLLOWING.replace("follow = { first_pass = \"first\", tolerance_rel = 1e-4 }\n", "");
    let constant = plan_with(&constant_text, &[]).unwrap();
    assert!(
        (swept - constant.swept_deg()).abs() < 1e-6,
        "{swept} against {}",
        constant.swept_deg()
    );
    // The time: each piece a trapezoid of its own at its speed; the slowest speed over the whole arc takes
    // more than three times as long.
    let inst = simulated();
    let time = TimeModel::new(&inst);
    let sched = schedule_sweeps(&plan, &time, None, None);
    let accel = inst.axis(AxisRole::DetectorArm).unwrap().accel_deg_s2;
    for step in &sched.steps {
        let arc = &plan.arcs[step.arc];
        let motion = trapezoid_time_s(arc.length_deg(), arc.request.speed_deg_s, accel);
        assert!(
            (step.motion_s - motion).abs() < 1e-9,
            "{} against {motion}",
            step.motion_s
        );
    }
    let slowest = profiles[0].slowest_deg_s();
    let steady: f64 = constant
        .arcs
        .iter()
        .map(|a| trapezoid_time_s(a.length_deg(), slowest, accel))
        .sum();
    let followed: f64 = sched.steps.iter().map(|s| s.motion_s).sum();
    assert!(
        followed < steady / 3.0,
        "followed {followed:.1} s, at {slowest} deg/s throughout {steady:.1} s"
    );
}

#[test]
fn a_profiles_pieces_are_swept_one_after_the_other_one_way_even_from_an_arm_standing_mid_arc() {
    let profiles = profiles(FOLLOWING);
    let plan = plan_with(FOLLOWING, &profiles).unwrap();
    let time = TimeModel::new(&simulated());
    // The arm stands in the middle of the lobe's slow piece, where the nearest piece end is inside the arc.
    let slow = plan
        .arcs
        .iter()
        .min_by(|a, b| a.request.speed_deg_s.total_cmp(&b.request.speed_deg_s))
        .unwrap();
    let mut start = slow.piece.from_pose;
    start.detector_deg = 0.5 * (slow.piece.from_pose.detector_deg + slow.piece.to_pose.detector_deg);
    let sched = schedule_sweeps(&plan, &time, Some((start, None)), None);
    assert_eq!(sched.steps.len(), plan.arcs.len());
    // Every piece is entered where the one before it ended, except where the path itself breaks (its own
    // pieces: the arms' separation); the pieces of one path piece go one way.
    let breaks = sched
        .steps
        .windows(2)
        .filter(|w| w[0].end_pose != w[1].start_pose)
        .count();
    let path_pieces = plan
        .arcs
        .windows(2)
        .filter(|w| w[0].piece.to_pose != w[1].piece.from_pose)
        .count();
    assert_eq!(breaks, path_pieces, "{:#?}", sched.steps);
    for w in sched.steps.windows(2) {
        if w[0].end_pose == w[1].start_pose {
            assert_eq!(w[0].forward, w[1].forward);
        }
    }
}

#[test]
fn an_arc_that_follows_needs_its_profile_and_follow_is_checked() {
    let err = plan_with(FOLLOWING, &[]).unwrap_err().to_string();
    assert!(err.contains("no speed profile for the arc at 30 deg"), "{err}");
    // A profile of another arc is not this one's.
    let mut other = profiles(FOLLOWING);
    other[0].held_deg = 45.0;
    assert!(plan_with(FOLLOWING, &other).is_err());
    for (bad, says) in [
        (
            "tolerance_rel = 0.0",
            "tolerance_rel: expected a relative smearing in (0, 0.5]",
        ),
        (
            "tolerance_rel = 1e-3, min_speed_deg_s = 20.0",
            "min_speed_deg_s: expected deg/s in (0, 16]",
        ),
        (
            "tolerance_rel = 1e-3, min_piece_deg = 0.01",
            "min_piece_deg: expected degrees in [0.1, 90]",
        ),
        (
            "tolerance_rel = 1e-3, resolution_deg = 10.0",
            "resolution_deg: expected degrees in [0.05, 5]",
        ),
    ] {
        let text = FOLLOWING.replace("tolerance_rel = 1e-4", bad);
        let err = plan_with(&text, &profiles(FOLLOWING)).unwrap_err().to_string();
        assert!(err.contains(says), "{bad}: {err}");
        assert!(err.contains("follow"), "{err}");
    }
    let unknown = FOLLOWING.replace("tolerance_rel = 1e-4", "tolerance_rel = 1e-4, speed = 2.0");
    assert!(PlanSpec::from_toml(&unknown, "test.toml").is_err());
}
