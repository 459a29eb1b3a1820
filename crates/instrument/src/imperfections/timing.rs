//! `[simulator.imperfections.timing]`: how far the simulated hardware's timing is from what the instrument file
//! claims, as relative standard deviations. The simulator draws each axis's real top speed, acceleration, settle
//! time and backlash, the wheel's real time per position, the detector's real dark current and the source's real
//! white relative noise from them (simulator/src/imperfections/timing.rs);
//! `gonio selftest` should find each. A non-zero `settle_sd` also makes every axis's load ring after each move
//! (simulator/src/motion/settling.rs), dying down within the axis's real settle time.

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// `[simulator.imperfections.timing]`: relative standard deviations (fractions of the claimed value).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimingImperfections {
    /// Each axis's real top speed about its `max_speed_deg_s`.
    #[serde(default)]
    pub speed_sd: f64,
    /// Each axis's real acceleration about its `accel_deg_s2`.
    #[serde(default)]
    pub accel_sd: f64,
    /// The wheel's real time per position about its `seconds_per_position`.
    #[serde(default)]
    pub wheel_sd: f64,
    /// Each axis's real settle time about its `settle_s`; non-zero: the loads ring after each move.
    #[serde(default)]
    pub settle_sd: f64,
    /// Each axis's real backlash about its `backlash_deg`.
    #[serde(default)]
    pub backlash_sd: f64,
    /// The detector head's real dark current about `[instrument.detector] dark_current_a`.
    #[serde(default)]
    pub dark_current_sd: f64,
    /// The source's real white relative noise about `[instrument.source] relative_noise`.
    #[serde(default)]
    pub relative_noise_sd: f64,
}

impl TimingImperfections {
    pub fn is_ideal(&self) -> bool {
        self.speed_sd == 0.0
            && self.accel_sd == 0.0
            && self.wheel_sd == 0.0
            && self.settle_sd == 0.0
            && self.backlash_sd == 0.0
            && self.dark_current_sd == 0.0
            && self.relative_noise_sd == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "timing";
        for (key, value) in [
            ("speed_sd", self.speed_sd),
            ("accel_sd", self.accel_sd),
            ("wheel_sd", self.wheel_sd),
            ("settle_sd", self.settle_sd),
            ("backlash_sd", self.backlash_sd),
            ("dark_current_sd", self.dark_current_sd),
            ("relative_noise_sd", self.relative_noise_sd),
        ] {
            check(
                G,
                key,
                value,
                0.2,
                "hardware that far from its file is another device: correct the file",
            )?;
        }
        Ok(())
    }
}
