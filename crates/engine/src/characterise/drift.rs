//! The source's warm-up and drift from repeated direct-beam readings.
//!
//! Model: `P(t) = A - B exp(-(t - t_0) / tau)` (a source approaching its settled power `A` with one time constant,
//! `t_0` the first reading: when the source was switched on is not something the readings tell), fitted by
//! linear least squares in `(A, B)` on a grid of `tau`, the best `tau` refined by a parabola through its
//! neighbours. Reported: the deficit `B / A` at the first reading, `tau`, the relative drift rate at the last
//! reading (per hour) and the residuals' rms (what no warm-up explains: flicker and random walk).

use serde::{Deserialize, Serialize};

/// What the readings show of the source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceDrift {
    pub band_nm: f64,
    /// Instrument time of the first and the last reading (s since the procedure started).
    pub first_s: f64,
    pub last_s: f64,
    pub readings: usize,
    /// Settled power relative deficit at the first reading, `B / A`, with its standard uncertainty.
    pub warmup_deficit: f64,
    pub warmup_deficit_u: f64,
    /// Time constant (s); the grid's edge when the readings do not bound it.
    pub warmup_time_s: f64,
    /// Relative drift rate at the last reading (1/h): what is left of the warm-up there.
    pub drift_per_hour_at_end: f64,
    /// Relative rms of the readings about the fit.
    pub residual_rms: f64,
}

impl SourceDrift {
    /// The fitted power at instrument time `t_s` relative to the settled power: `1 - (B / A) exp(-(t - t_0) / tau)`.
    pub fn relative_power(&self, t_s: f64) -> f64 {
        1.0 - self.warmup_deficit * (-(t_s - self.first_s) / self.warmup_time_s).exp()
    }
}

/// Time constants tried (s): log-spaced from 10 s to 3 h.
fn tau_grid() -> Vec<f64> {
    (0..=60)
        .map(|k| 10.0 * 1080f64.powf(f64::from(k) / 60.0))
        .collect()
}

/// Linear least squares of `p = A - B e^(-(t - t0)/tau)`: (A, B, sum of squared residuals, var B).
fn solve(samples: &[(f64, f64)], tau: f64) -> Option<(f64, f64, f64, f64)> {
    let t0 = samples.first()?.0;
    let (mut s11, mut s12, mut s22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(t, p) in samples {
        let e = -(-(t - t0) / tau).exp();
        s11 += 1.0;
        s12 += e;
        s22 += e * e;
        b1 += p;
        b2 += e * p;
    }
    let det = s11 * s22 - s12 * s12;
    if det.abs() <= 1e-12 * s11 * s22.max(1e-300) {
        return None;
    }
    let a = (s22 * b1 - s12 * b2) / det;
    let b = (s11 * b2 - s12 * b1) / det;
    let ssr: f64 = samples
        .iter()
        .map(|&(t, p)| (p - (a - b * (-(t - t0) / tau).exp())).powi(2))
        .sum();
    let dof = samples.len().saturating_sub(3).max(1) as f64;
    Some((a, b, ssr, ssr / dof * s11 / det))
}

/// Fit `samples` (instrument time s, net direct beam W) read at `band_nm`. `wander_per_hour` is the source's
/// drift the instrument file states (`[instrument.source] drift_per_hour`): over the watch it can pass for part
/// of a warm-up, so that much of the deficit is uncertain besides the readings' scatter. None with fewer than
/// five readings or no positive power.
pub fn fit_drift(band_nm: f64, samples: &[(f64, f64)], wander_per_hour: f64) -> Option<SourceDrift> {
    if samples.len() < 5 || samples.iter().any(|s| !(s.1 > 0.0 && s.0.is_finite())) {
        return None;
    }
    let grid = tau_grid();
    let fits: Vec<Option<(f64, f64, f64, f64)>> = grid.iter().map(|&tau| solve(samples, tau)).collect();
    let (best, &(a, b, ssr, var_b)) = fits
        .iter()
        .enumerate()
        .filter_map(|(k, f)| f.as_ref().map(|f| (k, f)))
        .min_by(|x, y| x.1.2.total_cmp(&y.1.2))?;
    // Golden-section search in ln(tau) between the best grid point's neighbours.
    let cost = |ln_tau: f64| solve(samples, ln_tau.exp()).map_or(f64::INFINITY, |f| f.2);
    let (mut lo, mut hi) = (
        grid[best.saturating_sub(1)].ln(),
        grid[(best + 1).min(grid.len() - 1)].ln(),
    );
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..60 {
        let (m1, m2) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
        if cost(m1) <= cost(m2) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let tau = (0.5 * (lo + hi)).exp();
    let (a, b, ssr, var_b) = solve(samples, tau).unwrap_or((a, b, ssr, var_b));
    // A source's wander is correlated from one reading to the next, which white residuals would not be: the
    // deficit's variance is widened by (1 + rho) / (1 - rho), rho the residuals' lag-one autocorrelation (the
    // usual AR(1) correction for the effective number of independent readings).
    let t_first = samples[0].0;
    let residuals: Vec<f64> = samples
        .iter()
        .map(|&(t, p)| p - (a - b * (-(t - t_first) / tau).exp()))
        .collect();
    let lag0: f64 = residuals.iter().map(|r| r * r).sum();
    let lag1: f64 = residuals.windows(2).map(|w| w[0] * w[1]).sum();
    let rho = if lag0 > 0.0 {
        (lag1 / lag0).clamp(0.0, 0.95)
    } else {
        0.0
    };
    let var_b = var_b * (1.0 + rho) / (1.0 - rho);
    let (t0, t1) = (samples[0].0, samples[samples.len() - 1].0);
    let rate_per_s = b / tau * (-(t1 - t0) / tau).exp() / a;
    Some(SourceDrift {
        band_nm,
        first_s: t0,
        last_s: t1,
        readings: samples.len(),
        warmup_deficit: b / a,
        warmup_deficit_u: (var_b.max(0.0).sqrt() / a).hypot(wander_per_hour.abs() * (t1 - t0) / 3600.0),
        warmup_time_s: tau,
        drift_per_hour_at_end: rate_per_s * 3600.0,
        residual_rms: (ssr / samples.len() as f64).sqrt() / a,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_warming_source_gives_back_its_deficit_and_time_constant() {
        let (w, tau) = (0.01, 900.0);
        let samples: Vec<(f64, f64)> = (0..60)
            .map(|k| {
                let t = 30.0 * f64::from(k);
                (t, 5e-4 * (1.0 - w * (-t / tau).exp()))
            })
            .collect();
        let d = fit_drift(550.0, &samples, 0.0).expect("fit");
        assert!((d.warmup_deficit - w).abs() < 2e-4, "{d:?}");
        assert!((d.warmup_time_s / tau - 1.0).abs() < 0.05, "{d:?}");
        assert!(d.drift_per_hour_at_end > 0.0 && d.residual_rms < 1e-6, "{d:?}");
    }

    #[test]
    fn a_steady_source_shows_no_deficit_and_too_few_readings_none() {
        let samples: Vec<(f64, f64)> = (0..20)
            .map(|k| (10.0 * f64::from(k), 1e-3 * (1.0 + 1e-5 * f64::from(k % 2))))
            .collect();
        let d = fit_drift(450.0, &samples, 0.0).expect("fit");
        assert!(
            d.warmup_deficit.abs() < 3.0 * d.warmup_deficit_u.max(1e-5),
            "{d:?}"
        );
        assert!(fit_drift(450.0, &samples[..4], 0.0).is_none());
    }
}
