//! Unit tests of recovery homing.

use super::*;

const CLEARANCE: f64 = 10.5;

fn homing(lo: f64, hi: f64, home: f64) -> Homing {
    Homing {
        name: "detector".into(),
        may_be: Span { lo, hi },
        home_deg: home,
        still_deg: 0.005,
    }
}

fn other(at: f64, movable: bool) -> Other {
    Other {
        name: "light".into(),
        at: Span::at(at),
        movable,
        min_deg: -100.0,
        max_deg: 100.0,
    }
}

/// Brute force, independent of the interval arithmetic: the smallest separation, on the circle, between
/// the arm at any sampled point of `a` and the other at any sampled point of `b`.
fn sampled_min_sep(a: (f64, f64), b: (f64, f64)) -> f64 {
    let n = 120;
    let mut min = f64::INFINITY;
    for i in 0..=n {
        let x = a.0 + (a.1 - a.0) * f64::from(i) / f64::from(n);
        for j in 0..=n {
            let y = b.0 + (b.1 - b.0) * f64::from(j) / f64::from(n);
            let r = (x - y).rem_euclid(360.0);
            min = min.min(r.min(360.0 - r));
        }
    }
    min
}

#[test]
fn gaps_between_spans_match_brute_force_on_the_circle() {
    let cases = [
        ((0.0, 10.0), (25.0, 30.0)),
        ((-100.0, -90.0), (170.0, 175.0)),
        ((-5.0, 5.0), (3.0, 40.0)),
        ((60.0, 60.0), (-60.0, -60.0)),
        ((-179.0, -170.0), (170.0, 175.0)),
    ];
    for ((a0, a1), (b0, b1)) in cases {
        let gap = Span::between(a0, a1).gap_deg(Span::between(b0, b1));
        let brute = sampled_min_sep((a0, a1), (b0, b1));
        assert!(
            (gap - brute).abs() < 0.2,
            "{a0}..{a1} vs {b0}..{b1}: {gap} vs {brute}"
        );
    }
}

#[test]
fn the_light_arm_between_the_detector_and_its_home_is_parked_beyond_the_home() {
    // Detector at 60 deg, home at 0, light arm at 30 deg: in the way.
    let arm = homing(60.0, 60.0, 0.0);
    let Plan::Park { park_deg } = plan(&arm, &other(30.0, true), CLEARANCE) else {
        panic!("expected a parking move");
    };
    // Below the home (the other side, 70+ deg, would take it past the detector).
    assert!((park_deg - (0.0 - 1.25 * CLEARANCE)).abs() < 1e-9, "{park_deg}");
    // The parking path keeps clear of the detector, and the homing sweep of the parked light arm.
    assert!(sampled_min_sep((30.0, park_deg), (60.0, 60.0)) >= CLEARANCE);
    assert!(sampled_min_sep((60.0, 0.0), (park_deg, park_deg)) >= CLEARANCE);
    // Without a reference the light arm cannot be moved: refused, with the reason.
    let Plan::Refuse(why) = plan(&arm, &other(30.0, false), CLEARANCE) else {
        panic!("expected a refusal");
    };
    assert!(
        why.contains("lost its reference too") && why.contains("by hand"),
        "{why}"
    );
}

#[test]
fn an_arm_out_of_the_way_or_one_that_does_not_travel_is_homed_at_once() {
    assert_eq!(
        plan(&homing(60.0, 60.0, 0.0), &other(-20.0, false), CLEARANCE),
        Plan::Home
    );
    // Both at home (power-up, arms together): homing does not move them.
    assert_eq!(
        plan(&homing(0.0, 0.0, 0.0), &other(0.0, false), CLEARANCE),
        Plan::Home
    );
    // The uncertain span counts: last known 60, read back 20 (a stop mid-move), light at 40.
    assert!(matches!(
        plan(&homing(20.0, 60.0, 0.0), &other(45.0, false), CLEARANCE),
        Plan::Refuse(_)
    ));
}

#[test]
fn parking_spots_respect_limits_and_refuse_when_none_is_reachable() {
    // Light at 30 between the detector (95) and home (0); below the home is beyond its limit of -5 deg, and
    // beyond the detector is past it: no spot.
    let mut o = other(30.0, true);
    o.min_deg = -5.0;
    let Plan::Refuse(why) = plan(&homing(95.0, 95.0, 0.0), &o, CLEARANCE) else {
        panic!("expected a refusal");
    };
    assert!(why.contains("limits [-5.00, 100.00]"), "{why}");
    // Every plan the planner makes keeps the clearance along the way, by brute force, over a grid of cases.
    for d in (-95..=95).step_by(10) {
        for l in (-95..=95).step_by(10) {
            let (d, l) = (f64::from(d), f64::from(l));
            if (d - l).abs() < CLEARANCE {
                continue;
            }
            let arm = homing(d, d, 0.0);
            match plan(&arm, &other(l, true), CLEARANCE) {
                Plan::Home => assert!(sampled_min_sep((d, 0.0), (l, l)) >= CLEARANCE - 1e-9, "{d} {l}"),
                Plan::Park { park_deg } => {
                    assert!((-100.0..=100.0).contains(&park_deg));
                    assert!(
                        sampled_min_sep((l, park_deg), (d, d)) >= CLEARANCE - 1e-9,
                        "{d} {l}"
                    );
                    assert!(
                        sampled_min_sep((d, 0.0), (park_deg, park_deg)) >= CLEARANCE - 1e-9,
                        "{d} {l}"
                    );
                }
                Plan::Refuse(_) => {
                    // Only when no spot exists: both sides of the sweep out of reach.
                    let below = 0.0f64.min(d) - 1.25 * CLEARANCE;
                    let above = 0.0f64.max(d) + 1.25 * CLEARANCE;
                    let reach = |p: f64| {
                        (-100.0..=100.0).contains(&p) && sampled_min_sep((l, p), (d, d)) >= CLEARANCE
                    };
                    assert!(!reach(below) && !reach(above), "{d} {l}");
                }
            }
        }
    }
}

#[test]
fn start_up_homes_first_the_arm_whose_way_is_clear() {
    // Light at -50, detector at -20, both homing to 0: the light arm's way crosses the detector.
    let light = Homing {
        name: "light".into(),
        ..homing(-50.0, -50.0, 0.0)
    };
    let detector = homing(-20.0, -20.0, 0.0);
    let at = |x: f64| other(x, false);
    let first = start_up_order([&light, &detector], [&at(-20.0), &at(-50.0)], CLEARANCE);
    assert_eq!(first, Ok(1), "the detector first");
    // Detector at -50 and light at -20: the light first.
    let light = Homing {
        name: "light".into(),
        ..homing(-20.0, -20.0, 0.0)
    };
    let detector = homing(-50.0, -50.0, 0.0);
    let first = start_up_order([&light, &detector], [&at(-50.0), &at(-20.0)], CLEARANCE);
    assert_eq!(first, Ok(0));
    // Arms on either side of home, both in the way of the other: no order.
    let light = Homing {
        name: "light".into(),
        ..homing(-5.0, -5.0, 0.0)
    };
    let detector = homing(5.0, 5.0, 0.0);
    let first = start_up_order([&light, &detector], [&at(5.0), &at(-5.0)], CLEARANCE);
    assert!(first.is_err(), "{first:?}");
}
