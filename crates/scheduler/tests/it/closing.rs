//! How a campaign's schedule ends: the calibration that closes it when it is placed pass by pass (an adaptive
//! campaign's), and the order that ends where that closing moves least (`order::order_towards`).

use crate::common::*;
use crate::plans_and_order::{ISO, build, iso_grid};

use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::order;
use gonio_scheduler::schedule::{self, StepKind};
use gonio_scheduler::timing::TimeModel;
use proptest::prelude::*;

/// A campaign placed pass by pass (an adaptive one) learns which pass was its last only when the planner
/// stops: its closing is then scheduled on its own, from where the last pass left the instrument and with the
/// cadence it left. The last of the schedules that continue one another, then its closing, is the complete
/// schedule: the same steps and the same time, with or without a cadence; without a blank, no dark.
#[test]
fn a_closing_scheduled_after_a_continued_schedule_is_the_complete_schedules_own() {
    let inst = simulated();
    let cadence = format!(
        "{}[plan.calibration]\ndark_every_points = 7\nreference_every_points = 11\n",
        iso_grid(20.0, 60.0, 60.0)
    );
    let mut no_blank = inst.clone();
    if let Some(w) = no_blank.filter_wheel.as_mut() {
        w.positions.retain(|p| !p.blank);
    }
    for (what, text, inst, closing_kinds) in [
        (
            "no cadence",
            iso_grid(20.0, 60.0, 60.0),
            &inst,
            vec![StepKind::Dark],
        ),
        ("a cadence", cadence.clone(), &inst, {
            let mut k = vec![StepKind::Dark];
            k.extend([StepKind::Reference; 3]);
            k
        }),
        (
            "no blank",
            cadence.replace("dark_every_points = 7\n", ""),
            &no_blank,
            vec![StepKind::Reference; 3],
        ),
    ] {
        let plan = build(&text, inst, ISO).expect("plan");
        let time = TimeModel::new(inst);
        let complete = schedule::schedule(&plan, &time, None);
        let open = schedule::schedule_last(&plan, &time, None, None);
        let last = open.steps.last().expect("steps").pose;
        let closing = schedule::schedule_closing(&plan, &time, last, open.end);
        let kinds: Vec<StepKind> = closing.steps.iter().map(|s| s.kind).collect();
        assert_eq!(kinds, closing_kinds, "{what}");
        assert!(closing.steps.iter().all(|s| s.geometry.is_none()), "{what}");
        let joined: Vec<StepKind> = open.steps.iter().chain(&closing.steps).map(|s| s.kind).collect();
        let whole: Vec<StepKind> = complete.steps.iter().map(|s| s.kind).collect();
        assert_eq!(joined, whole, "{what}");
        let sum = open.breakdown.total_s() + closing.breakdown.total_s();
        assert!(
            (sum - complete.breakdown.total_s()).abs() < 1e-9,
            "{what}: {sum} s against {} s",
            complete.breakdown.total_s()
        );
        assert_eq!(closing.end.wheel, complete.end.wheel, "{what}");
        assert!(
            (closing.end.since_dark_s - complete.end.since_dark_s).abs() < 1e-9,
            "{what}"
        );
    }
}

/// Poses along the detector arm, 5 deg apart: leaving from the first is free, from any other dear. With the exit
/// costs the order ends at the first pose, and the moves and the exit take less than the free order's.
#[test]
fn an_order_towards_an_exit_ends_where_leaving_costs_least() {
    let tm = TimeModel::new(&simulated());
    let poses: Vec<Pose> = (0..12)
        .map(|k| Pose::new(-30.0, 20.0 + 5.0 * f64::from(k), 0.0, 0.0))
        .collect();
    let free = order::order(&poses, None, &tm);
    let mut exit_s = vec![60.0; poses.len()];
    exit_s[0] = 0.0;
    let towards = order::order_towards(&poses, None, &exit_s, &tm);
    let mut sorted = towards.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..poses.len()).collect::<Vec<_>>());
    assert_eq!(towards.last(), Some(&0), "{towards:?}");
    // Its moves may take longer (reversed, every move approaches from the other side: the backlash), not the
    // moves and the exit together.
    let total = |t: &[usize]| order::path_cost_towards(t, &poses, None, &exit_s, &tm);
    assert!(
        total(&towards) < total(&free),
        "{} s with the exit against {} s",
        total(&towards),
        total(&free)
    );
    // Without the exit costs (or with a list of the wrong length) it is the free order.
    assert_eq!(order::order_towards(&poses, None, &[], &tm), free);
    assert_eq!(order::order_towards(&poses, None, &[1.0], &tm), free);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// With exit costs, the order is a permutation, never worse than raster order counting the exit, and no
    /// better than the brute-force optimum counting it.
    #[test]
    fn an_order_towards_an_exit_against_raster_and_brute_force(
        ri in random_instrument(),
        raw in prop::collection::vec((-50.0..-5.0f64, 5.0..60.0f64, -15.0..15.0f64, -90.0..90.0f64, 0.0..5.0f64), 2..7),
    ) {
        let inst = ri.build();
        let tm = TimeModel::new(&inst);
        let poses: Vec<Pose> = raw
            .iter()
            .map(|(l, d, t, r, _)| Pose::new(*l, d + ri.min_sep, if ri.in_plane { 0.0 } else { *t }, *r))
            .collect();
        let exit_s: Vec<f64> = raw.iter().map(|x| x.4).collect();
        let tour = order::order_towards(&poses, None, &exit_s, &tm);
        let mut sorted = tour.clone();
        sorted.sort_unstable();
        prop_assert_eq!(&sorted, &(0..poses.len()).collect::<Vec<_>>());
        let cost = |t: &[usize]| order::path_cost_towards(t, &poses, None, &exit_s, &tm);
        let c = cost(&tour);
        prop_assert!(c <= cost(&sorted) + 1e-9);
        let mut best = f64::INFINITY;
        let mut perm = sorted.clone();
        crate::plans_and_order::permute(&mut perm, 0, &mut |p| best = best.min(cost(p)));
        prop_assert!(best <= c + 1e-9);
    }
}

/// An adaptive campaign's last pass ends where its closing normalisation moves least: on a grid closed by
/// direct-beam readings (light -90, detector 90), the last pass and its closing take less than the same pass
/// ordered to end anywhere and closed from where it ends (223.6 + 14.9 s against 224.6 + 10.4 s).
#[test]
fn the_last_pass_is_ordered_towards_its_closing() {
    let inst = simulated();
    let time = TimeModel::new(&inst);
    let text = format!(
        "{}[plan.calibration]\nreference_every_s = 600.0\nreference_pose_deg = {{ light = -90.0, detector = 90.0 }}\n",
        iso_grid(15.0, 45.0, 75.0)
    );
    let plan = build(&text, &inst, ISO).expect("plan");
    let start = Pose::new(-30.0, 30.0, 0.0, 0.0);
    let with_closing = |s: &schedule::Schedule| {
        let last = s.steps.last().expect("steps").pose;
        let closing = schedule::schedule_closing(&plan, &time, last, s.end);
        (s.breakdown.total_s(), closing.breakdown.total_s())
    };
    let (open_s, open_close_s) =
        with_closing(&schedule::schedule_continuing(&plan, &time, Some(&start), None));
    let (last_s, last_close_s) = with_closing(&schedule::schedule_last(&plan, &time, Some(&start), None));
    eprintln!(
        "ordered to end anywhere: {open_s:.2} + {open_close_s:.2} s; towards the closing: {last_s:.2} + {last_close_s:.2} s"
    );
    assert!(
        last_close_s < open_close_s,
        "{last_close_s} s against {open_close_s} s"
    );
    assert!(last_s + last_close_s < open_s + open_close_s);
}

/// Both orders are walked and the quicker kept: a complete schedule is never longer than the same plan ordered
/// to end anywhere and closed from where it ends, whatever the walk's last traversal (an even number of repeats
/// or of bands' tours runs the tour backwards last, ending at its other end).
#[test]
fn a_schedule_towards_its_closing_is_never_longer_than_one_ordered_to_end_anywhere() {
    let inst = simulated();
    let time = TimeModel::new(&inst);
    let calibration = "[plan.calibration]\nreference_every_s = 600.0\nreference_pose_deg = { light = -90.0, detector = 90.0 }\n";
    let grid = iso_grid(15.0, 45.0, 75.0);
    let plans = [
        ("three bands", format!("{grid}{calibration}")),
        (
            "two bands",
            format!("{grid}{calibration}").replace("[450.0, 550.0, 650.0]", "[450.0, 650.0]"),
        ),
        (
            "two repeats",
            format!("{grid}{calibration}").replace("[plan]\n", "[plan]\nrepeats = 2\n"),
        ),
    ];
    for (what, text) in plans {
        let plan = build(&text, &inst, ISO).expect("plan");
        assert!(plan.calibration.references(), "{what}");
        let complete = schedule::schedule(&plan, &time, None);
        let anywhere = schedule::schedule_continuing(&plan, &time, None, None);
        let last = anywhere.steps.last().expect("steps").pose;
        let closed = anywhere.breakdown.total_s()
            + schedule::schedule_closing(&plan, &time, last, anywhere.end)
                .breakdown
                .total_s();
        eprintln!(
            "{what}: {:.2} s, ordered to end anywhere {closed:.2} s",
            complete.breakdown.total_s()
        );
        assert!(
            complete.breakdown.total_s() <= closed + 1e-9,
            "{what}: {} s against {closed} s",
            complete.breakdown.total_s()
        );
    }
}
