//! Lambertian reflection: `f = rho / pi`, directional albedo exactly rho.

use std::f64::consts::PI;

use crate::brdf::{Brdf, DirectionSample};
use crate::geometry::Direction;
use crate::models::{ParamError, check_range, sample_cosine};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// An ideal diffuse reflector with (spectral) albedo `rho` in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Lambertian {
    albedo: Spectral,
}

impl Lambertian {
    pub fn new(albedo: Spectral) -> Result<Lambertian, ParamError> {
        check_range("albedo", &albedo, 0.0, 1.0, "albedo")?;
        Ok(Lambertian { albedo })
    }

    pub fn albedo(&self) -> &Spectral {
        &self.albedo
    }

    /// The same model with every spectral parameter frozen at `wavelength`.
    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Lambertian, SpectrumError> {
        Ok(Lambertian {
            albedo: self.albedo.resolved(wavelength)?,
        })
    }
}

impl Brdf for Lambertian {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let rho = self.albedo.at(wavelength)?;
        if wi.z() <= 0.0 || wo.z() <= 0.0 {
            return Ok(0.0);
        }
        Ok(rho / PI)
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
