//! Conductor Fresnel reflectance with extreme indices against an independent computation in complex arithmetic.

use gonio_brdf::fresnel;

use super::Failures;

/// Unpolarised Fresnel reflectance of a conductor from complex arithmetic (Snell's law with a complex index),
/// independent of the library's closed form.
fn fresnel_complex(cos_i: f64, eta: f64, k: f64) -> f64 {
    #[derive(Clone, Copy)]
    struct Cx(f64, f64);
    let mul = |a: Cx, b: Cx| Cx(a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
    let div = |a: Cx, b: Cx| {
        let d = b.0 * b.0 + b.1 * b.1;
        Cx((a.0 * b.0 + a.1 * b.1) / d, (a.1 * b.0 - a.0 * b.1) / d)
    };
    let sqrt = |a: Cx| {
        let r = a.0.hypot(a.1);
        let re = ((r + a.0) / 2.0).max(0.0).sqrt();
        let im = ((r - a.0) / 2.0).max(0.0).sqrt().copysign(a.1);
        Cx(re, im)
    };
    let n = Cx(eta, k);
    let n2 = mul(n, n);
    let sin2 = 1.0 - cos_i * cos_i;
    // n cos_t = sqrt(n^2 - sin^2 theta_i).
    let n_cos_t = sqrt(Cx(n2.0 - sin2, n2.1));
    let ci = Cx(cos_i, 0.0);
    let rs = div(Cx(ci.0 - n_cos_t.0, -n_cos_t.1), Cx(ci.0 + n_cos_t.0, n_cos_t.1));
    // rp = (n^2 cos_i - n cos_t) / (n^2 cos_i + n cos_t).
    let n2ci = mul(n2, ci);
    let rp = div(
        Cx(n2ci.0 - n_cos_t.0, n2ci.1 - n_cos_t.1),
        Cx(n2ci.0 + n_cos_t.0, n2ci.1 + n_cos_t.1),
    );
    0.5 * (rs.0 * rs.0 + rs.1 * rs.1 + rp.0 * rp.0 + rp.1 * rp.1)
}

#[test]
fn fresnel_with_extreme_indices_matches_complex_arithmetic() {
    let mut fails = Failures::default();
    for &(eta, k) in &[
        (0.05, 20.0),
        (0.05, 100.0),
        (0.35, 2.714),
        (1.5, 0.0),
        (3.0, 0.01),
        (0.2, 0.0),
    ] {
        for &ci in &[1.0, 1.0 - 1e-12, 0.9, 0.5, 0.1, 1e-3, 1e-6, 1e-12, 0.0] {
            let f = fresnel::conductor(ci, eta, k);
            let g = fresnel_complex(ci, eta, k);
            if !(f.is_finite() && (0.0..=1.0).contains(&f) && (f - g).abs() <= 1e-12 * g.max(1e-300) + 1e-15)
            {
                fails.add(format!("eta {eta} k {k} cos {ci}: {f} vs complex {g}"));
            }
        }
    }
    fails.assert_none("fresnel");
}
