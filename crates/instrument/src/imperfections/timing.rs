//! `[simulator.imperfections.timing]`: how far the simulated hardware's timing is from what the instrument file
//! claims, as relative standard deviations. The simulator draws each axis's real top speed and acceleration and
//! the wheel's real time per position from them (simulator/src/imperfections/timing.rs); `gonio selftest` should
//! find each.

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
}

impl TimingImperfections {
    pub fn is_ideal(&self) -> bool {
        self.speed_sd == 0.0 && self.accel_sd == 0.0 && self.wheel_sd == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "timing";
        for (key, value) in [
            ("speed_sd", self.speed_sd),
            ("accel_sd", self.accel_sd),
            ("wheel_sd", self.wheel_sd),
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
