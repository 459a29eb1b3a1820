//! The relative method with a reference read at one geometry.
//!
//! The reference sample (known BRDF `f_ref`, angular shape included) is read at the reference geometry `g_r`
//! (`[calibration] reference_geometry_deg`): `S_ref = P_i Omega_d cos(theta_o,r) f_ref(g_r)`, which measures the
//! instrument's throughput `P_i Omega_d` as the direct beam does in the absolute method, without removing the
//! sample holder's content from the beam path or a detector facing the source. A sample reading at any geometry
//! `g` then gives
//! `f(g) = f_ref(g_r) cos(theta_o,r) / cos(theta_o) * (S - S_dark) / (S_ref - S_dark,ref)`.
//! This is the measurement equation of `gonio_brdf::measurement::relative_brdf` with, as "reference BRDF at the
//! measured geometry", the transfer [`Transfer`] `T(wi, wo) = f_ref(g_r) cos(theta_o,r) / cos(theta_o)`: its
//! calibration uncertainty, the detector-angle term (through dT/dtheta_o = T tan theta_o, the same as the
//! absolute method's) and the geometry checks come from there. The solid angle cancels. The positioning at the
//! reference geometry adds to the reference reading's own uncertainty ([`Transfer::positioning_rel_std`]).
//!
//! In the simulator the reference is a second set of optics on the same source (`Rig::build_optics`): what is read
//! while it is mounted is the reference material's own aperture integral, so a dry-run shows the method's real
//! residual errors (e.g. the reference's finite-aperture average against its point value).

use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Direction, SpectrumError, Wavelength};
use gonio_scheduler::kinematics::Geometry;

/// Step of the central differences for the positioning sensitivity (rad).
const STEP_RAD: f64 = 1e-5;

/// `T(wi, wo) = f_ref(g_r) cos(theta_o,r) / cos(theta_o)`: the reference reading carried to another geometry.
#[derive(Debug, Clone)]
pub(crate) struct Transfer {
    material: Material,
    wi_r: Direction,
    wo_r: Direction,
}

impl Transfer {
    pub(crate) fn new(material: Material, geometry: &Geometry) -> Transfer {
        let (wi_r, wo_r) = geometry.directions();
        Transfer { material, wi_r, wo_r }
    }

    /// `f_ref(wi, wo) cos(theta_o)`: what a reading of the reference is proportional to.
    fn collected(
        &self,
        wi: &Direction,
        wo: &Direction,
        wavelength: Wavelength,
    ) -> Result<f64, SpectrumError> {
        Ok(self.material.eval(wi, wo, wavelength)? * wo.cos_theta())
    }

    /// Relative standard uncertainty of a reference reading from the positioning at the reference geometry:
    /// `angle_std_rad` times the relative slope of `f_ref cos(theta_o)` in theta_i and theta_o (quadrature).
    pub(crate) fn positioning_rel_std(&self, wavelength: Wavelength, angle_std_rad: f64) -> f64 {
        let at = |wi: &Direction, wo: &Direction| self.collected(wi, wo, wavelength).unwrap_or(f64::NAN);
        let centre = at(&self.wi_r, &self.wo_r);
        if !(centre.is_finite() && centre > 0.0) {
            return 0.0;
        }
        // A negative polar angle continues through the pole (to the opposite azimuth): central differences
        // stay central at normal incidence.
        let tilt = |d: &Direction, delta: f64| {
            let (theta, phi) = d.to_spherical();
            Direction::from_spherical(theta + delta, phi)
        };
        let slope_i = (at(&tilt(&self.wi_r, STEP_RAD), &self.wo_r)
            - at(&tilt(&self.wi_r, -STEP_RAD), &self.wo_r))
            / (2.0 * STEP_RAD);
        let slope_o = (at(&self.wi_r, &tilt(&self.wo_r, STEP_RAD))
            - at(&self.wi_r, &tilt(&self.wo_r, -STEP_RAD)))
            / (2.0 * STEP_RAD);
        let rel = slope_i.hypot(slope_o) / centre * angle_std_rad;
        if rel.is_finite() { rel } else { 0.0 }
    }
}

impl Brdf for Transfer {
    fn eval(&self, _wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let cos_o = wo.cos_theta();
        if cos_o <= 0.0 {
            return Ok(0.0);
        }
        Ok(self.collected(&self.wi_r, &self.wo_r, wavelength)? / cos_o)
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn is_spectrally_flat(&self) -> bool {
        self.material.is_spectrally_flat()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_transfer_carries_the_reference_reading_by_the_detector_cosine() {
        let spectralon = Material::preset("spectralon").expect("preset");
        let g = Geometry::new(0.0, 0.0, 45.0, 180.0);
        let t = Transfer::new(spectralon.clone(), &g);
        let wl = Wavelength::from_nm(550.0).expect("wl");
        let (wi_r, wo_r) = g.directions();
        let f_r = spectralon.eval(&wi_r, &wo_r, wl).expect("eval");
        let wi = Direction::from_spherical_deg(30.0, 0.0);
        let wo = Direction::from_spherical_deg(60.0, 180.0);
        // f_ref(g_r) cos 45 / cos 60 = f_ref sqrt(2)
        let expected = f_r * std::f64::consts::FRAC_1_SQRT_2 / 0.5;
        let got = t.eval(&wi, &wo, wl).expect("eval");
        assert!((got - expected).abs() < 1e-14 * expected, "{got} vs {expected}");
        // Lambertian reference: only cos(theta_o,r) varies, d ln cos / d theta = -tan 45 = -1.
        let rel = t.positioning_rel_std(wl, 1e-3);
        assert!((rel - 1e-3).abs() < 1e-8, "{rel}");
    }
}
