//! A small Levenberg-Marquardt least-squares solver with box bounds; its linear algebra (the normal equations,
//! the Cholesky factorisation, the solves and the covariance's inverse) is nalgebra's.
//!
//! The iteration itself stays here: the problems have at most a dozen parameters and a few thousand residuals,
//! need box bounds and a residual function that may fail, and the few lines below say exactly what is done.
//!
//! Method (Marquardt 1963, with the scaling of Moré 1978): minimise `sum r_k(x)^2`; each step solves
//! `(J^T J + lambda diag(J^T J)) dx = -J^T r`, is projected onto the bounds, accepted when the cost falls
//! (lambda divided by 3) and refused otherwise (lambda multiplied by 4). The Jacobian is by central differences
//! (one-sided at a bound). Stops when the relative fall of the cost or the relative step is below 1e-12, or
//! after `max_iterations`.

// Dense matrix code reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};

/// What the solver returns.
#[derive(Debug, Clone)]
pub struct Solution {
    pub x: Vec<f64>,
    /// `sum r_k^2` at `x`.
    pub cost: f64,
    pub iterations: usize,
}

/// The residual function: `None` when the model cannot be evaluated at `x` (treated as an infinite cost).
pub trait Residuals {
    fn residuals(&self, x: &[f64]) -> Option<Vec<f64>>;
}

impl<F: Fn(&[f64]) -> Option<Vec<f64>>> Residuals for F {
    fn residuals(&self, x: &[f64]) -> Option<Vec<f64>> {
        self(x)
    }
}

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Central-difference Jacobian (row-major, `n x p`), one-sided where a bound is in the way.
pub fn jacobian(
    f: &dyn Residuals,
    x: &[f64],
    r0: &[f64],
    lower: &[f64],
    upper: &[f64],
) -> Option<Vec<Vec<f64>>> {
    let n = r0.len();
    let p = x.len();
    let mut jac = vec![vec![0.0; p]; n];
    for j in 0..p {
        let h = 1e-6 * x[j].abs().max(1e-3);
        let (lo, hi) = (
            lower.get(j).copied().unwrap_or(f64::NEG_INFINITY),
            upper.get(j).copied().unwrap_or(f64::INFINITY),
        );
        let mut xp = x.to_vec();
        let mut xm = x.to_vec();
        let (rp, rm, span) = if x[j] + h <= hi && x[j] - h >= lo {
            xp[j] += h;
            xm[j] -= h;
            (f.residuals(&xp)?, f.residuals(&xm)?, 2.0 * h)
        } else if x[j] + h <= hi {
            xp[j] += h;
            (f.residuals(&xp)?, r0.to_vec(), h)
        } else {
            xm[j] -= h;
            (r0.to_vec(), f.residuals(&xm)?, h)
        };
        if rp.len() != n || rm.len() != n {
            return None;
        }
        for k in 0..n {
            jac[k][j] = (rp[k] - rm[k]) / span;
        }
    }
    Some(jac)
}

/// Rows of row vectors as a matrix.
fn matrix(rows: &[Vec<f64>]) -> DMatrix<f64> {
    let cols = rows.first().map_or(0, Vec::len);
    DMatrix::from_fn(rows.len(), cols, |i, j| {
        rows[i].get(j).copied().unwrap_or(f64::NAN)
    })
}

/// A matrix as rows of row vectors.
fn rows(m: &DMatrix<f64>) -> Vec<Vec<f64>> {
    (0..m.nrows())
        .map(|i| (0..m.ncols()).map(|j| m[(i, j)]).collect())
        .collect()
}

/// `J^T J` and `J^T r`.
pub fn normal_equations(jac: &[Vec<f64>], r: &[f64]) -> (Vec<Vec<f64>>, Vec<f64>) {
    let j = matrix(jac);
    let r = DVector::from_column_slice(r);
    let a = j.tr_mul(&j);
    let g = j.tr_mul(&r);
    (rows(&a), g.iter().copied().collect())
}

/// The sandwich covariance `A B A` of a weighted least-squares solution: `bread` is `(J^T J)^-1`, and
/// `B = J^T diag(noise) J` with `noise[k]` the variance of residual `k` that the data's own errors give (for
/// residuals `r_k = s_k (m_k - f_k)` with `f_k` of variance `v_k`: `s_k^2 v_k`). When the residuals are
/// standardised by their own errors (`noise` all 1) it is `bread`; when they are weighted otherwise (a cosine
/// weight, a robust weight) it is what their scatter does to the parameters, which `bread` alone is not.
pub fn sandwich(bread: &[Vec<f64>], jac: &[Vec<f64>], noise: &[f64]) -> Vec<Vec<f64>> {
    let a = matrix(bread);
    let j = matrix(jac);
    let d = DMatrix::from_diagonal(&DVector::from_column_slice(noise));
    let b = j.tr_mul(&(d * &j));
    rows(&(&a * b * &a))
}

/// The Cholesky factorisation of a symmetric positive-definite matrix; `None` when it is not numerically so: a
/// pivot below 1e-14 of the largest diagonal element counts as singular (nalgebra's own test only refuses a
/// pivot that is not positive, which lets a rank-deficient normal matrix through with a huge inverse).
fn factor(a: &[Vec<f64>]) -> Option<Cholesky<f64, Dyn>> {
    let m = matrix(a);
    if m.iter().any(|v| !v.is_finite()) || m.nrows() != m.ncols() {
        return None;
    }
    let scale = m.diagonal().iter().map(|v| v.abs()).fold(0.0, f64::max);
    let c = Cholesky::new(m)?;
    let l = c.l_dirty();
    (0..l.nrows())
        .all(|i| l[(i, i)] * l[(i, i)] > 1e-14 * scale)
        .then_some(c)
}

/// Cholesky factor `L` of a symmetric positive-definite matrix (lower triangle; rows of row vectors); `None`
/// when it is not (numerically) positive definite.
pub fn cholesky(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    factor(a).map(|c| rows(&c.l()))
}

/// Solves `L L^T x = b` for a factor from [`cholesky`].
pub fn cholesky_solve(l: &[Vec<f64>], b: &[f64]) -> Vec<f64> {
    let l = matrix(l);
    let mut x = DVector::from_column_slice(b);
    // Forward then back substitution through nalgebra's triangular solvers; a zero pivot leaves NaN, as the
    // division would.
    if !l.solve_lower_triangular_mut(&mut x) || !l.tr_solve_lower_triangular_mut(&mut x) {
        return vec![f64::NAN; b.len()];
    }
    x.iter().copied().collect()
}

/// The inverse of a symmetric positive-definite matrix; `None` when it is singular.
pub fn spd_inverse(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    factor(a).map(|c| rows(&c.inverse()))
}

/// Minimises `sum r(x)^2` from `x0` within `[lower, upper]` (module doc). `None` when the residuals cannot be
/// evaluated at the (projected) start.
pub fn minimise(
    f: &dyn Residuals,
    x0: &[f64],
    lower: &[f64],
    upper: &[f64],
    max_iterations: usize,
) -> Option<Solution> {
    let project = |x: &mut Vec<f64>| {
        for (j, v) in x.iter_mut().enumerate() {
            *v = v.clamp(lower[j], upper[j]);
        }
    };
    let mut x = x0.to_vec();
    project(&mut x);
    let mut r = f.residuals(&x)?;
    let mut c = cost(&r);
    // No residual: nothing to minimise (and no Jacobian to build the normal equations from).
    if !c.is_finite() || r.is_empty() {
        return None;
    }
    let mut lambda = 1e-3;
    let mut iterations = 0;
    'outer: while iterations < max_iterations {
        iterations += 1;
        let Some(jac) = jacobian(f, &x, &r, lower, upper) else {
            break;
        };
        let (a, g) = normal_equations(&jac, &r);
        let p = x.len();
        let diag_max = (0..p).map(|i| a[i][i]).fold(0.0, f64::max);
        if diag_max <= 0.0 || !diag_max.is_finite() {
            break;
        }
        loop {
            let mut damped = a.clone();
            for (i, row) in damped.iter_mut().enumerate() {
                row[i] += lambda * a[i][i].max(1e-12 * diag_max);
            }
            let step =
                cholesky(&damped).map(|l| cholesky_solve(&l, &g.iter().map(|v| -v).collect::<Vec<_>>()));
            if let Some(step) = step {
                let mut trial: Vec<f64> = x.iter().zip(&step).map(|(a, b)| a + b).collect();
                project(&mut trial);
                if let Some(rt) = f.residuals(&trial) {
                    let ct = cost(&rt);
                    if ct.is_finite() && ct < c {
                        let moved = trial
                            .iter()
                            .zip(&x)
                            .map(|(a, b)| (a - b).abs() / b.abs().max(1e-3))
                            .fold(0.0, f64::max);
                        let fell = (c - ct) / c.max(f64::MIN_POSITIVE);
                        x = trial;
                        r = rt;
                        c = ct;
                        lambda = (lambda / 3.0).max(1e-12);
                        if fell < 1e-12 || moved < 1e-12 {
                            break 'outer;
                        }
                        continue 'outer;
                    }
                }
            }
            lambda *= 4.0;
            if lambda > 1e14 {
                break 'outer;
            }
        }
    }
    Some(Solution {
        x,
        cost: c,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_sandwich_is_the_weighted_means_own_variance() {
        // One parameter, the mean of f_k, fitted with weights s_k: r_k = s_k (x - f_k), f_k of variance v_k.
        // Its variance is sum s^4 v / (sum s^2)^2; (J^T J)^-1 alone says 1 / sum s^2.
        let (s, v) = ([1.0, 0.5, 0.2, 0.9], [1.0, 4.0, 0.25, 2.0]);
        let jac: Vec<Vec<f64>> = s.iter().map(|s| vec![*s]).collect();
        let s2: f64 = s.iter().map(|s| s * s).sum();
        let bread = vec![vec![1.0 / s2]];
        let noise: Vec<f64> = s.iter().zip(&v).map(|(s, v)| s * s * v).collect();
        let got = super::sandwich(&bread, &jac, &noise)[0][0];
        let want = s.iter().zip(&v).map(|(s, v)| s.powi(4) * v).sum::<f64>() / (s2 * s2);
        assert!((got / want - 1.0).abs() < 1e-12, "{got} vs {want}");
        // Residuals standardised by their errors: the bread.
        let unit = vec![1.0; s.len()];
        assert!((super::sandwich(&bread, &jac, &unit)[0][0] - 1.0 / s2).abs() < 1e-15);
    }

    use super::*;

    #[test]
    fn fits_an_exponential_decay_exactly() {
        // y = 2.5 exp(-1.3 t) + 0.5 sampled without noise: the minimum is the generating parameters.
        let ts: Vec<f64> = (0..30).map(|i| i as f64 * 0.1).collect();
        let ys: Vec<f64> = ts.iter().map(|t| 2.5 * (-1.3 * t).exp() + 0.5).collect();
        let f = |x: &[f64]| -> Option<Vec<f64>> {
            Some(
                ts.iter()
                    .zip(&ys)
                    .map(|(t, y)| x[0] * (-x[1] * t).exp() + x[2] - y)
                    .collect(),
            )
        };
        let s = minimise(&f, &[1.0, 0.5, 0.0], &[0.0, 0.0, -10.0], &[10.0, 10.0, 10.0], 200).expect("solves");
        assert!(
            (s.x[0] - 2.5).abs() < 1e-7 && (s.x[1] - 1.3).abs() < 1e-7 && (s.x[2] - 0.5).abs() < 1e-7,
            "{:?}",
            s.x
        );
        assert!(s.cost < 1e-20, "{}", s.cost);
    }

    #[test]
    fn respects_bounds() {
        // Minimum of (x - 3)^2 under x <= 2 is at the bound.
        let f = |x: &[f64]| -> Option<Vec<f64>> { Some(vec![x[0] - 3.0]) };
        let s = minimise(&f, &[0.0], &[0.0], &[2.0], 100).expect("solves");
        assert_eq!(s.x[0], 2.0);
    }

    #[test]
    fn inverse_of_a_known_matrix() {
        let a = vec![vec![4.0, 2.0], vec![2.0, 3.0]];
        let inv = spd_inverse(&a).expect("spd");
        // inverse = 1/8 [[3, -2], [-2, 4]]
        for (got, want) in [
            (inv[0][0], 0.375),
            (inv[0][1], -0.25),
            (inv[1][0], -0.25),
            (inv[1][1], 0.5),
        ] {
            assert!((got - want).abs() < 1e-15, "{got} vs {want}");
        }
        assert!(spd_inverse(&[vec![1.0, 1.0], vec![1.0, 1.0]]).is_none());
    }

    #[test]
    fn cholesky_solves_and_refuses_what_is_not_positive_definite() {
        // A = [[4, 2, 0], [2, 5, 1], [0, 1, 3]], x = [1, -2, 3]: b = A x = [0, -5, 7].
        let a = vec![vec![4.0, 2.0, 0.0], vec![2.0, 5.0, 1.0], vec![0.0, 1.0, 3.0]];
        let l = cholesky(&a).expect("spd");
        assert_eq!(l[0][1], 0.0, "a lower triangle");
        let x = cholesky_solve(&l, &[0.0, -5.0, 7.0]);
        for (got, want) in x.iter().zip([1.0, -2.0, 3.0]) {
            assert!((got - want).abs() < 1e-14, "{x:?}");
        }
        // Indefinite, numerically singular (a pivot of 1e-16 against a diagonal of 1), and not finite.
        assert!(cholesky(&[vec![1.0, 2.0], vec![2.0, 1.0]]).is_none());
        assert!(cholesky(&[vec![1.0, 1.0], vec![1.0, 1.0 + 1e-16]]).is_none());
        assert!(cholesky(&[vec![f64::NAN]]).is_none());
        // J^T J and J^T r of a 3 x 2 Jacobian.
        let (n, g) = normal_equations(
            &[vec![1.0, 2.0], vec![3.0, 4.0], vec![5.0, 6.0]],
            &[1.0, 0.0, -1.0],
        );
        assert_eq!(n, vec![vec![35.0, 44.0], vec![44.0, 56.0]]);
        assert_eq!(g, vec![-4.0, -4.0]);
    }
}
