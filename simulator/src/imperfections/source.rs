//! The source's imperfections: how its power really varies, beyond the instrument file's smooth drift and white
//! noise (crate::optics::source, which multiplies its own power by these factors).
//!
//! # Models (magnitudes from `[simulator.imperfections.source]`; the run starts with the source just switched on)
//! - **Warm-up**: `1 - w exp(-t / tau)`: a lamp or LED settling thermally after switch-on, approaching its settled
//!   power from below with one time constant.
//! - **Random walk**: a relative Brownian wander `W(t)`, `W(0) = 0`, `Var W(t) = s^2 t / 1 h`: the slow,
//!   unpredictable part of a real source's drift. Its knots every [`WALK_STEP_S`] are independent normal steps
//!   from the seed, interpolated linearly between them; within a step that misses a Brownian bridge of standard
//!   deviation `s sqrt(step / 1 h) / 2` at most, 0.1 % of `s` for the minute step. The walk is drawn where it is
//!   asked for, as a pure function of the seed and the instant (crate::imperfections::walk), so nothing of it is
//!   drawn at start-up.
//! - **Flicker**: a relative fluctuation with a 1/f spectrum between 0.01 and 10 Hz: [`FLICKER_LINES`]
//!   sinusoids at log-spaced frequencies (equal power per log-frequency interval, which is what 1/f means), each
//!   of amplitude `r sqrt(2 / N)` so that the total rms is `r`, with drawn phases. It changes from one 3 ms
//!   sample of the meter to the next and between a normalisation reading and the sample reading after it.
//!
//! Slow factor (warm-up and walk): `(1 - w e^(-t/tau)) (1 + W(t))`; fast factor: `1 + F(t)`. Both are pure
//! functions of the seed and the instant, so every optics on the same source agree at the same instant.

use gonio_instrument::SourceImperfections;
use serde::Serialize;

use super::draw::Draws;
pub use super::walk::WALK_STEP_S;
use super::walk::Walk;

/// Sinusoids in the flicker (log-spaced over three decades, 0.01-10 Hz).
pub const FLICKER_LINES: usize = 31;
const FLICKER_LOW_HZ: f64 = 0.01;
const FLICKER_DECADES: f64 = 3.0;

/// One line of the flicker.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FlickerLine {
    pub frequency_hz: f64,
    /// Relative amplitude.
    pub amplitude: f64,
    pub phase_rad: f64,
}

/// The hidden source values of one instrument.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SourceTruth {
    pub warmup_fraction: f64,
    pub warmup_time_s: f64,
    pub random_walk_per_rthour: f64,
    pub flicker_rms: f64,
    /// The walk; `None` when it is off.
    #[serde(skip)]
    walk: Option<Walk>,
    #[serde(skip)]
    flicker: Vec<FlickerLine>,
}

impl SourceTruth {
    pub fn draw(settings: &SourceImperfections, seed: u64) -> SourceTruth {
        let draws = Draws::new(seed);
        let walk =
            (settings.random_walk_per_rthour > 0.0).then(|| Walk::new(settings.random_walk_per_rthour, seed));
        let flicker = if settings.flicker_rms > 0.0 {
            let amplitude = settings.flicker_rms * (2.0 / FLICKER_LINES as f64).sqrt();
            (0..FLICKER_LINES)
                .map(|k| FlickerLine {
                    frequency_hz: FLICKER_LOW_HZ
                        * 10f64.powf(FLICKER_DECADES * k as f64 / (FLICKER_LINES - 1) as f64),
                    amplitude,
                    phase_rad: draws.phase_deg("source-flicker", k as u64).to_radians(),
                })
                .collect()
        } else {
            Vec::new()
        };
        SourceTruth {
            warmup_fraction: settings.warmup_fraction,
            warmup_time_s: settings.warmup_time_s,
            random_walk_per_rthour: settings.random_walk_per_rthour,
            flicker_rms: settings.flicker_rms,
            walk,
            flicker,
        }
    }

    /// The walk's relative value at `t_s`.
    pub fn walk_at(&self, t_s: f64) -> f64 {
        self.walk.as_ref().map_or(0.0, |w| w.at(t_s))
    }

    /// The slow factor at `t_s`: warm-up times random walk.
    pub fn slow_factor(&self, t_s: f64) -> f64 {
        if !t_s.is_finite() {
            return 1.0;
        }
        let warm = if self.warmup_fraction > 0.0 && self.warmup_time_s > 0.0 {
            1.0 - self.warmup_fraction * (-t_s.max(0.0) / self.warmup_time_s).exp()
        } else {
            1.0
        };
        (warm * (1.0 + self.walk_at(t_s))).max(0.0)
    }

    /// The fast factor at `t_s`: flicker.
    pub fn fast_factor(&self, t_s: f64) -> f64 {
        if self.flicker.is_empty() || !t_s.is_finite() {
            return 1.0;
        }
        let f: f64 = self
            .flicker
            .iter()
            .map(|l| l.amplitude * (std::f64::consts::TAU * l.frequency_hz * t_s + l.phase_rad).sin())
            .sum();
        (1.0 + f).max(0.0)
    }

    pub fn is_ideal(&self) -> bool {
        self.warmup_fraction == 0.0 && self.walk.is_none() && self.flicker.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(w: f64, tau: f64, s: f64, r: f64, seed: u64) -> SourceTruth {
        SourceTruth::draw(
            &SourceImperfections {
                warmup_fraction: w,
                warmup_time_s: tau,
                random_walk_per_rthour: s,
                flicker_rms: r,
            },
            seed,
        )
    }

    #[test]
    fn warm_up_is_the_exponential_written_out() {
        let t = truth(0.02, 600.0, 0.0, 0.0, 1);
        assert_eq!(t.slow_factor(0.0), 0.98);
        assert!((t.slow_factor(600.0) - (1.0 - 0.02 / std::f64::consts::E)).abs() < 1e-15);
        assert_eq!(t.fast_factor(3.0), 1.0);
    }

    #[test]
    fn the_walk_spreads_as_sqrt_time_over_many_instruments() {
        // Over 400 seeds, Var W(4 h) = s^2 * 4 within sampling error (chi-square, 400 dof: +-15 % at 2 sigma).
        let s = 1e-3;
        let n = 400;
        let var = (0..n)
            .map(|seed| truth(0.0, 0.0, s, 0.0, seed).walk_at(4.0 * 3600.0).powi(2))
            .sum::<f64>()
            / f64::from(n as u32);
        let ratio = var / (s * s * 4.0);
        assert!((ratio - 1.0).abs() < 0.2, "variance ratio {ratio}");
        let t = truth(0.0, 0.0, s, 0.0, 3);
        assert_eq!(t.walk_at(0.0), 0.0);
        // Linear between knots.
        let mid = t.walk_at(1.5 * WALK_STEP_S);
        assert!((mid - 0.5 * (t.walk_at(WALK_STEP_S) + t.walk_at(2.0 * WALK_STEP_S))).abs() < 1e-15);
    }

    #[test]
    fn flicker_has_the_requested_rms_and_moves_between_samples() {
        let t = truth(0.0, 0.0, 0.0, 1e-3, 9);
        // Sample 1000 s at 3 ms: the rms of the fluctuation is r within a few percent.
        let n = 333_333;
        let mut s2 = 0.0;
        for k in 0..n {
            let x = t.fast_factor(f64::from(k) * 0.003) - 1.0;
            s2 += x * x;
        }
        let rms = (s2 / f64::from(n)).sqrt();
        assert!((rms / 1e-3 - 1.0).abs() < 0.1, "rms {rms}");
        assert_ne!(t.fast_factor(0.0), t.fast_factor(0.003));
    }
}
