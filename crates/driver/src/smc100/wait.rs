//! Polling one controller until it reaches a state, with the deadline, the confirmation of alarming states and
//! the read-back asked with the question made when the move should be over.

use std::sync::atomic::Ordering;
use std::time::Duration;

use tokio::time::Instant;

use super::axis::{Smc100Axis, number_at, ts_reason};
use super::protocol::{State, Ts, parse_ts, wire_number};
use super::{POLL_MAX, POLL_MIN};
use crate::error::DriverError;
use crate::motion::PollSchedule;

/// How long to wait for a state, and what else to ask on the way (see [`Smc100Axis::wait_state`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Wait {
    /// Deadline from the start of the wait (lengthened by the controller's PT estimate when asked).
    pub(super) timeout: Duration,
    /// When the awaited state is predicted, from the start of the wait.
    pub(super) predicted: Duration,
    /// Ask PT for this distance with the first question.
    pub(super) pt_distance: Option<f64>,
    /// Ask for the read-back (two TP) with the questions made when the move should be over.
    pub(super) readback: bool,
}

impl Wait {
    pub(super) fn plain(timeout: Duration, predicted: Duration) -> Wait {
        Wait {
            timeout,
            predicted,
            pt_distance: None,
            readback: false,
        }
    }
}

impl Smc100Axis {
    /// Poll TS until `done(state)`, on a [`PollSchedule`] (the first question at once). DISABLE, NOT REFERENCED
    /// (unless awaited), CONFIGURATION and unknown states end the wait with the device's reason, once confirmed
    /// (see [`Smc100Axis::confirmed`]). Returns the final TS and, when `wait.readback` asked for it and the final
    /// question carried two agreeing TP reads, the read-back position (controller units).
    pub(super) async fn wait_state(
        &self,
        done: impl Fn(State) -> bool,
        wait: Wait,
        target_deg: Option<f64>,
    ) -> Result<(Ts, Option<f64>), DriverError> {
        let start = Instant::now();
        let mut timeout = wait.timeout;
        let mut schedule = PollSchedule::new(start + wait.predicted, POLL_MIN, POLL_MAX);
        let mut first = true;
        loop {
            let now = Instant::now();
            let pt_arg = wait.pt_distance.filter(|_| first).map(wire_number);
            // A question asked when the move should be over also asks for the read-back (two TP), so that the
            // arrival costs no further exchange.
            let readback = wait.readback
                && (schedule.expect_over(now) || (first && self.early_finish.load(Ordering::Relaxed)));
            let mut queries: Vec<(&str, &str)> = Vec::with_capacity(4);
            if let Some(arg) = pt_arg.as_deref() {
                queries.push(("PT", arg));
            }
            queries.push(("TS", ""));
            if readback {
                queries.extend([("TP", ""), ("TP", "")]);
            }
            let r = self.chain.queries(self.addr, &queries).await?;
            let mut at = 0;
            if pt_arg.is_some() {
                // The controller's own estimate of the move time can only lengthen the deadline: it knows its
                // real profile.
                if let Some(pt) = number_at(&r, 0)
                    && (0.0..600.0).contains(&pt)
                {
                    timeout = timeout.max(Duration::from_secs_f64(2.0 * pt + 2.0));
                }
                at = 1;
            }
            let (ts, read) = match r.get(at).and_then(|v| v.as_deref()).and_then(parse_ts) {
                Some(ts) => {
                    // (A wait acts on the state only; error bits are for the status report.)
                    let confirmed = self.confirmed(ts, false).await?;
                    // Read-back values count only when they followed this very TS (not a confirmation).
                    let read = match (number_at(&r, at + 1), number_at(&r, at + 2)) {
                        (Some(a), Some(b)) if confirmed == ts && self.reads_agree(a, b, false) => Some(b),
                        _ => None,
                    };
                    (confirmed, read)
                }
                None => {
                    tracing::warn!(axis = %self.dev(), replies = ?r, "malformed TS reply; asking again");
                    (
                        self.confirmed(self.chain.ts(self.addr).await?, false).await?,
                        None,
                    )
                }
            };
            if done(ts.state) {
                if wait.readback && first {
                    self.early_finish.store(true, Ordering::Relaxed);
                }
                return Ok((ts, read));
            }
            if wait.readback && first {
                self.early_finish.store(false, Ordering::Relaxed);
            }
            match ts.state {
                State::Moving | State::Homing(_) => {}
                State::NotReferenced(_) => {
                    return Err(DriverError::NotReferenced {
                        device: self.dev(),
                        state: ts_reason(&ts),
                    });
                }
                State::Ready(_) => {}
                _ => {
                    return Err(DriverError::MotionFault {
                        device: self.dev(),
                        target_deg: target_deg.unwrap_or(f64::NAN),
                        reason: ts_reason(&ts),
                    });
                }
            }
            let now = Instant::now();
            let deadline = start + timeout;
            if now >= deadline {
                tracing::warn!(axis = %self.dev(), "deadline passed while moving; stopping the axis");
                let _ = self.chain.stop_all(&[self.addr]).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: match target_deg {
                        Some(t) => format!("move to {t} deg"),
                        None => "homing".into(),
                    },
                    timeout,
                });
            }
            first = false;
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
        }
    }
}
