//! Gauss-Legendre nodes on [-1, 1], computed by Newton iteration on the Legendre recurrence and cached.

use super::*;

/// One Gauss-Legendre node on [-1, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GaussNode {
    pub x: f64,
    pub weight: f64,
}

const CACHED_ORDERS: usize = 1024;

/// The `n`-point Gauss-Legendre rule on [-1, 1], nodes ascending. Orders up to 1024 are computed once and cached;
/// larger ones are computed on each call. `n = 0` is treated as 1.
pub fn gauss_legendre(n: usize) -> Cow<'static, [GaussNode]> {
    static CACHE: [OnceLock<Box<[GaussNode]>>; CACHED_ORDERS + 1] =
        [const { OnceLock::new() }; CACHED_ORDERS + 1];
    let n = n.max(1);
    match CACHE.get(n) {
        Some(cell) => Cow::Borrowed(&**cell.get_or_init(|| compute_gauss_legendre(n).into_boxed_slice())),
        None => Cow::Owned(compute_gauss_legendre(n)),
    }
}

/// Legendre P_n(x) and P_{n-1}(x) by the three-term recurrence.
fn legendre_pair(n: usize, x: f64) -> (f64, f64) {
    let (mut p_prev, mut p) = (1.0, x);
    for k in 2..=n {
        let kf = k as f64;
        let next = ((2.0 * kf - 1.0) * x * p - (kf - 1.0) * p_prev) / kf;
        p_prev = p;
        p = next;
    }
    (p, p_prev)
}

fn compute_gauss_legendre(n: usize) -> Vec<GaussNode> {
    let nf = n as f64;
    let mut nodes = vec![GaussNode { x: 0.0, weight: 0.0 }; n];
    for i in 0..n.div_ceil(2) {
        // Tricomi's initial guess for the i-th largest root; Newton converges in a few steps from it.
        let mut x = (PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        let mut derivative = 1.0;
        for iteration in 0..100 {
            let (p, p_prev) = legendre_pair(n, x);
            // (1 - x^2) as (1 - x)(1 + x): 1 - x is exact near the end points.
            let one_minus_x2 = (1.0 - x) * (1.0 + x);
            derivative = nf * (p_prev - x * p) / one_minus_x2;
            let dx = p / derivative;
            x -= dx;
            if dx.abs() <= 1e-17 || (iteration > 0 && dx.abs() <= 4.0 * f64::EPSILON * x.abs()) {
                let (p, p_prev) = legendre_pair(n, x);
                derivative = nf * (p_prev - x * p) / ((1.0 - x) * (1.0 + x));
                break;
            }
        }
        let weight = 2.0 / ((1.0 - x) * (1.0 + x) * derivative * derivative);
        nodes[n - 1 - i] = GaussNode { x, weight };
        nodes[i] = GaussNode { x: -x, weight };
    }
    if n % 2 == 1 {
        // The middle root is exactly 0; remove the Newton residue.
        nodes[n / 2].x = 0.0;
    }
    nodes
}
