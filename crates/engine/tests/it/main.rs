//! Integration tests of gonio-engine: one test binary (the simulator, the drivers and the store are linked
//! once). `time_scales` is a target of its own: it installs a global tracing subscriber and keeps every core
//! busy on the real clock, which would slow every test beside it.
//!
//! - `align`: the alignment on the simulated realistic instrument (tokio's paused clock).
//! - `align_sample`: alignment on the sample itself on the simulated realistic instrument.
//! - `characterise`: the meter's ranges, the instrument signature and the source's warm-up, on seeds of our own.
//! - `engine`: the engine in process on the simulated instrument under tokio's paused clock.
//! - `layering`: the dependency rules of ARCHITECTURE.md for the engine.
//! - `loaders_fuzz`: the file loaders fed mutated documents.
//! - `motion`: the motion layer on its own (no campaign, no store), as a console will drive it.
//! - `positioning`: values brought from where the axes stopped to the nominal geometry, against the truth.
//! - `relative`: the relative calibration method end to end on the simulated instrument.
//! - `selftest`: the self-test on the simulated instrument.
//! - `stalls`: stall injection in a dry-run.
//! - `sweeps`: sweeps run by the engine: arcs covered, values against the truth, a pause between sweeps.
//! - `timing`: the scheduler's predicted instrument time against a simulator dry-run of the same plan.

mod common;

mod align;
mod align_sample;
mod characterise;
mod engine;
mod follow;
mod layering;
mod loaders_fuzz;
mod motion;
mod positioning;
mod relative;
mod selftest;
mod spectral_probe;
mod stalls;
mod sweeps;
mod timing;
mod uniformity;
