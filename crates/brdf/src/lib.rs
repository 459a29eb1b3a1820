//! gonio-brdf: the physics of a gonioreflectometer, in f64.
//!
//! Module map:
//! - [`geometry`]: unit directions in the sample frame, spherical angles, half/difference (Rusinkiewicz) and
//!   isotropic parameterisations, reciprocity.
//! - [`spectrum`]: wavelengths and quantities that vary with them.
//! - [`brdf`]: the [`Brdf`] trait every model implements.
//! - [`fresnel`]: exact unpolarised Fresnel reflectance (conductor with complex index, dielectric).
//! - [`microfacet`]: GGX and Beckmann distributions, Smith masking, microfacet sampling, the delta switch-over.
//! - [`rgl`]: measured BRDF from an RGL material file (`.bsdf`), evaluated as Mitsuba 3 does.
//! - [`models`]: the analytic models (Lambertian, mirror, Oren-Nayar, Phong, conductor, plastic).
//! - [`radiometry`]: solid angles (patch, aperture in stable form, cone), projected solid angle, radiance <-> irradiance.
//! - [`integrate`]: hemisphere and cone quadrature with error estimates (Gauss-Legendre x trapezoid, lobe-adapted,
//!   quasi-Monte Carlo through `Brdf::sample`), directional albedo.
//! - [`measurement`]: the measurement equation (absolute, relative), validity checks, uncertainty propagation.
//! - [`checks`]: property checks (reciprocity, energy, non-negativity, finiteness, isotropy) and their report.
//! - [`merl`]: the MERL binary format; [`measured`]: a tabulated isotropic BRDF on the MERL grid.
//! - [`material`]: the `[material]` TOML table (files, presets, campaign documents) -> [`Material`].
//! - [`presets`]: the built-in materials, data files from config/materials/ compiled in.
//!
//! Conventions: radians inside, degrees only at the edges; BRDF values in 1/sr without the cosine factor;
//! `wi` points towards the source, `wo` towards the detector. No I/O except reading and writing data files,
//! no async.

pub mod brdf;
pub mod checks;
pub mod fresnel;
pub mod geometry;
pub mod integrate;
pub mod material;
pub mod measured;
pub mod measurement;
pub mod merl;
pub mod microfacet;
pub mod models;
pub mod presets;
pub mod radiometry;
pub mod rgl;
pub mod spectrum;

pub use brdf::{Brdf, DeltaLobe, DirectionSample};
pub use geometry::{Direction, HalfDiff, IsotropicAngles};
pub use material::{Material, MaterialError, MaterialSpec};
pub use spectrum::{Spectral, SpectrumError, Wavelength};
