//! The analytic reflectance models, one file each, all implementing [`crate::Brdf`] with the definitions of
//! shared/reference/radiometry-and-materials.md ("Models").
//!
//! Shared guarantees (checked by `tests/it/models.rs`): `eval` is finite and >= 0 for any pair of unit directions,
//! exactly 0 when either cosine is <= 0 (tested before any division), and reciprocal: the formulas are written
//! so that swapping `wi` and `wo` performs the same floating-point operations on swapped operands, which makes
//! `eval(wi, wo) == eval(wo, wi)` hold bit for bit.
//!
//! Constructors validate their parameters and return a [`ParamError`] naming the offending key (the key of the
//! `[material]` TOML table), so that `crate::material` can point at the file and line.

pub mod conductor;
pub mod lambertian;
pub mod mirror;
pub mod oren_nayar;
pub mod phong;
pub mod plastic;

pub use conductor::Conductor;
pub use lambertian::Lambertian;
pub use mirror::Mirror;
pub use oren_nayar::OrenNayar;
pub use phong::Phong;
pub use plastic::Plastic;

use std::f64::consts::PI;

use crate::brdf::DirectionSample;
use crate::geometry::Direction;
use crate::spectrum::Spectral;

/// A model parameter out of its valid range. `key` is the parameter's name in the `[material]` table.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ParamError {
    pub key: &'static str,
    pub message: String,
}

impl ParamError {
    pub(crate) fn new(key: &'static str, message: impl Into<String>) -> ParamError {
        ParamError {
            key,
            message: message.into(),
        }
    }
}

/// Largest refractive index or extinction coefficient a conductor or mirror may have: no material comes near
/// (metals in the visible and near infrared stay below about 100), and far larger values overflow the squares in
/// the Fresnel factor into a NaN reflectance.
pub const MAX_OPTICAL_CONSTANT: f64 = 1000.0;

/// Checks that a spectral value lies in `[lo, hi]` at every wavelength (a table's extremes are its entries: its
/// monotone cubic never leaves the range of the two entries around a wavelength, crate::spectrum).
pub(crate) fn check_range(
    key: &'static str,
    value: &Spectral,
    lo: f64,
    hi: f64,
    what: &str,
) -> Result<(), ParamError> {
    let (min, max) = value.min_max();
    if !(min >= lo && max <= hi) {
        let bad = if min >= lo { max } else { min };
        return Err(ParamError::new(
            key,
            format!("{what} must be in [{lo}, {hi}], got {bad}"),
        ));
    }
    Ok(())
}

/// Checks that a spectral value is > `lo` (strictly) and finite everywhere.
pub(crate) fn check_above(
    key: &'static str,
    value: &Spectral,
    lo: f64,
    what: &str,
) -> Result<(), ParamError> {
    let (min, max) = value.min_max();
    if !(min > lo && max.is_finite()) {
        return Err(ParamError::new(
            key,
            format!("{what} must be greater than {lo}, got {min}"),
        ));
    }
    Ok(())
}

/// Checks that a spectral value is >= `lo` and finite everywhere.
pub(crate) fn check_at_least(
    key: &'static str,
    value: &Spectral,
    lo: f64,
    what: &str,
) -> Result<(), ParamError> {
    let (min, max) = value.min_max();
    if !(min >= lo && max.is_finite()) {
        return Err(ParamError::new(
            key,
            format!("{what} must be at least {lo}, got {min}"),
        ));
    }
    Ok(())
}

/// Cosine-weighted hemisphere sampling about the normal: density `cos(theta) / pi`.
pub(crate) fn sample_cosine(u: [f64; 2]) -> DirectionSample {
    // Keep u0 below 1 so that the direction stays strictly above the horizon and the density positive.
    let u0 = u[0].clamp(0.0, 1.0 - f64::EPSILON);
    let r = u0.sqrt();
    let phi = 2.0 * PI * u[1];
    let z = (1.0 - u0).sqrt();
    let wo = Direction::new(r * phi.cos(), r * phi.sin(), z).unwrap_or(Direction::NORMAL);
    DirectionSample {
        wo,
        pdf_per_sr: wo.z() / PI,
    }
}

/// Density of [`sample_cosine`].
pub(crate) fn pdf_cosine(wo: &Direction) -> f64 {
    wo.z().max(0.0) / PI
}

/// Splits one uniform number between two strategies chosen with probability `p` and `1 - p`, returning which
/// one was chosen and the number rescaled to [0, 1).
pub(crate) fn choose(u: f64, p: f64) -> (bool, f64) {
    if u < p {
        (true, (u / p).min(1.0 - f64::EPSILON))
    } else {
        (false, ((u - p) / (1.0 - p)).min(1.0 - f64::EPSILON))
    }
}
