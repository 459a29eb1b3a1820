//! The trapezoidal profile of one axis over one straight leg: where it is at any time, for the arm separation
//! check of a move and for placing a sweep's readings along the arc the arm covered.

/// Duration of a trapezoidal profile over `distance` (any sign; its magnitude is used).
pub fn trapezoid_time_s(distance_deg: f64, max_speed_deg_s: f64, accel_deg_s2: f64) -> f64 {
    let d = distance_deg.abs();
    if d <= 0.0 {
        return 0.0;
    }
    let (v, a) = (max_speed_deg_s, accel_deg_s2);
    if d >= v * v / a {
        d / v + v / a
    } else {
        2.0 * (d / a).sqrt()
    }
}

/// Intervals of the midpoint rule for a mean position ([`Trapezoid::mean_over`]): a trapezoid's position is
/// piecewise quadratic, so the rule is within a ramp's arc / (12 x 64^2) of exact.
const MEAN_SAMPLES: usize = 64;

/// One straight leg of an axis's motion from rest to rest, in physical degrees against clock seconds (sign of the
/// axis direction applied): `from_deg` at `t0_s`, speed limit `v`, acceleration `a`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trapezoid {
    pub t0_s: f64,
    pub from_deg: f64,
    pub to_deg: f64,
    pub v: f64,
    pub a: f64,
}

impl Trapezoid {
    pub fn duration_s(&self) -> f64 {
        trapezoid_time_s(self.to_deg - self.from_deg, self.v, self.a)
    }

    /// Time spent accelerating (and, by symmetry, decelerating).
    pub fn ramp_s(&self) -> f64 {
        let d = (self.to_deg - self.from_deg).abs();
        if d >= self.v * self.v / self.a {
            self.v / self.a
        } else {
            (d / self.a).sqrt()
        }
    }

    /// Position at clock time `t_s` (at rest before and after the leg).
    pub fn position(&self, t_s: f64) -> f64 {
        let d = (self.to_deg - self.from_deg).abs();
        let sign = (self.to_deg - self.from_deg).signum();
        let total = self.duration_s();
        let ramp = self.ramp_s();
        let t = (t_s - self.t0_s).clamp(0.0, total);
        let top = self.a * ramp;
        let s = if t <= ramp {
            0.5 * self.a * t * t
        } else if t <= total - ramp {
            0.5 * self.a * ramp * ramp + top * (t - ramp)
        } else {
            let r = total - t;
            d - 0.5 * self.a * r * r
        };
        self.from_deg + sign * s.min(d)
    }

    /// The time-average of the position over clock times `[ta, tb]` (by the midpoint rule on
    /// [`MEAN_SAMPLES`] intervals): where a reading integrated over that window belongs. At cruise it is the
    /// middle of the arc covered; in a ramp it lies towards the slower end (a third of the arc from rest for a
    /// window that starts at rest), which the middle of the arc would miss by a sixth of the arc.
    pub fn mean_over(&self, ta: f64, tb: f64) -> f64 {
        if tb <= ta {
            return self.position(ta);
        }
        let h = (tb - ta) / MEAN_SAMPLES as f64;
        (0..MEAN_SAMPLES)
            .map(|k| self.position(ta + (k as f64 + 0.5) * h))
            .sum::<f64>()
            / MEAN_SAMPLES as f64
    }

    /// The clock time at which the cruise passes `x` (None outside the cruise).
    pub fn cruise_time_of(&self, x: f64) -> Option<f64> {
        let (total, ramp) = (self.duration_s(), self.ramp_s());
        if total - 2.0 * ramp <= 0.0 {
            return None;
        }
        let (xa, xb) = (
            self.position(self.t0_s + ramp),
            self.position(self.t0_s + total - ramp),
        );
        let (lo, hi) = (xa.min(xb), xa.max(xb));
        if !(lo..=hi).contains(&x) || (xb - xa).abs() <= 0.0 {
            return None;
        }
        Some(self.t0_s + ramp + (x - xa) / (xb - xa) * (total - 2.0 * ramp))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_profile_reaches_its_end_at_its_duration_and_cruise_times_invert_it() {
        let p = Trapezoid {
            t0_s: 2.0,
            from_deg: 10.0,
            to_deg: -20.0,
            v: 4.0,
            a: 80.0,
        };
        // 30 degrees at 4 deg/s with 80 deg/s^2: 7.5 s plus v/a.
        assert!((p.duration_s() - (7.5 + 0.05)).abs() < 1e-12);
        assert_eq!(p.position(0.0), 10.0);
        assert!((p.position(2.0 + p.duration_s()) + 20.0).abs() < 1e-12);
        for x in [5.0, 0.0, -12.5] {
            let t = p.cruise_time_of(x).expect("on the cruise");
            assert!((p.position(t) - x).abs() < 1e-9, "{x}: {}", p.position(t));
        }
        assert!(p.cruise_time_of(9.99).is_none(), "in the ramp");
        // The mean position over a window: the arc's middle at cruise; a third of the way from rest.
        let (ta, tb) = (2.5, 3.5);
        assert!((p.mean_over(ta, tb) - 0.5 * (p.position(ta) + p.position(tb))).abs() < 1e-9);
        let ramp = 4.0 / 80.0;
        let third = 10.0 - (10.0 - p.position(2.0 + ramp)) / 3.0;
        assert!(
            // The midpoint rule's error on a ramp: its arc (0.1 deg) / (12 x 64^2), 2e-6 deg.
            (p.mean_over(2.0, 2.0 + ramp) - third).abs() < 3e-6,
            "{}",
            p.mean_over(2.0, 2.0 + ramp)
        );
        assert_eq!(p.mean_over(3.0, 3.0), p.position(3.0));
    }
}
