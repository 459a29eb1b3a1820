//! The meter's ranges from their overlaps and darks: each range's gain relative to a reference range, its
//! nonlinearity and its residual zero offset, and the correction that takes them out of a reading.
//!
//! # Model (the engine's own, first order in each error)
//! A range `r` of full scale `F_r` reports `R = S (1 + G_r) (1 + b_r S / F_r) + O_r` for a true signal `S`: a gain
//! `G_r`, a nonlinearity `b_r` (the relative deviation at full scale, zero at zero) and an offset `O_r` (W). Every
//! BRDF is the ratio of two readings, so only gains relative to one range matter: the largest range's gain is
//! taken as 0 and every other gain is relative to it.
//!
//! # Observations
//! - **Darks per range** (the beam blocked, the range fixed): `D_r = D + O_r`, `D` the dark current and the
//!   ambient light (the same on every range). A campaign subtracts its own dark, read on the smallest range, so
//!   the offsets that matter are `O_r - O_0 = D_r - D_0`; `O_0` itself is part of the dark.
//! - **Overlaps** (the same light read on ranges `r` and `r + 1` within a second): after the offsets,
//!   `ln(R_r / R_(r+1)) = G_r - G_(r+1) + b_r x_r - b_(r+1) x_(r+1)`, `x = R / F` the reading's fraction of full
//!   scale. Levels spread over `x_r` from 0.2 to 0.9 separate the gain step from the nonlinearities.
//!
//! The fit is linear least squares with a weak prior on each unknown (so that a range no overlap reaches stays at
//! its prior and is reported as not observable), and the Birge ratio applied when the residuals scatter more
//! than their stated uncertainties explain.

// Dense matrix code reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

use gonio_results::fit::lm::{normal_equations, spd_inverse};
use serde::{Deserialize, Serialize};

/// Prior standard deviation of a gain relative to the reference range: ten times the 0.2 % of full scale a
/// photodiode power meter's datasheet gives as its accuracy; only holds a gain no overlap reaches.
pub const GAIN_PRIOR: f64 = 0.02;
/// Prior standard deviation of a nonlinearity at full scale: four times the 0.05 % silicon photodiodes and their
/// amplifiers are linear to far from saturation (Schaefer, Zalewski & Geist 1983). The largest range is never
/// read near its full scale by an overlap, so its nonlinearity stays near this prior.
pub const NONLINEARITY_PRIOR: f64 = 2.0e-3;

/// One overlap: the same light read on range `range` (`low_w`) and on `range + 1` (`high_w`), raw readings (W),
/// with the standard uncertainty of `ln(low / high)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Overlap {
    pub range: usize,
    pub low_w: f64,
    pub high_w: f64,
    pub ln_ratio_u: f64,
}

/// The dark of one range: mean reading (W) and its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RangeDark {
    pub range: usize,
    pub mean_w: f64,
    pub u_w: f64,
}

/// One range's calibration (the calibration file's `[[detector.ranges]]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeCalibration {
    pub index: usize,
    pub full_scale_w: f64,
    /// Gain relative to the reference range (fraction).
    pub gain: f64,
    pub gain_u: f64,
    /// Relative deviation at full scale.
    pub nonlinearity: f64,
    pub nonlinearity_u: f64,
    /// Zero offset relative to the smallest range's (W).
    pub offset_w: f64,
    pub offset_w_u: f64,
    /// Whether the overlaps determine the gain and the nonlinearity (posterior well inside the prior).
    pub observable: bool,
}

/// All ranges: the reading correction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangesCalibration {
    /// The range every gain is relative to.
    pub reference_range: usize,
    pub ranges: Vec<RangeCalibration>,
    /// The overlap fit's chi-squared per degree of freedom (before scaling).
    pub reduced_chi2: f64,
}

impl RangesCalibration {
    /// The true signal (W) for a raw reading `power_w` on range `range`, and the standard uncertainty the
    /// correction itself adds (W). A range the calibration does not know is left as it is; of a range whose gain
    /// is not observable only the offset is taken out.
    pub fn correct(&self, power_w: f64, range: usize) -> (f64, f64) {
        let Some(c) = self.ranges.get(range) else {
            return (power_w, 0.0);
        };
        let net = power_w - c.offset_w;
        if !c.observable {
            // No overlap reached this range: its offset (from the darks) is known, its gain is not, and a gain
            // at the prior's 0 +- 2 % would claim nothing true.
            return (net, c.offset_w_u);
        }
        let x = if c.full_scale_w > 0.0 {
            net / c.full_scale_w
        } else {
            0.0
        };
        let value = net / ((1.0 + c.gain) * (1.0 + c.nonlinearity * x));
        let rel_u = (c.gain_u.powi(2) + (c.nonlinearity_u * x).powi(2)).sqrt();
        (value, (c.offset_w_u.powi(2) + (value * rel_u).powi(2)).sqrt())
    }
}

/// Whether a reading of `power_w` under auto-range is so near a range's full scale (within 1 %) that which of
/// the two ranges took it cannot be told from the value: the index of the upper range when it is.
pub fn near_range_boundary(power_w: f64, full_scale_w: &[f64]) -> Option<usize> {
    full_scale_w
        .iter()
        .position(|fs| (power_w / fs - 1.0).abs() < 0.01)
        .map(|k| k + 1)
        .filter(|&k| k < full_scale_w.len())
}

/// Why the ranges could not be calibrated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RangeFitError {
    #[error("the meter has {0} ranges: overlaps need at least two")]
    TooFewRanges(usize),
    #[error("no overlap of two ranges could be read")]
    NoOverlaps,
    #[error("the overlap fit is singular")]
    Singular,
    #[error("the dark of range {0} was not read")]
    MissingDark(usize),
}

/// Fit the ranges (module doc) of a meter with full scales `full_scale_w` (smallest first) from `darks` (one per
/// range) and `overlaps`.
pub fn fit_ranges(
    full_scale_w: &[f64],
    darks: &[RangeDark],
    overlaps: &[Overlap],
) -> Result<RangesCalibration, RangeFitError> {
    let n = full_scale_w.len();
    if n < 2 {
        return Err(RangeFitError::TooFewRanges(n));
    }
    let dark = |r: usize| {
        darks
            .iter()
            .find(|d| d.range == r)
            .copied()
            .ok_or(RangeFitError::MissingDark(r))
    };
    let d0 = dark(0)?;
    let mut offsets = vec![(0.0, d0.u_w); n];
    for r in 1..n {
        let d = dark(r)?;
        offsets[r] = (d.mean_w - d0.mean_w, d.u_w.hypot(d0.u_w));
    }
    let usable: Vec<&Overlap> = overlaps
        .iter()
        .filter(|o| {
            o.range + 1 < n
                && o.ln_ratio_u > 0.0
                && o.low_w - offsets[o.range].0 > 0.0
                && o.high_w - offsets[o.range + 1].0 > 0.0
        })
        .collect();
    if usable.is_empty() {
        return Err(RangeFitError::NoOverlaps);
    }
    // Unknowns: the gains of ranges 0..n-1 (the last, the reference, is 0), the n nonlinearities, and a
    // correction to each offset r >= 1 from its dark (which knows it only to its own uncertainty: a converter
    // step on the largest ranges, and every overlap read on that range shares it).
    let reference = n - 1;
    let p = (n - 1) + n + (n - 1);
    let gain = |r: usize| (r < reference).then_some(r);
    let nonlin = |r: usize| n - 1 + r;
    let offset = |r: usize| (r >= 1).then(|| 2 * n - 1 + (r - 1));
    // Each offset correction is solved for in units of its prior, which keeps the normal equations well scaled
    // (an offset's coefficient is 1 / reading, ~1e4 per W against a gain's 1).
    let offset_prior = |r: usize| offsets[r].1.max(1e-6 * full_scale_w[r]);
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut y: Vec<f64> = Vec::new();
    for o in &usable {
        let (r, s) = (o.range, o.range + 1);
        let low = o.low_w - offsets[r].0;
        let high = o.high_w - offsets[s].0;
        let mut row = vec![0.0; p];
        if let Some(k) = gain(r) {
            row[k] += 1.0;
        }
        if let Some(k) = gain(s) {
            row[k] -= 1.0;
        }
        row[nonlin(r)] += low / full_scale_w[r];
        row[nonlin(s)] -= high / full_scale_w[s];
        // d ln((R_r - O_r) / (R_s - O_s)) / dO = -1 / (R_r - O_r) and +1 / (R_s - O_s).
        if let Some(k) = offset(r) {
            row[k] -= offset_prior(r) / low;
        }
        if let Some(k) = offset(s) {
            row[k] += offset_prior(s) / high;
        }
        rows.push(row.iter().map(|v| v / o.ln_ratio_u).collect());
        y.push((low / high).ln() / o.ln_ratio_u);
    }
    let observations = rows.len();
    for k in 0..p {
        let prior = if k < n - 1 {
            GAIN_PRIOR
        } else if k < 2 * n - 1 {
            NONLINEARITY_PRIOR
        } else {
            1.0
        };
        let mut row = vec![0.0; p];
        row[k] = 1.0 / prior;
        rows.push(row);
        y.push(0.0);
    }
    let (a, g) = normal_equations(&rows, &y);
    let cov = spd_inverse(&a).ok_or(RangeFitError::Singular)?;
    let x: Vec<f64> = (0..p).map(|i| (0..p).map(|j| cov[i][j] * g[j]).sum()).collect();
    let chi2: f64 = rows[..observations]
        .iter()
        .zip(&y)
        .map(|(row, yk)| {
            let pred: f64 = row.iter().zip(&x).map(|(a, b)| a * b).sum();
            (yk - pred).powi(2)
        })
        .sum();
    // Degrees of freedom: the observations less the gains and nonlinearities they determine.
    let dof = observations.saturating_sub(2 * n - 1).max(1);
    let reduced_chi2 = chi2 / dof as f64;
    let scale = reduced_chi2.max(1.0).sqrt();
    let u = |k: usize| cov[k][k].max(0.0).sqrt() * scale;
    let ranges = (0..n)
        .map(|r| {
            let (g, g_u) = gain(r).map_or((0.0, 0.0), |k| (x[k], u(k)));
            let (b, b_u) = (x[nonlin(r)], u(nonlin(r)));
            let (o, o_u) = offset(r).map_or((0.0, 0.0), |k| {
                (offsets[r].0 + x[k] * offset_prior(r), u(k) * offset_prior(r))
            });
            RangeCalibration {
                index: r,
                full_scale_w: full_scale_w[r],
                gain: g,
                gain_u: g_u,
                nonlinearity: b,
                nonlinearity_u: b_u,
                offset_w: o,
                offset_w_u: o_u,
                observable: g_u < 0.1 * GAIN_PRIOR && b_u < 0.5 * NONLINEARITY_PRIOR,
            }
        })
        .collect();
    Ok(RangesCalibration {
        reference_range: reference,
        ranges,
        reduced_chi2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A meter with known errors, read by the model of the module doc.
    struct Meter {
        fs: Vec<f64>,
        gain: Vec<f64>,
        nonlin: Vec<f64>,
        offset: Vec<f64>,
    }

    impl Meter {
        fn read(&self, r: usize, s: f64) -> f64 {
            s * (1.0 + self.gain[r]) * (1.0 + self.nonlin[r] * s / self.fs[r]) + self.offset[r]
        }
    }

    fn meter() -> Meter {
        Meter {
            fs: vec![5e-8, 5e-7, 5e-6, 5e-5],
            gain: vec![1e-3, -5e-4, 2e-3, -1e-3],
            nonlin: vec![5e-4, -8e-4, 3e-4, 0.0],
            offset: vec![2e-12, -1e-11, 3e-10, 1e-9],
        }
    }

    fn observe(m: &Meter, dark_w: f64) -> (Vec<RangeDark>, Vec<Overlap>) {
        let darks = (0..m.fs.len())
            .map(|r| RangeDark {
                range: r,
                mean_w: m.read(r, dark_w),
                u_w: 1e-15,
            })
            .collect();
        let mut overlaps = Vec::new();
        for r in 0..m.fs.len() - 1 {
            for k in 0..8 {
                let s = m.fs[r] * (0.2 + 0.1 * f64::from(k));
                overlaps.push(Overlap {
                    range: r,
                    low_w: m.read(r, s + dark_w),
                    high_w: m.read(r + 1, s + dark_w),
                    ln_ratio_u: 1e-5,
                });
            }
        }
        (darks, overlaps)
    }

    #[test]
    fn exact_overlaps_give_back_the_meters_errors() {
        let m = meter();
        let (darks, overlaps) = observe(&m, 1e-10);
        let c = fit_ranges(&m.fs, &darks, &overlaps).expect("fit");
        let top = m.fs.len() - 1;
        for (r, rc) in c.ranges.iter().enumerate() {
            let relative_gain = (1.0 + m.gain[r]) / (1.0 + m.gain[top]) - 1.0;
            assert!((rc.gain - relative_gain).abs() < 3e-5, "range {r}: {rc:?}");
            assert!(
                (rc.offset_w - (m.offset[r] - m.offset[0])).abs() < 2e-6 * m.fs[r],
                "range {r}: {rc:?}"
            );
            if r < top {
                assert!((rc.nonlinearity - m.nonlin[r]).abs() < 1e-4, "range {r}: {rc:?}");
                assert!(rc.observable);
            }
        }
        // A signal read on any range and corrected is the same signal (the dark's offset on range 0 apart).
        for r in 0..top {
            let s = 0.6 * m.fs[r];
            let (v, _) = c.correct(m.read(r, s), r);
            let (top_v, _) = c.correct(m.read(top, s), top);
            assert!(((v - top_v) / s).abs() < 2e-4, "range {r}: {v} vs {top_v}");
        }
    }

    #[test]
    fn a_range_no_overlap_reaches_is_not_observable_and_stays_at_its_prior() {
        let m = meter();
        let (darks, overlaps) = observe(&m, 1e-10);
        let without_lowest: Vec<Overlap> = overlaps.into_iter().filter(|o| o.range > 0).collect();
        let c = fit_ranges(&m.fs, &darks, &without_lowest).expect("fit");
        assert!(!c.ranges[0].observable);
        assert!(c.ranges[0].gain_u > 0.5 * GAIN_PRIOR);
        assert!(c.ranges[1].observable);
    }

    #[test]
    fn refusals_say_what_is_missing() {
        let m = meter();
        let (darks, _) = observe(&m, 1e-10);
        assert_eq!(fit_ranges(&m.fs, &darks, &[]), Err(RangeFitError::NoOverlaps));
        assert_eq!(
            fit_ranges(&m.fs, &darks[1..], &[]),
            Err(RangeFitError::MissingDark(0))
        );
        assert_eq!(
            fit_ranges(&m.fs[..1], &darks, &[]),
            Err(RangeFitError::TooFewRanges(1))
        );
    }
}
