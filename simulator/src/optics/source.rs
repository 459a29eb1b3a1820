//! The light source's power over time: a slow deterministic drift and a seeded relative noise.
//!
//! - Drift: `P(t) = P0 (1 + drift_per_hour * g(t))`, with `g` a sum of three sinusoids of periods 1.3, 2.9 and
//!   6.1 hours and seeded phases, each term scaled so that its slope is at most 1/3 per hour and shifted so that
//!   `g(0) = 0`. The drift rate therefore never exceeds `drift_per_hour` per hour, the source starts at its nominal
//!   power, and the wander is smooth (a daemon interpolating between reference readings sees realistic behaviour).
//! - Noise: a relative fluctuation `1 + sigma n(t)` with `n` standard normal, drawn from a counter-free hash of
//!   (seed, t_s): the same instant gives the same fluctuation whoever asks (the direct-beam monitor and the sample
//!   reading agree), any call order reproduces the same values, and nothing is drawn when the noise is off.

use std::f64::consts::PI;

/// Drift periods (hours).
const DRIFT_PERIODS_H: [f64; 3] = [1.3, 2.9, 6.1];

#[derive(Debug, Clone)]
pub struct SourceModel {
    power_w: f64,
    drift_per_hour: f64,
    relative_noise: f64,
    seed: u64,
    drift_on: bool,
    noise_on: bool,
    phases: [f64; 3],
    /// The source's hidden imperfections (warm-up, random walk, flicker); `None` on the ideal instrument.
    imperfections: Option<crate::imperfections::SourceTruth>,
}

impl SourceModel {
    pub fn new(power_w: f64, drift_per_hour: f64, relative_noise: f64, seed: u64) -> SourceModel {
        let mut phases = [0.0; 3];
        for (k, p) in phases.iter_mut().enumerate() {
            *p = 2.0 * PI * unit_uniform(mix(seed ^ 0xD1F7_0000_0000_0000, k as u64));
        }
        SourceModel {
            power_w,
            drift_per_hour,
            relative_noise,
            seed,
            drift_on: drift_per_hour != 0.0,
            noise_on: relative_noise > 0.0,
            phases,
            imperfections: None,
        }
    }

    /// Give the source its hidden imperfections (crate::imperfections::source); `None`: the ideal source.
    pub fn set_imperfections(&mut self, truth: Option<crate::imperfections::SourceTruth>) {
        self.imperfections = truth;
    }

    pub fn set_drift(&mut self, on: bool) {
        self.drift_on = on && self.drift_per_hour != 0.0;
    }

    pub fn set_noise(&mut self, on: bool) {
        self.noise_on = on && self.relative_noise > 0.0;
    }

    pub fn noise_enabled(&self) -> bool {
        self.noise_on
    }

    /// The imperfection factors at `t_s` (crate::imperfections::source): slow (warm-up, walk) and flicker;
    /// both 1 on the ideal source.
    pub fn imperfection_factors(&self, t_s: f64) -> (f64, f64) {
        self.imperfections
            .as_ref()
            .map_or((1.0, 1.0), |t| (t.slow_factor(t_s), t.fast_factor(t_s)))
    }

    /// The nominal power before drift and noise (W).
    pub fn nominal_power_w(&self) -> f64 {
        self.power_w
    }

    /// The drifted power at time `t_s`, without noise (W): the file's smooth drift times, on an imperfect
    /// instrument, the warm-up and the random walk.
    pub fn drifted_power_w(&self, t_s: f64) -> f64 {
        let smooth = self.smooth_drift_w(t_s);
        match &self.imperfections {
            Some(t) => smooth * t.slow_factor(t_s),
            None => smooth,
        }
    }

    fn smooth_drift_w(&self, t_s: f64) -> f64 {
        if !self.drift_on || !t_s.is_finite() {
            return self.power_w;
        }
        let t_h = t_s / 3600.0;
        let mut g = 0.0;
        for (period, phase) in DRIFT_PERIODS_H.iter().zip(&self.phases) {
            // Amplitude T/(2 pi 3): slope of this term <= 1/3 per hour.
            let a = period / (6.0 * PI);
            g += a * ((2.0 * PI * t_h / period + phase).sin() - phase.sin());
        }
        (self.power_w * (1.0 + self.drift_per_hour * g)).max(0.0)
    }

    /// The relative noise factor `1 + sigma n(t)` at time `t_s` (exactly 1 when the noise is off: no draw),
    /// times the flicker on an imperfect instrument.
    pub fn noise_factor(&self, t_s: f64) -> f64 {
        let flicker = self.imperfections.as_ref().map_or(1.0, |t| t.fast_factor(t_s));
        flicker * self.white_noise_factor(t_s)
    }

    fn white_noise_factor(&self, t_s: f64) -> f64 {
        if !self.noise_on {
            return 1.0;
        }
        let h = mix(self.seed, t_s.to_bits());
        let u1 = unit_uniform(h);
        let u2 = unit_uniform(mix(h, 0x5EED));
        // Box-Muller; u1 in (0, 1] so the log is finite.
        let n = (-2.0 * (1.0 - u1).ln()).sqrt() * (2.0 * PI * u2).cos();
        (1.0 + self.relative_noise * n).max(0.0)
    }
}

/// SplitMix64 finaliser of a combined key: a well-mixed 64-bit hash.
fn mix(a: u64, b: u64) -> u64 {
    let mut z = a
        .wrapping_add(b.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) from the top 53 bits.
fn unit_uniform(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_starts_at_nominal_and_is_rate_bounded() {
        let s = SourceModel::new(1e-3, 0.002, 0.0, 7);
        assert_eq!(s.drifted_power_w(0.0), 1e-3);
        let mut prev = s.drifted_power_w(0.0);
        let mut max_dev: f64 = 0.0;
        for i in 1..=3600 {
            let t = i as f64 * 10.0; // 10 hours in 10 s steps
            let p = s.drifted_power_w(t);
            // |dP/dt| <= P0 * drift_per_hour per hour.
            assert!((p - prev).abs() <= 1e-3 * 0.002 * (10.0 / 3600.0) * (1.0 + 1e-9));
            max_dev = max_dev.max((p / 1e-3 - 1.0).abs());
            prev = p;
        }
        // It does move (a few tenths of a percent over hours), and stays within the bound of 10 h of drift.
        assert!(max_dev > 1e-4 && max_dev < 0.02, "{max_dev}");
    }

    #[test]
    fn noise_is_reproducible_and_has_the_requested_spread() {
        let a = SourceModel::new(1.0, 0.0, 0.01, 42);
        let b = SourceModel::new(1.0, 0.0, 0.01, 42);
        let c = SourceModel::new(1.0, 0.0, 0.01, 43);
        let n = 20_000;
        let (mut sum, mut sum2, mut differ) = (0.0, 0.0, 0);
        for i in 0..n {
            let t = i as f64 * 0.003;
            let x = a.noise_factor(t);
            assert_eq!(x, b.noise_factor(t));
            if x != c.noise_factor(t) {
                differ += 1;
            }
            sum += x - 1.0;
            sum2 += (x - 1.0) * (x - 1.0);
        }
        let mean = sum / n as f64;
        let sd = (sum2 / n as f64 - mean * mean).sqrt();
        assert!(mean.abs() < 4.0 * 0.01 / (n as f64).sqrt(), "mean {mean}");
        assert!((sd / 0.01 - 1.0).abs() < 0.03, "sd {sd}");
        assert_eq!(differ, n);
    }

    #[test]
    fn noise_off_is_exactly_one() {
        let mut s = SourceModel::new(1.0, 0.0, 0.01, 1);
        s.set_noise(false);
        assert_eq!(s.noise_factor(12.5), 1.0);
        assert!(!s.noise_enabled());
    }
}
