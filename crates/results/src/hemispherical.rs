//! The directional-hemispherical reflectance of a measured run: the integral of f(wi, wo) cos(theta_o) over the
//! upper hemisphere of wo, for one incidence, of gonio's interpolant of the run ([`IsoGrid`], no extrapolation).
//!
//! Where the interpolant has no value (outside the measured region, around a hole such as the retro-reflection
//! the arms cannot reach) the integrand is 0: the result is the reflectance *of the measured region*, a lower
//! bound of the sample's, and [`Hemispherical::covered_projected_sr`] says how much of the hemisphere's
//! projected solid angle (pi sr) that region is. A negative interpolated value (noise around a zero signal)
//! counts as 0, as in every export that resamples ([`covered_value`]).
//!
//! Quadrature: [`gonio_brdf::integrate`]'s Gauss-Legendre x trapezoid rule about the normal, doubled until its
//! error estimate (the difference from half the resolution) is below [`REL_TOL`] of the value or the evaluation
//! budget is spent; the estimate is returned with the value. The interpolant is continuous between nodes but
//! stops at the edge of the measured region, where convergence is first order; the estimate stays honest there.

use gonio_brdf::geometry::{Direction, IsotropicAngles};
use gonio_brdf::integrate::{Estimate, Region, Rule, Tolerance, integrate_adaptive};

use crate::iso::IsoGrid;

/// Target relative error of the reflectance.
pub const REL_TOL: f64 = 1e-3;

/// Evaluations the adaptive rule may spend on the reflectance (about a second in an optimised build for the
/// slowest case, normal incidence on a grid with holes) and on the covered projected solid angle, which is only
/// reported (to 1 %).
const BUDGET: usize = 1_000_000;
const COVERAGE_BUDGET: usize = 250_000;

/// The value an export uses at (wi, wo): the interpolant's, clamped at 0 (module doc); `None` where it has none
/// or a direction is at or below the horizon.
pub fn covered_value(grid: &IsoGrid, wi: &Direction, wo: &Direction) -> Option<f64> {
    if !(wi.is_above_horizon() && wo.is_above_horizon()) {
        return None;
    }
    grid.eval(&IsotropicAngles::from_directions(wi, wo))
        .map(|v| v.max(0.0))
}

/// The integrals for one incidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hemispherical {
    /// Directional-hemispherical reflectance over the measured region (dimensionless, 0..1 for a passive sample).
    pub reflectance: Estimate,
    /// Projected solid angle (integral of cos(theta_o) d omega, sr) of the directions where the interpolant has a
    /// value: pi when the whole hemisphere is covered.
    pub covered_projected_sr: Estimate,
}

/// The integrals (module doc) at incidence `theta_i_rad` (the azimuth does not matter: the grid is isotropic).
pub fn directional_hemispherical(grid: &IsoGrid, theta_i_rad: f64) -> Hemispherical {
    let wi = Direction::from_spherical(theta_i_rad, 0.0);
    let rule = Rule::GaussTrapezoid {
        n_radial: 16,
        n_azimuth: 32,
    };
    let region = Region::upper_hemisphere();
    let integral = |indicator: bool| {
        let tolerance = Tolerance {
            rel: if indicator { 1e-2 } else { REL_TOL },
            abs: 1e-12,
            max_evaluations: if indicator { COVERAGE_BUDGET } else { BUDGET },
        };
        let f = |wo: &Direction| -> Result<f64, std::convert::Infallible> {
            let cos = wo.cos_theta();
            Ok(match (covered_value(grid, &wi, wo), indicator) {
                (Some(_), true) => cos,
                (Some(v), false) => v * cos,
                (None, _) => 0.0,
            })
        };
        match integrate_adaptive(f, &region, rule, tolerance) {
            Ok(e) => e,
            Err(never) => match never {},
        }
    };
    Hemispherical {
        reflectance: integral(false),
        covered_projected_sr: integral(true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::iso::IsoPoint;
    use std::f64::consts::PI;

    fn lambertian_grid(albedo: f64, theta_max_deg: f64) -> IsoGrid {
        let mut pts = Vec::new();
        let mut t = 0.0;
        let mut thetas = Vec::new();
        while t <= theta_max_deg + 1e-9 {
            thetas.push(t);
            t += 10.0;
        }
        for &ti in &thetas {
            for &to in &thetas {
                for dp in [0.0, 60.0, 120.0, 180.0] {
                    pts.push(IsoPoint {
                        band_nm: 550.0,
                        angles: IsotropicAngles {
                            theta_i: f64::to_radians(ti),
                            theta_o: f64::to_radians(to),
                            delta_phi: f64::to_radians(dp),
                        },
                        f_sr: albedo / PI,
                        u_sr: None,
                    });
                }
            }
        }
        IsoGrid::build(&pts)
    }

    #[test]
    fn a_lambertian_run_integrates_to_its_albedo_over_the_covered_cap() {
        // Covered up to 80 degrees: the projected solid angle of the cap is pi sin^2(80).
        let g = lambertian_grid(0.6, 80.0);
        for ti in [0.0, 30.0, 60.0] {
            let h = directional_hemispherical(&g, f64::to_radians(ti));
            let cap = PI * f64::to_radians(80.0).sin().powi(2);
            // The coverage is integrated to 1 % only (it is reported, not used).
            assert!(
                (h.covered_projected_sr.value - cap).abs() < 1e-2 * cap,
                "{ti}: {:?} vs {cap}",
                h.covered_projected_sr
            );
            let want = 0.6 * cap / PI;
            assert!(
                (h.reflectance.value - want).abs() < 2e-3 * want,
                "{ti}: {:?} vs {want}",
                h.reflectance
            );
            assert!(h.reflectance.error < 2e-3 * want, "{:?}", h.reflectance);
        }
        // Fully covered (to 90 degrees): the albedo itself.
        let h = directional_hemispherical(&lambertian_grid(0.6, 90.0), 0.5);
        assert!((h.reflectance.value - 0.6).abs() < 1e-3, "{:?}", h.reflectance);
    }
}
