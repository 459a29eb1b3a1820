//! The simulated clock: every timed thing in the simulator reads it.
//!
//! Simulated time is the tokio clock's elapsed time since the simulation started, multiplied by a time scale.
//! Under tokio's paused clock (`#[tokio::test(start_paused = true)]`) sleeping auto-advances, so a dry run spends
//! no wall time on motion; in pseudo-terminal mode a scale above 1 makes the instrument faster than real time.
//! Waits end at or after their target, at most one tokio timer tick (1 ms of real time) late.

use std::time::Duration;

use tokio::time::Instant;

/// Simulated seconds = tokio elapsed seconds x `time_scale`.
#[derive(Debug, Clone, Copy)]
pub struct SimClock {
    start: Instant,
    time_scale: f64,
}

impl SimClock {
    /// A clock starting now. `time_scale` must be finite and > 0 (checked by the caller).
    pub fn new(time_scale: f64) -> SimClock {
        SimClock {
            start: Instant::now(),
            time_scale,
        }
    }

    pub fn time_scale(&self) -> f64 {
        self.time_scale
    }

    /// Simulated seconds since the start.
    pub fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64() * self.time_scale
    }

    /// The first tokio instant at which the simulated clock reads at least `t_s` (clamped to the start).
    /// Rounded up by a nanosecond: converting seconds to a `Duration` may round down, and a waiter woken a hair
    /// early would see the event still in the future and wait again for the same instant forever.
    pub fn instant_at(&self, t_s: f64) -> Instant {
        self.start + self.real_duration(t_s) + Duration::from_nanos(1)
    }

    /// Tokio (real or paused) duration for a span of simulated seconds; negative or NaN spans are zero and
    /// absurdly long ones are capped at a year so that arithmetic on instants cannot overflow.
    pub fn real_duration(&self, sim_s: f64) -> Duration {
        let real = sim_s / self.time_scale;
        if real.is_nan() || real <= 0.0 {
            Duration::ZERO
        } else {
            Duration::from_secs_f64(real.min(365.0 * 86_400.0))
        }
    }

    /// Sleep until the simulated clock reads `t_s`.
    pub async fn sleep_until_s(&self, t_s: f64) {
        tokio::time::sleep_until(self.instant_at(t_s)).await;
    }

    /// Sleep for `dt_s` simulated seconds.
    pub async fn sleep_s(&self, dt_s: f64) {
        tokio::time::sleep(self.real_duration(dt_s)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn paused_clock_advances_by_scaled_sleep() {
        let clock = SimClock::new(10.0);
        assert_eq!(clock.now_s(), 0.0);
        // 5 simulated seconds at 10x is half a real (paused) second.
        clock.sleep_s(5.0).await;
        assert!((clock.now_s() - 5.0).abs() < 1e-6, "{}", clock.now_s());
        assert_eq!(clock.real_duration(-1.0), Duration::ZERO);
        assert_eq!(clock.real_duration(f64::NAN), Duration::ZERO);
    }

    #[tokio::test(start_paused = true)]
    async fn sleep_until_reaches_the_target_time() {
        let clock = SimClock::new(1.0);
        clock.sleep_until_s(2.5).await;
        // Never early; tokio's timer wheel has millisecond ticks, so at most one tick late.
        assert!(
            clock.now_s() >= 2.5 && clock.now_s() <= 2.5 + 0.001 + 1e-9,
            "{}",
            clock.now_s()
        );
    }
}
