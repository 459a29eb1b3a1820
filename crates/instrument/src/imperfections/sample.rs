//! `[simulator.imperfections.sample]`: magnitudes of the sample's non-uniformity. The model is documented in
//! simulator/src/imperfections/sample.rs.

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// `[simulator.imperfections.sample]`: relative reflectance changes as plain fractions.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SampleImperfections {
    /// Standard deviation of each component of a linear reflectance gradient, as the change from the centre to
    /// the sample's edge (fraction).
    #[serde(default)]
    pub gradient_sd: f64,
    /// Standard deviation of the centre-to-edge (radial, quadratic) reflectance change (fraction): a pressed or
    /// sprayed sample is often brighter or darker towards its rim.
    #[serde(default)]
    pub radial_sd: f64,
}

impl SampleImperfections {
    pub fn is_ideal(&self) -> bool {
        self.gradient_sd == 0.0 && self.radial_sd == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "sample";
        for (key, value) in [("gradient_sd", self.gradient_sd), ("radial_sd", self.radial_sd)] {
            check(G, key, value, 0.2, "a sample that uneven is several samples")?;
        }
        Ok(())
    }
}
