//! Waiting for a device to finish a move or a homing, shared by the axis drivers: when to ask again
//! ([`PollSchedule`]) and the loop's deadline, with the axis stopped when it passes ([`Poll`]). What to ask and
//! what an answer means stays with each driver: this module knows nothing of a protocol.

use std::future::Future;
use std::time::Duration;

use tokio::time::Instant;

use crate::error::DriverError;

/// How long after the predicted end of a move the question that should find it over goes out: the clock's tick,
/// so that a move ending on time (to rounding) is over when asked, not a hair short of it, which would cost a
/// whole [`PollSchedule`] `min_gap` more.
pub const ARRIVAL_MARGIN: Duration = Duration::from_millis(1);

/// When to ask a controller again whether a move is over.
///
/// The first question goes out at once (a move that is already over, or a fault at the start, is seen without
/// any wait). While the move is predicted to run, the pauses split the time up to [`ARRIVAL_MARGIN`] after the
/// predicted end into equal parts no longer than `max_gap`: a stall or a limit is noticed within `max_gap`,
/// which matters when another axis is moving in the same phase and must be stopped, and the last question goes
/// out just after the predicted end rather than a capped pause short of it. From the predicted end on, the pause
/// starts at `min_gap` and doubles up to `max_gap`, so a move that ends on time is seen within `min_gap` of its
/// end and one that runs late costs a handful of questions, not a flood. `min_gap` is the shortest pause between two status questions to one
/// controller: no schedule asks faster than the controller answers.
#[derive(Debug, Clone)]
pub struct PollSchedule {
    predicted_end: Instant,
    min_gap: Duration,
    max_gap: Duration,
    /// The pause after the predicted end, doubling.
    late_gap: Duration,
}

impl PollSchedule {
    /// A schedule for a move predicted to end at `predicted_end`. `max_gap` is raised to `min_gap` if below.
    pub fn new(predicted_end: Instant, min_gap: Duration, max_gap: Duration) -> PollSchedule {
        let max_gap = max_gap.max(min_gap);
        PollSchedule {
            predicted_end,
            min_gap,
            max_gap,
            late_gap: min_gap,
        }
    }

    /// The pause before the next question, asked at `now` after an answer "still moving".
    pub fn next_pause(&mut self, now: Instant) -> Duration {
        if now < self.predicted_end {
            let remaining = self.predicted_end + ARRIVAL_MARGIN - now;
            let parts = (remaining.as_secs_f64() / self.max_gap.as_secs_f64())
                .ceil()
                .max(1.0);
            return remaining.div_f64(parts).max(self.min_gap);
        }
        let pause = self.late_gap;
        self.late_gap = (self.late_gap * 2).min(self.max_gap);
        pause
    }

    /// Whether the move is predicted to be over at `now` (a question then also asks for the read-back).
    pub fn expect_over(&self, now: Instant) -> bool {
        now >= self.predicted_end
    }
}

/// One wait for a move or a homing to end: the deadline, the schedule of questions, and what happens when the
/// deadline passes (the axis is stopped, so that a move that went wrong does not run on unwatched, and the wait
/// ends in a typed [`DriverError::Timeout`]). A driver asks its question, decides from the answer whether the
/// wait is over, and otherwise calls [`Poll::pause`]:
///
/// ```ignore
/// let mut poll = Poll::new(device, "move to 5 deg", timeout, predicted, POLL_MIN, POLL_MAX);
/// loop {
///     if over(ask().await?) { break; }
///     poll.pause(|| stop()).await?;
/// }
/// ```
#[derive(Debug)]
pub struct Poll {
    device: String,
    request: String,
    start: Instant,
    timeout: Duration,
    schedule: PollSchedule,
    first: bool,
}

impl Poll {
    /// A wait starting now for `request` on `device` (both for the timeout's message), ending by `timeout` at
    /// the latest; the awaited state is predicted `predicted` from now (see [`PollSchedule`]).
    pub fn new(
        device: String,
        request: impl Into<String>,
        timeout: Duration,
        predicted: Duration,
        min_gap: Duration,
        max_gap: Duration,
    ) -> Poll {
        let start = Instant::now();
        Poll {
            device,
            request: request.into(),
            start,
            timeout,
            schedule: PollSchedule::new(start + predicted, min_gap, max_gap),
            first: true,
        }
    }

    /// Whether no pause has been taken yet: the question about to go out is the first of this wait.
    pub fn is_first(&self) -> bool {
        self.first
    }

    /// Whether the awaited state is predicted by now (a question then may also ask for the read-back).
    pub fn expect_over(&self) -> bool {
        self.schedule.expect_over(Instant::now())
    }

    /// Lengthen the deadline to `timeout` from the start of the wait (never shortens it): for a device's own
    /// estimate of the move, which knows its real profile.
    pub fn lengthen(&mut self, timeout: Duration) {
        self.timeout = self.timeout.max(timeout);
    }

    /// After an answer "not over yet": pause until the next question, or, when the deadline has passed, stop
    /// the axis with `stop` (its own failure is not the error to report) and end the wait with a timeout.
    pub async fn pause<S, F, T>(&mut self, stop: S) -> Result<(), DriverError>
    where
        S: FnOnce() -> F,
        F: Future<Output = Result<T, DriverError>>,
    {
        let now = Instant::now();
        let deadline = self.start + self.timeout;
        if now >= deadline {
            tracing::warn!(axis = %self.device, request = %self.request, "deadline passed while moving; stopping the axis");
            if let Err(e) = stop().await {
                tracing::warn!(axis = %self.device, error = %e, "stop after the deadline failed");
            }
            return Err(DriverError::Timeout {
                device: self.device.clone(),
                request: self.request.clone(),
                timeout: self.timeout,
            });
        }
        self.first = false;
        tokio::time::sleep(self.schedule.next_pause(now).min(deadline - now)).await;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polls_reach_the_predicted_end_in_capped_steps_then_back_off() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut p = PollSchedule::new(t0 + ms(120), ms(10), ms(50));
        assert!(!p.expect_over(t0));
        // During the move: equal parts of at most the cap up to the margin after the predicted end (121 ms in
        // three), recomputed from each question (after a 2 ms exchange, 79 ms in two), the last exactly there.
        assert_eq!(p.next_pause(t0), ms(121).div_f64(3.0));
        assert_eq!(p.next_pause(t0 + ms(42)), ms(79).div_f64(2.0));
        assert_eq!(p.next_pause(t0 + ms(100)), ms(21));
        // Never shorter than the minimum gap, even just before the end.
        assert_eq!(p.next_pause(t0 + ms(118)), ms(10));
        // Late: 10, 20, 40, then capped at 50.
        assert!(p.expect_over(t0 + ms(120)));
        let late: Vec<Duration> = (0..5).map(|i| p.next_pause(t0 + ms(120 + i))).collect();
        assert_eq!(late, vec![ms(10), ms(20), ms(40), ms(50), ms(50)]);
        // A cap below the minimum gap is raised to it.
        let mut q = PollSchedule::new(t0, ms(10), ms(1));
        assert_eq!(q.next_pause(t0 + ms(1)), ms(10));
        assert_eq!(q.next_pause(t0 + ms(2)), ms(10));
    }

    #[tokio::test(start_paused = true)]
    async fn a_wait_pauses_on_its_schedule_then_stops_the_axis_at_its_deadline() {
        let ms = Duration::from_millis;
        let t0 = Instant::now();
        let mut poll = Poll::new("a".into(), "move to 1 deg", ms(100), ms(30), ms(10), ms(50));
        assert!(poll.is_first() && !poll.expect_over());
        let stops = std::cell::Cell::new(0);
        let stop = || async {
            stops.set(stops.get() + 1);
            Ok::<(), DriverError>(())
        };
        poll.pause(stop).await.expect("within the deadline");
        assert_eq!(Instant::now() - t0, ms(31), "up to just after the predicted end");
        assert!(!poll.is_first() && poll.expect_over());
        // A device estimate lengthens the deadline, never shortens it.
        poll.lengthen(ms(120));
        poll.lengthen(ms(1));
        let mut pauses = 0;
        let err = loop {
            match poll.pause(stop).await {
                Ok(()) => pauses += 1,
                Err(e) => break e,
            }
        };
        // 10, 20, 40, 19 (cut at the deadline, 120 ms): four pauses, then the stop and the timeout.
        assert_eq!(pauses, 4);
        assert_eq!(Instant::now() - t0, ms(120));
        assert_eq!(stops.get(), 1, "the axis was stopped once");
        assert!(
            matches!(&err, DriverError::Timeout { device, request, timeout }
                if device == "a" && request == "move to 1 deg" && *timeout == ms(120)),
            "{err:?}"
        );
    }
}
