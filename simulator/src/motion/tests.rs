//! The motion physics' tests.
use super::*;

fn params() -> AxisParams {
    AxisParams {
        hw_min_deg: -100.0,
        hw_max_deg: 100.0,
        backlash_deg: 0.0,
        encoder_resolution_deg: 0.0005,
    }
}

#[test]
fn trapezoid_and_triangle_times_follow_the_formula() {
    // d >= v^2/a: 30/20 + 20/80
    assert!((trapezoid_time_s(30.0, 20.0, 80.0) - (1.5 + 0.25)).abs() < 1e-12);
    // d < v^2/a = 5: 2 sqrt(1/80)
    assert!((trapezoid_time_s(1.0, 20.0, 80.0) - 2.0 * (1.0f64 / 80.0).sqrt()).abs() < 1e-12);
    assert_eq!(trapezoid_time_s(0.0, 20.0, 80.0), 0.0);
}

#[test]
fn profile_ends_at_target_at_formula_time_and_is_continuous() {
    for (d, v, a) in [
        (30.0, 20.0, 80.0),
        (1.0, 20.0, 80.0),
        (-45.0, 10.0, 15.0),
        (5.0, 20.0, 80.0),
    ] {
        let mut m = AxisMotion::new(params(), 0.0);
        let end = m.start_move(0.0, d, v, a, None);
        assert!((end - trapezoid_time_s(d, v, a)).abs() < 1e-12);
        let mut prev = 0.0;
        let n = 1000;
        for k in 1..=n {
            let t = end * f64::from(k) / f64::from(n);
            let p = m.motor_deg(t);
            // Monotone and never faster than v.
            assert!((p - prev) * d.signum() >= -1e-12);
            assert!((p - prev).abs() <= v * end / f64::from(n) + 1e-9);
            prev = p;
        }
        assert_eq!(m.motor_deg(end + 1.0), d);
        assert!(!m.is_moving(end + 1.0));
        assert_eq!(m.end_reason(), MoveEnd::Arrived);
    }
}

#[test]
fn midpoint_of_symmetric_profile_is_half_way() {
    let mut m = AxisMotion::new(params(), 10.0);
    let end = m.start_move(0.0, 40.0, 20.0, 80.0, None);
    assert!((m.motor_deg(end / 2.0) - 25.0).abs() < 1e-9);
}

#[test]
fn backlash_lands_high_when_approaching_from_above() {
    let p = AxisParams {
        backlash_deg: 0.01,
        ..params()
    };
    let mut m = AxisMotion::new(p, 0.0);
    let t = m.start_move(0.0, 10.0, 20.0, 80.0, None);
    assert!((m.load_deg(t) - 10.0).abs() < 1e-12, "from below: exact");
    let t2 = m.start_move(t, 5.0, 20.0, 80.0, None);
    assert!(
        (m.load_deg(t2) - 5.01).abs() < 1e-12,
        "from above: lags by the backlash"
    );
    assert!((m.encoder_deg(t2) - 5.01).abs() < 1e-9);
    // A tiny move up inside the play does not move the load.
    let t3 = m.start_move(t2, 5.004, 20.0, 80.0, None);
    assert!((m.load_deg(t3) - 5.01).abs() < 1e-12);
    let t4 = m.start_move(t3, 6.0, 20.0, 80.0, None);
    assert!((m.load_deg(t4) - 6.0).abs() < 1e-12);
}

#[test]
fn encoder_quantises_to_its_resolution() {
    let mut m = AxisMotion::new(params(), 0.0);
    let t = m.start_move(0.0, 1.23456, 20.0, 80.0, None);
    let e = m.encoder_deg(t);
    assert!((e - 1.2345).abs() < 1e-9 || (e - 1.235).abs() < 1e-9, "{e}");
    assert!((e / 0.0005 - (e / 0.0005).round()).abs() < 1e-6);
}

#[test]
fn limit_switch_stops_the_axis_at_the_limit() {
    let mut m = AxisMotion::new(params(), 90.0);
    let end = m.start_move(0.0, 120.0, 20.0, 80.0, None);
    assert!(end < trapezoid_time_s(30.0, 20.0, 80.0));
    assert!((m.motor_deg(end + 1.0) - 100.0).abs() < 1e-9);
    assert_eq!(m.end_reason(), MoveEnd::LimitPositive);
}

#[test]
fn stall_stops_short_at_the_fraction() {
    let mut m = AxisMotion::new(params(), 0.0);
    let end = m.start_move(0.0, 50.0, 20.0, 80.0, Some(0.5));
    assert!((m.motor_deg(end + 1.0) - 25.0).abs() < 1e-9);
    assert_eq!(m.end_reason(), MoveEnd::Stalled);
}

#[test]
fn mechanics_slower_than_commanded_move_at_their_own_limits() {
    let mut m = AxisMotion::new(params(), 0.0).with_mechanical_limits(10.0, 40.0);
    // Commanded 20 deg/s and 80 deg/s^2; the mechanics give 10 and 40: 0.25 s ramps, 2.5 deg each.
    let end = m.start_move(0.0, 40.0, 20.0, 80.0, None);
    assert!((end - trapezoid_time_s(40.0, 10.0, 40.0)).abs() < 1e-12, "{end}");
    assert!((m.velocity_deg_s(1.0) - 10.0).abs() < 1e-12);
    let mut free = AxisMotion::new(params(), 0.0);
    assert!(free.start_move(0.0, 40.0, 20.0, 80.0, None) < end);
}

#[test]
fn stop_decelerates_over_v_squared_over_2a() {
    let mut m = AxisMotion::new(params(), 0.0);
    m.start_move(0.0, 90.0, 20.0, 80.0, None);
    // Cruising at 20 deg/s from t = 0.25 on.
    let p1 = m.motor_deg(1.0);
    let end = m.stop(1.0, 80.0);
    assert!((end - 1.25).abs() < 1e-12);
    assert!((m.motor_deg(2.0) - (p1 + 400.0 / 160.0)).abs() < 1e-9);
    assert_eq!(m.end_reason(), MoveEnd::Stopped);
}

#[test]
fn new_move_during_a_move_decelerates_then_goes() {
    let mut m = AxisMotion::new(params(), 0.0);
    m.start_move(0.0, 90.0, 20.0, 80.0, None);
    let end = m.start_move(1.0, 0.0, 20.0, 80.0, None);
    assert_eq!(m.motor_deg(end + 0.1), 0.0);
    assert!(end > 1.25);
}

/// A meter's window still ahead of the present is looked at without advancing the axis: every instant of it
/// sees its own position (what the axis, advanced in order, would show there), and the present is still
/// answered afterwards. Advanced to the window's end first, the axis would answer every earlier instant with
/// the window's end (a reading of 30 samples would see one pose, 90 ms ahead of its middle).
#[test]
fn looking_ahead_sees_each_instant_and_leaves_the_present_alone() {
    let with_backlash = AxisParams {
        backlash_deg: 0.01,
        ..params()
    };
    let mut m = AxisMotion::new(with_backlash, 0.0);
    let end = m.start_move(0.0, 20.0, 10.0, 80.0, None);
    let mut reference = m.clone();
    let times: Vec<f64> = (0..=40).map(|k| 0.05 * f64::from(k)).collect();
    let ahead: Vec<f64> = times.iter().map(|&t| m.optical_deg_ahead(t)).collect();
    for (&t, &a) in times.iter().zip(&ahead) {
        assert!((a - reference.optical_deg(t)).abs() < 1e-12, "at {t}: {a}");
    }
    // Nothing advanced: the present (t = 0.2 s) is where the axis is then, not where the window ends.
    let now = m.load_deg(0.2);
    assert!((now - reference_at(0.2)).abs() < 1e-12, "{now}");
    assert!(m.optical_deg_ahead(end + 1.0) > 19.98);
    // A past instant is answered by the state's own time.
    assert_eq!(m.optical_deg_ahead(0.1), m.load_deg(0.2));

    fn reference_at(t: f64) -> f64 {
        let mut r = AxisMotion::new(
            AxisParams {
                backlash_deg: 0.01,
                ..params()
            },
            0.0,
        );
        r.start_move(0.0, 20.0, 10.0, 80.0, None);
        r.load_deg(t)
    }
}
