//! Numerical stability stress suite for gonio-brdf (issue 7): every model (the presets, a tabulated model, and
//! randomly parameterised models of every kind with extreme parameters), the conversions, the radiometry and the
//! measurement equation, driven with hostile inputs.
//!
//! Hostile inputs: polar angles exactly 0 and 90 degrees and within 1e-12 rad of them, `wi == wo`,
//! `wi == mirror(wo)`, antipodal directions, directions below the horizon; roughness alpha from 1e-6 to 1
//! (log-uniform, and exactly at the clamp 1e-4 and the delta switch-over 1e-3), anisotropic alphas, albedo exactly
//! 0 and 1, conductor indices with k >> eta (eta 0.05, k 20), Phong exponents 0 to 1e6; aperture half-angles from
//! 1e-6 to 0.5 rad; powers from 1e-15 W to 1 W.
//!
//! Required: no NaN, no Inf, no negative BRDF, exactly 0 below the horizon, reciprocity residual <= 1e-12
//! relative, directional albedo <= 1 + its integration error, reflected power continuous across the alpha clamp
//! and the delta switch-over, conversions round-tripping, and the measurement equation either returning a finite
//! value equal to the simulated truth or refusing with the typed error that names the problem.
//!
//! Two tiers:
//! - fast (default, `cargo test -p gonio-brdf --test stress`): the deterministic hostile grid on every model plus
//!   100,000 random (model, geometry) pairs and a few dozen albedo integrals; a few seconds;
//! - large (`GONIO_STRESS=large cargo test --release -p gonio-brdf --test stress`): 10,000,000 random
//!   (model, geometry) pairs, 40 random models per kind, and albedo integrals for 12 random models per kind
//!   (its run time has not been measured yet on this machine).
//!
//! Failures are collected (the first 20 are printed with their inputs and the count of all), so one run lists
//! every kind of defect at once. The random generator is a fixed-seed SplitMix64: runs are reproducible.
//!
//! One module per contract: the pointwise contract on the hostile grid and random pairs (`pointwise`), energy and
//! the continuity of reflected power (`energy`), Fresnel against complex arithmetic (`fresnel`), direction
//! conversions (`conversions`), solid angles and radiance (`radiometry`), and the measurement equation
//! (`measurement`). The random models are built in `models`; the generator and the failure collector are here.

mod conversions;
mod energy;
mod fresnel;
mod measurement;
mod models;
mod pointwise;
mod radiometry;

use gonio_brdf::{Spectral, Wavelength};

const WL: Wavelength = Wavelength::DEFAULT;

/// Which tier runs: `GONIO_STRESS=large` selects the large one.
fn large() -> bool {
    std::env::var("GONIO_STRESS").is_ok_and(|v| v == "large")
}

/// SplitMix64: a tiny, fixed-seed generator (reproducible, no dependency).
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// Log-uniform in [lo, hi].
    fn log_range(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp().clamp(lo, hi)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    /// One of the given values, or a draw from `f`.
    fn pick(&mut self, special: &[f64], f: impl FnOnce(&mut Rng) -> f64) -> f64 {
        let k = self.below(special.len() + 2);
        if k < special.len() { special[k] } else { f(self) }
    }
}

/// Collects failures; panics at the end with the first few and the count.
#[derive(Default)]
struct Failures {
    count: usize,
    first: Vec<String>,
}

impl Failures {
    fn add(&mut self, what: String) {
        self.count += 1;
        if self.first.len() < 20 {
            self.first.push(what);
        }
    }
    fn assert_none(&self, suite: &str) {
        assert!(
            self.count == 0,
            "{suite}: {} failures; first ones:\n{}",
            self.count,
            self.first.join("\n")
        );
    }
}

fn c(v: f64) -> Spectral {
    Spectral::Constant(v)
}
