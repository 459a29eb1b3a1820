//! gonio-results: measured runs made useful - exports for other tools, analytic model fits, plots.
//!
//! Module map:
//! - [`points`]: the points CSV, one column definition with its writer (used by `gonio run`, the daemon's API
//!   and the exports) and its reader (by header, with file/line/column errors).
//! - [`provenance`]: the run record, the typed content of run.json, assembled from what the store keeps so
//!   that a run directory and the same campaign in a daemon's store have the same provenance.
//! - [`run`]: a run (points and provenance) from a run directory or assembled by the caller.
//! - [`iso`]: the isotropic reduction (theta_i, theta_o, delta_phi) with reciprocity, and the piecewise-linear
//!   interpolant on the measurement grid.
//! - [`hemispherical`]: the directional-hemispherical reflectance of the interpolant over the measured region.
//! - [`export`]: CSV and JSON with units and the run's provenance; [`merl_export`]: the MERL binary
//!   (isotropic data resampled onto the MERL grid, uncovered cells marked -1); [`zemax`]: the BSDF Data
//!   Interchange text of Zemax OpticStudio (about the specular direction, TIS per incidence); [`astm`]: a BRDF
//!   table after ASTM E1392 / E2387; [`rgl`]: the RGL tensor file of Mitsuba 3's and pbrt-v4's `measured`
//!   BSDF. Every export carries [`provenance_summary`] (files named by their SHA-256, from the `sha2` crate).
//! - [`budget`]: a point's uncertainty budget (GUM components in 1/sr, independent or shared by a group) and
//!   its compact text form; [`budget_summary`]: run.json's `uncertainty`, the budgets over a run.
//! - [`fit`]: robust, cosine- and uncertainty-weighted least squares of an analytic model, with parameter
//!   uncertainties, written as a material file.
//! - [`plot`]: SVG plots (plotters): in-plane polar slices, (theta_o, phi_o) heat maps, measurement against model.
//!
//! Dependencies point one way: this crate knows gonio-brdf (geometry, models, materials, the MERL format) and
//! nothing of the daemon; the daemon turns its store's records into this crate's types (its `export` module)
//! and the `gonio` binary hands a [`run::Run`] over.

pub mod angular_class;
pub mod aperture;
pub mod astm;
pub mod band_component;
pub mod budget;
pub mod budget_summary;
pub mod error;
pub mod export;
pub mod fit;
pub mod hemispherical;
pub mod iso;
pub mod merl_export;
pub mod parallel;
pub mod plot;
pub mod points;
pub mod provenance;
pub mod provenance_summary;
pub mod report;
pub mod rgl;
pub mod run;
pub mod sweeps;
pub mod zemax;

pub use error::ResultsError;
pub use run::Run;
