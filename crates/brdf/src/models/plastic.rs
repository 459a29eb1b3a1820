//! Plastic: a smooth-statistics dielectric coat (microfacet reflection with the dielectric Fresnel factor of
//! index `ior`) over a coloured Lambertian base of albedo `albedo`.
//!
//! `f = F(wi.h) D(h) G / (4 cos_i cos_o)  +  albedo / pi * (1 - F(cos_i)) (1 - F(cos_o)) * K`
//!
//! The diffuse term is reciprocal because it is a symmetric product. Its normalisation
//! `K = 1 / (ior^2 (1 - albedo * Fbar_int))` with `Fbar_int = 1 - (1 - Fbar) / ior^2` follows the classic
//! derivation (light enters through the coat with `1 - F(cos_i)`, is scattered by the base, is
//! compressed into the denser medium by `1/ior^2`, escapes with `1 - F(cos_o)` or is internally reflected with
//! the hemispherical average `Fbar_int` and scattered again: a geometric series); `Fbar` is the hemispherical
//! cosine-weighted average of the external Fresnel reflectance ([`fresnel::dielectric_hemispherical_average`]).
//! It makes the diffuse albedo exactly `albedo (1 - Fbar) (1 - F(cos_i)) / (ior^2 - albedo (ior^2 - 1 + Fbar))`,
//! which equals `1 - F(cos_i)` at albedo 1 and is smaller below.
//!
//! Energy bound: the total directional albedo is the coat's `S(wi)` plus the diffuse part, which at albedo 1
//! is `(1 - F(cos_i)) * COAT_BOUND`. The physical normalisation alone (`COAT_BOUND` = 1) would bound the total
//! by 1 only if `S(wi) <= F(cos_i)`, and a rough coat violates that slightly: facets tilted away from `wi` see
//! a more oblique incidence and reflect more than the macro-surface would. A brute-force scan (distribution x
//! masking x alpha in [0.02, 1] x anisotropy ratio up to 30 x ior in [1.05, 4] x theta_i in [0, 89] degrees)
//! found the largest admissible factor to be 0.9976 for isotropic coats and 0.9874 for an anisotropy ratio of
//! 30. Hence `COAT_BOUND = 0.98` and plastic accepts anisotropy ratios up to [`ANISOTROPY_MAX`] = 10. This is
//! an empirical bound, re-checked by `plastic_albedo_is_bounded` in tests/it/models.rs; it darkens the base by 2%
//! relative to the physical derivation, which is within the spread of real plastics.

use std::f64::consts::PI;

use crate::brdf::{Brdf, DeltaLobe, DirectionSample};
use crate::fresnel;
use crate::geometry::Direction;
use crate::microfacet::{Distribution, Masking, Microfacet};
use crate::models::conductor::check_alpha;
use crate::models::{ParamError, check_range, choose, pdf_cosine, sample_cosine};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// Largest accepted coat index.
pub const IOR_MAX: f64 = 4.0;

/// Safety factor on the diffuse normalisation; see the module doc.
pub const COAT_BOUND: f64 = 0.98;

/// Largest accepted ratio between the two roughnesses of an anisotropic coat (see the module doc).
pub const ANISOTROPY_MAX: f64 = 10.0;

#[derive(Debug, Clone, PartialEq)]
pub struct Plastic {
    microfacet: Microfacet,
    alpha_given: (f64, f64),
    ior: Spectral,
    albedo: Spectral,
    /// `Fbar` when `ior` is a constant (the common case), so that `eval` does not integrate.
    fbar_cached: Option<f64>,
}

impl Plastic {
    /// Roughness in (0, 1] (clamped and switched to a delta as for the conductor; anisotropy ratio at most
    /// [`ANISOTROPY_MAX`]), coat index `ior` in [1, 4], base `albedo` in [0, 1].
    pub fn new(
        distribution: Distribution,
        masking: Masking,
        alpha_x: f64,
        alpha_y: f64,
        ior: Spectral,
        albedo: Spectral,
    ) -> Result<Plastic, ParamError> {
        check_alpha(alpha_x, alpha_y)?;
        if alpha_x.max(alpha_y) > ANISOTROPY_MAX * alpha_x.min(alpha_y) {
            return Err(ParamError::new(
                "alpha_y",
                format!(
                    "the coat's anisotropy alpha_x : alpha_y = {alpha_x} : {alpha_y} exceeds {ANISOTROPY_MAX} \
                     (the energy bound is verified up to that ratio)"
                ),
            ));
        }
        check_range("ior", &ior, 1.0, IOR_MAX, "the coat's refractive index ior")?;
        check_range("albedo", &albedo, 0.0, 1.0, "albedo")?;
        let fbar_cached = match &ior {
            Spectral::Constant(n) => Some(fresnel::dielectric_hemispherical_average(*n)),
            Spectral::Table(_) => None,
        };
        Ok(Plastic {
            microfacet: Microfacet::new(distribution, masking, alpha_x, alpha_y),
            alpha_given: (alpha_x, alpha_y),
            ior,
            albedo,
            fbar_cached,
        })
    }

    pub fn microfacet(&self) -> &Microfacet {
        &self.microfacet
    }
    pub fn alpha(&self) -> (f64, f64) {
        self.alpha_given
    }
    pub fn ior(&self) -> &Spectral {
        &self.ior
    }
    pub fn albedo(&self) -> &Spectral {
        &self.albedo
    }

    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Plastic, SpectrumError> {
        let ior = self.ior.resolved(wavelength)?;
        let albedo = self.albedo.resolved(wavelength)?;
        let fbar_cached = match &ior {
            Spectral::Constant(n) => Some(
                self.fbar_cached
                    .unwrap_or_else(|| fresnel::dielectric_hemispherical_average(*n)),
            ),
            Spectral::Table(_) => None,
        };
        Ok(Plastic {
            ior,
            albedo,
            fbar_cached,
            ..self.clone()
        })
    }

    /// The diffuse normalisation `K` (module doc) for a coat index and base albedo.
    fn diffuse_scale(&self, ior: f64, rho: f64) -> f64 {
        let fbar = match self.fbar_cached {
            Some(f) => f,
            None => fresnel::dielectric_hemispherical_average(ior),
        };
        let n2 = ior * ior;
        let fbar_int = 1.0 - (1.0 - fbar) / n2;
        COAT_BOUND / (n2 * (1.0 - rho * fbar_int))
    }

    /// The diffuse part only: `albedo/pi (1 - F(cos_i)) (1 - F(cos_o)) K` (0 below the horizon).
    pub fn eval_diffuse(
        &self,
        wi: &Direction,
        wo: &Direction,
        wavelength: Wavelength,
    ) -> Result<f64, SpectrumError> {
        let (ior, rho) = (self.ior.at(wavelength)?, self.albedo.at(wavelength)?);
        let (ci, co) = (wi.z(), wo.z());
        if ci <= 0.0 || co <= 0.0 {
            return Ok(0.0);
        }
        let ti = 1.0 - fresnel::dielectric(ci, ior);
        let to = 1.0 - fresnel::dielectric(co, ior);
        Ok(rho / PI * (ti * to) * self.diffuse_scale(ior, rho))
    }
}

impl Brdf for Plastic {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let diffuse = self.eval_diffuse(wi, wo, wavelength)?;
        if diffuse == 0.0 && (wi.z() <= 0.0 || wo.z() <= 0.0) {
            return Ok(0.0);
        }
        let ior = self.ior.at(wavelength)?;
        let specular = if self.microfacet.is_delta() {
            0.0
        } else {
            match self.microfacet.lobe(wi, wo) {
                Some(l) if l.value > 0.0 => fresnel::dielectric(l.cos_d, ior) * l.value,
                _ => 0.0,
            }
        };
        Ok(specular + diffuse)
    }

    fn is_isotropic(&self) -> bool {
        self.microfacet.is_isotropic()
    }

    fn is_spectrally_flat(&self) -> bool {
        self.ior.is_constant() && self.albedo.is_constant()
    }

    fn delta_lobe(&self, wi: &Direction, wavelength: Wavelength) -> Result<Option<DeltaLobe>, SpectrumError> {
        let ior = self.ior.at(wavelength)?;
        if !self.microfacet.is_delta() || wi.z() <= 0.0 {
            return Ok(None);
        }
        let reflectance = fresnel::dielectric(wi.z(), ior) * self.microfacet.delta_masking(wi);
        Ok(Some(DeltaLobe { reflectance }))
    }

    fn has_delta_lobe(&self) -> bool {
        self.microfacet.is_delta()
    }

    /// A mixture of the coat's microfacet sampling and cosine sampling for the base, chosen with probability
    /// in proportion to `F(cos_i)` and `albedo (1 - F(cos_i))` (kept within [0.1, 0.9] so that neither part is
    /// starved). In the delta regime only the base is sampled.
    fn sample(
        &self,
        wi: &Direction,
        u: [f64; 2],
        wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        let (ior, rho) = (self.ior.at(wavelength)?, self.albedo.at(wavelength)?);
        if wi.z() <= 0.0 || self.microfacet.is_delta() {
            return Ok(Some(sample_cosine(u)));
        }
        let f = fresnel::dielectric(wi.z(), ior);
        let p_spec = (f / (f + rho * (1.0 - f)).max(f64::MIN_POSITIVE)).clamp(0.1, 0.9);
        let (spec, u0) = choose(u[0], p_spec);
        let wo = if spec {
            match self.microfacet.sample_reflection(wi, [u0, u[1]]) {
                Some(s) => s.wo,
                None => return Ok(Some(sample_cosine(u))),
            }
        } else {
            sample_cosine([u0, u[1]]).wo
        };
        let pdf = p_spec * self.microfacet.pdf_reflection(wi, &wo) + (1.0 - p_spec) * pdf_cosine(&wo);
        Ok(Some(DirectionSample {
            wo,
            pdf_per_sr: if pdf > 0.0 && pdf.is_finite() {
                pdf
            } else {
                f64::MAX
            },
        }))
    }

    /// The smaller alpha of the coat; 0 in the delta regime.
    fn lobe_width(&self) -> Option<f64> {
        if self.microfacet.is_delta() {
            Some(0.0)
        } else {
            Some(self.microfacet.alpha_x().min(self.microfacet.alpha_y()))
        }
    }
}
