//! The ideal mirror: a Fresnel-weighted delta lobe and nothing else.
//!
//! A delta cannot be evaluated pointwise: `eval` is 0 everywhere and [`Brdf::delta_lobe`] gives the power
//! fraction `F(theta_i)` reflected exactly into `wi.reflect_about_normal()` (exact conductor Fresnel with the
//! complex index `eta + i k`).

use crate::brdf::{Brdf, DeltaLobe};
use crate::fresnel;
use crate::geometry::Direction;
use crate::models::{MAX_OPTICAL_CONSTANT, ParamError, check_above, check_at_least, check_range};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// A perfectly smooth conductor.
#[derive(Debug, Clone, PartialEq)]
pub struct Mirror {
    eta: Spectral,
    k: Spectral,
}

impl Mirror {
    /// `eta` in (0, 1000] and `k` in [0, 1000]: the real and imaginary parts of the complex refractive index
    /// (both capped at [`MAX_OPTICAL_CONSTANT`] at every wavelength).
    pub fn new(eta: Spectral, k: Spectral) -> Result<Mirror, ParamError> {
        check_above("eta", &eta, 0.0, "the refractive index eta")?;
        check_range("eta", &eta, 0.0, MAX_OPTICAL_CONSTANT, "the refractive index eta")?;
        check_at_least("k", &k, 0.0, "the extinction coefficient k")?;
        check_range("k", &k, 0.0, MAX_OPTICAL_CONSTANT, "the extinction coefficient k")?;
        Ok(Mirror { eta, k })
    }

    pub fn eta(&self) -> &Spectral {
        &self.eta
    }
    pub fn k(&self) -> &Spectral {
        &self.k
    }

    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Mirror, SpectrumError> {
        Ok(Mirror {
            eta: self.eta.resolved(wavelength)?,
            k: self.k.resolved(wavelength)?,
        })
    }
}

impl Brdf for Mirror {
    /// Always 0: the mirror has no diffuse or glossy part, only the delta lobe.
    fn eval(&self, _wi: &Direction, _wo: &Direction, _wavelength: Wavelength) -> Result<f64, SpectrumError> {
        Ok(0.0)
    }

    fn is_isotropic(&self) -> bool {
        true
    }

    fn is_spectrally_flat(&self) -> bool {
        self.eta.is_constant() && self.k.is_constant()
    }

    fn delta_lobe(&self, wi: &Direction, wavelength: Wavelength) -> Result<Option<DeltaLobe>, SpectrumError> {
        let (eta, k) = (self.eta.at(wavelength)?, self.k.at(wavelength)?);
        if wi.z() <= 0.0 {
            return Ok(None);
        }
        Ok(Some(DeltaLobe {
            reflectance: fresnel::conductor(wi.z(), eta, k),
        }))
    }

    fn has_delta_lobe(&self) -> bool {
        true
    }

    /// 0: the lobe is a delta (callers must use `delta_lobe`, not resolution, for it).
    fn lobe_width(&self) -> Option<f64> {
        Some(0.0)
    }
}
