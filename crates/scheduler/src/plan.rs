//! The `[plan]` table of a campaign file, and the plan it describes: which geometries and bands to measure,
//! what was skipped and why. Ordering and timing are `crate::schedule`'s job.
//!
//! # Schema (all angles in degrees, wavelengths in nm; see `config/campaigns/plan-examples.toml`)
//! ```toml
//! [plan]
//! bands_nm = [450.0, 550.0, 650.0] # bands of the instrument's filter wheel; default: all of them
//! repeats = 1                      # passes over the whole plan (each pass runs the previous one backwards)
//! reciprocity = true               # measure (i, o) OR (o, i), never both; default true
//! rotation_deg = 0.0               # sample rotation held for isotropic samples; default 0
//! sweep_bands_nm = [550.0]         # the bands [[plan.sweeps]] are swept in, among bands_nm; default all
//!
//! [plan.grid]                      # exactly one of [plan.grid] and [plan.adaptive]
//! kind = "isotropic"               # "full" | "isotropic" | "in-plane" | "points"
//! theta_i_deg = { from = 0.0, to = 60.0, step = 15.0 } # a range (both ends included) or a list [0.0, 30.0]
//! theta_o_deg = [0.0, 20.0, 40.0, 60.0]
//! delta_phi_deg = { from = 0.0, to = 180.0, step = 45.0 }
//! # kind = "full":     theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg
//! # kind = "in-plane": theta_i_deg, theta_o_deg (signed: > 0 on the specular side, phi_o = plane + 180;
//! #                    < 0 on the source's side, phi_o = plane), plane_phi_deg (default [0.0])
//! # kind = "points":   points = [[theta_i, phi_i, theta_o, phi_o], ...]
//!
//! [plan.calibration]               # optional; no calibration steps without it
//! dark_every_points = 200          # a dark reading (wheel on its blank) every N measured points...
//! dark_every_s = 1800.0            # ...and/or every T seconds of instrument time; plus one at start and end
//! reference_every_points = 200     # direct-beam readings (every band), same rules
//! reference_every_s = 1800.0
//! reference_pose_deg = { light = -90.0, detector = 90.0 } # axis name -> physical angle; others stay put
//!
//! [plan.adaptive]                  # see crate::adaptive
//! budget_points = 400
//! ```
//! Skips, counted per (geometry, band) so that kept + skipped = requested: `duplicate`, `isotropic` (same
//! theta_i, theta_o, delta_phi as another point of an isotropic sample: absolute phi is never swept),
//! `reciprocity`, `spectrally-flat`, and the constraint names of `crate::constraints`.

//!
//! Parts: `spec` holds the records (the schema as deserialised, the built plan); `grid` expands a
//! `[plan.grid]` into requested geometries; `build` checks bands and calibration against the instrument and
//! reduces and solves the requests into a [`Plan`].

mod build;
mod grid;
mod spec;

pub use build::{
    BuildContext, build, build_from_geometries, calibration, geometry_kind_name, plan_bands, sweep_bands,
};
pub use grid::angle_list;
pub use spec::{
    AdaptiveSpec, Calibration, CalibrationSpec, DEFAULT_DIRECT_BEAM_POSE, FirstPassSweeps, FollowSpec,
    GridKind, GridSpec, Plan, PlanSpec, PlannedGeometry, ReferenceAt, SampleTraits, Served, SweepSpec,
    SweptArm,
};

/// A plan that cannot be built; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("campaign file {origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("[plan{table}] {key}: {message}")]
    Invalid {
        table: String,
        key: String,
        message: String,
    },
}

/// Geometries a grid may enumerate at most. Enumerating, de-duplicating and checking a larger one would take the
/// validation minutes and gigabytes (a denial of service through one submitted file), and a campaign of this size
/// would already run for weeks.
pub const MAX_GRID_GEOMETRIES: usize = 1_000_000;

/// (geometry, band, repeat) readings a plan may hold at most (see [`MAX_GRID_GEOMETRIES`]).
pub const MAX_PLANNED_READINGS: usize = 5_000_000;

/// A [`PlanError::Invalid`] for `[plan.<table>] <key>` (the top-level table when `table` is empty).
fn invalid(table: &str, key: &str, message: impl Into<String>) -> PlanError {
    let table = if table.is_empty() {
        String::new()
    } else {
        format!(".{table}")
    };
    PlanError::Invalid {
        table,
        key: key.to_string(),
        message: message.into(),
    }
}
