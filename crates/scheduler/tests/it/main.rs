//! Integration tests of gonio-scheduler: one test binary.
//!
//! - `adaptive`: adaptive plans against a uniform grid of the same size, reconstructed with the same
//!   interpolation and compared with a dense reference.
//! - `adaptive_first_pass`: `first_pass_theta_i_deg` of `[plan.adaptive]`.
//! - `closing`: how a schedule ends: the closing calibration of a campaign placed pass by pass, and the order
//!   that ends where that closing moves least.
//! - `kinematics_and_moves`: kinematics round trips, constraint checks and the move planner, against
//!   independent expectations.
//! - `plans_and_order`: plans, schedules (constraints on every point and move), ordering against raster order
//!   and a brute-force optimum, and the lower bound.
//! - `sweeps`: sweeps in the plan: swept paths against every rule, their time model, their errors.
//! - `stress`: the numerical stability stress suite for the kinematics (`cargo test -p gonio-scheduler --test
//!   it stress`).

mod common;

mod adaptive;
mod adaptive_first_pass;
mod closing;
mod follow;
mod kinematics_and_moves;
mod plans_and_order;
mod stress;
mod sweeps;
