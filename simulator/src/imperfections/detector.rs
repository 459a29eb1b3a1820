//! The detector's imperfections: what the photodiode and the meter do to a reading.
//!
//! # Models (magnitudes from `[simulator.imperfections.detector]`; `I` a photocurrent in amperes)
//! - **Saturation** of the photodiode: the current it delivers is `I / (1 + I / I_sat)` (the series resistance's
//!   voltage drop forward-biases the junction at high light levels; the first-order form of the compression).
//!   It acts on the total photocurrent (light, stray light, ambient, dark), before the meter.
//! - **Ambient light**: a photocurrent `A (1 + v sin(2 pi t / T + phi))` whatever the filter (room light reaching
//!   the detector through the baffles), phi drawn. Dark readings see it too; it slowly moves between them.
//! - **Per range** `r` (one draw each, from the seed): a gain error `g_r` (the transimpedance resistor's
//!   tolerance; adjacent ranges disagree by `g_r - g_(r+1)`), a nonlinearity `b_r` (the current reads
//!   `I (1 + b_r I / I_fs)`: relative deviation `b_r` at full scale, zero at zero), a residual zero offset
//!   `o_r I_fs`. The meter reports `I (1 + g_r) (1 + b_r I / I_fs) + o_r I_fs` for a true current `I` on range `r`
//!   with full-scale current `I_fs`; the range is chosen (auto-range) on the true current.
//! - **Amplifier noise**: a white input current noise of density `e` (A/sqrt(Hz)) adds `e^2 B` to each sample's
//!   variance (B the sample's noise bandwidth), beside the meter's own shot and Johnson noise.
//! - **Stray light** (the instrument signature): with the filter open and the beam not blocked, light scattered
//!   by the source optics, the mounts and the room reaches the detector as if from a sample of BRDF
//!   `f_sig(alpha) = peak / (1 + (alpha / w)^2) + floor`, alpha the angle between the detector arm and the
//!   undeviated beam: the detector receives `P_i Omega_d f_sig(alpha)` more (P_i the beam power, Omega_d the
//!   aperture's solid angle). It is there with the sample removed (that is how a lab measures it: ASTM E2387's
//!   instrument signature) and is not removed by a dark reading, which has the beam off.

use gonio_instrument::DetectorImperfections;
use serde::Serialize;

use super::draw::Draws;

/// The hidden errors of one range of the meter (index 0 = the smallest range).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RangeTruth {
    /// Gain error (fraction).
    pub gain: f64,
    /// Nonlinearity coefficient: relative deviation at full scale.
    pub nonlinearity: f64,
    /// Residual zero offset as a fraction of the range's full-scale current.
    pub offset_fs: f64,
}

/// The instrument signature's shape (BRDF-equivalent, 1/sr).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Signature {
    pub peak_sr: f64,
    pub width_deg: f64,
    pub floor_sr: f64,
}

impl Signature {
    /// `f_sig` at `alpha_rad` from the undeviated beam (1/sr).
    pub fn at(&self, alpha_rad: f64) -> f64 {
        let peak = if self.peak_sr > 0.0 && self.width_deg > 0.0 {
            let x = alpha_rad.to_degrees() / self.width_deg;
            self.peak_sr / (1.0 + x * x)
        } else {
            0.0
        };
        peak + self.floor_sr
    }

    pub fn is_zero(&self) -> bool {
        self.peak_sr == 0.0 && self.floor_sr == 0.0
    }
}

/// The hidden detector values of one instrument.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectorTruth {
    /// One entry per range of `[instrument.detector] ranges_w`, in its order.
    pub ranges: Vec<RangeTruth>,
    /// 0: no saturation.
    pub saturation_current_a: f64,
    pub amplifier_noise_a_per_rthz: f64,
    pub signature: Signature,
    pub ambient_a: f64,
    pub ambient_variation: f64,
    pub ambient_period_s: f64,
    pub ambient_phase_deg: f64,
    /// How long after a request a reading starts integrating (s).
    pub reading_delay_s: f64,
}

impl DetectorTruth {
    /// Draw the values for a meter with `ranges` ranges from `seed`.
    pub fn draw(settings: &DetectorImperfections, ranges: usize, seed: u64) -> DetectorTruth {
        let draws = Draws::new(seed);
        let ranges = (0..ranges as u64)
            .map(|r| {
                let (g, b) = draws.normal_pair("range-gain-nonlinearity", r);
                let (o, _) = draws.normal_pair("range-offset", r);
                RangeTruth {
                    gain: settings.range_gain_sd * g,
                    nonlinearity: settings.nonlinearity_sd * b,
                    offset_fs: settings.offset_sd_fs * o,
                }
            })
            .collect();
        DetectorTruth {
            ranges,
            saturation_current_a: settings.saturation_current_a,
            amplifier_noise_a_per_rthz: settings.amplifier_noise_a_per_rthz,
            signature: Signature {
                peak_sr: settings.stray_peak_sr,
                width_deg: settings.stray_width_deg,
                floor_sr: settings.stray_floor_sr,
            },
            ambient_a: settings.ambient_a,
            ambient_variation: settings.ambient_variation,
            ambient_period_s: settings.ambient_period(),
            ambient_phase_deg: if settings.ambient_a > 0.0 {
                draws.phase_deg("ambient", 0)
            } else {
                0.0
            },
            reading_delay_s: settings.reading_delay_ms / 1000.0,
        }
    }

    /// The photodiode's output for a photocurrent `i_a` (A): saturation.
    pub fn photodiode_a(&self, i_a: f64) -> f64 {
        if self.saturation_current_a > 0.0 && i_a > 0.0 {
            i_a / (1.0 + i_a / self.saturation_current_a)
        } else {
            i_a
        }
    }

    /// The ambient light's photocurrent at `t_s` (A).
    pub fn ambient_at_a(&self, t_s: f64) -> f64 {
        if self.ambient_a == 0.0 {
            return 0.0;
        }
        let arg = std::f64::consts::TAU * t_s / self.ambient_period_s + self.ambient_phase_deg.to_radians();
        (self.ambient_a * (1.0 + self.ambient_variation * arg.sin())).max(0.0)
    }

    /// What the meter reports for a true current `i_a` on range `range` of full-scale current `full_scale_a`.
    pub fn meter_a(&self, range: usize, i_a: f64, full_scale_a: f64) -> f64 {
        let Some(r) = self.ranges.get(range) else {
            return i_a;
        };
        if full_scale_a.is_nan() || full_scale_a <= 0.0 {
            return i_a;
        }
        i_a * (1.0 + r.gain) * (1.0 + r.nonlinearity * i_a / full_scale_a) + r.offset_fs * full_scale_a
    }

    /// True when nothing is off.
    pub fn is_ideal(&self) -> bool {
        self.ranges
            .iter()
            .all(|r| r.gain == 0.0 && r.nonlinearity == 0.0 && r.offset_fs == 0.0)
            && self.saturation_current_a == 0.0
            && self.amplifier_noise_a_per_rthz == 0.0
            && self.signature.is_zero()
            && self.ambient_a == 0.0
            && self.reading_delay_s == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_meter_transfer_is_the_documented_formula() {
        let s = DetectorImperfections {
            range_gain_sd: 0.01,
            nonlinearity_sd: 0.01,
            offset_sd_fs: 0.001,
            ..Default::default()
        };
        let d = DetectorTruth::draw(&s, 3, 5);
        assert_eq!(d.ranges.len(), 3);
        let r = d.ranges[1];
        assert!(r.gain != 0.0 && r.nonlinearity != 0.0 && r.offset_fs != 0.0);
        // Written out: 2e-6 A on a 5e-6 A range.
        let expected = 2e-6 * (1.0 + r.gain) * (1.0 + r.nonlinearity * 0.4) + r.offset_fs * 5e-6;
        assert!((d.meter_a(1, 2e-6, 5e-6) - expected).abs() < 1e-18);
        // Ranges are drawn independently, and the same seed gives the same meter.
        assert_ne!(d.ranges[0], d.ranges[1]);
        assert_eq!(d, DetectorTruth::draw(&s, 3, 5));
        assert_ne!(d, DetectorTruth::draw(&s, 3, 6));
    }

    #[test]
    fn saturation_ambient_and_signature_follow_their_models() {
        let d = DetectorTruth::draw(
            &DetectorImperfections {
                saturation_current_a: 1.0,
                ambient_a: 1e-10,
                ambient_variation: 0.5,
                ambient_period_s: 100.0,
                stray_peak_sr: 1e-3,
                stray_width_deg: 2.0,
                stray_floor_sr: 1e-6,
                ..Default::default()
            },
            6,
            1,
        );
        assert!((d.photodiode_a(0.01) - 0.01 / 1.01).abs() < 1e-15);
        let amb: Vec<f64> = (0..100).map(|k| d.ambient_at_a(f64::from(k))).collect();
        let (lo, hi) = amb
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &a| (l.min(a), h.max(a)));
        assert!(
            lo > 0.5e-10 - 1e-13 && lo < 0.52e-10 && hi > 1.48e-10 && hi < 1.5e-10 + 1e-13,
            "{lo} {hi}"
        );
        assert!((d.signature.at(0.0) - (1e-3 + 1e-6)).abs() < 1e-15);
        assert!((d.signature.at(2f64.to_radians()) - (0.5e-3 + 1e-6)).abs() < 1e-12);
        assert!(
            d.meter_a(0, 1e-9, 5e-8) == 1e-9,
            "no range errors drawn: the meter is exact"
        );
    }
}
