//! Fresnel reflectance of a smooth interface, unpolarised, exactly as written in
//! shared/reference/radiometry-and-materials.md ("Models"): a conductor with complex index `eta + i k`, and a
//! dielectric with real relative index `eta`.
//!
//! Every function takes the cosine of the angle of incidence measured from the interface normal; its sign is
//! ignored (light is assumed to arrive from the outside medium) and it is clamped to [0, 1] so that a cosine a
//! rounding error above 1 cannot produce a NaN. At grazing incidence (cos = 0) every interface reflects
//! everything: the functions return exactly 1 there.

/// Unpolarised reflectance of a conductor (complex relative index `eta + i k`) for light arriving at
/// `cos_theta` from the normal.
///
/// With `c = cos(theta)`, `s2 = 1 - c^2`:
/// `a2b2 = sqrt((eta^2 - k^2 - s2)^2 + 4 eta^2 k^2)`, `a = sqrt((a2b2 + eta^2 - k^2 - s2) / 2)`,
/// `Rs = (a2b2 + c^2 - 2 a c) / (a2b2 + c^2 + 2 a c)`,
/// `Rp = Rs (c^2 a2b2 + s2^2 - 2 a c s2) / (c^2 a2b2 + s2^2 + 2 a c s2)`, `F = (Rs + Rp) / 2`.
/// A vanishing denominator only happens for a degenerate index (eta = k = 0, or an index-matched interface at
/// grazing incidence); the limit of total reflection (1) is returned there instead of 0/0.
pub fn conductor(cos_theta: f64, eta: f64, k: f64) -> f64 {
    if let Some((num, den)) = conductor_ratio(cos_theta, eta, k) {
        return (num / den).clamp(0.0, 1.0);
    }
    // A vanishing denominator: the ratios one by one, with the limits.
    let c = cos_theta.abs().min(1.0);
    let c2 = c * c;
    let s2 = (1.0 - c2).max(0.0);
    let eta2 = eta * eta;
    let k2 = k * k;
    let t0 = eta2 - k2 - s2;
    let a2b2 = (t0 * t0 + 4.0 * eta2 * k2).sqrt();
    let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
    let two_ac = 2.0 * a * c;
    let rs_num = a2b2 + c2 - two_ac;
    let rs_den = a2b2 + c2 + two_ac;
    let rp_base = c2 * a2b2 + s2 * s2;
    let rp_odd = two_ac * s2;
    let rp_den = rp_base + rp_odd;
    let rs = if rs_den > 0.0 {
        (rs_num / rs_den).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let rp = if rp_den > 0.0 {
        rs * ((rp_base - rp_odd) / rp_den).clamp(0.0, 1.0)
    } else {
        rs
    };
    0.5 * (rs + rp)
}

/// [`conductor`] as a ratio `(num, den)` with `den > 0`, or `None` for the degenerate indices where a
/// denominator vanishes (then use [`conductor`]). `(Rs + Rp) / 2 = Rs (1 + Rp/Rs) / 2 = Rs rp_base / rp_den`:
/// one division instead of two, which the rough conductor folds into its lobe's division (the hot path of every
/// conductor evaluation; the same value up to rounding, never clamped: `num` may round a hair below 0 where the
/// reflectance is 0).
pub(crate) fn conductor_ratio(cos_theta: f64, eta: f64, k: f64) -> Option<(f64, f64)> {
    let c = cos_theta.abs().min(1.0);
    let c2 = c * c;
    // 1 - c^2 loses digits near the pole, where it is tiny and only matters relative to O(1) terms: harmless.
    let s2 = (1.0 - c2).max(0.0);
    let eta2 = eta * eta;
    let k2 = k * k;
    let t0 = eta2 - k2 - s2;
    let a2b2 = (t0 * t0 + 4.0 * eta2 * k2).sqrt();
    let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
    let two_ac = 2.0 * a * c;
    let rs_den = a2b2 + c2 + two_ac;
    let rp_base = c2 * a2b2 + s2 * s2;
    let rp_den = rp_base + two_ac * s2;
    (rs_den > 0.0 && rp_den > 0.0).then_some(((a2b2 + c2 - two_ac) * rp_base, rs_den * rp_den))
}

/// Unpolarised reflectance of a dielectric interface with relative index `eta` (transmitted over incident
/// medium) for light arriving at `cos_theta` from the normal.
///
/// `g^2 = eta^2 - 1 + c^2`; negative means total internal reflection (returns 1);
/// `F = 0.5 ((g - c)/(g + c))^2 (1 + ((c (g + c) - 1)/(c (g - c) + 1))^2)`.
pub fn dielectric(cos_theta: f64, eta: f64) -> f64 {
    let c = cos_theta.abs().min(1.0);
    let g2 = eta * eta - 1.0 + c * c;
    if g2 < 0.0 {
        return 1.0;
    }
    let g = g2.sqrt();
    let sum = g + c;
    if sum <= 0.0 {
        // Index-matched interface (eta = 1) at exactly grazing incidence: 0/0; the grazing limit is 1.
        return 1.0;
    }
    let t1 = (g - c) / sum;
    let den = c * (g - c) + 1.0;
    if den <= 0.0 {
        // Only for eta = 0, which no caller validates as a material; total reflection is the limit.
        return 1.0;
    }
    let t2 = (c * sum - 1.0) / den;
    (0.5 * t1 * t1 * (1.0 + t2 * t2)).clamp(0.0, 1.0)
}

/// Normal-incidence reflectance of a conductor: `((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2)`.
pub fn r0_conductor(eta: f64, k: f64) -> f64 {
    let k2 = k * k;
    ((eta - 1.0) * (eta - 1.0) + k2) / ((eta + 1.0) * (eta + 1.0) + k2)
}

/// Normal-incidence reflectance of a dielectric: `((eta - 1)/(eta + 1))^2`.
pub fn r0_dielectric(eta: f64) -> f64 {
    let r = (eta - 1.0) / (eta + 1.0);
    r * r
}

/// Hemispherical-cosine average of the dielectric reflectance, `2 * integral_0^1 F(c) c dc` (light arriving
/// uniformly in radiance from the outside). Used to normalise diffuse terms under a coat.
///
/// Computed with 64-point Gauss-Legendre on [0, 1]; the integrand is smooth for eta >= 1 (g stays >= c),
/// so the rule is accurate to ~1e-12 there.
pub fn dielectric_hemispherical_average(eta: f64) -> f64 {
    let mut sum = 0.0;
    for &(x, w) in gauss_legendre_64().iter() {
        // Map [-1, 1] to [0, 1].
        let c = 0.5 * (x + 1.0);
        sum += 0.5 * w * dielectric(c, eta) * c;
    }
    (2.0 * sum).clamp(0.0, 1.0)
}

/// Nodes and weights of the 64-point Gauss-Legendre rule on [-1, 1], computed once by Newton iteration on
/// the Legendre polynomial (each node converges to full precision in a few steps).
fn gauss_legendre_64() -> &'static [(f64, f64); 64] {
    static RULE: std::sync::OnceLock<[(f64, f64); 64]> = std::sync::OnceLock::new();
    RULE.get_or_init(|| {
        const N: usize = 64;
        let mut rule = [(0.0, 0.0); N];
        for (i, slot) in rule.iter_mut().enumerate() {
            // Tricomi's initial guess for the i-th root.
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (N as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (p, d) = legendre_and_derivative(N, x);
                dp = d;
                let dx = p / d;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            let (_, d) = legendre_and_derivative(N, x);
            if d.is_finite() {
                dp = d;
            }
            *slot = (x, 2.0 / ((1.0 - x * x) * dp * dp));
        }
        rule
    })
}

/// P_n(x) and P_n'(x) by the three-term recurrence.
fn legendre_and_derivative(n: usize, x: f64) -> (f64, f64) {
    let mut p0 = 1.0;
    let mut p1 = x;
    for j in 2..=n {
        let jf = j as f64;
        let p2 = ((2.0 * jf - 1.0) * x * p1 - (jf - 1.0) * p0) / jf;
        p0 = p1;
        p1 = p2;
    }
    let d = n as f64 * (x * p1 - p0) / (x * x - 1.0);
    (p1, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-division form of `conductor` against Rs and Rp computed separately, as written in the reference.
    #[test]
    fn conductor_matches_the_two_ratio_form() {
        let mut worst: f64 = 0.0;
        for &(eta, k) in &[
            (0.35, 2.714),
            (1.5, 0.0),
            (0.959, 6.687),
            (2.0, 0.5),
            (0.2, 3.0),
            (1.0, 0.0),
        ] {
            for i in 0..=1000 {
                let c = f64::from(i) / 1000.0;
                let (c2, s2) = (c * c, 1.0 - c * c);
                let t0 = eta * eta - k * k - s2;
                let a2b2 = (t0 * t0 + 4.0 * eta * eta * k * k).sqrt();
                let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
                let rs = (a2b2 + c2 - 2.0 * a * c) / (a2b2 + c2 + 2.0 * a * c);
                let rp =
                    rs * (c2 * a2b2 + s2 * s2 - 2.0 * a * c * s2) / (c2 * a2b2 + s2 * s2 + 2.0 * a * c * s2);
                let expect = 0.5 * (rs + rp);
                let got = conductor(c, eta, k);
                if expect.is_finite() {
                    worst = worst.max((got - expect).abs());
                }
            }
        }
        assert!(worst <= 1e-15, "largest difference {worst:e}");
    }

    #[test]
    fn normal_incidence_matches_r0() {
        for &(eta, k) in &[(0.35, 2.714), (1.5, 0.0), (0.959, 6.687), (2.0, 0.5)] {
            let f = conductor(1.0, eta, k);
            assert!((f - r0_conductor(eta, k)).abs() < 1e-14, "eta {eta} k {k}: {f}");
        }
        assert!((dielectric(1.0, 1.5) - 0.04).abs() < 1e-15);
        assert!((r0_dielectric(1.5) - 0.04).abs() < 1e-15);
    }

    #[test]
    fn conductor_with_zero_k_is_the_dielectric() {
        for i in 0..=20 {
            let c = i as f64 / 20.0;
            let a = conductor(c, 1.5, 0.0);
            let b = dielectric(c, 1.5);
            assert!((a - b).abs() < 1e-14, "c {c}: {a} vs {b}");
        }
    }

    #[test]
    fn grazing_reflects_everything() {
        assert_eq!(conductor(0.0, 0.35, 2.714), 1.0);
        assert_eq!(dielectric(0.0, 1.5), 1.0);
        assert_eq!(dielectric(0.0, 1.0), 1.0);
        // Degenerate indices stay finite.
        assert!(conductor(1.0, 0.0, 0.0).is_finite());
        assert!(conductor(0.0, 1.0, 0.0).is_finite());
    }

    #[test]
    fn total_internal_reflection_from_the_dense_side() {
        // Inside glass looking out: relative index 1/1.5, critical angle asin(1/1.5) = 41.8 degrees.
        assert_eq!(dielectric(0.5, 1.0 / 1.5), 1.0);
        assert!(dielectric(0.9, 1.0 / 1.5) < 1.0);
    }

    #[test]
    fn brewster_angle_zeroes_p_polarisation() {
        // At Brewster's angle Rp = 0, so F = Rs/2 = 0.5 ((n^2-1)/(n^2+1))^2 for n = 1.5.
        let n: f64 = 1.5;
        let c = 1.0 / (1.0 + n * n).sqrt();
        let rs = ((n * n - 1.0) / (n * n + 1.0)).powi(2);
        assert!((dielectric(c, n) - 0.5 * rs).abs() < 1e-14);
    }

    #[test]
    fn hemispherical_average_of_glass() {
        // Known value for n = 1.5: about 0.0918 (e.g. tabulated diffuse Fresnel reflectance of glass).
        let fbar = dielectric_hemispherical_average(1.5);
        assert!((fbar - 0.0918).abs() < 5e-4, "{fbar}");
        // The rule integrates 2 c (i.e. F = 1) to 1 exactly: check via the node weights.
        let s: f64 = gauss_legendre_64().iter().map(|&(_, w)| w).sum();
        assert!((s - 2.0).abs() < 1e-13);
    }
}
