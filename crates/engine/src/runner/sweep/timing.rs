//! When a swept arm was where: the dating of the controller's position reports against the commanded
//! trapezoid (`gonio_scheduler::timing::Trapezoid`).

use gonio_driver::PositionReport;

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
}
