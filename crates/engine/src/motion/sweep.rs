//! One axis swept at a set speed while something is read back to back: the motion a campaign's sweeps
//! (crate::runner's sweep module) and the self-test's timing of them (crate::selftest) share.
//!
//! The pass: the axis's speed set for the sweep (the instrument file's acceleration), the move to the arc's end
//! commanded, `reader` read back to back until the axis has arrived, a position report asked beside every
//! `report_every`-th reading (concurrently: the controller's line and the meter's are separate), then the
//! verified arrival; the caller sets the axis's own speed back ([`restore_speed`]). What comes back is the commanded trapezoid (started when
//! the command went out), each reading's request time with what it read, the dated reports, and the swept axis's read-back at its
//! arrival (where it is: the other axes did not move, and are not asked). Where the arm
//! was at any instant is then the trapezoid shifted by the arm's lag behind it, which [`Pass::lag_s`] takes from
//! the reports made while it cruised.
//!
//! A report's dating (`sampled_at`): a controller takes the position somewhere between the query's arrival
//! and its reply's start on the line. When, the instrument file's `position_sampled_ms` says when it is known
//! (counted from the query's sending, measured by the self-test); otherwise the report is dated in the middle
//! of that window and the window's width is what remains unknown.

use gonio_driver::PositionReport;
use gonio_scheduler::timing::Trapezoid;

use super::{Device, Motion, MotionError};
use crate::rig::RigAxis;

/// The sweep's motion may take this much longer than its profile (and 5 s) before it is given up.
const OVERRUN: f64 = 1.5;

/// How the reports of one controller are dated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ReportDating {
    /// Bytes a second on the controller's line (8N1: ten bits a byte); 0: not a timed line.
    pub bytes_per_s: f64,
    /// When the controller takes the position after the host sent the query (s), when known.
    pub sampled_after_s: Option<f64>,
}

impl ReportDating {
    /// The dating of `axis`'s reports from the instrument file: its device's baud rate and
    /// `position_sampled_ms`; an axis whose device the file lacks has an untimed line.
    pub(crate) fn of(file: &gonio_instrument::InstrumentFile, axis: &gonio_instrument::Axis) -> ReportDating {
        let device = file.instrument.device(&axis.device);
        ReportDating {
            bytes_per_s: device.map_or(0.0, |d| f64::from(d.line_baud()) / 10.0),
            sampled_after_s: device.and_then(|d| d.position_sampled_ms).map(|ms| ms / 1000.0),
        }
    }

    /// When the controller took the position it reported in an exchange sent at `sent_s` and answered at
    /// `received_s` (clock seconds), and the width of the window it may have taken it in (s). The window runs
    /// from the request's arrival to the reply's start on the line. Known sampling: that long after the query
    /// was sent, no later than the reply's start. Unknown: the window's middle. A reply that came
    /// sooner than its bytes take on the line (a faster link than the file says) is dated when its bytes would
    /// have started back, with no window. Dated at the middle of the whole exchange instead, a report is late by
    /// half its reply's time on the line (about a millisecond at 57,600 baud): every reading would be placed
    /// behind the arm, a bias whose sign changes with the sweep's direction.
    pub(crate) fn sampled_at(&self, sent_s: f64, received_s: f64, report: &PositionReport) -> (f64, f64) {
        let wire = |n: usize| {
            if self.bytes_per_s > 0.0 {
                n as f64 / self.bytes_per_s
            } else {
                0.0
            }
        };
        let earliest = sent_s + wire(report.request_bytes);
        let latest = received_s - wire(report.reply_bytes);
        if let Some(s) = self.sampled_after_s.filter(|s| s.is_finite()) {
            return ((sent_s + s).min(latest.max(sent_s)), (latest - earliest).max(0.0));
        }
        if latest < earliest {
            return (latest.max(sent_s), 0.0);
        }
        (0.5 * (earliest + latest), latest - earliest)
    }
}

/// What a pass reads back to back (the meter, as a campaign's sweep or the self-test configured it). A trait
/// rather than an async closure: its future is declared `Send`, which a run spawned on the daemon's runtime
/// needs and an async closure's borrowed captures cannot yet state.
pub(crate) trait Reader {
    type Reading;
    fn read(&mut self) -> impl std::future::Future<Output = Self::Reading> + Send;
    /// How long one reading integrates (s): [`sweep_axis`] asks for none that would run more than half of it
    /// past the motion's end.
    fn integration_s(&self) -> f64;
}

/// What one pass gave (module doc).
#[derive(Debug)]
pub(crate) struct Pass<R> {
    /// The commanded profile, started when the move command went out (clock seconds).
    pub profile: Trapezoid,
    /// Each reading's request time (clock seconds) and what it read.
    pub taken: Vec<(f64, R)>,
    /// The position reports: when the controller took each position (clock seconds) and the position (deg).
    pub reports: Vec<(f64, f64)>,
    /// The widest window a report could have been taken in (s).
    pub widest_window_s: f64,
    /// The latest a report would have been dated after its query was sent without a known sampling instant
    /// (s): the window's middle, what a file silent on it makes a sweep assume.
    pub assumed_after_s: f64,
    /// How the reports were dated.
    pub dating: ReportDating,
    /// The axis's read-back at its arrival (physical degrees).
    pub arrived_deg: f64,
}

impl<R> Pass<R> {
    /// The widest window a report was dated in without knowing where in it the controller took the position
    /// (s): 0 when the sampling instant is known.
    pub(crate) fn unknown_window_s(&self) -> f64 {
        if self.dating.sampled_after_s.is_some() {
            0.0
        } else {
            self.widest_window_s
        }
    }

    /// The arm's lag behind the commanded profile (s): the median over the reports made while it cruised, with
    /// the spread of those (s); None without such a report.
    pub(crate) fn lag_s(&self) -> Option<(f64, f64)> {
        let mut lags: Vec<f64> = self
            .reports
            .iter()
            .filter_map(|(t, x)| self.profile.cruise_time_of(*x).map(|tp| t - tp))
            .collect();
        lags.sort_by(f64::total_cmp);
        let median = *lags.get(lags.len() / 2)?;
        Some((median, lags.last()? - lags.first()?))
    }
}

/// Where the swept arm's load is against its motor (physical degrees) during a sweep of `span_deg`: points are
/// approached from below in controller coordinates (gonio_driver::motion::approach_waypoints), the contact the
/// axis's zero refers to; a sweep down the controller's scale pushes the load from the other side of the
/// backlash, a whole `backlash_deg` further up the controller's scale.
pub(crate) fn load_offset_deg(axis: &gonio_instrument::Axis, span_deg: f64) -> f64 {
    let direction = f64::from(axis.direction.signum());
    if direction * span_deg < 0.0 {
        direction * axis.backlash_deg
    } else {
        0.0
    }
}

/// One pass of `axis` from where it stands (`from_deg`, physical) to `to_deg` at `speed_deg_s` (module doc).
/// `report_every`: a position report beside every this many readings (at least 1), dated by `dating`
/// ([`ReportDating::of`] the instrument file, or the self-test's own). Fails on the emergency
/// stop, on a device that fails, and when the motion outlasts its profile by half and 5 s (the axis is then
/// stopped and a person must look).
pub(crate) async fn sweep_axis<R: Reader>(
    motion: &Motion<'_>,
    axis: &RigAxis,
    (from_deg, to_deg): (f64, f64),
    speed_deg_s: f64,
    report_every: usize,
    dating: ReportDating,
    reader: &mut R,
) -> Result<Pass<R::Reading>, MotionError> {
    let cfg = &axis.config;
    let clock = motion.clock();
    let what = format!("set {} to {speed_deg_s} deg/s for a sweep", cfg.name);
    motion
        .device(Device::Axis(axis), &what, || {
            axis.driver.set_speed(speed_deg_s, cfg.accel_deg_s2)
        })
        .await?;
    // The arm starts when the controller has the command, which is sent at once; the driver may hold its reply
    // back (the SMC100's pause after a command that sets something). The profile starts when the command goes
    // out, so that the loop below ends with the motion, not that pause later. The readings start after the
    // reply: a reading whose window spans the command would be placed by the profile while the simulated meter
    // (simulator/src/pm100/physics.rs) fixes a window's poses when it is asked, before the motion it does not
    // know of yet.
    let profile = Trapezoid {
        t0_s: clock.now_s(),
        from_deg,
        to_deg,
        v: speed_deg_s,
        a: cfg.accel_deg_s2,
    };
    let what = format!("start the sweep of {} to {to_deg:.4} deg", cfg.name);
    motion
        .device(Device::Axis(axis), &what, || axis.driver.start_move(to_deg))
        .await?;
    let deadline = profile.t0_s + OVERRUN * profile.duration_s() + 5.0;
    let every = report_every.max(1);
    let unknown = ReportDating {
        sampled_after_s: None,
        ..dating
    };
    let mut pass = Pass {
        profile,
        taken: Vec::new(),
        reports: Vec::new(),
        widest_window_s: 0.0,
        assumed_after_s: 0.0,
        dating,
        arrived_deg: f64::NAN,
    };
    let end_s = profile.t0_s + profile.duration_s();
    let half_reading_s = 0.5 * reader.integration_s().max(0.0);
    loop {
        if motion.control.estop_requested() {
            let _ = axis.driver.stop().await;
            return Err(MotionError::Estop);
        }
        let requested_s = clock.now_s();
        // A reading that would run more than half of it past the motion's predicted end would mostly read the
        // arm at rest, and the next piece would wait for it. The arm is asked where it is: within half a
        // reading of its stop, the driver's wait for the arrival takes over (asked during the motion, it looks
        // again just after the predicted end) and the arc's last half reading is left unread; an arm running
        // late (slower than its file) is read on.
        if !pass.taken.is_empty() && requested_s + half_reading_s > end_s {
            let nearly_there = axis.driver.position_report().await.is_ok_and(|r| {
                time_to_stop_s((to_deg - r.position_deg).abs(), speed_deg_s, cfg.accel_deg_s2)
                    <= half_reading_s
            });
            if nearly_there {
                break;
            }
        }
        let reading = if pass.taken.len() % every == every - 1 {
            // Each report is dated by its own exchange, not when the reading beside it ends: dated late, it
            // would put every reading behind the arm (a bias that changes sign with the sweep's direction).
            let report = async {
                let t0 = clock.now_s();
                let r = axis.driver.position_report().await;
                r.ok().map(|r| {
                    let t1 = clock.now_s();
                    let (t, window) = dating.sampled_at(t0, t1, &r);
                    let (assumed, _) = unknown.sampled_at(t0, t1, &r);
                    (t, window, assumed - t0, r.position_deg)
                })
            };
            let (reading, report) = tokio::join!(reader.read(), report);
            if let Some((t, window, assumed, deg)) = report {
                pass.widest_window_s = pass.widest_window_s.max(window);
                pass.assumed_after_s = pass.assumed_after_s.max(assumed);
                pass.reports.push((t, deg));
            }
            reading
        } else {
            reader.read().await
        };
        pass.taken.push((requested_s, reading));
        let now = clock.now_s();
        if now >= end_s {
            let status = axis.driver.status().await;
            if status.as_ref().is_ok_and(|s| !s.moving) {
                break;
            }
        }
        if now > deadline {
            let _ = axis.driver.stop().await;
            return Err(MotionError::NeedsOperator(format!(
                "the sweep of {} did not end within {:.1} s of its predicted {:.1} s",
                cfg.name,
                now - profile.t0_s,
                profile.duration_s()
            )));
        }
    }
    let what = format!("end the sweep of {} at {to_deg:.4} deg", cfg.name);
    pass.arrived_deg = motion
        .device(Device::Axis(axis), &what, || axis.driver.wait_arrived(to_deg))
        .await?;
    Ok(pass)
}

/// How long an arm cruising at `v` (deg/s) takes to stop `d` degrees further on, braking at `a` (deg/s^2) (s).
fn time_to_stop_s(d: f64, v: f64, a: f64) -> f64 {
    if !(v > 0.0 && a > 0.0) {
        return if d > 0.0 { f64::INFINITY } else { 0.0 };
    }
    let braking = v * v / (2.0 * a);
    if d >= braking {
        (d - braking) / v + v / a
    } else {
        (2.0 * d / a).sqrt()
    }
}

/// The axis's own speed (the instrument file's) set back after sweeping, before it moves otherwise: the pass
/// leaves it at the sweep's, which the next piece of a sweep that follows the BRDF replaces with its own.
pub(crate) async fn restore_speed(motion: &Motion<'_>, axis: &RigAxis) -> Result<(), MotionError> {
    let cfg = &axis.config;
    let what = format!("restore the speed of {}", cfg.name);
    motion
        .device(Device::Axis(axis), &what, || {
            axis.driver.set_speed(cfg.max_speed_deg_s, cfg.accel_deg_s2)
        })
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report() -> PositionReport {
        PositionReport {
            position_deg: 0.0,
            request_bytes: 5,
            reply_bytes: 13,
        }
    }

    #[test]
    fn an_arm_stops_after_its_cruise_and_its_braking() {
        // 20 deg/s braking at 80 deg/s^2: 2.5 deg of braking in 0.25 s; 4.5 deg out, 0.1 s of cruise first.
        assert!((time_to_stop_s(4.5, 20.0, 80.0) - 0.35).abs() < 1e-12);
        assert!((time_to_stop_s(2.5, 20.0, 80.0) - 0.25).abs() < 1e-12);
        // Within the braking: from rest to rest the last d degrees take sqrt(2 d / a).
        assert!((time_to_stop_s(0.4, 20.0, 80.0) - 0.1).abs() < 1e-12);
        assert_eq!(time_to_stop_s(0.0, 20.0, 80.0), 0.0);
        assert_eq!(time_to_stop_s(1.0, 0.0, 80.0), f64::INFINITY);
    }

    #[test]
    fn a_position_is_dated_between_its_request_and_its_reply_on_the_line() {
        let report = report();
        let unknown = ReportDating {
            bytes_per_s: 5760.0,
            sampled_after_s: None,
        };
        // 57,600 baud: 5,760 bytes/s; 5 bytes out take 0.868 ms, 13 back 2.257 ms. Answered 4 ms after the
        // request: taken between 0.868 and 1.743 ms, dated at their middle.
        let (t, window) = unknown.sampled_at(1.0, 1.004, &report);
        let (lo, hi) = (1.0 + 5.0 / 5760.0, 1.004 - 13.0 / 5760.0);
        assert!((t - 0.5 * (lo + hi)).abs() < 1e-12, "{t}");
        assert!((window - (hi - lo)).abs() < 1e-12, "{window}");
        // Answered as soon as the reply could cross: taken when the reply started.
        let (t, window) = unknown.sampled_at(1.0, 1.0025, &report);
        assert!((t - (1.0025 - 13.0 / 5760.0)).abs() < 1e-12, "{t}");
        assert_eq!(window, 0.0);
        // No timed line: anywhere in the exchange, dated at its middle.
        let untimed = ReportDating {
            bytes_per_s: 0.0,
            sampled_after_s: None,
        };
        let (t, window) = untimed.sampled_at(1.0, 1.001, &report);
        assert!(
            (t - 1.0005).abs() < 1e-12 && (window - 0.001).abs() < 1e-12,
            "{t} {window}"
        );
        // A reply faster than even its own bytes: never before the request.
        assert_eq!(unknown.sampled_at(1.0, 1.001, &report), (1.0, 0.0));
    }

    #[test]
    fn a_known_sampling_instant_dates_a_report_inside_its_window() {
        let report = report();
        let arrival = 1.0 + 5.0 / 5760.0;
        let reply_starts = 1.012 - 13.0 / 5760.0;
        // Taken as the query was sent (0 ms: the simulator's devices), as it arrived, 4 ms after it was sent,
        // later than the reply could start (kept before it), and 1 ms before it was sent (a meter that starts
        // its readings 1 ms after their requests, its controller taking positions at once).
        for (after_s, expected) in [
            (-0.001, 0.999),
            (0.0, 1.0),
            (5.0 / 5760.0, arrival),
            (0.004, 1.004),
            (0.050, reply_starts),
        ] {
            let known = ReportDating {
                bytes_per_s: 5760.0,
                sampled_after_s: Some(after_s),
            };
            let (t, window) = known.sampled_at(1.0, 1.012, &report);
            assert!((t - expected).abs() < 1e-12, "{after_s}: {t} against {expected}");
            assert!((window - (reply_starts - arrival)).abs() < 1e-12, "{window}");
        }
    }

    #[test]
    fn the_lag_is_the_median_over_the_cruise() {
        let profile = Trapezoid {
            t0_s: 10.0,
            from_deg: 0.0,
            to_deg: 20.0,
            v: 10.0,
            a: 100.0,
        };
        // The arm 20 ms behind the profile; reports in the cruise, one in the first ramp (ignored).
        let lag = 0.020;
        let reports: Vec<(f64, f64)> = [10.05, 10.5, 11.0, 11.4, 11.7]
            .iter()
            .map(|&t| (t, profile.position(t - lag)))
            .collect();
        let pass: Pass<()> = Pass {
            profile,
            taken: Vec::new(),
            reports,
            widest_window_s: 0.004,
            assumed_after_s: 0.003,
            dating: ReportDating {
                bytes_per_s: 0.0,
                sampled_after_s: None,
            },
            arrived_deg: 12.0,
        };
        let (median, spread) = pass.lag_s().expect("reports on the cruise");
        assert!((median - lag).abs() < 1e-9, "{median}");
        assert!(spread < 1e-9, "{spread}");
        assert_eq!(pass.unknown_window_s(), 0.004);
        let none: Pass<()> = Pass {
            profile,
            taken: Vec::new(),
            reports: vec![(10.01, profile.position(10.01))],
            widest_window_s: 0.004,
            assumed_after_s: 0.003,
            dating: ReportDating {
                bytes_per_s: 0.0,
                sampled_after_s: Some(0.0),
            },
            arrived_deg: 12.0,
        };
        assert_eq!(none.lag_s(), None);
        // Told when the controller takes its positions: no window is left unknown.
        assert_eq!(none.unknown_window_s(), 0.0);
    }
}
