//! Polling one controller until it reaches a state, with the deadline, the confirmation of alarming states and
//! the read-back asked with the question made when the move should be over.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use super::controller::Controller;
use super::protocol::{State, Ts, number_at, parse_ts, ts_reason, wire_number};
use super::{POLL_MAX, POLL_MIN};
use crate::error::DriverError;
use crate::poll::Poll;

/// How long to wait for a state, and what else to ask on the way (see [`wait_state`]).
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

/// Poll TS of `ctl` until `done(state)`, on a [`Poll`] (the first question at once). DISABLE, NOT REFERENCED
/// (unless awaited), CONFIGURATION and unknown states end the wait with the device's reason, once confirmed
/// (see [`Controller::confirmed`]). Returns the final TS and, when `wait.readback` asked for it and the final
/// question carried two agreeing TP reads, the read-back position (controller units).
///
/// `early_finish` remembers whether the last such wait was over at its first question (a tiny move, or a
/// controller much faster than its configured motion): the first question of the next one then asks for the
/// read-back at once, saving an exchange.
pub(super) async fn wait_state(
    ctl: &Controller,
    early_finish: &AtomicBool,
    done: impl Fn(State) -> bool,
    wait: Wait,
    target_deg: Option<f64>,
) -> Result<(Ts, Option<f64>), DriverError> {
    let request = match target_deg {
        Some(t) => format!("move to {t} deg"),
        None => "homing".into(),
    };
    let mut poll = Poll::new(
        ctl.device.clone(),
        request,
        wait.timeout,
        wait.predicted,
        POLL_MIN,
        POLL_MAX,
    );
    loop {
        let first = poll.is_first();
        let pt_arg = wait.pt_distance.filter(|_| first).map(wire_number);
        // A question asked when the move should be over also asks for the read-back (two TP), so that the
        // arrival costs no further exchange.
        let readback =
            wait.readback && (poll.expect_over() || (first && early_finish.load(Ordering::Relaxed)));
        let mut queries: Vec<(&str, &str)> = Vec::with_capacity(4);
        if let Some(arg) = pt_arg.as_deref() {
            queries.push(("PT", arg));
        }
        queries.push(("TS", ""));
        if readback {
            queries.extend([("TP", ""), ("TP", "")]);
        }
        let r = ctl.chain.queries(ctl.addr, &queries).await?;
        let mut at = 0;
        if pt_arg.is_some() {
            // The controller's own estimate of the move time can only lengthen the deadline: it knows its
            // real profile.
            if let Some(pt) = number_at(&r, 0)
                && (0.0..600.0).contains(&pt)
            {
                poll.lengthen(Duration::from_secs_f64(2.0 * pt + 2.0));
            }
            at = 1;
        }
        let (ts, read) = match r.get(at).and_then(|v| v.as_deref()).and_then(parse_ts) {
            Some(ts) => {
                // (A wait acts on the state only; error bits are for the status report.)
                let confirmed = ctl.confirmed(ts, false).await?;
                // Read-back values count only when they followed this very TS (not a confirmation).
                let read = match (number_at(&r, at + 1), number_at(&r, at + 2)) {
                    (Some(a), Some(b)) if confirmed == ts && ctl.reads_agree(a, b, 0.0) => Some(b),
                    _ => None,
                };
                (confirmed, read)
            }
            None => {
                if r.get(at).is_some_and(Option::is_none) && ctl.chain.lost_first_ts(ctl.addr) {
                    tracing::debug!(axis = %ctl.device, replies = ?r, "first TS unanswered, as recorded for real SMC100s; asking again");
                } else {
                    tracing::warn!(axis = %ctl.device, replies = ?r, "malformed TS reply; asking again");
                }
                (ctl.confirmed(ctl.chain.ts(ctl.addr).await?, false).await?, None)
            }
        };
        if wait.readback && first {
            early_finish.store(done(ts.state), Ordering::Relaxed);
        }
        if done(ts.state) {
            return Ok((ts, read));
        }
        match ts.state {
            State::Moving | State::Homing(_) | State::Ready(_) => {}
            State::NotReferenced(_) => {
                return Err(DriverError::NotReferenced {
                    device: ctl.device.clone(),
                    state: ts_reason(&ts),
                });
            }
            _ => {
                return Err(DriverError::MotionFault {
                    device: ctl.device.clone(),
                    target_deg: target_deg.unwrap_or(f64::NAN),
                    reason: ts_reason(&ts),
                });
            }
        }
        poll.pause(|| ctl.chain.stop_all(std::slice::from_ref(&ctl.addr)))
            .await?;
    }
}
