//! Integration tests of gonio-brdf: one test binary. The stress suite (`tests/stress`) is a target of its own:
//! its large tier runs alone, in release, for minutes (`GONIO_STRESS=large`).
//!
//! - `energy`: energy and integration identities through the public API.
//! - `materials`: materials and presets against independent expectations.
//! - `merl`: the MERL binary format and the measured BRDF.
//! - `models`: the analytic models, Fresnel and microfacet distributions against independent expectations.
//! - `presets_check`: every preset obeys the physical laws `gonio brdf check` tests, at every band of the
//!   simulated instrument.

mod energy;
mod materials;
mod merl;
mod models;
mod presets_check;
