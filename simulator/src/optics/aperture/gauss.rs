//! Gauss-Legendre nodes and weights, the 1-D rule under the tensor and latitude rules (and the clipped cone's
//! projected solid angle), computed once per order.

use std::f64::consts::PI;
use std::sync::OnceLock;

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
}
