//! `[simulator.imperfections.detector]`: magnitudes of what the photodiode and the meter do to a reading. The
//! models are documented in simulator/src/imperfections/detector.rs.

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// `[simulator.imperfections.detector]`. Relative quantities are plain fractions (0.001 = 0.1 %), currents in
/// amperes, angles in degrees, BRDF-equivalent stray light in 1/sr.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DetectorImperfections {
    /// Standard deviation of each range's gain error (fraction): the meter's transimpedance on range `r` is
    /// `1 + g_r` times its nominal value, one draw per range, so adjacent ranges disagree.
    #[serde(default)]
    pub range_gain_sd: f64,
    /// Standard deviation of each range's nonlinearity coefficient (fraction at full scale): a current `I` on
    /// range `r` reads `I (1 + b_r I / I_fs)`.
    #[serde(default)]
    pub nonlinearity_sd: f64,
    /// Standard deviation of each range's residual zero offset, as a fraction of the range's full-scale current.
    #[serde(default)]
    pub offset_sd_fs: f64,
    /// The photodiode's saturation current (A): a photocurrent `I` comes out as `I / (1 + I / I_sat)`. 0: off.
    #[serde(default)]
    pub saturation_current_a: f64,
    /// The amplifier's input current noise density (A/sqrt(Hz)), white, added to every sample's shot and
    /// Johnson noise (it switches the per-sample noise on even where `[instrument.detector] noise` is off).
    #[serde(default)]
    pub amplifier_noise_a_per_rthz: f64,
    /// The instrument signature: light that reaches the detector by paths other than the sample, as an
    /// equivalent BRDF of the beam, `f_sig(alpha) = stray_peak_sr / (1 + (alpha / stray_width_deg)^2) +
    /// stray_floor_sr`, with alpha the angle between the detector arm and the undeviated beam (1/sr).
    #[serde(default)]
    pub stray_peak_sr: f64,
    /// Half-width of the signature's peak about the undeviated beam (degrees; needed when `stray_peak_sr` > 0).
    #[serde(default)]
    pub stray_width_deg: f64,
    /// The signature's floor far from the beam (1/sr): room, mounts and arms scattering the beam.
    #[serde(default)]
    pub stray_floor_sr: f64,
    /// Ambient (room) light's photocurrent on the detector (A), whatever filter is in the beam.
    #[serde(default)]
    pub ambient_a: f64,
    /// Relative amplitude of the ambient light's slow variation (0 = constant, 1 = between 0 and twice).
    #[serde(default)]
    pub ambient_variation: f64,
    /// Period of that variation (s; 0 means 1800).
    #[serde(default)]
    pub ambient_period_s: f64,
    /// How long after a measurement request the meter starts integrating (ms): the request's USB transfer
    /// and the meter's own sample clock. A sweep places its readings by when they were requested: the
    /// self-test's sampling instant (`position_sampled_ms`) takes this in.
    #[serde(default)]
    pub reading_delay_ms: f64,
}

impl DetectorImperfections {
    /// The ambient light's period when the file says 0 (s).
    pub const DEFAULT_AMBIENT_PERIOD_S: f64 = 1800.0;

    pub fn is_ideal(&self) -> bool {
        self.range_gain_sd == 0.0
            && self.nonlinearity_sd == 0.0
            && self.offset_sd_fs == 0.0
            && self.saturation_current_a == 0.0
            && self.amplifier_noise_a_per_rthz == 0.0
            && self.stray_peak_sr == 0.0
            && self.stray_floor_sr == 0.0
            && self.ambient_a == 0.0
            && self.reading_delay_ms == 0.0
    }

    /// The ambient light's period in use (s).
    pub fn ambient_period(&self) -> f64 {
        if self.ambient_period_s > 0.0 {
            self.ambient_period_s
        } else {
            Self::DEFAULT_AMBIENT_PERIOD_S
        }
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "detector";
        // Limits: a meter beyond them is broken, not imperfect, and the small-error models would not hold.
        for (key, value, limit, why) in [
            (
                "range_gain_sd",
                self.range_gain_sd,
                0.05,
                "a meter that far off fails calibration",
            ),
            (
                "nonlinearity_sd",
                self.nonlinearity_sd,
                0.05,
                "a detector that nonlinear is not a power meter",
            ),
            (
                "offset_sd_fs",
                self.offset_sd_fs,
                0.01,
                "an offset that large is seen at once",
            ),
            (
                "saturation_current_a",
                self.saturation_current_a,
                1e3,
                "no photodiode carries a kiloampere",
            ),
            (
                "amplifier_noise_a_per_rthz",
                self.amplifier_noise_a_per_rthz,
                1e-9,
                "noise that large hides the lowest range",
            ),
            (
                "stray_peak_sr",
                self.stray_peak_sr,
                1e3,
                "more than the direct beam itself",
            ),
            (
                "stray_width_deg",
                self.stray_width_deg,
                90.0,
                "a peak wider than a quadrant is not a peak",
            ),
            (
                "stray_floor_sr",
                self.stray_floor_sr,
                1e-2,
                "that much stray light swamps a white diffuser",
            ),
            (
                "ambient_a",
                self.ambient_a,
                1e-6,
                "a room that bright is not a dark lab",
            ),
            (
                "ambient_variation",
                self.ambient_variation,
                1.0,
                "a light cannot go below dark",
            ),
            (
                "ambient_period_s",
                self.ambient_period_s,
                86_400.0 * 7.0,
                "a week-long cycle is a drift",
            ),
            (
                "reading_delay_ms",
                self.reading_delay_ms,
                50.0,
                "a meter that slow to start a reading is broken",
            ),
        ] {
            check(G, key, value, limit, why)?;
        }
        if self.stray_peak_sr > 0.0 && self.stray_width_deg <= 0.0 {
            return Err(ImperfectionsError::Needed {
                group: G,
                key: "stray_width_deg",
                needed_by: "stray_peak_sr",
                value: self.stray_width_deg,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn off_by_default_and_bad_values_name_their_key() {
        assert!(DetectorImperfections::default().is_ideal());
        assert_eq!(DetectorImperfections::default().validate(), Ok(()));
        let d = DetectorImperfections {
            range_gain_sd: -0.1,
            ..Default::default()
        };
        let msg = d.validate().expect_err("negative").to_string();
        assert!(
            msg.contains("[simulator.imperfections.detector] range_gain_sd"),
            "{msg}"
        );
        let d = DetectorImperfections {
            ambient_variation: 2.0,
            ..Default::default()
        };
        assert!(
            d.validate()
                .expect_err("too large")
                .to_string()
                .contains("ambient_variation")
        );
        let d = DetectorImperfections {
            stray_peak_sr: 1e-3,
            ..Default::default()
        };
        let msg = d.validate().expect_err("width needed").to_string();
        assert!(
            msg.contains("stray_width_deg") && msg.contains("stray_peak_sr"),
            "{msg}"
        );
        assert_eq!(DetectorImperfections::default().ambient_period(), 1800.0);
        // A reading delay alone makes the meter imperfect; beyond 50 ms it is refused.
        let slow = |ms: f64| DetectorImperfections {
            reading_delay_ms: ms,
            ..Default::default()
        };
        assert!(!slow(1.5).is_ideal() && slow(1.5).validate().is_ok());
        for bad in [100.0, -1.0] {
            let msg = slow(bad).validate().expect_err("refused").to_string();
            assert!(msg.contains("reading_delay_ms"), "{msg}");
        }
    }
}
