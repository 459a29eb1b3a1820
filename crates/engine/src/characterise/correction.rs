//! A characterisation applied to a campaign's readings and values: the ranges' correction on every reading,
//! the signature subtracted from every value, and the points below the NEBRDF flagged.

use super::DetectorCalibration;

/// What the signature does to one value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SignatureAt {
    /// Subtract this BRDF-equivalent (1/sr, already over `cos(theta_o)`), with its standard uncertainty.
    Subtract { brdf_sr: f64, u_sr: f64 },
    /// The detector is nearer the beam's forward direction than the signature was measured: nothing subtracted,
    /// the point flagged.
    NearBeam,
    /// No signature for this band.
    Unknown,
}

/// The flag of a point nearer the beam than the signature was measured.
pub const FLAG_NEAR_BEAM: &str = "signature-not-measured-here";
/// The flag of a point whose value is below the noise-equivalent BRDF (three times it).
pub const FLAG_BELOW_NEBRDF: &str = "below-nebrdf";

/// The detector's calibration as a campaign applies it.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorCorrection {
    pub calibration: DetectorCalibration,
}

impl DetectorCorrection {
    pub fn new(calibration: DetectorCalibration) -> DetectorCorrection {
        DetectorCorrection { calibration }
    }

    /// A raw reading (W) on the range at index `range` as the true signal, with the standard uncertainty the
    /// correction adds (W).
    pub fn reading(&self, power_w: f64, range: Option<usize>) -> (f64, f64) {
        match (&self.calibration.ranges, range) {
            (Some(c), Some(k)) => c.correct(power_w, k),
            _ => (power_w, 0.0),
        }
    }

    fn band(&self, band_nm: f64) -> Option<&super::BandSignature> {
        self.calibration
            .signature
            .iter()
            .find(|s| (s.band_nm - band_nm).abs() < 1e-6)
    }

    /// The signature `alpha_deg` from the beam's forward direction (super::signature::alpha_deg) for a value
    /// viewed at `theta_o_deg` in `band_nm`.
    pub fn signature(&self, band_nm: f64, alpha_deg: f64, theta_o_deg: f64) -> SignatureAt {
        let Some(s) = self.band(band_nm) else {
            return SignatureAt::Unknown;
        };
        let cos = theta_o_deg.to_radians().cos();
        match s.at(alpha_deg) {
            Some((f, u)) if cos > 0.0 => SignatureAt::Subtract {
                brdf_sr: f / cos,
                u_sr: u / cos,
            },
            Some(_) => SignatureAt::Unknown,
            None => SignatureAt::NearBeam,
        }
    }

    /// The NEBRDF (1/sr) of one reading averaging `samples` at `theta_o_deg` in `band_nm`, when measured.
    pub fn nebrdf_sr(&self, band_nm: f64, samples: u32, theta_o_deg: f64) -> Option<f64> {
        self.band(band_nm).map(|s| s.nebrdf_sr(samples, theta_o_deg))
    }

    /// The least standard deviation of a reading averaging `samples` in `band_nm` (W): the darks' measured noise
    /// over `sqrt(samples)`, when measured.
    pub fn noise_floor_w(&self, band_nm: f64, samples: u32) -> Option<f64> {
        let w = self.band(band_nm)?.dark_noise_one_sample_w?;
        Some(w / f64::from(samples.max(1)).sqrt()).filter(|w| w.is_finite() && *w > 0.0)
    }

    /// Whether `value_sr` (a reading averaging `samples` at `theta_o_deg` in `band_nm`) is below three NEBRDF:
    /// a point flagged [`FLAG_BELOW_NEBRDF`]. False where the NEBRDF was not measured.
    pub fn below_nebrdf(&self, value_sr: f64, band_nm: f64, samples: u32, theta_o_deg: f64) -> bool {
        self.nebrdf_sr(band_nm, samples, theta_o_deg)
            .is_some_and(|ne| value_sr < 3.0 * ne)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::characterise::BandSignature;
    use crate::characterise::signature::alpha_deg;

    /// A characterisation of the 550 nm band only: a signature measured from 3 to 90 deg, one NEBRDF of 1e-4
    /// 1/sr for one sample at normal viewing.
    pub(crate) fn correction() -> DetectorCorrection {
        DetectorCorrection::new(DetectorCalibration {
            ranges: None,
            signature: vec![BandSignature {
                band_nm: 550.0,
                alpha_deg: vec![3.0, 90.0],
                brdf_sr: vec![1e-3, 1e-5],
                u_sr: vec![1e-5, 1e-6],
                nebrdf_one_sample_sr: 1e-4,
                dark_noise_one_sample_w: Some(2e-13),
            }],
        })
    }

    #[test]
    fn the_signature_is_subtracted_over_the_cosine_and_refused_near_the_beam() {
        let c = correction();
        // Light at -60, detector at 60: 60 deg from the beam's forward direction.
        match c.signature(550.0, alpha_deg(-60.0, 60.0), 60.0) {
            SignatureAt::Subtract { brdf_sr, .. } => {
                let (f, _) = c.calibration.signature[0].at(60.0).expect("inside");
                assert!((brdf_sr - 2.0 * f).abs() < 1e-15, "{brdf_sr}");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            c.signature(550.0, alpha_deg(-89.0, 89.0), 89.0),
            SignatureAt::NearBeam
        );
        assert_eq!(
            c.signature(450.0, alpha_deg(-60.0, 60.0), 60.0),
            SignatureAt::Unknown
        );
        assert_eq!(c.reading(1e-6, Some(2)), (1e-6, 0.0));
        assert!(
            c.nebrdf_sr(550.0, 1, 0.0)
                .is_some_and(|v| (v - 1e-4).abs() < 1e-18)
        );
    }
}
