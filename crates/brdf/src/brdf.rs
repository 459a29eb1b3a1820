//! The `Brdf` trait: what every reflectance model offers to the rest of the program.

use crate::geometry::Direction;
use crate::spectrum::{SpectrumError, Wavelength};

/// How a model reflects an ideal specular (Dirac delta) component, if it has one.
///
/// A delta lobe cannot be evaluated pointwise: [`Brdf::eval`] leaves it out, and callers that integrate over a
/// detector aperture (the simulator) or reason about measurability (the scheduler) add it analytically: the
/// power reflected into the mirror direction `wi.reflect_about_normal()` is `reflectance * P_i`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeltaLobe {
    /// Fraction of the incident power carried by the delta lobe (Fresnel reflectance at theta_i), in [0, 1].
    pub reflectance: f64,
}

/// A direction drawn by importance sampling, with its probability density in 1/sr (solid-angle measure).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectionSample {
    pub wo: Direction,
    pub pdf_per_sr: f64,
}

/// A bidirectional reflectance distribution function.
///
/// Contract for implementations (checked by the property tests and by `gonio brdf check`):
/// - `eval` returns f(wi, wo) in 1/sr WITHOUT the cosine factor, finite and >= 0 for every pair of unit
///   directions, and exactly 0 when either direction is at or below the horizon (cos theta <= 0);
/// - it is reciprocal: `eval(wi, wo) == eval(wo, wi)` up to rounding;
/// - it conserves energy: the directional albedo is <= 1 for every wi;
/// - the only error is a wavelength outside a spectral table of the model's parameters.
pub trait Brdf: Send + Sync + std::fmt::Debug {
    /// f(wi, wo) in 1/sr, no cosine, delta lobes excluded.
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError>;

    /// True when rotating both directions about the normal never changes the value.
    fn is_isotropic(&self) -> bool;

    /// True when no parameter varies with wavelength: measuring one band tells all.
    fn is_spectrally_flat(&self) -> bool;

    /// The ideal specular lobe for light arriving from `wi`, if the model has one.
    fn delta_lobe(
        &self,
        _wi: &Direction,
        _wavelength: Wavelength,
    ) -> Result<Option<DeltaLobe>, SpectrumError> {
        Ok(None)
    }

    /// True when the model has a delta lobe for some incidence (so pointwise evaluation misses part of it).
    fn has_delta_lobe(&self) -> bool {
        false
    }

    /// A direction drawn roughly in proportion to `f(wi, wo) cos(theta_o)` from the uniform numbers `u` in [0,1)^2,
    /// for integrators that need to follow a sharp lobe. `None` when the model offers no sampling routine.
    fn sample(
        &self,
        _wi: &Direction,
        _u: [f64; 2],
        _wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        Ok(None)
    }

    /// A typical angular width of the model's sharpest feature, in radians (e.g. the microfacet alpha).
    /// Integrators and adaptive planners use it to choose their resolution. `None` for smooth models.
    fn lobe_width(&self) -> Option<f64> {
        None
    }
}
