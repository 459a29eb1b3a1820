use super::*;

fn hemisphere_rules() -> Vec<(Region, Rule)> {
    let tilted = Direction::from_spherical(1.1, 0.4);
    let grazing = Direction::from_spherical(FRAC_PI_2 - 1e-3, -2.0);
    vec![
        (
            Region::upper_hemisphere(),
            Rule::GaussTrapezoid {
                n_radial: 16,
                n_azimuth: 32,
            },
        ),
        (
            Region::upper_hemisphere_about(Direction::NORMAL),
            Rule::LobeAdapted {
                lobe_width_rad: 0.01,
                n_per_panel: 16,
                n_azimuth: 32,
            },
        ),
        (
            Region::upper_hemisphere_about(tilted),
            Rule::GaussTrapezoid {
                n_radial: 24,
                n_azimuth: 48,
            },
        ),
        (
            Region::upper_hemisphere_about(tilted),
            Rule::LobeAdapted {
                lobe_width_rad: 0.05,
                n_per_panel: 24,
                n_azimuth: 48,
            },
        ),
        (
            Region::upper_hemisphere_about(grazing),
            Rule::LobeAdapted {
                lobe_width_rad: 1e-3,
                n_per_panel: 32,
                n_azimuth: 64,
            },
        ),
    ]
}

#[test]
fn gauss_legendre_nodes_are_exact() {
    // n = 5: known nodes and weights.
    let g = gauss_legendre(5);
    let x2 = (5.0 - 2.0 * (10.0f64 / 7.0).sqrt()).sqrt() / 3.0;
    let w2 = (322.0 + 13.0 * 70.0f64.sqrt()) / 900.0;
    assert_eq!(g[2].x, 0.0);
    assert!((g[2].weight - 128.0 / 225.0).abs() < 1e-15);
    assert!((g[3].x - x2).abs() < 1e-15 && (g[3].weight - w2).abs() < 1e-15);
    assert!((g[1].x + x2).abs() < 1e-15);
    // Exactness for polynomials of degree 2n-1 and weights summing to 2, at a high order too.
    for n in [1, 2, 7, 64, 513, 1500] {
        let g = gauss_legendre(n);
        let total: f64 = g.iter().map(|p| p.weight).sum();
        assert!((total - 2.0).abs() < 1e-13, "n = {n}: {total}");
        let deg = (2 * n - 2).min(40) as i32;
        let integral: f64 = g.iter().map(|p| p.weight * p.x.powi(deg)).sum();
        assert!((integral - 2.0 / (deg as f64 + 1.0)).abs() < 1e-13, "n = {n}");
        assert!(g.windows(2).all(|w| w[0].x < w[1].x));
    }
}

#[test]
fn hemisphere_solid_angle_and_cosine_integral_with_every_rule() {
    for (region, rule) in hemisphere_rules() {
        let omega = integrate_infallible(|_| 1.0, &region, rule);
        assert!(
            (omega.value - 2.0 * PI).abs() < 1e-12,
            "{rule:?} {region:?}: {omega:?}"
        );
        assert!(omega.error < 1e-8, "{omega:?}");
        let cos = integrate_infallible(|w| w.cos_theta(), &region, rule);
        assert!((cos.value - PI).abs() < 1e-12, "{rule:?} {region:?}: {cos:?}");
    }
}

#[test]
fn cone_integrals_match_closed_forms() {
    use crate::radiometry::{cone_solid_angle_sr, projected_solid_angle_sr};
    for (theta_a, beta) in [
        (0.0, 0.01),
        (0.7, 0.2),
        (1.5, 0.2),
        (FRAC_PI_2, 0.05),
        (1.9, 0.5),
        (0.3, 2.5),
    ] {
        let axis = Direction::from_spherical(theta_a, 0.8);
        let region = Region::cone(axis, beta);
        for rule in [
            Rule::GaussTrapezoid {
                n_radial: 16,
                n_azimuth: 32,
            },
            Rule::LobeAdapted {
                lobe_width_rad: beta / 4.0,
                n_per_panel: 16,
                n_azimuth: 32,
            },
        ] {
            let psa = integrate_infallible(|w| w.cos_theta().max(0.0), &region, rule);
            let exact = projected_solid_angle_sr(&axis, beta);
            assert!(
                (psa.value - exact).abs() <= 1e-12 * exact.max(1e-3),
                "{theta_a} {beta} {rule:?}: {psa:?} vs {exact}"
            );
            assert!(
                (psa.value - exact).abs() <= psa.error.max(1e-15),
                "error estimate must bound the error"
            );
        }
        // Unclipped cone: the plain solid angle.
        let unclipped = Region {
            clip_to_upper_hemisphere: false,
            ..region
        };
        let omega = integrate_infallible(
            |_| 1.0,
            &unclipped,
            Rule::GaussTrapezoid {
                n_radial: 8,
                n_azimuth: 16,
            },
        );
        assert!((omega.value - cone_solid_angle_sr(beta)).abs() < 1e-13);
    }
}

/// A narrow lobe exp(k (w.a - 1)) about a tilted axis: its integral over the sphere is
/// 2 pi (1 - exp(-2k)) / k, and the part below the horizon is below 1e-300 for the axes used.
/// `1 - w.a` is computed as |w - a|^2 / 2 so that the integrand itself is accurate to a few ulps.
fn one_minus_dot(w: &Direction, a: &Direction) -> f64 {
    let (dx, dy, dz) = (w.x() - a.x(), w.y() - a.y(), w.z() - a.z());
    0.5 * (dx * dx + dy * dy + dz * dz)
}

#[test]
fn narrow_lobe_rules_agree_and_error_estimates_bound_the_error() {
    for (k, theta_a) in [(1e2f64, 0.4), (1e4, 0.9), (1e6, 0.3), (1e8, 1.2)] {
        let axis = Direction::from_spherical(theta_a, 2.0);
        let exact = 2.0 * PI * (1.0 - (-2.0 * k).exp()) / k;
        let lobe = |w: &Direction| (-k * one_minus_dot(w, &axis)).exp();
        let width = 1.0 / k.sqrt();
        let adapted = integrate_adaptive(
            |w| Ok::<f64, ()>(lobe(w)),
            &Region::upper_hemisphere_about(axis),
            Rule::LobeAdapted {
                lobe_width_rad: width,
                n_per_panel: 4,
                n_azimuth: 8,
            },
            Tolerance::relative(1e-10),
        )
        .expect("infallible");
        let true_error = (adapted.value - exact).abs();
        assert!(true_error <= 1e-10 * exact, "k = {k}: {adapted:?} vs {exact}");
        assert!(
            true_error <= adapted.error,
            "k = {k}: estimate {} < true {true_error}",
            adapted.error
        );
        // Every fixed resolution of the lobe rule: the estimate bounds the true error, down to the floor set
        // by representing directions in f64 (a direction within 1e-4 rad of the axis carries its deviation
        // with a relative error of ~1e-12; the integrand cannot be evaluated better than that).
        for n in [4, 8, 16, 32] {
            let e = integrate_infallible(
                lobe,
                &Region::upper_hemisphere_about(axis),
                Rule::LobeAdapted {
                    lobe_width_rad: width,
                    n_per_panel: n,
                    n_azimuth: 2 * n,
                },
            );
            assert!(
                (e.value - exact).abs() <= e.error.max(1e-13 * exact),
                "k = {k}, n = {n}: {e:?} vs {exact}"
            );
        }
    }
    // The Gauss x trapezoid rule resolves a moderately narrow lobe and agrees with the lobe rule.
    let k: f64 = 1e3;
    let axis = Direction::from_spherical(0.5, 1.0);
    let lobe = |w: &Direction| Ok::<f64, ()>((-k * one_minus_dot(w, &axis)).exp());
    let exact = 2.0 * PI * (1.0 - (-2.0 * k).exp()) / k;
    let gt = integrate_adaptive(
        lobe,
        &Region::upper_hemisphere(),
        Rule::GaussTrapezoid {
            n_radial: 8,
            n_azimuth: 16,
        },
        Tolerance::relative(1e-9),
    )
    .expect("infallible");
    assert!(
        (gt.value - exact).abs() <= gt.error.max(1e-9 * exact),
        "{gt:?} vs {exact}"
    );
    assert!((gt.value - exact).abs() < 1e-8 * exact);
}

#[test]
fn errors_from_the_integrand_are_returned() {
    let r = integrate(
        |_| Err::<f64, &str>("boom"),
        &Region::upper_hemisphere(),
        Rule::GaussTrapezoid {
            n_radial: 2,
            n_azimuth: 2,
        },
    );
    assert_eq!(r, Err("boom"));
}

#[test]
fn empty_regions_integrate_to_zero() {
    let below = Region::cone(Direction::from_spherical(2.5, 0.0), 0.3);
    let e = integrate_infallible(
        |_| 1.0,
        &below,
        Rule::GaussTrapezoid {
            n_radial: 4,
            n_azimuth: 8,
        },
    );
    assert_eq!(e.value, 0.0);
    let zero = Region::cone(Direction::NORMAL, 0.0);
    assert_eq!(
        integrate_infallible(
            |_| 1.0,
            &zero,
            Rule::GaussTrapezoid {
                n_radial: 4,
                n_azimuth: 8
            }
        )
        .value,
        0.0
    );
}
