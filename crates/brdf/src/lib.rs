//! gonio-brdf: the physics of a gonioreflectometer, in f64.
//!
//! Module map:
//! - [`geometry`]: unit directions in the sample frame, spherical angles, half/difference (Rusinkiewicz) and
//!   isotropic parameterisations, reciprocity.
//! - [`spectrum`]: wavelengths and quantities that vary with them.
//! - [`brdf`]: the [`Brdf`] trait every model implements.
//!
//! Conventions: radians inside, degrees only at the edges; BRDF values in 1/sr without the cosine factor;
//! `wi` points towards the source, `wo` towards the detector. No I/O except reading and writing data files,
//! no async.

pub mod brdf;
pub mod geometry;
pub mod spectrum;

pub use brdf::{Brdf, DeltaLobe, DirectionSample};
pub use geometry::{Direction, HalfDiff, IsotropicAngles};
pub use spectrum::{Spectral, SpectrumError, Wavelength};
