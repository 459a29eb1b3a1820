//! The instrument signature (ASTM E2387): what the detector reads with no sample, as a BRDF-equivalent against
//! the angle from the undeviated beam, per band, and the noise-equivalent BRDF (NEBRDF) from the darks' noise.
//!
//! With the holder empty, the light that reaches the detector at an angle `alpha` from the beam's forward
//! direction is scattered by the source optics, the mounts and the room. Read as a BRDF it is
//! `f_sig(alpha) = (S - D) / (P Omega)` with `P` the direct beam and `Omega` the aperture's solid angle: a
//! campaign's point at `alpha` then reads `f + f_sig(alpha) / cos(theta_o)` (its measurement equation divides
//! by `P Omega cos(theta_o)` where the signature has no cosine), so the signature is subtracted as that.

use serde::{Deserialize, Serialize};

/// One band's signature: `brdf_sr[k]` (1/sr) with standard uncertainty `u_sr[k]` at `alpha_deg[k]` (ascending).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandSignature {
    pub band_nm: f64,
    pub alpha_deg: Vec<f64>,
    pub brdf_sr: Vec<f64>,
    pub u_sr: Vec<f64>,
    /// Noise-equivalent BRDF of one reading at the meter's averaging of one sample, viewed along the normal
    /// (1/sr): the darks' noise over `P Omega`. At averaging `N` and polar angle `theta_o` it is this over
    /// `sqrt(N) cos(theta_o)`.
    pub nebrdf_one_sample_sr: f64,
    /// The darks' noise itself (W): the standard deviation of single-sample readings on the blank, from which
    /// the NEBRDF was worked out. No reading in the band is less noisy (over `sqrt(N)` at averaging `N`), whatever
    /// the meter's noise model says: on realistic.toml the head's amplifier doubles it on the lowest range.
    /// Absent from calibration files written before it was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dark_noise_one_sample_w: Option<f64>,
}

/// The angle between the detector arm and the beam's forward direction for arm angles in the arms' plane (deg):
/// the beam leaves the light arm at `light_deg` and goes on towards `light_deg + 180`.
pub fn alpha_deg(light_deg: f64, detector_deg: f64) -> f64 {
    let d = (detector_deg - light_deg - 180.0).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// The angle between the detector and the beam's forward direction (deg) at the directions towards the source
/// `wi` and the detector `wo`: the angle between `wo` and `-wi`, the same in the sample's frame as between the
/// arms ([`alpha_deg`] of the pose that reaches them).
pub fn alpha_between_deg(wi: &gonio_brdf::Direction, wo: &gonio_brdf::Direction) -> f64 {
    (-wi.dot(wo)).clamp(-1.0, 1.0).acos().to_degrees()
}

impl BandSignature {
    /// The signature at `alpha` (1/sr) and its standard uncertainty, interpolated linearly in `ln alpha`; beyond
    /// the largest angle measured, the value there. `None` nearer the beam than the smallest angle measured,
    /// where the beam itself reaches the detector.
    pub fn at(&self, alpha: f64) -> Option<(f64, f64)> {
        let a = &self.alpha_deg;
        let (first, last) = (*a.first()?, *a.last()?);
        if alpha.is_nan() || alpha < first {
            return None;
        }
        if alpha >= last {
            let k = a.len() - 1;
            return Some((self.brdf_sr[k], self.u_sr[k]));
        }
        let k = a.partition_point(|&x| x <= alpha).clamp(1, a.len() - 1);
        let (x0, x1) = (a[k - 1].ln(), a[k].ln());
        let t = if x1 > x0 {
            (alpha.ln() - x0) / (x1 - x0)
        } else {
            0.0
        };
        let lerp = |v: &[f64]| v[k - 1] + t * (v[k] - v[k - 1]);
        Some((lerp(&self.brdf_sr), lerp(&self.u_sr)))
    }

    /// Widen each value's uncertainty by the table's local slope times `u_alpha_deg`, the standard uncertainty
    /// of the angle from the beam each was read at (the arms' zeros and the beam's direction).
    pub fn widen_for_angle(&mut self, u_alpha_deg: f64) {
        let n = self.alpha_deg.len();
        if n < 2 || u_alpha_deg.is_nan() || u_alpha_deg <= 0.0 {
            return;
        }
        let slopes: Vec<f64> = (0..n)
            .map(|k| {
                let (i, j) = (k.saturating_sub(1), (k + 1).min(n - 1));
                let da = self.alpha_deg[j] - self.alpha_deg[i];
                if da > 0.0 {
                    (self.brdf_sr[j] - self.brdf_sr[i]) / da
                } else {
                    0.0
                }
            })
            .collect();
        for (u, slope) in self.u_sr.iter_mut().zip(slopes) {
            *u = u.hypot(slope * u_alpha_deg);
        }
    }

    /// The NEBRDF (1/sr) of one reading averaging `samples` at polar angle `theta_o_deg`.
    pub fn nebrdf_sr(&self, samples: u32, theta_o_deg: f64) -> f64 {
        let cos = theta_o_deg.to_radians().cos().max(1e-6);
        self.nebrdf_one_sample_sr / (f64::from(samples.max(1)).sqrt() * cos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alpha_is_the_angle_from_the_beams_forward_direction() {
        assert_eq!(alpha_deg(-90.0, 90.0), 0.0);
        assert!((alpha_deg(-90.0, 80.0) - 10.0).abs() < 1e-12);
        assert!((alpha_deg(-60.0, 60.0) - 60.0).abs() < 1e-12);
        assert!((alpha_deg(-85.0, 85.0) - 10.0).abs() < 1e-12);
        assert!((alpha_deg(-30.0, -20.0) - 170.0).abs() < 1e-12);
        // From the directions: the specular arrangement at 30 deg (light at -30, detector at 30) is 120 deg
        // from the beam, as the arms say.
        use gonio_brdf::Direction;
        let (wi, wo) = (
            Direction::from_spherical_deg(30.0, 0.0),
            Direction::from_spherical_deg(30.0, 180.0),
        );
        assert!((alpha_between_deg(&wi, &wo) - alpha_deg(-30.0, 30.0)).abs() < 1e-9);
        let (wi, wo) = (
            Direction::from_spherical_deg(85.0, 0.0),
            Direction::from_spherical_deg(85.0, 180.0),
        );
        assert!((alpha_between_deg(&wi, &wo) - 10.0).abs() < 1e-9);
    }

    #[test]
    fn interpolation_is_in_log_angle_and_refuses_nearer_the_beam() {
        let s = BandSignature {
            band_nm: 550.0,
            alpha_deg: vec![2.0, 8.0, 32.0],
            brdf_sr: vec![4e-3, 2e-3, 1e-5],
            u_sr: vec![1e-4, 1e-4, 1e-6],
            nebrdf_one_sample_sr: 1e-4,
            dark_noise_one_sample_w: None,
        };
        assert_eq!(s.at(1.0), None);
        assert_eq!(s.at(2.0), Some((4e-3, 1e-4)));
        // Half-way in ln(alpha) between 2 and 8 is 4.
        let (v, _) = s.at(4.0).expect("inside");
        assert!((v - 3e-3).abs() < 1e-15, "{v}");
        assert_eq!(s.at(90.0), Some((1e-5, 1e-6)));
        assert!((s.nebrdf_sr(100, 60.0) - 2e-5).abs() < 1e-15);
    }
}
