//! `[simulator.imperfections.beam]`: what the beam really is, against the uniform, centred, collimated disc
//! `[instrument.source]` describes (`beam_radius_mm`, `divergence_deg`). The models are documented in
//! simulator/src/imperfections/beam.rs.

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// The beam's intensity across its section.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum BeamProfile {
    /// Uniform over a disc of `[instrument.source] beam_radius_mm` (the ideal instrument's beam).
    #[default]
    TopHat,
    /// Gaussian, `exp(-2 r^2 / w^2)` with `w = gaussian_radius_mm` (the 1/e^2 radius): a laser, or a
    /// fibre-coupled lamp imaged through a pinhole.
    Gaussian,
}

/// `[simulator.imperfections.beam]`: the profile is a fixed property of the source; the pointing and the
/// divergence's error are drawn from the seed.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BeamImperfections {
    /// The beam's profile (default "top-hat").
    #[serde(default)]
    pub profile: BeamProfile,
    /// The Gaussian profile's 1/e^2 radius (mm; needed when `profile = "gaussian"`).
    #[serde(default)]
    pub gaussian_radius_mm: f64,
    /// Standard deviation of each component of the beam's pointing error: the angle between the beam and the
    /// light arm's axis (degrees).
    #[serde(default)]
    pub pointing_sd_deg: f64,
    /// Distance from the source's output (where the pointing error starts) to the arms' axis (mm; needed when
    /// `pointing_sd_deg` > 0): the spot moves by this distance times the pointing angle.
    #[serde(default)]
    pub source_distance_mm: f64,
    /// Standard deviation of the true full divergence angle about `[instrument.source] divergence_deg`
    /// (degrees; the true value is never below 0).
    #[serde(default)]
    pub divergence_sd_deg: f64,
}

impl BeamImperfections {
    pub fn is_ideal(&self) -> bool {
        self.profile == BeamProfile::TopHat && self.pointing_sd_deg == 0.0 && self.divergence_sd_deg == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "beam";
        for (key, value, limit, why) in [
            (
                "gaussian_radius_mm",
                self.gaussian_radius_mm,
                25.0,
                "a beam that wide overfills every sample the holder takes",
            ),
            (
                "pointing_sd_deg",
                self.pointing_sd_deg,
                1.0,
                "a beam that far off the arm misses the sample",
            ),
            (
                "source_distance_mm",
                self.source_distance_mm,
                5000.0,
                "an arm that long is not a lab goniometer",
            ),
            (
                "divergence_sd_deg",
                self.divergence_sd_deg,
                2.0,
                "a beam that uncertain is not collimated",
            ),
        ] {
            check(G, key, value, limit, why)?;
        }
        if self.profile == BeamProfile::Gaussian && self.gaussian_radius_mm <= 0.0 {
            return Err(ImperfectionsError::Needed {
                group: G,
                key: "gaussian_radius_mm",
                needed_by: "profile = \"gaussian\"",
                value: self.gaussian_radius_mm,
            });
        }
        if self.pointing_sd_deg > 0.0 && self.source_distance_mm <= 0.0 {
            return Err(ImperfectionsError::Needed {
                group: G,
                key: "source_distance_mm",
                needed_by: "pointing_sd_deg",
                value: self.source_distance_mm,
            });
        }
        Ok(())
    }
}
