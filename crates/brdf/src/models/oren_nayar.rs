//! Oren-Nayar rough diffuse reflection (the qualitative model), in the trig-free form.
//!
//! Classic form: `f = rho/pi (A + B max(0, cos(phi_i - phi_o)) sin(alpha) tan(beta))` with
//! `alpha = max(theta_i, theta_o)`, `beta = min(theta_i, theta_o)`, `A = 1 - 0.5 s2/(s2 + 0.33)`,
//! `B = 0.45 s2/(s2 + 0.09)`, `s2 = sigma^2` (sigma in radians).
//! Trig-free form used here: `f = rho/pi (A + B max(0, s) / max(cos_i, cos_o))` with
//! `s = dot(wi, wo) - cos_i cos_o = x_i x_o + y_i y_o = sin(theta_i) sin(theta_o) cos(phi_i - phi_o)`.
//! They are exactly equal: `sin(alpha) tan(beta) = sin(theta_i) sin(theta_o) / cos(beta)` and
//! `cos(beta) = max(cos_i, cos_o)`. `s` is computed from the in-plane components directly, which avoids the
//! cancellation of `dot - cos cos` near the pole; the division is safe because both cosines are tested > 0 first.

use std::f64::consts::PI;

use crate::brdf::{Brdf, DirectionSample};
use crate::geometry::Direction;
use crate::models::{ParamError, check_range, sample_cosine};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// Largest accepted roughness, degrees (slope standard deviation).
pub const SIGMA_MAX_DEG: f64 = 90.0;

#[derive(Debug, Clone, PartialEq)]
pub struct OrenNayar {
    albedo: Spectral,
    sigma_deg: f64,
    a: f64,
    b: f64,
}

impl OrenNayar {
    /// `albedo` in [0, 1]; `sigma_deg` (roughness, the standard deviation of facet slope angles) in [0, 90].
    pub fn new(albedo: Spectral, sigma_deg: f64) -> Result<OrenNayar, ParamError> {
        check_range("albedo", &albedo, 0.0, 1.0, "albedo")?;
        if !(0.0..=SIGMA_MAX_DEG).contains(&sigma_deg) {
            return Err(ParamError::new(
                "sigma_deg",
                format!("sigma_deg must be in [0, {SIGMA_MAX_DEG}] degrees, got {sigma_deg}"),
            ));
        }
        let s2 = sigma_deg.to_radians().powi(2);
        let a = 1.0 - 0.5 * s2 / (s2 + 0.33);
        let b = 0.45 * s2 / (s2 + 0.09);
        Ok(OrenNayar {
            albedo,
            sigma_deg,
            a,
            b,
        })
    }

    pub fn albedo(&self) -> &Spectral {
        &self.albedo
    }
    pub fn sigma_deg(&self) -> f64 {
        self.sigma_deg
    }
    /// The coefficients (A, B) of the model.
    pub fn coefficients(&self) -> (f64, f64) {
        (self.a, self.b)
    }

    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<OrenNayar, SpectrumError> {
        Ok(OrenNayar {
            albedo: self.albedo.resolved(wavelength)?,
            ..self.clone()
        })
    }
}

impl Brdf for OrenNayar {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let rho = self.albedo.at(wavelength)?;
        let (ci, co) = (wi.z(), wo.z());
        if ci <= 0.0 || co <= 0.0 {
            return Ok(0.0);
        }
        let s = wi.x() * wo.x() + wi.y() * wo.y();
        let term = if s > 0.0 { self.b * s / ci.max(co) } else { 0.0 };
        Ok(rho / PI * (self.a + term))
    }

    fn is_isotropic(&self) -> bool {
        true
    }

    fn is_spectrally_flat(&self) -> bool {
        self.albedo.is_constant()
    }

    fn sample(
        &self,
        _wi: &Direction,
        u: [f64; 2],
        _wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        Ok(Some(sample_cosine(u)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trig_free_form_equals_the_classic_formula() {
        let m = OrenNayar::new(Spectral::Constant(0.7), 25.0).expect("valid");
        let (a, b) = m.coefficients();
        let wl = Wavelength::DEFAULT;
        for &(ti, pi_, to, po) in &[
            (0.3, 0.1, 1.1, 0.5),
            (1.2, -2.0, 0.4, -1.5),
            (0.8, 0.0, 0.8, 3.0),
            (0.2, 1.0, 1.4, 1.2),
        ] {
            let wi = Direction::from_spherical(ti, pi_);
            let wo = Direction::from_spherical(to, po);
            let alpha = f64::max(ti, to);
            let beta = f64::min(ti, to);
            let classic = 0.7 / PI * (a + b * f64::max(0.0, (pi_ - po).cos()) * alpha.sin() * beta.tan());
            let v = m.eval(&wi, &wo, wl).expect("constant");
            assert!((v - classic).abs() <= 1e-14 * classic, "{v} vs {classic}");
        }
    }

    #[test]
    fn smooth_limit_is_lambertian() {
        let m = OrenNayar::new(Spectral::Constant(0.5), 0.0).expect("valid");
        let v = m
            .eval(
                &Direction::from_spherical(0.5, 0.0),
                &Direction::from_spherical(1.0, 0.3),
                Wavelength::DEFAULT,
            )
            .expect("constant");
        assert_eq!(v, 0.5 / PI);
    }
}
