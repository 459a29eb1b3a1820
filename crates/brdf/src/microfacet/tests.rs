use super::*;

fn mf(d: Distribution, ax: f64, ay: f64) -> Microfacet {
    Microfacet::new(d, Masking::Separable, ax, ay)
}

#[test]
fn beckmann_cartesian_form_matches_the_angular_formula() {
    let m = mf(Distribution::Beckmann, 0.3, 0.15);
    for &(theta, phi) in &[(0.2, 0.3), (0.7, -1.2), (1.2, 2.5)] {
        let w = Direction::from_spherical(theta, phi);
        let t2 = f64::tan(theta).powi(2);
        let e = t2 * (phi.cos().powi(2) / 0.09 + phi.sin().powi(2) / 0.0225);
        let expect = (-e).exp() / (PI * 0.3 * 0.15 * theta.cos().powi(4));
        assert!(
            (m.d(&w) - expect).abs() <= 1e-12 * expect,
            "{} vs {expect}",
            m.d(&w)
        );
    }
}

#[test]
fn lambda_matches_the_reference_formulas() {
    for &(theta, phi) in &[(0.2f64, 0.3f64), (0.9, -1.2), (1.5, 2.5)] {
        let w = Direction::from_spherical(theta, phi);
        let alpha2 = 0.4f64.powi(2) * phi.cos().powi(2) + 0.1f64.powi(2) * phi.sin().powi(2);
        let ggx = mf(Distribution::Ggx, 0.4, 0.1).lambda(&w);
        let expect_ggx = (-1.0 + (1.0 + alpha2 * theta.tan().powi(2)).sqrt()) / 2.0;
        assert!(
            (ggx - expect_ggx).abs() <= 1e-13 * expect_ggx.max(1e-3),
            "{ggx} vs {expect_ggx}"
        );
        let a = 1.0 / (alpha2.sqrt() * theta.tan());
        let expect_b = (libm::erf(a) - 1.0) / 2.0 + (-a * a).exp() / (2.0 * a * PI.sqrt());
        let b = mf(Distribution::Beckmann, 0.4, 0.1).lambda(&w);
        assert!((b - expect_b).abs() <= 1e-13, "{b} vs {expect_b}");
    }
}

#[test]
fn lambda_limits_at_pole_and_horizon() {
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        let m = mf(d, 0.2, 0.2);
        assert_eq!(m.lambda(&Direction::NORMAL), 0.0);
        assert_eq!(
            m.lambda(&Direction::from_spherical_deg(90.0, 10.0)),
            f64::INFINITY
        );
        assert_eq!(
            m.g1(&Direction::from_spherical_deg(90.0, 10.0), &Direction::NORMAL),
            0.0
        );
        let near = Direction::from_spherical(std::f64::consts::FRAC_PI_2 - 1e-9, 0.3);
        let l = m.lambda(&near);
        assert!(l.is_finite() && l > 0.0);
    }
}

/// The GGX hot path of `lobe` (unnormalised half vector, division-free Smith roots) against the textbook
/// `D(h) G(wi, wo, h) / (4 cos_i cos_o)` built from `d` and `g`, over random pairs, roughnesses from the
/// clamp to 1, anisotropy and both maskings; and exactly reciprocal.
#[test]
fn ggx_lobe_matches_the_textbook_form() {
    let mut s: u64 = 3;
    let mut unit = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    for &(ax, ay) in &[
        (1e-4, 1e-4),
        (0.003, 0.003),
        (0.08, 0.08),
        (0.3, 0.05),
        (1.0, 1.0),
        (0.5, 0.9),
    ] {
        for masking in [Masking::Separable, Masking::HeightCorrelated] {
            let m = Microfacet::new(Distribution::Ggx, masking, ax, ay);
            for _ in 0..2000 {
                let wi = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                let wo = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                let Some(h) = Direction::new(wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z()) else {
                    continue;
                };
                let expect = m.d(&h) * m.g(&wi, &wo, &h) / (4.0 * wi.z() * wo.z());
                let got = m.lobe(&wi, &wo).expect("above the horizon").value;
                let back = m.lobe(&wo, &wi).expect("above the horizon").value;
                assert_eq!(got.to_bits(), back.to_bits(), "reciprocity");
                if expect.is_finite() && expect > 1e-300 {
                    worst = worst.max((got - expect).abs() / expect);
                }
            }
        }
    }
    assert!(worst <= 1e-12, "largest relative difference {worst:e}");
}

/// The rough conductor's fused GGX path (Fresnel and lobe as one ratio) against the Fresnel factor times
/// `lobe`, and reciprocal bit for bit.
#[test]
fn fused_ggx_conductor_equals_fresnel_times_lobe() {
    use crate::brdf::Brdf;
    use crate::fresnel;
    use crate::models::Conductor;
    use crate::spectrum::{Spectral, Wavelength};
    let wl = Wavelength::DEFAULT;
    let mut s: u64 = 5;
    let mut unit = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    for &(ax, ay, eta, k) in &[
        (0.08, 0.08, 0.35, 2.714),
        (0.3, 0.05, 1.5, 0.0),
        (1.0, 1.0, 0.05, 20.0),
    ] {
        for masking in [Masking::Separable, Masking::HeightCorrelated] {
            let c = Conductor::new(
                Distribution::Ggx,
                masking,
                ax,
                ay,
                Spectral::Constant(eta),
                Spectral::Constant(k),
            )
            .expect("valid");
            for _ in 0..2000 {
                let wi = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                let wo = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                let got = c.eval(&wi, &wo, wl).expect("constant");
                assert_eq!(got.to_bits(), c.eval(&wo, &wi, wl).expect("constant").to_bits());
                let l = c.microfacet().lobe(&wi, &wo).expect("above the horizon");
                let expect = fresnel::conductor(l.cos_d, eta, k) * l.value;
                if expect > 1e-300 {
                    worst = worst.max((got - expect).abs() / expect);
                }
            }
        }
    }
    assert!(worst <= 1e-13, "largest relative difference {worst:e}");
}

/// `delta_cone_fraction` against the aperture integral of the (Fresnel-free) lobe just above the switch,
/// divided by the delta lobe's masking: what a detector cone about the mirror direction collects.
#[test]
fn delta_cone_fraction_matches_the_lobe_just_above_the_switch() {
    use crate::integrate::{Region, Rule, Tolerance, integrate_adaptive};
    for distribution in [Distribution::Ggx, Distribution::Beckmann] {
        for &(ax, ay, theta_deg, phi_deg, beta) in &[
            (1.0, 1.0, 0.0, 0.0, 0.01),
            (1.0, 1.0, 60.0, 20.0, 0.01),
            (1.0, 0.5, 80.0, 30.0, 0.003),
            (1.0, 0.5, 30.0, 90.0, 0.05),
        ] {
            let above = Microfacet::new(
                distribution,
                Masking::HeightCorrelated,
                ALPHA_DELTA * ax * (1.0 + 1e-9),
                ALPHA_DELTA * ay * (1.0 + 1e-9),
            );
            let wi = Direction::from_spherical_deg(theta_deg, phi_deg);
            let mirror = wi.reflect_about_normal();
            let cone = integrate_adaptive(
                |w: &Direction| -> Result<f64, ()> {
                    Ok(above.lobe(&wi, w).map_or(0.0, |l| l.value) * w.z().max(0.0))
                },
                &Region::cone(mirror, beta),
                Rule::LobeAdapted {
                    lobe_width_rad: ALPHA_DELTA,
                    n_per_panel: 8,
                    n_azimuth: 16,
                },
                Tolerance::relative(1e-9),
            )
            .expect("no error");
            let collected = cone.value / above.delta_masking(&wi);
            let predicted = above.delta_cone_fraction(&wi, beta);
            assert!(
                (collected - predicted).abs() < 1e-5,
                "{distribution:?} ({ax}, {ay}) theta {theta_deg} phi {phi_deg} beta {beta}: lobe {collected} vs {predicted}"
            );
        }
    }
    let m = Microfacet::new(Distribution::Ggx, Masking::Separable, 1e-3, 1e-3);
    // Normal incidence: the GGX CDF of theta_h, exactly.
    let t2 = (0.005f64).tan().powi(2);
    assert!((m.delta_cone_fraction(&Direction::NORMAL, 0.01) - t2 / (1e-6 + t2)).abs() < 1e-15);
    assert_eq!(m.delta_cone_fraction(&Direction::NORMAL, 0.0), 0.0);
    assert_eq!(
        m.delta_cone_fraction(&Direction::from_spherical_deg(90.0, 0.0), 0.01),
        1.0
    );
}

#[test]
fn alpha_is_clamped_and_delta_switch_needs_both() {
    let m = mf(Distribution::Ggx, 0.0, f64::NAN);
    assert_eq!((m.alpha_x(), m.alpha_y()), (ALPHA_MIN, ALPHA_MIN));
    assert!(m.is_delta());
    assert!(!mf(Distribution::Ggx, 5e-4, 2e-3).is_delta());
    assert!(!mf(Distribution::Ggx, 1e-3, 1e-3).is_delta());
}
