//! gonio-scheduler: which incident/outgoing geometries a campaign measures, and in what order.
//!
//! Pure computation: an instrument and a campaign's `[plan]` in, an ordered, validated list of steps out (and,
//! for adaptive plans, the next batch given the points measured so far). No I/O, no async.
//!
//! Module map:
//! - [`kinematics`]: sample-frame geometry ([`kinematics::Geometry`]) <-> physical axis angles
//!   ([`kinematics::Pose`]) for the reference and in-plane geometries; every axis solution.
//! - [`constraints`]: the rules that remove a point, each with a name ([`constraints::Reason`]).
//! - [`timing`]: the motion-time model (trapezoidal profiles, backlash, settle, wheel, readings) and the
//!   move planner the daemon executes ([`timing::TimeModel::plan_move`]).
//! - [`plan`]: the `[plan]` schema, grids, and the reductions (isotropy, reciprocity, flat bands, constraints)
//!   with skip counts by reason.
//! - [`order`]: the visiting order (constructive heuristics + 2-opt/Or-opt) and a provable lower bound.
//! - [`separation`]: parting arms that start closer than the safety separation (power-up).
//! - [`schedule`]: the ordered steps (measure, dark, reference) with predicted times and the raster comparison.
//! - [`adaptive`]: adaptive plans, batch by batch.
//! - [`sweep`]: sweeps (one arm turning while the meter reads): the swept paths checked, ordered and timed.
//!
//! Units: degrees at this crate's edges (`_deg`: plans, poses, CSV), radians only inside direction maths;
//! seconds (`_s`), millimetres (`_mm`), nanometres (`_nm`).

pub mod adaptive;
pub mod constraints;
pub mod kinematics;
pub mod order;
pub mod plan;
pub mod schedule;
pub mod separation;
pub mod sweep;
pub mod timing;
