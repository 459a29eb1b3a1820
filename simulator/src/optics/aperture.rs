//! The aperture integral `∫_cone f(wi, w) cos(theta_w) d omega` over the detector's acceptance cone, computed as
//! cheaply as the tolerance allows.
//!
//! The cone has its axis along `wo` (the detector centre) and half-angle `beta = atan(r / d)`. Coordinates about
//! the axis: `w(rho, phi) = cos rho a + sin rho (cos phi e1 + sin phi e2)`, `d omega = sin rho d rho d phi`.
//!
//! Strategies, chosen by [`Plan`], for a cone entirely above the horizon:
//! - `Flat` (the BRDF is constant, e.g. Lambertian): one evaluation times the exact projected solid angle of the
//!   cone, `pi sin^2(beta) cos(theta_o)`.
//! - `Tensor`: a sequence of rules of increasing order, Gauss-Legendre in rho times the trapezoid rule in phi
//!   (exponentially convergent for a periodic smooth integrand), starting from the centre rule when the BRDF varies
//!   slowly on the scale of the aperture. Two successive rules give the error estimate.
//! - `Adaptive`: globally adaptive Genz-Malik cubature (degree 7 with an embedded degree 5 rule) on rectangles of
//!   (rho, phi), for lobes narrower than the aperture and kinks, seeded with a partition refined towards the
//!   lobe's peak ([`Features::peak`]).
//!
//! A cone across the horizon (near-grazing readings) takes the same plan on its part above the horizon only,
//! integrated in latitude coordinates (sigma, tau) in which the horizon is a coordinate line (`Latitude` below):
//! `cos(theta_w)` vanishes linearly there and the integrand is smooth, where the rules in (rho, phi) saw the
//! clamp `max(0, cos theta_w)` as a kink along a curve, and the adaptive rule spent 13,000-27,000 evaluations on
//! it in the benchmark's near-grazing scenes. There:
//! - `Flat`: one evaluation (at a direction above the horizon) times the projected solid angle of the clipped
//!   cone, a 1-D integral of an analytic function by Gauss-Legendre at two orders (their difference is the error
//!   estimate); more accurate than the closed form of the clipped cap, which cancels on thin slivers.
//! - `Tensor`: Gauss-Legendre in sigma times Gauss-Legendre in tau, a sequence of orders as above but guarded
//!   (see below), falling back to `Adaptive` if it does not converge. A lobe narrower than the aperture is
//!   mapped out first (a Cauchy substitution onto its peak in sigma and onto its ridge in azimuth,
//!   [`Peak::across`]), so a smooth model takes this rule whatever its lobe.
//! - `Adaptive`: Genz-Malik on rectangles of (sigma, tau), for kinks other than circles of latitude and
//!   meridians (Oren-Nayar's theta_o = theta_i and cos(phi_o - phi_i) = 0 are coordinate lines, cut exactly:
//!   [`Features::kink_theta`], [`Features::kink_azimuth`]) and tabulated data.
//! - A cone entirely below the horizon gives 0 with no evaluation. (A cone across the horizon that contains the
//!   zenith, half-angle > pi/4, keeps the adaptive rule in (rho, phi).)
//!
//! The error estimate for the tensor sequences (`sequence::converge`): the difference d_k between successive levels
//! measures the error of the coarser one; the finer one is reported with `2 d_k`, more when the differences fall
//! slowly (the rest of a geometric tail). A result is accepted from the second difference on: two coarse rules
//! can agree by chance when both miss the same feature (seen: a plastic lobe's flank, two rules 3.4e-8 apart
//! and both 1.2e-5 off). The exception is a sequence from the centre rule above the horizon, planned for a BRDF
//! smooth on a scale 30 times the aperture's (a diffuse sample): the centre rule's error is second order, which
//! the next rule, exact to degree 3, cannot share, so their difference is the centre rule's error. Only when the differences have fallen steeply twice in a row (steady
//! exponential convergence, as for a smooth lobe) may the acceptance extrapolate to `10 d_k (d_k / d_{k-1})`; a
//! kink in the BRDF (Oren-Nayar has two: at cos(phi_o - phi_i) = 0 and at theta_o = theta_i) makes the
//! differences fall irregularly and can fool any extrapolation from one ratio. The latitude sequence is guarded
//! besides: it never reports less than a tenth of the previous difference. These rules were set against random geometries: 9,000 above the horizon and 14,000 across
//! it, each reading within the tolerance with an estimate that covers its error (tests/it/optics/estimates.rs,
//! tests/it/horizon.rs; the environment variables there widen the search).
//!
//! Where the code is: the cone, the plans and [`integrate`] here; the rules in `tensor.rs` (above the horizon),
//! `across.rs` (across it, in the coordinates of `latitude.rs`) and `adaptive.rs` (Genz-Malik), on the
//! integrand of `integrand.rs`; the sequences' error estimate in `sequence.rs`; the nodes in `gauss.rs`.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::Direction;

mod across;
mod adaptive;
mod gauss;
mod integrand;
mod latitude;
mod sequence;
mod tensor;

use across::across;
use adaptive::adaptive;
pub use gauss::gauss_legendre;
use integrand::{Coordinates, Integrand};
use latitude::Latitude;
use tensor::tensor;

/// How to integrate, decided from what the BRDF is known to look like near the aperture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plan {
    /// The BRDF is constant: one evaluation.
    Flat,
    /// Smooth across the aperture; `start` is the first level of the rule sequence (0 = the coarsest).
    Tensor { start: usize },
    /// A feature narrower than the aperture, or a kink: adaptive cubature, starting from a partition refined
    /// towards the lobe's peak when there is one.
    Adaptive,
}

/// What is known about the BRDF near the aperture, for the rules to adapt to.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Features {
    /// A lobe: the adaptive rule refines towards it; the rules across the horizon also map their coordinates
    /// onto it when it is narrower than the aperture.
    pub peak: Option<Peak>,
    /// A polar angle (rad) where the BRDF has a kink along a whole circle of latitude (Oren-Nayar's
    /// theta_o = theta_i). The rules across the horizon integrate in latitude coordinates, where that circle is a
    /// coordinate line, and cut there, so that each side is smooth. The rules for cones above the horizon ignore
    /// it: the planner sends such a cone with the kink near it to the adaptive rule.
    pub kink_theta: Option<f64>,
    /// An azimuth (rad) where the BRDF has a kink along the vertical plane through the normal (Oren-Nayar's
    /// cos(phi_o - phi_i) = 0). In latitude coordinates that is a meridian: the rules across the horizon cut
    /// each row at it, and cut sigma where it leaves the cone through the rim. Above the horizon the adaptive
    /// rule starts from a partition cut along the plane's trace through the cone.
    pub kink_azimuth: Option<f64>,
}

/// Where a sharp lobe peaks and how wide it is, in outgoing directions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    pub direction: Direction,
    /// Angular width of the lobe about its peak, in the plane of incidence (rad, > 0).
    pub width: f64,
    /// The lobe's angular width across the plane of incidence, for outgoing directions at elevation e:
    /// `across.0 + across.1 sin(e)` (rad, > 0 above the horizon). A lobe symmetric about its peak (Phong):
    /// `(width, 0)`. A microfacet lobe is a function of the half vector, which turns by
    /// `1 / (cos theta_i + cos theta_o)` per unit of out-of-plane angle: `(alpha cos theta_i, alpha)`, about
    /// 0.007 rad near the horizon for alpha 0.08 at 85 degrees incidence, where the in-plane width is still
    /// `2 alpha`.
    pub across: (f64, f64),
}

/// The result of an aperture integral.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConeIntegral {
    /// `∫ f cos d omega` (sr^-1 * sr = dimensionless).
    pub value: f64,
    /// Estimate of the absolute error of `value`.
    pub error: f64,
    /// Number of BRDF evaluations spent.
    pub evaluations: u32,
}

/// The detector's acceptance cone in the sample frame.
#[derive(Debug, Clone, Copy)]
pub struct Cone {
    pub axis: Direction,
    pub half_angle: f64,
    e1: [f64; 3],
    e2: [f64; 3],
}

impl Cone {
    pub fn new(axis: Direction, half_angle: f64) -> Cone {
        let a = [axis.x(), axis.y(), axis.z()];
        // Any unit vector perpendicular to the axis; pick the lab axis least aligned with it.
        let helper = if a[0].abs() <= a[1].abs() && a[0].abs() <= a[2].abs() {
            [1.0, 0.0, 0.0]
        } else if a[1].abs() <= a[2].abs() {
            [0.0, 1.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let e1 = normalize(cross(&a, &helper));
        let e2 = cross(&a, &e1);
        Cone {
            axis,
            half_angle,
            e1,
            e2,
        }
    }

    /// True when every direction of the cone lies strictly above the horizon.
    pub fn above_horizon(&self) -> bool {
        self.axis.theta() + self.half_angle < PI / 2.0
    }

    /// `∫_cone cos(theta) d omega` for a cone above the horizon: `pi sin^2(beta) cos(theta_axis)`
    /// (the integral of w over a cap is `pi sin^2(beta)` times its axis).
    pub fn projected_solid_angle(&self) -> f64 {
        let s = self.half_angle.sin();
        PI * s * s * self.axis.z()
    }

    fn direction(&self, sin_rho: f64, cos_rho: f64, sin_phi: f64, cos_phi: f64) -> [f64; 3] {
        let a = [self.axis.x(), self.axis.y(), self.axis.z()];
        let mut w = [0.0; 3];
        for k in 0..3 {
            w[k] = cos_rho * a[k] + sin_rho * (cos_phi * self.e1[k] + sin_phi * self.e2[k]);
        }
        w
    }
}

fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = v[0].hypot(v[1]).hypot(v[2]);
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Where a cone lies against the horizon.
#[derive(Debug, Clone)]
enum Side {
    /// Every direction strictly above ([`Cone::above_horizon`]).
    Above,
    /// No direction above, or no solid angle (a half-angle that is 0, negative or NaN): the integral is 0.
    Below,
    /// Across the horizon: the part above, in latitude coordinates.
    Across(Box<Latitude>),
    /// Across the horizon with the zenith inside the cone or a half-angle of pi/2 or more, where the latitude
    /// coordinates do not apply (both need a half-angle > pi/4: never a real detector). Integrated the old way:
    /// adaptively in (rho, phi), the horizon a kink.
    Unsupported,
}

impl Cone {
    fn side(&self) -> Side {
        if self.half_angle.is_nan() || self.half_angle <= 0.0 {
            // No width (or no number): no solid angle.
            return Side::Below;
        }
        if self.above_horizon() {
            return Side::Above;
        }
        let beta = self.half_angle;
        // Elevation of the axis above the horizon, exact near 0 (where it matters).
        let elevation = self.axis.z().atan2(self.axis.sin_theta());
        if elevation + beta <= 0.0 {
            return Side::Below;
        }
        if beta >= FRAC_PI_2 || elevation + beta >= FRAC_PI_2 {
            return Side::Unsupported;
        }
        match Latitude::new(beta, elevation, self.axis.phi()) {
            Some(lat) => Side::Across(Box::new(lat)),
            None => Side::Unsupported,
        }
    }
}

/// The integrand's BRDF part; the integrator adds `max(0, cos theta)` and the Jacobian.
pub trait ApertureFunction {
    fn f(&mut self, w: &Direction) -> f64;
}

impl<F: FnMut(&Direction) -> f64> ApertureFunction for F {
    fn f(&mut self, w: &Direction) -> f64 {
        self(w)
    }
}

/// Integrate `f cos` over the cone to relative tolerance `tol` following `plan`.
///
/// A cone entirely above the horizon uses the rules in (rho, phi); one across it, the same plan on its part above
/// the horizon in latitude coordinates; one entirely below gives 0 with no evaluation.
pub fn integrate<F: ApertureFunction>(
    cone: &Cone,
    f: &mut F,
    plan: Plan,
    features: &Features,
    tol: f64,
) -> ConeIntegral {
    let mut it = Integrand {
        cone,
        f,
        evaluations: 0,
        coordinates: Coordinates::Polar,
    };
    match cone.side() {
        Side::Above => match plan {
            Plan::Flat => {
                it.evaluations += 1;
                let fv = it.f.f(&cone.axis);
                let value = fv * cone.projected_solid_angle();
                ConeIntegral {
                    value,
                    error: 4.0 * f64::EPSILON * value.abs(),
                    evaluations: it.evaluations,
                }
            }
            Plan::Tensor { start } => tensor(&mut it, start, tol, features),
            Plan::Adaptive => adaptive(&mut it, tol, features),
        },
        Side::Below => ConeIntegral {
            value: 0.0,
            error: 0.0,
            evaluations: 0,
        },
        Side::Across(lat) => across(&mut it, *lat, plan, features, tol),
        Side::Unsupported => adaptive(&mut it, tol, features),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_brdf_gives_the_projected_solid_angle_with_every_plan() {
        let axis = Direction::from_spherical(0.7, 0.3);
        let cone = Cone::new(axis, 0.2);
        let exact = PI * 0.2f64.sin().powi(2) * 0.7f64.cos();
        for plan in [
            Plan::Flat,
            Plan::Tensor { start: 0 },
            Plan::Tensor { start: 2 },
            Plan::Adaptive,
        ] {
            let r = integrate(&cone, &mut |_: &Direction| 1.0, plan, &Features::default(), 1e-10);
            assert!(
                (r.value - exact).abs() < 1e-10 * exact,
                "{plan:?}: {} vs {exact}",
                r.value
            );
            assert!(r.error <= 1e-10 * exact);
        }
    }

    #[test]
    fn cone_straddling_the_horizon_is_integrated_over_its_part_above() {
        // Constant f = 1 over a cone whose axis is on the horizon: half the cone is below. Axis along x, e1/e2 span
        // y and z: cos theta = sin rho * (component along z), and ∫ max(0, sin rho sin phi') sin rho d rho d phi'
        // = 2 ∫ sin^2 rho d rho = beta - sin(2 beta)/2. Every plan, at two tolerances: the error meets the
        // tolerance, the estimate covers the error, and the horizon costs no refinement: the tensor rules converge
        // at once, the adaptive one refines a smooth integrand (no kink along the horizon to chase).
        let beta: f64 = 0.1;
        let cone = Cone::new(Direction::from_spherical(PI / 2.0, 0.0), beta);
        let exact = beta - (2.0 * beta).sin() / 2.0;
        for tol in [1e-8, 1e-12] {
            for plan in [
                Plan::Flat,
                Plan::Tensor { start: 0 },
                Plan::Tensor { start: 3 },
                Plan::Adaptive,
            ] {
                let r = integrate(&cone, &mut |_: &Direction| 1.0, plan, &Features::default(), tol);
                let err = (r.value - exact).abs();
                assert!(err <= tol * exact, "{plan:?} tol {tol}: {} vs {exact}", r.value);
                assert!(
                    err <= r.error,
                    "{plan:?} tol {tol}: error {err:e} above its estimate {:e}",
                    r.error
                );
                assert!(
                    r.error <= tol * exact,
                    "{plan:?} tol {tol}: estimate {:e}",
                    r.error
                );
                let most = match plan {
                    Plan::Flat => 1,
                    Plan::Tensor { .. } => 600,
                    Plan::Adaptive => 5000,
                };
                assert!(
                    r.evaluations <= most,
                    "{plan:?} tol {tol}: {} evaluations",
                    r.evaluations
                );
            }
        }
    }
}
