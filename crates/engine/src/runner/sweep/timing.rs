//! Where a swept arm was when: the commanded trapezoid of the swept axis and the dating of the controller's
//! position reports against it.

use gonio_driver::PositionReport;

/// Intervals of the midpoint rule for a reading's mean position ([`Profile::mean_over`]): a trapezoid's
/// position is piecewise quadratic, so the rule is within a ramp's arc / (12 x 64^2) of exact.
const MEAN_SAMPLES: usize = 64;

/// The commanded trapezoid of the swept axis (physical degrees against clock seconds).
#[derive(Debug, Clone, Copy)]
pub(super) struct Profile {
    pub(super) t0_s: f64,
    pub(super) from_deg: f64,
    pub(super) to_deg: f64,
    pub(super) v: f64,
    pub(super) a: f64,
}

impl Profile {
    pub(super) fn duration_s(&self) -> f64 {
        gonio_scheduler::timing::trapezoid_time_s(self.to_deg - self.from_deg, self.v, self.a)
    }

    pub(super) fn ramp_s(&self) -> f64 {
        let d = (self.to_deg - self.from_deg).abs();
        if d >= self.v * self.v / self.a {
            self.v / self.a
        } else {
            (d / self.a).sqrt()
        }
    }

    /// Position at clock time `t`.
    pub(super) fn at(&self, t: f64) -> f64 {
        let d = (self.to_deg - self.from_deg).abs();
        let sign = (self.to_deg - self.from_deg).signum();
        let (total, ramp) = (self.duration_s(), self.ramp_s());
        let t = (t - self.t0_s).clamp(0.0, total);
        let s = if t <= ramp {
            0.5 * self.a * t * t
        } else if t <= total - ramp {
            0.5 * self.a * ramp * ramp + self.a * ramp * (t - ramp)
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
    pub(super) fn mean_over(&self, ta: f64, tb: f64) -> f64 {
        if tb <= ta {
            return self.at(ta);
        }
        let h = (tb - ta) / MEAN_SAMPLES as f64;
        (0..MEAN_SAMPLES)
            .map(|k| self.at(ta + (k as f64 + 0.5) * h))
            .sum::<f64>()
            / MEAN_SAMPLES as f64
    }

    /// The clock time at which the cruise passes `x` (None outside the cruise).
    pub(super) fn cruise_time_of(&self, x: f64) -> Option<f64> {
        let (total, ramp) = (self.duration_s(), self.ramp_s());
        if total - 2.0 * ramp <= 0.0 {
            return None;
        }
        let (xa, xb) = (self.at(self.t0_s + ramp), self.at(self.t0_s + total - ramp));
        let (lo, hi) = (xa.min(xb), xa.max(xb));
        if !(lo..=hi).contains(&x) || (xb - xa).abs() <= 0.0 {
            return None;
        }
        Some(self.t0_s + ramp + (x - xa) / (xb - xa) * (total - 2.0 * ramp))
    }
}

/// When the controller took the position it reported in an exchange sent at `sent_s` and answered at
/// `received_s` (clock seconds), on a line carrying `bytes_per_s` (0: not a timed line): after the request had
/// crossed the line and before the reply started back, so the middle of that window; its width is what remains
/// unknown. A reply that came sooner than its bytes take on the line at that speed (a faster link than the
/// instrument file says) is dated when its bytes would have started back, with no window. Dated at the middle of
/// the whole exchange instead, a report is late by half its reply's time on the line (about a millisecond at
/// 57,600 baud): every reading would be placed behind the arm, a bias whose sign changes with the sweep's
/// direction.
pub(super) fn position_sampled_at(
    sent_s: f64,
    received_s: f64,
    report: &PositionReport,
    bytes_per_s: f64,
) -> (f64, f64) {
    let wire = |n: usize| {
        if bytes_per_s > 0.0 {
            n as f64 / bytes_per_s
        } else {
            0.0
        }
    };
    let earliest = sent_s + wire(report.request_bytes);
    let latest = received_s - wire(report.reply_bytes);
    if latest >= earliest {
        (0.5 * (earliest + latest), latest - earliest)
    } else {
        (latest.max(sent_s), 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_position_is_dated_between_its_request_and_its_reply_on_the_line() {
        let report = PositionReport {
            position_deg: 0.0,
            request_bytes: 5,
            reply_bytes: 13,
        };
        // 57,600 baud: 5,760 bytes/s; 5 bytes out take 0.868 ms, 13 back 2.257 ms. Answered 4 ms after the
        // request: taken between 0.868 and 1.743 ms, dated at their middle.
        let (t, window) = position_sampled_at(1.0, 1.004, &report, 5760.0);
        let (lo, hi) = (1.0 + 5.0 / 5760.0, 1.004 - 13.0 / 5760.0);
        assert!((t - 0.5 * (lo + hi)).abs() < 1e-12, "{t}");
        assert!((window - (hi - lo)).abs() < 1e-12, "{window}");
        // Answered as soon as the reply could cross: taken when the reply started.
        let (t, window) = position_sampled_at(1.0, 1.0025, &report, 5760.0);
        assert!((t - (1.0025 - 13.0 / 5760.0)).abs() < 1e-12, "{t}");
        assert_eq!(window, 0.0);
        // No timed line: anywhere in the exchange, dated at its middle.
        let (t, window) = position_sampled_at(1.0, 1.001, &report, 0.0);
        assert!(
            (t - 1.0005).abs() < 1e-12 && (window - 0.001).abs() < 1e-12,
            "{t} {window}"
        );
        // A reply faster than even its own bytes: never before the request.
        assert_eq!(position_sampled_at(1.0, 1.001, &report, 5760.0), (1.0, 0.0));
    }

    #[test]
    fn the_profile_reaches_its_end_at_its_duration_and_cruise_times_invert_it() {
        let p = Profile {
            t0_s: 2.0,
            from_deg: 10.0,
            to_deg: -20.0,
            v: 4.0,
            a: 80.0,
        };
        // 30 degrees at 4 deg/s with 80 deg/s^2: 7.5 s plus v/a.
        assert!((p.duration_s() - (7.5 + 0.05)).abs() < 1e-12);
        assert_eq!(p.at(0.0), 10.0);
        assert!((p.at(2.0 + p.duration_s()) + 20.0).abs() < 1e-12);
        for x in [5.0, 0.0, -12.5] {
            let t = p.cruise_time_of(x).expect("on the cruise");
            assert!((p.at(t) - x).abs() < 1e-9, "{x}: {}", p.at(t));
        }
        assert!(p.cruise_time_of(9.99).is_none(), "in the ramp");
        // The mean position over a window: the arc's middle at cruise; a third of the way from rest.
        let (ta, tb) = (2.5, 3.5);
        assert!((p.mean_over(ta, tb) - 0.5 * (p.at(ta) + p.at(tb))).abs() < 1e-9);
        let ramp = 4.0 / 80.0;
        let third = 10.0 - (10.0 - p.at(2.0 + ramp)) / 3.0;
        assert!(
            // The midpoint rule's error on a ramp: its arc (0.1 deg) / (12 x 64^2), 2e-6 deg.
            (p.mean_over(2.0, 2.0 + ramp) - third).abs() < 3e-6,
            "{}",
            p.mean_over(2.0, 2.0 + ramp)
        );
        assert_eq!(p.mean_over(3.0, 3.0), p.at(3.0));
    }
}
