//! The tensor rules for a cone above the horizon and a BRDF smooth across it: Gauss-Legendre in rho times the
//! trapezoid rule in phi (exponentially convergent for a periodic smooth integrand), from the centre rule up,
//! falling back to the adaptive rule when the sequence does not converge.

use std::f64::consts::PI;
use std::sync::OnceLock;

use super::adaptive::adaptive;
use super::gauss::gauss_legendre;
use super::integrand::Integrand;
use super::sequence::converge;
use super::{ApertureFunction, ConeIntegral, Features};

/// The tensor rules: (Gauss-Legendre nodes in rho, trapezoid nodes in phi). Level 0 is the centre rule.
const TENSOR_LEVELS: [(usize, usize); 7] = [(2, 4), (3, 6), (4, 8), (6, 12), (8, 16), (12, 24), (16, 32)];

pub(super) fn tensor<F: ApertureFunction>(
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
