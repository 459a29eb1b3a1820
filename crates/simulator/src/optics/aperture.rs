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
//! The error estimate for the tensor sequences ([`converge`]): the difference d_k between successive levels
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
//! it, each reading within the tolerance with an estimate that covers its error (tests/optics.rs,
//! tests/horizon.rs; the environment variables there widen the search).

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::OnceLock;

use gonio_brdf::Direction;

mod latitude;
use latitude::{Latitude, Row};

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

/// The integration variables: (rho, phi) about the axis, or latitude coordinates for the part of a cone above
/// the horizon.
#[derive(Debug, Clone)]
enum Coordinates {
    Polar,
    Latitude(Box<Latitude>),
}

/// Everything an integration needs, counting evaluations.
struct Integrand<'a, F: ApertureFunction> {
    cone: &'a Cone,
    f: &'a mut F,
    evaluations: u32,
    coordinates: Coordinates,
}

impl<F: ApertureFunction> Integrand<'_, F> {
    /// The integrand at (u, v): `f(w) max(0, cos theta_w) sin rho` at (rho, phi), or the latitude integrand at
    /// (v, tau) (sigma = sigma(v)).
    fn at(&mut self, u: f64, v: f64) -> f64 {
        match &self.coordinates {
            Coordinates::Polar => {
                let (sr, cr) = u.sin_cos();
                let (sp, cp) = v.sin_cos();
                self.at_trig(sr, cr, sp, cp)
            }
            Coordinates::Latitude(lat) => {
                let (sigma, jacobian) = lat.sigma(u);
                let row = lat.row(sigma);
                jacobian * row_value(&mut *self.f, &mut self.evaluations, lat, &row, v)
            }
        }
    }

    fn at_trig(&mut self, sr: f64, cr: f64, sp: f64, cp: f64) -> f64 {
        let w = self.cone.direction(sr, cr, sp, cp);
        if w[2] <= 0.0 {
            return 0.0;
        }
        let Some(dir) = Direction::new(w[0], w[1], w[2]) else {
            return 0.0;
        };
        self.evaluations += 1;
        self.f.f(&dir) * dir.z() * sr
    }

    /// The latitude integrand at tau in a row, without the sigma map's Jacobian.
    fn at_row(&mut self, lat: &Latitude, row: &Row, tau: f64) -> f64 {
        row_value(&mut *self.f, &mut self.evaluations, lat, row, tau)
    }
}

/// [`Integrand::at_row`] on the integrand's parts, so that the latitude can be borrowed from the integrand.
fn row_value<F: ApertureFunction>(
    f: &mut F,
    evaluations: &mut u32,
    lat: &Latitude,
    row: &Row,
    tau: f64,
) -> f64 {
    if row.weight <= 0.0 {
        return 0.0;
    }
    match lat.point(row, tau) {
        Some((dir, jacobian)) if dir.z() > 0.0 => {
            *evaluations += 1;
            f.f(&dir) * row.weight * jacobian
        }
        _ => 0.0,
    }
}

/// The tensor rules: (Gauss-Legendre nodes in rho, trapezoid nodes in phi). Level 0 is the centre rule.
const TENSOR_LEVELS: [(usize, usize); 7] = [(2, 4), (3, 6), (4, 8), (6, 12), (8, 16), (12, 24), (16, 32)];

/// Extrapolate only after two successive differences have each fallen by this factor or more: steady
/// exponential convergence. A kink in the BRDF (Oren-Nayar has two) makes the differences fall irregularly, and
/// the estimate then stays with the last difference.
const EXTRAPOLATE_BELOW: f64 = 0.05;

/// Safety factor on a plain difference as the error estimate: the finer rule's error has been seen up to 1.4 times
/// the difference when convergence slows between levels.
const PLAIN: f64 = 2.0;

/// Safety factor on the extrapolated error estimate.
const SAFETY: f64 = 10.0;

/// The guarded sequence (across the horizon) never reports an error below this fraction of the previous
/// difference: no faster convergence than 10 times per level is believed, however the last two agree. At 1/100
/// two coarse rules that agreed by chance got through (a Phong tail 16 degrees from its peak, differences 5.2e-5
/// then 3.0e-7, the last rule 6.3e-7 off), and so did a gold lobe near grazing at the last level, 3.2e-6 off with
/// an estimate of 4.6e-7.
const GUARD: f64 = 0.1;

/// Upper bound on BRDF evaluations for the adaptive rule (about 5 ms of work); the error estimate says how far
/// from the tolerance the result is when it is reached.
const MAX_ADAPTIVE_EVALUATIONS: u32 = 200_000;

/// The latitude rules (module docs): (Gauss-Legendre nodes in sigma per piece, Gauss-Legendre nodes in tau).
/// tau spans at most the aperture's width, sigma the whole shape of the clipped cone (the factors sin(e),
/// sin(sigma) and W are low-order trigonometric polynomials over up to pi), so for a BRDF smooth on the scale of
/// the aperture sigma needs more nodes than tau; a narrower lobe is mapped out first (`Latitude::adapted_to`).
const LATITUDE_LEVELS: [(usize, usize); 8] = [
    (3, 1),
    (4, 2),
    (6, 3),
    (8, 4),
    (12, 6),
    (16, 8),
    (24, 12),
    (32, 16),
];

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

/// The part of the cone above the horizon, in latitude coordinates.
fn across<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    lat: Latitude,
    plan: Plan,
    features: &Features,
    tol: f64,
) -> ConeIntegral {
    if plan == Plan::Flat {
        // The BRDF is constant above the horizon: evaluate it once at a direction strictly above (the middle of
        // the clipped part; the axis itself may be below), times the exact projected solid angle.
        let row = lat.row(0.5 * lat.sigma_max);
        let fv = match lat.point(&row, 0.0) {
            Some((dir, _)) => {
                it.evaluations += 1;
                it.f.f(&dir)
            }
            None => 0.0,
        };
        let (psa, psa_error) = lat.projected_solid_angle();
        return ConeIntegral {
            value: fv * psa,
            error: fv.abs() * psa_error,
            evaluations: it.evaluations,
        };
    }
    let lat = lat.adapted_to(features);
    it.coordinates = Coordinates::Latitude(Box::new(lat));
    match plan {
        Plan::Tensor { start } => {
            let pieces = lat.pieces();
            let rule = |it: &mut Integrand<'_, F>, level: usize| {
                let (n, m) = LATITUDE_LEVELS[level];
                latitude_rule(it, &lat, &pieces, n, m)
            };
            let last = LATITUDE_LEVELS.len() - 1;
            converge(it, start.min(last - 2), last, tol, true, rule)
                .unwrap_or_else(|| adaptive(it, tol, features))
        }
        _ => adaptive(it, tol, features),
    }
}

/// One latitude rule: n Gauss-Legendre nodes in v on each piece times m in tau.
fn latitude_rule<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    lat: &Latitude,
    pieces: &[[f64; 2]],
    n: usize,
    m: usize,
) -> f64 {
    let gv = gauss_legendre(n);
    // Rows cut at tau = 0 take the tau rule on each half, with half the nodes (rounded up).
    let tau_nodes: Vec<(f64, f64)> = if lat.rows_cut() {
        let half = gauss_legendre(m.div_ceil(2));
        [-0.5, 0.5]
            .iter()
            .flat_map(|&c| half.iter().map(move |&(t, w)| (c + 0.5 * t, 0.5 * w)))
            .collect()
    } else {
        gauss_legendre(m).to_vec()
    };
    let mut total = 0.0;
    for &[lo, hi] in pieces {
        let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo));
        let mut sum = 0.0;
        for &(x, w) in gv {
            let (sigma, jacobian) = lat.sigma(mid + half * x);
            let row = lat.row(sigma);
            let mut inner = 0.0;
            for &(t, wt) in &tau_nodes {
                inner += wt * it.at_row(lat, &row, t);
            }
            sum += w * jacobian * inner;
        }
        total += half * sum;
    }
    total
}

fn tensor<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    start: usize,
    tol: f64,
    features: &Features,
) -> ConeIntegral {
    // Level 0 is the centre rule; level k >= 1 is TENSOR_LEVELS[k - 1].
    let rule = |it: &mut Integrand<'_, F>, level: usize| {
        if level == 0 {
            it.evaluations += 1;
            it.f.f(&it.cone.axis) * it.cone.projected_solid_angle()
        } else {
            let (n, m) = TENSOR_LEVELS[level - 1];
            tensor_rule(it, n, m)
        }
    };
    let last = TENSOR_LEVELS.len();
    // The BRDF is not as smooth as the plan assumed: fall back to the adaptive rule.
    converge(it, start.min(last - 2), last, tol, false, rule).unwrap_or_else(|| adaptive(it, tol, features))
}

/// A sequence of rules of increasing order, `rule(it, level)` for level = `first..=last`, until the error
/// estimate from successive levels (module docs) meets the tolerance; None if the last level does not. Needs
/// `last >= first + 2`: a result is accepted from the second difference on (the first, unguarded from the centre
/// rule).
///
/// `guarded`: never report less than `GUARD` times the previous difference. Across the horizon two coarse rules have agreed by chance more closely still (a lobe's
/// ridge under-resolved alike, 1e-8 apart and both 2e-5 off).
fn converge<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    first: usize,
    last: usize,
    tol: f64,
    guarded: bool,
    mut rule: impl FnMut(&mut Integrand<'_, F>, usize) -> f64,
) -> Option<ConeIntegral> {
    let mut prev = rule(it, first);
    // The last two differences, newest first.
    let mut history: [Option<f64>; 2] = [None, None];
    for level in first + 1..=last {
        let value = rule(it, level);
        let d = (value - prev).abs();
        let scale = value.abs();
        let rounding = 64.0 * f64::EPSILON * scale;
        let error = match history {
            // From the centre rule (the BRDF smooth on a scale over 30 times the aperture's), the first
            // difference is the centre rule's second-order error, which the next rule (exact to degree 3)
            // cannot share by chance: it may accept.
            [None, _] if first == 0 && !guarded => (PLAIN * d).max(rounding),
            // Otherwise not before two differences: two rules can agree by chance.
            [None, _] => f64::INFINITY,
            [Some(pd), previous] => {
                let steady = pd > 0.0
                    && d < EXTRAPOLATE_BELOW * pd
                    && previous.is_some_and(|ppd| pd < EXTRAPOLATE_BELOW * ppd);
                // Converging slowly, at a ratio r per level, the rest of a geometric tail is d r / (1 - r):
                // more than d once r > 1/2. Not converging (r >= 1): ten times d, so that only a difference
                // far below the tolerance (rounding noise, typically) is accepted.
                let r = if pd > 0.0 { d / pd } else { 0.0 };
                let tail = if r < 1.0 {
                    (r / (1.0 - r)).clamp(1.0, 10.0)
                } else {
                    10.0
                };
                let plain = PLAIN * d * tail;
                let error = if steady {
                    // The extrapolation decides acceptance; what is reported is never less than the plain
                    // estimate, or the tolerance when that is more: steady convergence has been seen to slow
                    // down (extrapolated 1.3e-12, actual 2.7e-12).
                    (SAFETY * d * (d / pd)).max(plain.min(tol * scale))
                } else {
                    plain
                };
                let floor = if guarded { GUARD } else { 0.0 };
                error.max(floor * pd).max(rounding)
            }
        };
        let all_zero = value == 0.0 && prev == 0.0 && history[0] == Some(0.0);
        if error <= tol * scale || all_zero {
            return Some(ConeIntegral {
                value,
                error: if all_zero { 0.0 } else { error },
                evaluations: it.evaluations,
            });
        }
        prev = value;
        history = [Some(d), history[0]];
    }
    None
}

fn tensor_rule<F: ApertureFunction>(it: &mut Integrand<'_, F>, n: usize, m: usize) -> f64 {
    let beta = it.cone.half_angle;
    let gl = gauss_legendre(n);
    let ring_trig = trapezoid_trig(m);
    let dphi = 2.0 * PI / m as f64;
    let mut sum = 0.0;
    for &(x, w) in gl {
        let rho = 0.5 * beta * (x + 1.0);
        let (sr, cr) = rho.sin_cos();
        let mut ring = 0.0;
        for &(sp, cp) in ring_trig {
            ring += it.at_trig(sr, cr, sp, cp);
        }
        sum += w * ring;
    }
    sum * 0.5 * beta * dphi
}

/// (sin, cos) of the m equally spaced azimuths `2 pi j / m` (m <= 32), computed once.
fn trapezoid_trig(m: usize) -> &'static [(f64, f64)] {
    static TABLES: OnceLock<Vec<Vec<(f64, f64)>>> = OnceLock::new();
    let tables = TABLES.get_or_init(|| {
        (0..=32)
            .map(|m| {
                (0..m)
                    .map(|j| (2.0 * PI * j as f64 / m as f64).sin_cos())
                    .collect()
            })
            .collect()
    });
    tables.get(m).map(Vec::as_slice).unwrap_or(&[])
}

/// A rectangle of (rho, phi) with its Genz-Malik estimate.
#[derive(Debug, Clone, Copy)]
struct Region {
    centre: [f64; 2],
    half: [f64; 2],
    value: f64,
    error: f64,
    split_axis: usize,
}

impl PartialEq for Region {
    fn eq(&self, other: &Self) -> bool {
        self.error.total_cmp(&other.error) == Ordering::Equal
    }
}
impl Eq for Region {}
impl PartialOrd for Region {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Region {
    fn cmp(&self, other: &Self) -> Ordering {
        self.error.total_cmp(&other.error)
    }
}

/// Safety factor on the Genz-Malik estimate |I7 - I5|: on a region cut by a kink (Oren-Nayar's) the degree-7
/// result can be off by more than its difference with the degree-5 one (seen: 1.5 times); on smooth regions the
/// difference already over-estimates the degree-7 error by orders of magnitude, so the factor costs little.
const GM_SAFETY: f64 = 4.0;

// Genz-Malik degree-7 rule with embedded degree-5 rule, in two dimensions (weights sum to 1 on [-1, 1]^2).
const GM_L2: f64 = 0.358_568_582_800_318_1; // sqrt(9/70)
const GM_L3: f64 = 0.948_683_298_050_513_8; // sqrt(9/10)
const GM_L4: f64 = 0.948_683_298_050_513_8; // sqrt(9/10)
const GM_L5: f64 = 0.688_247_201_611_685_3; // sqrt(9/19)
const GM_W7: [f64; 5] = [
    (12824.0 - 9120.0 * 2.0 + 400.0 * 4.0) / 19683.0,
    980.0 / 6561.0,
    (1820.0 - 400.0 * 2.0) / 19683.0,
    200.0 / 19683.0,
    6859.0 / 19683.0 / 4.0,
];
const GM_W5: [f64; 4] = [
    (729.0 - 950.0 * 2.0 + 50.0 * 4.0) / 729.0,
    245.0 / 486.0,
    (265.0 - 100.0 * 2.0) / 1458.0,
    25.0 / 729.0,
];

fn genz_malik<F: ApertureFunction>(it: &mut Integrand<'_, F>, centre: [f64; 2], half: [f64; 2]) -> Region {
    let mut g = |u: f64, v: f64| it.at(centre[0] + u * half[0], centre[1] + v * half[1]);
    let f0 = g(0.0, 0.0);
    let mut s2 = 0.0;
    let mut s3 = 0.0;
    let mut fourth = [0.0; 2];
    for (axis, fourth_axis) in fourth.iter_mut().enumerate() {
        let (a2p, a2m, a3p, a3m) = if axis == 0 {
            (g(GM_L2, 0.0), g(-GM_L2, 0.0), g(GM_L3, 0.0), g(-GM_L3, 0.0))
        } else {
            (g(0.0, GM_L2), g(0.0, -GM_L2), g(0.0, GM_L3), g(0.0, -GM_L3))
        };
        s2 += a2p + a2m;
        s3 += a3p + a3m;
        // Fourth difference along the axis: decides where to split (as in HCubature / Genz-Malik).
        *fourth_axis =
            ((a2p + a2m - 2.0 * f0) - (GM_L2 * GM_L2 / (GM_L3 * GM_L3)) * (a3p + a3m - 2.0 * f0)).abs();
    }
    let s4 = g(GM_L4, GM_L4) + g(GM_L4, -GM_L4) + g(-GM_L4, GM_L4) + g(-GM_L4, -GM_L4);
    let s5 = g(GM_L5, GM_L5) + g(GM_L5, -GM_L5) + g(-GM_L5, GM_L5) + g(-GM_L5, -GM_L5);
    let area = 4.0 * half[0] * half[1];
    let i7 = area * (GM_W7[0] * f0 + GM_W7[1] * s2 + GM_W7[2] * s3 + GM_W7[3] * s4 + GM_W7[4] * s5);
    let i5 = area * (GM_W5[0] * f0 + GM_W5[1] * s2 + GM_W5[2] * s3 + GM_W5[3] * s4);
    let split_axis = if fourth[1] > fourth[0] { 1 } else { 0 };
    Region {
        centre,
        half,
        value: i7,
        error: GM_SAFETY * (i7 - i5).abs(),
        split_axis,
    }
}

fn adaptive<F: ApertureFunction>(it: &mut Integrand<'_, F>, tol: f64, features: &Features) -> ConeIntegral {
    let (u_cuts, v_cuts) = match &it.coordinates {
        Coordinates::Polar => initial_partition(it.cone, features),
        Coordinates::Latitude(lat) => lat.initial_partition(),
    };
    let mut heap = BinaryHeap::with_capacity(4 * u_cuts.len() * v_cuts.len());
    for r in u_cuts.windows(2) {
        for p in v_cuts.windows(2) {
            let centre = [0.5 * (r[0] + r[1]), 0.5 * (p[0] + p[1])];
            let half = [0.5 * (r[1] - r[0]), 0.5 * (p[1] - p[0])];
            heap.push(genz_malik(it, centre, half));
        }
    }
    let mut value: f64 = heap.iter().map(|r| r.value).sum();
    let mut error: f64 = heap.iter().map(|r| r.error).sum();
    loop {
        let rounding = 64.0 * f64::EPSILON * value.abs();
        if error <= (tol * value.abs()).max(rounding) || it.evaluations >= MAX_ADAPTIVE_EVALUATIONS {
            // Re-add from scratch: the running sums drift by rounding over thousands of updates.
            let value: f64 = heap.iter().map(|r| r.value).sum();
            let error: f64 = heap.iter().map(|r| r.error).sum();
            return ConeIntegral {
                value,
                error: error.max(rounding),
                evaluations: it.evaluations,
            };
        }
        let Some(worst) = heap.pop() else {
            return ConeIntegral {
                value: 0.0,
                error: 0.0,
                evaluations: it.evaluations,
            };
        };
        let a = worst.split_axis;
        let mut half = worst.half;
        half[a] *= 0.5;
        let mut c1 = worst.centre;
        let mut c2 = worst.centre;
        c1[a] -= half[a];
        c2[a] += half[a];
        let (r1, r2) = (genz_malik(it, c1, half), genz_malik(it, c2, half));
        value += r1.value + r2.value - worst.value;
        error += r1.error + r2.error - worst.error;
        heap.push(r1);
        heap.push(r2);
    }
}

/// The starting rectangles of the adaptive rule, as cuts in rho (from 0 to beta) and phi (a full turn).
///
/// Without a peak: 2 x 4 rectangles. With a peak at (rho_p, phi_p) of width w: cuts at rho_p +- w 2^k and
/// phi_p +- (w / rho_p) 2^k (k = 0, 1, ...), the partition a lobe-adapted rule would use, so that the rectangles
/// next to the peak are about one width across and the peak sits on their corners: it cannot hide between the
/// sample points of a large rectangle (the classic failure of adaptive cubature on a narrow peak).
fn initial_partition(cone: &Cone, features: &Features) -> (Vec<f64>, Vec<f64>) {
    let beta = cone.half_angle;
    // A kink along a vertical plane (normal p, horizontal) crosses the cone along the azimuths about the axis
    // where `w . p = cos(rho) (a . p) + sin(rho) (cos(phi) e1 . p + sin(phi) e2 . p)` vanishes; when the plane
    // contains the axis (a detector at the zenith, Oren-Nayar's plane always does) these are the two azimuths
    // `atan2(-e1 . p, e2 . p)` and that + pi, exactly, and near them otherwise: cut there.
    let kink_cuts: Vec<f64> = features
        .kink_azimuth
        .filter(|k| k.is_finite())
        .map(|k| {
            let p = [-k.sin(), k.cos(), 0.0];
            let phi = (-dot3(&cone.e1, &p)).atan2(dot3(&cone.e2, &p));
            vec![phi.rem_euclid(2.0 * PI), (phi + PI).rem_euclid(2.0 * PI)]
        })
        .unwrap_or_default();
    let with_kink = |mut cuts: Vec<f64>| {
        cuts.extend(&kink_cuts);
        cuts.sort_by(f64::total_cmp);
        cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12);
        cuts
    };
    let Some(peak) = features.peak.filter(|p| p.width > 0.0 && p.width.is_finite()) else {
        return (
            vec![0.0, 0.5 * beta, beta],
            with_kink((0..=4).map(|j| j as f64 * PI / 2.0).collect()),
        );
    };
    let p = [peak.direction.x(), peak.direction.y(), peak.direction.z()];
    let rho_p = peak.direction.angle_to(&cone.axis);
    let phi_p = (dot3(&p, &cone.e2))
        .atan2(dot3(&p, &cone.e1))
        .rem_euclid(2.0 * PI);
    let w = peak.width;
    let mut rho_cuts = vec![0.0, beta];
    let mut step = w;
    while step < 2.0 * beta {
        for c in [rho_p - step, rho_p + step] {
            if c > 0.0 && c < beta {
                rho_cuts.push(c);
            }
        }
        step *= 2.0;
    }
    if rho_p > 0.0 && rho_p < beta {
        rho_cuts.push(rho_p);
    }
    rho_cuts.sort_by(f64::total_cmp);
    rho_cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12 * beta);
    // Azimuth: geometric cuts about phi_p while they are narrower than a half turn, then a quarter grid.
    let mut phi_offsets = vec![0.0, PI];
    let mut step = w / rho_p.max(w);
    while step < PI {
        phi_offsets.push(step);
        phi_offsets.push(2.0 * PI - step);
        step *= 2.0;
    }
    phi_offsets.push(PI / 2.0);
    phi_offsets.push(3.0 * PI / 2.0);
    let mut phi_cuts: Vec<f64> = phi_offsets
        .iter()
        .map(|o| (phi_p + o).rem_euclid(2.0 * PI))
        .collect();
    phi_cuts.push(0.0);
    phi_cuts.push(2.0 * PI);
    (rho_cuts, with_kink(phi_cuts))
}

fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Gauss-Legendre nodes and weights on [-1, 1] for n points (1 <= n <= 32), computed once by Newton's method on
/// the Legendre recurrence (accurate to a few ulp).
pub fn gauss_legendre(n: usize) -> &'static [(f64, f64)] {
    static TABLES: OnceLock<Vec<Vec<(f64, f64)>>> = OnceLock::new();
    let tables = TABLES.get_or_init(|| (0..=32).map(compute_gauss_legendre).collect());
    tables.get(n.clamp(1, 32)).map(Vec::as_slice).unwrap_or(&[])
}

fn compute_gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        // Initial guess (Tricomi), then Newton.
        let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, d) = legendre(n, x);
            dp = d;
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre(n, x);
        if d != 0.0 {
            dp = d;
        }
        out.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    out
}

/// P_n(x) and P_n'(x).
fn legendre(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    if n == 0 {
        return (1.0, 0.0);
    }
    for k in 2..=n {
        let k = k as f64;
        let p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
        p0 = p1;
        p1 = p2;
    }
    let n = n as f64;
    (p1, n * (x * p1 - p0) / (x * x - 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in [1, 2, 5, 16, 32] {
            let gl = gauss_legendre(n);
            assert_eq!(gl.len(), n);
            for k in 0..2 * n {
                let num: f64 = gl.iter().map(|&(x, w)| w * x.powi(k as i32)).sum();
                let exact = if k % 2 == 1 { 0.0 } else { 2.0 / (k as f64 + 1.0) };
                assert!((num - exact).abs() < 1e-14, "n {n} k {k}: {num} vs {exact}");
            }
        }
    }

    #[test]
    fn genz_malik_weights_integrate_monomials() {
        // Degree 7 rule exact for x^a y^b, a + b <= 7, on [-1, 1]^2 (mean value = weights sum to 1).
        let f = |a: i32, b: i32| move |u: f64, v: f64| u.powi(a) * v.powi(b);
        for a in 0..=7 {
            for b in 0..=(7 - a) {
                let g = f(a, b);
                let pts: Vec<(f64, f64, f64)> = gm_points();
                let num: f64 = pts.iter().map(|&(u, v, w)| w * g(u, v)).sum::<f64>() * 4.0;
                let m = |k: i32| if k % 2 == 1 { 0.0 } else { 2.0 / (k as f64 + 1.0) };
                let exact = m(a) * m(b);
                assert!((num - exact).abs() < 1e-14, "x^{a} y^{b}: {num} vs {exact}");
            }
        }
    }

    fn gm_points() -> Vec<(f64, f64, f64)> {
        let mut p = vec![(0.0, 0.0, GM_W7[0])];
        for s in [1.0, -1.0] {
            p.push((s * GM_L2, 0.0, GM_W7[1]));
            p.push((0.0, s * GM_L2, GM_W7[1]));
            p.push((s * GM_L3, 0.0, GM_W7[2]));
            p.push((0.0, s * GM_L3, GM_W7[2]));
            for t in [1.0, -1.0] {
                p.push((s * GM_L4, t * GM_L4, GM_W7[3]));
                p.push((s * GM_L5, t * GM_L5, GM_W7[4]));
            }
        }
        p
    }

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
