//! Property checks of a BRDF against the physical laws, as library functions: used by the test suites and by
//! `gonio brdf check`.
//!
//! Every check runs over a deterministic set of directions ([`test_directions`]) that includes the pole,
//! directions within 1e-9 rad of the horizon, and, as pairs ([`test_pairs`]), `wi == wo` and `wi` the mirror of
//! `wo`:
//! - reciprocity: max over the pairs of `|f(wi, wo) - f(wo, wi)| / max(|f(wi, wo)|, |f(wo, wi)|)`;
//! - energy: the directional albedo ([`crate::integrate::directional_albedo`]) at incidences from 0 to 89.9 deg
//!   (and several azimuths for anisotropic models) must be <= 1 + its integration error + a small slack;
//! - non-negativity: the smallest value seen; finiteness: the number of non-finite values;
//! - isotropy (only for models that declare it): max relative change under rotations about the normal.

use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;

use crate::brdf::Brdf;
use crate::geometry::Direction;
use crate::integrate::{Estimate, directional_albedo};
use crate::spectrum::{SpectrumError, Wavelength};

/// Tolerances of [`check_brdf`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckOptions {
    pub wavelength: Wavelength,
    /// Largest accepted relative reciprocity residual.
    pub reciprocity_rel_tol: f64,
    /// Accepted excess of the albedo over 1 beyond its integration error.
    pub albedo_slack: f64,
    /// Relative tolerance asked of the albedo integration.
    pub integration_rel_tol: f64,
    /// An albedo whose error estimate exceeds this is reported as unresolved (a failure: energy unverified).
    pub max_albedo_error: f64,
    /// Largest accepted relative change under rotation about the normal (isotropic models only).
    pub isotropy_rel_tol: f64,
}

impl Default for CheckOptions {
    fn default() -> Self {
        CheckOptions {
            wavelength: Wavelength::DEFAULT,
            reciprocity_rel_tol: 1e-9,
            albedo_slack: 1e-6,
            integration_rel_tol: 1e-7,
            max_albedo_error: 1e-4,
            isotropy_rel_tol: 1e-9,
        }
    }
}

/// Incidence polar angles (degrees) at which the albedo is checked.
pub const ALBEDO_THETA_I_DEG: [f64; 13] = [
    0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0, 88.0, 89.0, 89.9,
];

/// The deterministic direction set: the pole, then polar angles from 1e-9 rad to within 1e-9 rad of the horizon
/// at five azimuths.
pub fn test_directions() -> Vec<Direction> {
    let thetas = [
        1e-9,
        0.05,
        0.3,
        0.6,
        0.9,
        1.2,
        1.45,
        FRAC_PI_2 - 1e-3,
        FRAC_PI_2 - 1e-9,
    ];
    let phis = [0.0, 0.9, 2.2, PI, -1.3];
    let mut out = vec![Direction::NORMAL];
    for &t in &thetas {
        for &p in &phis {
            out.push(Direction::from_spherical(t, p));
        }
    }
    out
}

/// Every ordered pair of [`test_directions`] (so `wi == wo` is included), plus each direction with its mirror.
pub fn test_pairs() -> Vec<(Direction, Direction)> {
    let dirs = test_directions();
    let mut pairs = Vec::with_capacity(dirs.len() * (dirs.len() + 1));
    for a in &dirs {
        for b in &dirs {
            pairs.push((*a, *b));
        }
        pairs.push((*a, a.reflect_about_normal()));
    }
    pairs
}

/// The worst relative residual of a comparison, and where.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residual {
    pub max_relative: f64,
    /// The pair (wi, wo) where it occurred.
    pub at: Option<(Direction, Direction)>,
    /// Comparisons made.
    pub count: usize,
}

impl Residual {
    fn new() -> Residual {
        Residual {
            max_relative: 0.0,
            at: None,
            count: 0,
        }
    }

    fn record(&mut self, a: f64, b: f64, at: (Direction, Direction)) {
        self.count += 1;
        if !(a.is_finite() && b.is_finite()) {
            // Counted by the finiteness check; a residual cannot be computed.
            return;
        }
        let scale = a.abs().max(b.abs());
        let r = if scale > 0.0 { (a - b).abs() / scale } else { 0.0 };
        if r > self.max_relative {
            self.max_relative = r;
            self.at = Some(at);
        }
    }
}

/// Max relative reciprocity residual over [`test_pairs`].
pub fn reciprocity_residual(brdf: &dyn Brdf, wavelength: Wavelength) -> Result<Residual, SpectrumError> {
    let mut res = Residual::new();
    for (wi, wo) in test_pairs() {
        let a = brdf.eval(&wi, &wo, wavelength)?;
        let b = brdf.eval(&wo, &wi, wavelength)?;
        res.record(a, b, (wi, wo));
    }
    Ok(res)
}

/// Max relative change of f when both directions are rotated about the normal (a few angles), over
/// [`test_pairs`].
pub fn isotropy_residual(brdf: &dyn Brdf, wavelength: Wavelength) -> Result<Residual, SpectrumError> {
    let mut res = Residual::new();
    for (wi, wo) in test_pairs() {
        let a = brdf.eval(&wi, &wo, wavelength)?;
        for angle in [0.5, 1.7, -2.3, PI] {
            let b = brdf.eval(&wi.rotate_z(angle), &wo.rotate_z(angle), wavelength)?;
            res.record(a, b, (wi, wo));
        }
    }
    Ok(res)
}

/// Smallest value and count of non-finite values over [`test_pairs`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValueScan {
    pub min_value: f64,
    pub min_at: Option<(Direction, Direction)>,
    pub non_finite: usize,
    pub evaluations: usize,
}

pub fn value_scan(brdf: &dyn Brdf, wavelength: Wavelength) -> Result<ValueScan, SpectrumError> {
    let mut scan = ValueScan {
        min_value: f64::INFINITY,
        min_at: None,
        non_finite: 0,
        evaluations: 0,
    };
    for (wi, wo) in test_pairs() {
        let v = brdf.eval(&wi, &wo, wavelength)?;
        scan.evaluations += 1;
        if !v.is_finite() {
            scan.non_finite += 1;
        } else if v < scan.min_value {
            scan.min_value = v;
            scan.min_at = Some((wi, wo));
        }
    }
    Ok(scan)
}

/// Directional albedo at each checked incidence, and the largest.
#[derive(Debug, Clone, PartialEq)]
pub struct AlbedoCheck {
    /// (incidence, albedo) for every incidence checked.
    pub per_incidence: Vec<(Direction, Estimate)>,
    /// The largest albedo (NaN counts as largest) and its incidence.
    pub max: Estimate,
    pub max_at: Direction,
}

/// The albedo at [`ALBEDO_THETA_I_DEG`] (azimuth 0; also 45 and 90 degrees for anisotropic models).
pub fn albedo_check(
    brdf: &dyn Brdf,
    wavelength: Wavelength,
    rel_tol: f64,
) -> Result<AlbedoCheck, SpectrumError> {
    let azimuths: &[f64] = if brdf.is_isotropic() {
        &[0.0]
    } else {
        &[0.0, 45.0, 90.0]
    };
    let mut per_incidence = Vec::new();
    let mut max = Estimate::exact(f64::NEG_INFINITY);
    let mut max_at = Direction::NORMAL;
    for &phi_deg in azimuths {
        for &theta_deg in &ALBEDO_THETA_I_DEG {
            let wi = Direction::from_spherical_deg(theta_deg, phi_deg);
            let a = directional_albedo(brdf, &wi, wavelength, rel_tol)?;
            // A NaN albedo is the worst possible and stays the reported maximum.
            if !max.value.is_nan() && (a.value.is_nan() || a.value > max.value) {
                max = a;
                max_at = wi;
            }
            per_incidence.push((wi, a));
        }
    }
    Ok(AlbedoCheck {
        per_incidence,
        max,
        max_at,
    })
}

/// Everything `gonio brdf check` reports.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckReport {
    pub options: CheckOptions,
    pub reciprocity: Residual,
    pub albedo: AlbedoCheck,
    pub values: ValueScan,
    /// `None` when the model does not declare isotropy.
    pub isotropy: Option<Residual>,
}

/// Runs every check.
pub fn check_brdf(brdf: &dyn Brdf, options: &CheckOptions) -> Result<CheckReport, SpectrumError> {
    let wl = options.wavelength;
    Ok(CheckReport {
        options: *options,
        reciprocity: reciprocity_residual(brdf, wl)?,
        albedo: albedo_check(brdf, wl, options.integration_rel_tol)?,
        values: value_scan(brdf, wl)?,
        isotropy: if brdf.is_isotropic() {
            Some(isotropy_residual(brdf, wl)?)
        } else {
            None
        },
    })
}

impl CheckReport {
    /// The laws found broken, one line each; empty when every check passed.
    pub fn failures(&self) -> Vec<String> {
        let o = &self.options;
        let mut out = Vec::new();
        if self.reciprocity.max_relative > o.reciprocity_rel_tol {
            out.push(format!(
                "reciprocity: relative residual {:.3e} exceeds {:.1e}{}",
                self.reciprocity.max_relative,
                o.reciprocity_rel_tol,
                pair_text(self.reciprocity.at)
            ));
        }
        let max = self.albedo.max;
        if max.value.is_nan() || max.value > 1.0 + o.albedo_slack + max.error {
            out.push(format!(
                "energy: directional albedo {:.9} (+- {:.1e}) exceeds 1 at theta_i = {:.2} deg",
                max.value,
                max.error,
                self.albedo.max_at.theta().to_degrees()
            ));
        }
        if let Some((wi, a)) = self
            .albedo
            .per_incidence
            .iter()
            .find(|(_, a)| a.error.is_nan() || a.error > o.max_albedo_error)
        {
            out.push(format!(
                "energy: albedo at theta_i = {:.2} deg not resolved (error estimate {:.1e} > {:.1e})",
                wi.theta().to_degrees(),
                a.error,
                o.max_albedo_error
            ));
        }
        if self.values.min_value < 0.0 {
            out.push(format!(
                "non-negativity: value {:.6e} 1/sr{}",
                self.values.min_value,
                pair_text(self.values.min_at)
            ));
        }
        if self.values.non_finite > 0 {
            out.push(format!(
                "finiteness: {} non-finite values",
                self.values.non_finite
            ));
        }
        if let Some(iso) = &self.isotropy {
            if iso.max_relative > o.isotropy_rel_tol {
                out.push(format!(
                    "isotropy: declared isotropic but changes by {:.3e} under rotation{}",
                    iso.max_relative,
                    pair_text(iso.at)
                ));
            }
        }
        out
    }

    pub fn passed(&self) -> bool {
        self.failures().is_empty()
    }
}

fn pair_text(pair: Option<(Direction, Direction)>) -> String {
    match pair {
        None => String::new(),
        Some((wi, wo)) => {
            let (ti, pi) = wi.to_spherical_deg();
            let (to, po) = wo.to_spherical_deg();
            format!(" at (theta_i, phi_i, theta_o, phi_o) = ({ti:.9}, {pi:.3}, {to:.9}, {po:.3}) deg")
        }
    }
}

fn verdict(ok: bool) -> &'static str {
    if ok { "ok" } else { "FAIL" }
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let o = &self.options;
        writeln!(f, "BRDF property check at {}", o.wavelength)?;
        let r = &self.reciprocity;
        writeln!(
            f,
            "  reciprocity     max relative residual {:.3e} over {} pairs (limit {:.1e}){}  {}",
            r.max_relative,
            r.count,
            o.reciprocity_rel_tol,
            if r.max_relative > 0.0 {
                pair_text(r.at)
            } else {
                String::new()
            },
            verdict(r.max_relative <= o.reciprocity_rel_tol)
        )?;
        let a = &self.albedo;
        let energy_ok = a.max.value <= 1.0 + o.albedo_slack + a.max.error
            && a.per_incidence.iter().all(|(_, e)| e.error <= o.max_albedo_error);
        writeln!(
            f,
            "  energy          max directional albedo {:.9} (+- {:.1e}) at theta_i = {:.2} deg, phi_i = {:.1} deg (limit 1)  {}",
            a.max.value,
            a.max.error,
            a.max_at.theta().to_degrees(),
            a.max_at.phi().to_degrees(),
            verdict(energy_ok)
        )?;
        write!(f, "                  albedo by theta_i (deg):")?;
        for (wi, e) in &a.per_incidence {
            write!(f, " {:.1}: {:.6}", wi.theta().to_degrees(), e.value)?;
        }
        writeln!(f)?;
        let v = &self.values;
        writeln!(
            f,
            "  non-negativity  min value {:.6e} 1/sr over {} evaluations  {}",
            v.min_value,
            v.evaluations,
            verdict(v.min_value >= 0.0)
        )?;
        writeln!(
            f,
            "  finiteness      {} non-finite values  {}",
            v.non_finite,
            verdict(v.non_finite == 0)
        )?;
        match &self.isotropy {
            Some(iso) => writeln!(
                f,
                "  isotropy        max relative change under rotation {:.3e} (limit {:.1e})  {}",
                iso.max_relative,
                o.isotropy_rel_tol,
                verdict(iso.max_relative <= o.isotropy_rel_tol)
            )?,
            None => writeln!(
                f,
                "  isotropy        not declared (anisotropic model): not checked"
            )?,
        }
        let failures = self.failures();
        if failures.is_empty() {
            write!(f, "result: PASS")
        } else {
            writeln!(f, "result: FAIL")?;
            for (i, line) in failures.iter().enumerate() {
                if i > 0 {
                    writeln!(f)?;
                }
                write!(f, "  - {line}")?;
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f = rho / pi: reciprocal, isotropic, albedo rho.
    #[derive(Debug)]
    struct Constant(f64);
    impl Brdf for Constant {
        fn eval(&self, wi: &Direction, wo: &Direction, _w: Wavelength) -> Result<f64, SpectrumError> {
            Ok(if wi.z() > 0.0 && wo.z() > 0.0 {
                self.0 / PI
            } else {
                0.0
            })
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn is_spectrally_flat(&self) -> bool {
            true
        }
    }

    /// Broken on purpose: not reciprocal (depends on theta_i only), declares isotropy but depends on phi_o,
    /// negative somewhere, NaN at the pole.
    #[derive(Debug)]
    struct Broken;
    impl Brdf for Broken {
        fn eval(&self, wi: &Direction, wo: &Direction, _w: Wavelength) -> Result<f64, SpectrumError> {
            if wi.z() <= 0.0 || wo.z() <= 0.0 {
                return Ok(0.0);
            }
            if wo.sin_theta() == 0.0 {
                return Ok(f64::NAN);
            }
            Ok(wi.z() + 0.5 * wo.x())
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn is_spectrally_flat(&self) -> bool {
            true
        }
    }

    #[test]
    fn direction_set_has_the_special_cases() {
        let dirs = test_directions();
        assert!(dirs.contains(&Direction::NORMAL));
        assert!(
            dirs.iter()
                .any(|d| (FRAC_PI_2 - d.theta()).abs() <= 1.000_001e-9 && d.z() > 0.0)
        );
        let pairs = test_pairs();
        assert!(pairs.iter().any(|(a, b)| a == b && a.theta() > 1.0));
        assert!(
            pairs
                .iter()
                .any(|(a, b)| *b == a.reflect_about_normal() && a.theta() > 1.0)
        );
    }

    #[test]
    fn a_good_brdf_passes() {
        let report = check_brdf(&Constant(0.9), &CheckOptions::default()).expect("flat");
        assert!(report.passed(), "{report}");
        assert!((report.albedo.max.value - 0.9).abs() < 1e-12);
        assert_eq!(report.values.min_value, 0.9 / PI);
        assert!(report.to_string().contains("result: PASS"));
    }

    #[test]
    fn energy_violation_fails_and_says_where() {
        let report = check_brdf(&Constant(1.2), &CheckOptions::default()).expect("flat");
        assert!(!report.passed());
        let failures = report.failures();
        assert_eq!(failures.len(), 1, "{failures:?}");
        assert!(failures[0].starts_with("energy"), "{failures:?}");
        assert!((report.albedo.max.value - 1.2).abs() < 1e-12);
    }

    #[test]
    fn every_broken_law_is_reported() {
        let report = check_brdf(&Broken, &CheckOptions::default()).expect("flat");
        let text = report.failures().join("\n");
        for law in [
            "reciprocity",
            "energy",
            "non-negativity",
            "finiteness",
            "isotropy",
        ] {
            assert!(text.contains(law), "{law} missing from:\n{text}");
        }
        assert!(report.to_string().contains("result: FAIL"));
    }
}
