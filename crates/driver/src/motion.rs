//! Motion arithmetic shared by the axis drivers: move durations (deadlines) and the backlash approach. When to
//! ask whether a move is over is [`crate::poll`].

use std::time::Duration;

use crate::error::DriverError;

/// Duration of a trapezoidal move of `distance` with speed limit `speed` and acceleration `accel`
/// (any consistent units): `d/v + v/a` when the move reaches full speed (`d >= v^2/a`), else `2 sqrt(d/a)`.
pub fn trapezoid_time_s(distance: f64, speed: f64, accel: f64) -> f64 {
    let d = distance.abs();
    if !(speed > 0.0 && accel > 0.0 && d.is_finite()) {
        return f64::INFINITY;
    }
    if d >= speed * speed / accel {
        d / speed + speed / accel
    } else {
        2.0 * (d / accel).sqrt()
    }
}

/// Deadline for a move: the trapezoid time, doubled, plus two seconds of margin for command latency, settling
/// and a controller that runs slower than configured. Capped at ten minutes so that no wait is unbounded even
/// with nonsense parameters.
pub fn move_deadline(distance: f64, speed: f64, accel: f64) -> Duration {
    let t = trapezoid_time_s(distance, speed, accel);
    let secs = if t.is_finite() { 2.0 * t + 2.0 } else { 600.0 };
    Duration::from_secs_f64(secs.min(600.0))
}

/// The positions to command to reach `target` from `current` so that the last approach is from below by more
/// than `backlash` (controller units). Returns one or two targets; the last one is always `target`.
/// `lower_limit` bounds the intermediate point.
pub fn approach_from_below(current: f64, target: f64, backlash: f64, lower_limit: f64) -> Vec<f64> {
    if backlash <= 0.0 || current < target - backlash {
        return vec![target];
    }
    // Overshoot by twice the backlash so the final approach takes up the play completely.
    let pre = (target - 2.0 * backlash).max(lower_limit);
    if pre < target {
        vec![pre, target]
    } else {
        vec![target]
    }
}

/// Arrival tolerance at a via point (a backlash overshoot, or any stop that is not where the axis is finally
/// going): after a move toward it the load may sit up to the backlash away from the motor, so the axis's
/// tolerance is widened by twice the backlash.
pub fn via_point_tolerance_deg(axis: &gonio_instrument::Axis) -> f64 {
    axis.tolerance_deg + 2.0 * axis.backlash_deg
}

/// The waypoints of a backlash-compensated move of `axis` from controller position `current_c` to the physical
/// angle `target_deg`: (physical target, arrival tolerance) pairs. The overshoot point is only a via point: the
/// load may sit up to the backlash away from the motor there, so its tolerance is widened by twice the backlash.
pub fn approach_waypoints(axis: &gonio_instrument::Axis, current_c: f64, target_deg: f64) -> Vec<(f64, f64)> {
    let target_c = axis.controller_from_physical_deg(target_deg);
    // Approach from below in *controller* coordinates (the mechanics' sense), within the controller limits.
    let lower_c = axis
        .controller_from_physical_deg(axis.min_deg)
        .min(axis.controller_from_physical_deg(axis.max_deg));
    let steps = approach_from_below(current_c, target_c, axis.backlash_deg, lower_c);
    let last = steps.len().saturating_sub(1);
    steps
        .into_iter()
        .enumerate()
        .map(|(i, step_c)| {
            let tolerance = if i < last {
                via_point_tolerance_deg(axis)
            } else {
                axis.tolerance_deg
            };
            (axis.physical_from_controller_deg(step_c), tolerance)
        })
        .collect()
}

/// Refuse a speed or acceleration that is not a finite positive number, before anything is sent.
pub fn check_speed(device: String, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
    for (what, v) in [
        ("speed (deg/s)", speed_deg_s),
        ("acceleration (deg/s^2)", accel_deg_s2),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(DriverError::OutOfRange {
                device,
                what: what.into(),
                value: v,
                min: 0.0,
                max: f64::INFINITY,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_matches_both_regimes() {
        // v = 20, a = 80: full speed needs d >= 5. d = 45: 45/20 + 20/80 = 2.5 s.
        assert!((trapezoid_time_s(45.0, 20.0, 80.0) - 2.5).abs() < 1e-12);
        // d = 1.25 < 5: triangle, 2 sqrt(1.25/80) = 0.25 s.
        assert!((trapezoid_time_s(-1.25, 20.0, 80.0) - 0.25).abs() < 1e-12);
        // Continuous at the boundary d = v^2/a = 5: 5/20 + 0.25 = 0.5 = 2 sqrt(5/80).
        assert!((trapezoid_time_s(5.0, 20.0, 80.0) - 0.5).abs() < 1e-12);
        assert_eq!(trapezoid_time_s(1.0, 0.0, 1.0), f64::INFINITY);
    }

    #[test]
    fn deadline_is_bounded_and_has_margin() {
        assert_eq!(move_deadline(45.0, 20.0, 80.0), Duration::from_secs_f64(7.0));
        assert_eq!(move_deadline(1.0, f64::NAN, 1.0), Duration::from_secs(600));
    }

    #[test]
    fn backlash_approach_is_from_below() {
        assert_eq!(approach_from_below(0.0, 10.0, 0.01, -100.0), vec![10.0]);
        assert_eq!(approach_from_below(20.0, 10.0, 0.01, -100.0), vec![9.98, 10.0]);
        // Within the backlash below the target still counts as "from above" (the play may not be taken up).
        assert_eq!(approach_from_below(9.995, 10.0, 0.01, -100.0), vec![9.98, 10.0]);
        // At the lower limit the pre-position is clamped; at the limit itself there is no room.
        assert_eq!(
            approach_from_below(0.0, -99.99, 0.01, -100.0),
            vec![-100.0, -99.99]
        );
        assert_eq!(approach_from_below(0.0, -100.0, 0.01, -100.0), vec![-100.0]);
        assert_eq!(approach_from_below(5.0, 1.0, 0.0, -100.0), vec![1.0]);
    }

    #[test]
    fn waypoints_overshoot_in_controller_sense_with_a_wider_via_tolerance() {
        let mut axis = gonio_instrument::InstrumentFile::simulated().instrument.axes[0].clone();
        axis.backlash_deg = 0.01;
        axis.tolerance_deg = 0.005;
        axis.zero_offset_deg = 5.0;
        axis.direction = -1;
        // Physical 10 deg is controller -5; coming from controller +20 (above), overshoot to -5.02 first.
        let w = approach_waypoints(&axis, 20.0, 10.0);
        assert_eq!(w.len(), 2);
        assert!(
            (w[0].0 - 10.02).abs() < 1e-12 && (w[0].1 - 0.025).abs() < 1e-15,
            "{w:?}"
        );
        assert_eq!(w[1], (10.0, 0.005));
        // Coming from below: one direct move with the plain tolerance.
        assert_eq!(approach_waypoints(&axis, -30.0, 10.0), vec![(10.0, 0.005)]);
    }

    #[test]
    fn non_positive_or_non_finite_speeds_are_refused() {
        assert!(check_speed("a".into(), 10.0, 50.0).is_ok());
        for (v, a) in [(0.0, 1.0), (1.0, -1.0), (f64::NAN, 1.0), (1.0, f64::INFINITY)] {
            assert!(check_speed("a".into(), v, a).is_err(), "{v} {a}");
        }
    }
}
