//! A cone across the horizon: the plan carried out on its part above the horizon in latitude coordinates (the
//! constant BRDF by the exact projected solid angle, the guarded sequence of Gauss-Legendre rules in sigma and tau,
//! else the adaptive rule), where `max(0, cos theta)` is no kink.

use super::adaptive::adaptive;
use super::gauss::gauss_legendre;
use super::integrand::{Coordinates, Integrand};
use super::latitude::Latitude;
use super::sequence::converge;
use super::{ApertureFunction, ConeIntegral, Features, Plan};

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

/// The part of the cone above the horizon, in latitude coordinates.
pub(super) fn across<F: ApertureFunction>(
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
