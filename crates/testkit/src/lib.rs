//! gonio-testkit: what gonio's tests share, one copy each. A dev-dependency only, never of a library's normal
//! build.
//!
//! - [`cli`]: the `gonio` binary under test and dry-runs through it; [`daemon`]: `gonio daemon` as a child
//!   process and `gonio ctl` against it; [`sim`]: `gonio sim --link-dir` as a child process, reached as real
//!   hardware is.
//! - [`campaign`]: campaign texts for dry-runs on the simulated instrument.
//! - [`rng`]: a small fixed-seed generator (reproducible random searches, no dependency).
//! - [`directions`]: hostile directions for the numerical stress suites; [`nm`]: a wavelength in a test.
//! - [`load`]: every core kept busy ([`CpuLoad`]), for timing that must hold on a loaded machine.
//! - [`imports`]: the import-loop check of ARCHITECTURE.md's rule ([`imports::import_loops`]), run on the
//!   workspace by tests/it/no_import_loops.rs.
//!
//! The daemon's in-process API set-up is not here: it needs the daemon, whose own tests use it, so it lives in
//! crates/daemon/tests/it/common (one copy for all the daemon's tests).

pub mod campaign;
pub mod cli;
pub mod daemon;
pub mod directions;
pub mod imports;
pub mod load;
pub mod rng;
pub mod sim;

pub use campaign::CampaignText;
pub use cli::{gonio, text};
pub use load::CpuLoad;

/// A wavelength the test knows to be valid, in nm.
pub fn nm(v: f64) -> gonio_brdf::Wavelength {
    gonio_brdf::Wavelength::from_nm(v).expect("valid wavelength")
}
