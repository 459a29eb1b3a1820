//! The `gonio` binary end to end: one test binary, each test running the command line as a user would (the
//! binary built by Cargo, `CARGO_BIN_EXE_gonio`), through gonio-testkit.
//!
//! - `align`: `gonio align` on the simulated instruments, standard input closed (the simulated operator does
//!   the operator's steps).
//! - `brdf_check`, `brdf_eval`: `gonio brdf check` and `gonio brdf eval`.
//! - `console`: `gonio ctl`'s console commands against a running `gonio daemon` on the simulated instrument.
//! - `ctl_align`: `gonio ctl align` and `gonio ctl calibrations` against a running daemon on the realistic
//!   simulated instrument.
//! - `daemon`: `gonio daemon` and `gonio ctl`.
//! - `devices`: `gonio devices`.
//! - `export`, `export_formats`, `export_rgl`: `gonio export`, to the formats of other communities checked from
//!   the outside.
//! - `first_run`: a quiet first run.
//! - `fit`: `gonio fit`.
//! - `imperfect`: the realistic simulated instrument (config/instruments/realistic.toml).
//! - `plan`: `gonio plan`.
//! - `plot`: `gonio plot`, and `gonio report` (`plot::report`, sharing its dry-run).
//! - `run`: `gonio run` on the simulated instrument.
//! - `selftest`: `gonio selftest` on the simulated instrument.
//! - `sim_pty`: `gonio sim` and dry-runs through pseudo-terminals.

mod align;
mod brdf_check;
mod brdf_eval;
mod console;
mod ctl_align;
mod daemon;
mod devices;
mod export;
mod export_formats;
mod export_rgl;
mod first_run;
mod fit;
mod imperfect;
mod plan;
mod plot;
mod run;
mod selftest;
mod sim_pty;
