//! Rough conductor: microfacet reflection with the exact complex-index Fresnel factor,
//! `f = F(wi.h) D(h) G / (4 cos_i cos_o)` (GGX or Beckmann, isotropic or anisotropic, separable or
//! height-correlated Smith masking). Below alpha 1e-3 the lobe becomes a delta lobe: see [`crate::microfacet`].

use crate::brdf::{Brdf, DeltaLobe, DirectionSample};
use crate::fresnel;
use crate::geometry::Direction;
use crate::microfacet::{Distribution, Masking, Microfacet};
use crate::models::{MAX_OPTICAL_CONSTANT, ParamError, check_above, check_at_least, check_range};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// Largest accepted roughness.
pub const ALPHA_MAX: f64 = 1.0;

#[derive(Debug, Clone, PartialEq)]
pub struct Conductor {
    microfacet: Microfacet,
    /// The roughness as given (before clamping), kept to describe the material faithfully.
    alpha_given: (f64, f64),
    eta: Spectral,
    k: Spectral,
}

/// Validates a roughness pair: each in (0, 1]. Keys name the TOML keys (`alpha` when isotropic).
pub(crate) fn check_alpha(alpha_x: f64, alpha_y: f64) -> Result<(), ParamError> {
    let iso = alpha_x == alpha_y;
    for (key, a) in [("alpha_x", alpha_x), ("alpha_y", alpha_y)] {
        if !(a > 0.0 && a <= ALPHA_MAX) {
            let key = if iso { "alpha" } else { key };
            return Err(ParamError::new(
                key,
                format!("{key} must be in (0, {ALPHA_MAX}], got {a}"),
            ));
        }
    }
    Ok(())
}

impl Conductor {
    /// Roughness in (0, 1] (values below 1e-4 are clamped to 1e-4, below 1e-3 the lobe is a delta);
    /// `eta` in (0, 1000] and `k` in [0, 1000] the complex refractive index (both capped at
    /// [`MAX_OPTICAL_CONSTANT`] at every wavelength).
    pub fn new(
        distribution: Distribution,
        masking: Masking,
        alpha_x: f64,
        alpha_y: f64,
        eta: Spectral,
        k: Spectral,
    ) -> Result<Conductor, ParamError> {
        check_alpha(alpha_x, alpha_y)?;
        check_above("eta", &eta, 0.0, "the refractive index eta")?;
        check_range("eta", &eta, 0.0, MAX_OPTICAL_CONSTANT, "the refractive index eta")?;
        check_at_least("k", &k, 0.0, "the extinction coefficient k")?;
        check_range("k", &k, 0.0, MAX_OPTICAL_CONSTANT, "the extinction coefficient k")?;
        Ok(Conductor {
            microfacet: Microfacet::new(distribution, masking, alpha_x, alpha_y),
            alpha_given: (alpha_x, alpha_y),
            eta,
            k,
        })
    }

    pub fn microfacet(&self) -> &Microfacet {
        &self.microfacet
    }
    /// (alpha_x, alpha_y) as given, before clamping.
    pub fn alpha(&self) -> (f64, f64) {
        self.alpha_given
    }
    pub fn eta(&self) -> &Spectral {
        &self.eta
    }
    pub fn k(&self) -> &Spectral {
        &self.k
    }

    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Conductor, SpectrumError> {
        Ok(Conductor {
            eta: self.eta.resolved(wavelength)?,
            k: self.k.resolved(wavelength)?,
            ..self.clone()
        })
    }
}

impl Brdf for Conductor {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let (eta, k) = (self.eta.at(wavelength)?, self.k.at(wavelength)?);
        if self.microfacet.is_delta() {
            return Ok(0.0);
        }
        // GGX: Fresnel and lobe as one ratio, one division (the hot path; the same value up to rounding).
        if let Some((num, den, cos_d)) = self.microfacet.ggx_fraction(wi, wo)
            && let Some((f_num, f_den)) = fresnel::conductor_ratio(cos_d, eta, k)
        {
            let v = (f_num * num) / (f_den * den);
            return Ok(if v.is_finite() && v > 0.0 { v } else { 0.0 });
        }
        Ok(match self.microfacet.lobe(wi, wo) {
            Some(l) if l.value > 0.0 => fresnel::conductor(l.cos_d, eta, k) * l.value,
            _ => 0.0,
        })
    }

    fn is_isotropic(&self) -> bool {
        self.microfacet.is_isotropic()
    }

    fn is_spectrally_flat(&self) -> bool {
        self.eta.is_constant() && self.k.is_constant()
    }

    fn delta_lobe(&self, wi: &Direction, wavelength: Wavelength) -> Result<Option<DeltaLobe>, SpectrumError> {
        let (eta, k) = (self.eta.at(wavelength)?, self.k.at(wavelength)?);
        if !self.microfacet.is_delta() || wi.z() <= 0.0 {
            return Ok(None);
        }
        let reflectance = fresnel::conductor(wi.z(), eta, k) * self.microfacet.delta_masking(wi);
        Ok(Some(DeltaLobe { reflectance }))
    }

    fn has_delta_lobe(&self) -> bool {
        self.microfacet.is_delta()
    }

    /// Microfacet sampling (GGX: visible normals; Beckmann: `D cos`), reflected about the sampled normal.
    /// Samples may land below the horizon, where `eval` is 0. In the delta regime the (clamped) lobe is still
    /// sampled; `eval` is 0 there and the delta lobe must be added analytically.
    fn sample(
        &self,
        wi: &Direction,
        u: [f64; 2],
        _wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        if wi.z() <= 0.0 {
            return Ok(Some(crate::models::sample_cosine(u)));
        }
        Ok(self.microfacet.sample_reflection(wi, u))
    }

    /// The smaller alpha (radians of slope, roughly the lobe's half width); 0 in the delta regime.
    fn lobe_width(&self) -> Option<f64> {
        if self.microfacet.is_delta() {
            Some(0.0)
        } else {
            Some(self.microfacet.alpha_x().min(self.microfacet.alpha_y()))
        }
    }
}
