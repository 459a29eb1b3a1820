//! `[simulator.imperfections.geometry]`: magnitudes of the geometric errors (the models are documented in
//! simulator/src/imperfections/geometry.rs).

use serde::{Deserialize, Serialize};

use super::ImperfectionsError;

/// `[simulator.imperfections.geometry]`: magnitudes of the geometric errors (the models are documented in
/// simulator/src/imperfections/geometry.rs).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GeometryImperfections {
    /// Standard deviation of each axis's true zero about the zero the instrument file states (degrees): the
    /// controller's zero is not the geometric zero. One independent draw per axis.
    #[serde(default)]
    pub zero_offset_sd_deg: f64,
    /// Standard deviation of each of the two components of the sample normal's tilt from the stage's rotation axis
    /// (degrees): a wedged sample or a holder not square to the axis. Fixed for the instrument; the normal wobbles
    /// as the stage rotates.
    #[serde(default)]
    pub sample_tilt_sd_deg: f64,
    /// Standard deviation of each component of the extra tilt of one mounting (degrees): each time the sample is
    /// put back in the holder (after a direct-beam reading) it seats a little differently.
    #[serde(default)]
    pub reseat_tilt_sd_deg: f64,
    /// Standard deviation of each horizontal component of the offset between the arms' rotation axis and the
    /// illuminated spot (mm).
    #[serde(default)]
    pub eccentricity_sd_mm: f64,
    /// Amplitude of the periodic (cyclic) error of every rotation axis's encoder (degrees); the phase of each axis
    /// is drawn.
    #[serde(default)]
    pub encoder_error_amplitude_deg: f64,
    /// Cycles of that error per revolution (1 = an encoder disc mounted off-centre; 0 means 1).
    #[serde(default)]
    pub encoder_error_harmonic: u32,
    /// Standard deviation of the detector aperture's true radius about the file's `aperture_radius_mm` (mm):
    /// how well it was measured. With the distance below, what the solid angle in the absolute equation is
    /// off by; the file's `solid_angle_u` is the lab's claim of it.
    #[serde(default)]
    pub aperture_radius_sd_mm: f64,
    /// Standard deviation of the aperture's true distance from the arms' axis about the file's `distance_mm`
    /// (mm).
    #[serde(default)]
    pub detector_distance_sd_mm: f64,
}

impl GeometryImperfections {
    /// The largest harmonic accepted: beyond that a "periodic error" is encoder noise, not geometry.
    pub const MAX_HARMONIC: u32 = 64;

    pub fn is_ideal(&self) -> bool {
        self.zero_offset_sd_deg == 0.0
            && self.sample_tilt_sd_deg == 0.0
            && self.reseat_tilt_sd_deg == 0.0
            && self.eccentricity_sd_mm == 0.0
            && self.encoder_error_amplitude_deg == 0.0
            && self.aperture_radius_sd_mm == 0.0
            && self.detector_distance_sd_mm == 0.0
    }

    /// The harmonic in use (0 in the file means 1).
    pub fn harmonic(&self) -> u32 {
        self.encoder_error_harmonic.max(1)
    }

    /// Finite, >= 0, and small enough for the models (small-angle errors, an offset much smaller than the arms).
    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "geometry";
        // Limits: these are errors of an instrument that works at all. A 5 degree tilt or a 10 mm eccentricity is
        // a broken set-up, not an imperfect one, and the models' small-error reading of "tilt" would not hold.
        for (key, value, limit, why) in [
            (
                "zero_offset_sd_deg",
                self.zero_offset_sd_deg,
                5.0,
                "an axis that far off is not homed",
            ),
            (
                "sample_tilt_sd_deg",
                self.sample_tilt_sd_deg,
                5.0,
                "a sample that tilted is not mounted",
            ),
            (
                "reseat_tilt_sd_deg",
                self.reseat_tilt_sd_deg,
                5.0,
                "a sample that tilted is not mounted",
            ),
            (
                "eccentricity_sd_mm",
                self.eccentricity_sd_mm,
                10.0,
                "the spot would miss the sample",
            ),
            (
                "encoder_error_amplitude_deg",
                self.encoder_error_amplitude_deg,
                1.0,
                "an encoder that far off fails its own check",
            ),
            (
                "aperture_radius_sd_mm",
                self.aperture_radius_sd_mm,
                0.5,
                "an aperture known that poorly has not been measured",
            ),
            (
                "detector_distance_sd_mm",
                self.detector_distance_sd_mm,
                10.0,
                "a distance known that poorly has not been measured",
            ),
        ] {
            super::check(G, key, value, limit, why)?;
        }
        if self.encoder_error_harmonic > Self::MAX_HARMONIC {
            return Err(ImperfectionsError::Harmonic {
                value: self.encoder_error_harmonic,
                limit: Self::MAX_HARMONIC,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_ideal_and_valid() {
        let d = super::super::Imperfections::default();
        assert!(d.is_ideal());
        assert_eq!(d.validate(), Ok(()));
    }

    #[test]
    fn each_bad_value_names_its_key() {
        for (key, set) in [
            ("zero_offset_sd_deg", 0usize),
            ("sample_tilt_sd_deg", 1),
            ("reseat_tilt_sd_deg", 2),
            ("eccentricity_sd_mm", 3),
            ("encoder_error_amplitude_deg", 4),
            ("aperture_radius_sd_mm", 5),
            ("detector_distance_sd_mm", 6),
        ] {
            for bad in [-1.0, f64::NAN, f64::INFINITY, 1e6] {
                let mut g = GeometryImperfections::default();
                let slot = match set {
                    0 => &mut g.zero_offset_sd_deg,
                    1 => &mut g.sample_tilt_sd_deg,
                    2 => &mut g.reseat_tilt_sd_deg,
                    3 => &mut g.eccentricity_sd_mm,
                    4 => &mut g.encoder_error_amplitude_deg,
                    5 => &mut g.aperture_radius_sd_mm,
                    _ => &mut g.detector_distance_sd_mm,
                };
                *slot = bad;
                let msg = g.validate().expect_err("refused").to_string();
                assert!(
                    msg.contains(key) && msg.contains("[simulator.imperfections.geometry]"),
                    "{msg}"
                );
            }
        }
        let g = GeometryImperfections {
            encoder_error_harmonic: 1000,
            ..Default::default()
        };
        assert!(
            g.validate()
                .expect_err("harmonic")
                .to_string()
                .contains("encoder_error_harmonic")
        );
    }
}
