//! Tests of the analytic models, Fresnel and microfacet distributions against independent expectations: closed
//! forms, published values, brute-force quadrature written here (not the library's integrators), and properties
//! (positivity, reciprocity, horizon) over adversarial directions. Materials and presets: tests/it/materials.rs.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::fresnel;
use gonio_brdf::microfacet::{Distribution, Masking, Microfacet};
use gonio_brdf::models::{Conductor, Lambertian, Mirror, OrenNayar, Phong, Plastic};
use gonio_brdf::{Brdf, Direction, Material, Spectral, Wavelength};
use gonio_testkit::nm;
use proptest::prelude::*;

// ----------------------------------------------------------------------------------------------------------
// Independent quadrature helpers

/// Gauss-Legendre nodes and weights on [-1, 1] (Newton on the Legendre recurrence).
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            for _ in 0..100 {
                let (p, d) = legendre(n, x);
                let dx = p / d;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            let (_, d) = legendre(n, x);
            (x, 2.0 / ((1.0 - x * x) * d * d))
        })
        .collect()
}

fn legendre(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for j in 2..=n {
        let jf = j as f64;
        let p2 = ((2.0 * jf - 1.0) * x * p1 - (jf - 1.0) * p0) / jf;
        p0 = p1;
        p1 = p2;
    }
    (p1, n as f64 * (x * p1 - p0) / (x * x - 1.0))
}

/// Integral over the upper hemisphere of g(w) d omega, in (theta, phi) about the normal: theta split into panels
/// growing geometrically from `w0` (so a peak at the pole of width ~w0 is resolved), Gauss-Legendre on each
/// panel, trapezoid in phi.
fn hemisphere_graded(g: &dyn Fn(&Direction) -> f64, w0: f64, n_gl: usize, n_phi: usize) -> f64 {
    let rule = gauss_legendre(n_gl);
    let mut edges = vec![0.0];
    let mut b = w0.min(FRAC_PI_2);
    while b < FRAC_PI_2 {
        edges.push(b);
        b *= 2.0;
    }
    edges.push(FRAC_PI_2);
    let mut total = 0.0;
    for pair in edges.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        for &(x, w) in &rule {
            let theta = 0.5 * (a + b) + 0.5 * (b - a) * x;
            let mut ring = 0.0;
            for j in 0..n_phi {
                let phi = 2.0 * PI * j as f64 / n_phi as f64;
                ring += g(&Direction::from_spherical(theta, phi));
            }
            total += 0.5 * (b - a) * w * theta.sin() * ring * 2.0 * PI / n_phi as f64;
        }
    }
    total
}

/// Integral of f(wi, wo) cos(theta_o) for a smooth BRDF part: Gauss-Legendre in cos(theta_o) x trapezoid in phi.
fn albedo_smooth(f: &dyn Fn(&Direction) -> f64, n_mu: usize, n_phi: usize) -> f64 {
    let rule = gauss_legendre(n_mu);
    let mut total = 0.0;
    for &(x, w) in &rule {
        let mu = 0.5 * (x + 1.0);
        let sin = (1.0 - mu * mu).sqrt();
        for j in 0..n_phi {
            let phi = 2.0 * PI * (j as f64 + 0.5) / n_phi as f64;
            let wo = Direction::new(sin * phi.cos(), sin * phi.sin(), mu).expect("unit");
            total += 0.5 * w * mu * f(&wo) * 2.0 * PI / n_phi as f64;
        }
    }
    total
}

/// Integral of f_spec(wi, wo) cos(theta_o) by stratified importance sampling of the microfacet lobe
/// (n x n strata): the estimator's weight is smooth, so the error is far below the tolerances used.
fn albedo_sampled(mf: &Microfacet, wi: &Direction, f: &dyn Fn(&Direction) -> f64, n: usize) -> f64 {
    let mut sum = 0.0;
    for i in 0..n {
        for j in 0..n {
            let u = [(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64];
            let s = mf.sample_reflection(wi, u).expect("wi above the horizon");
            if s.wo.z() > 0.0 {
                sum += f(&s.wo) * s.wo.z() / s.pdf_per_sr;
            }
        }
    }
    sum / (n * n) as f64
}

// ----------------------------------------------------------------------------------------------------------
// Fresnel

#[test]
fn gold_normal_incidence_reflectance_at_550_nm() {
    let gold = Material::preset("gold").expect("preset");
    let spec = gold.spec();
    let eta = spec.eta.expect("eta").at(nm(550.0)).expect("in range");
    let k = spec.k.expect("k").at(nm(550.0)).expect("in range");
    let r0 = fresnel::r0_conductor(eta, k);
    assert!((r0 - 0.847).abs() < 1e-3, "{r0}");
    assert!((fresnel::conductor(1.0, eta, k) - r0).abs() < 1e-15);
    // Gold is yellow: reflectance rises from ~0.39 at 450 nm to ~0.94 at 650 nm.
    let r = |wl: f64| {
        let s = gold.spec();
        fresnel::r0_conductor(
            s.eta.expect("eta").at(nm(wl)).expect("in"),
            s.k.expect("k").at(nm(wl)).expect("in"),
        )
    };
    assert!((r(450.0) - 0.39).abs() < 0.01, "{}", r(450.0));
    assert!((r(650.0) - 0.94).abs() < 0.01, "{}", r(650.0));
}

#[test]
fn dielectric_fresnel_known_values() {
    assert!((fresnel::dielectric(1.0, 1.5) - 0.04).abs() < 1e-15);
    assert_eq!(fresnel::dielectric(0.0, 1.5), 1.0);
    assert!(fresnel::dielectric(1e-9, 1.5) > 1.0 - 1e-8);
    assert!(fresnel::conductor(1e-9, 0.35, 2.714) > 1.0 - 1e-8);
    // Monotone rise towards grazing for a dielectric from outside.
    let mut last = 0.0;
    for i in (0..=100).rev() {
        let f = fresnel::dielectric(i as f64 / 100.0, 1.5);
        assert!(f >= last - 1e-15);
        last = f;
    }
}

// ----------------------------------------------------------------------------------------------------------
// Microfacet distributions

#[test]
fn distributions_are_normalised() {
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        for &(ax, ay) in &[
            (0.01, 0.01),
            (0.03, 0.03),
            (0.1, 0.1),
            (0.3, 0.3),
            (0.6, 0.6),
            (1.0, 1.0),
            (0.05, 0.2),
            (0.5, 0.1),
        ] {
            let mf = Microfacet::new(d, Masking::Separable, ax, ay);
            let n_phi = if ax == ay { 8 } else { 256 };
            let integral = hemisphere_graded(&|m| mf.d(m) * m.z(), f64::min(ax, ay), 24, n_phi);
            assert!(
                (integral - 1.0).abs() < 1e-6,
                "{d:?} alpha ({ax}, {ay}): {integral}"
            );
        }
    }
}

#[test]
fn ggx_white_furnace_at_normal_incidence() {
    // F = 1, single scattering: not energy preserving. At normal incidence Lambda(wi) = 0, so separable and
    // height-correlated masking agree.
    for &(alpha, expect, tol) in &[(0.5, 0.6878, 1e-4), (0.1, 0.9883, 1e-4), (0.01, 0.99990, 1e-5)] {
        for masking in [Masking::Separable, Masking::HeightCorrelated] {
            let mf = Microfacet::new(Distribution::Ggx, masking, alpha, alpha);
            let wi = Direction::NORMAL;
            let a = hemisphere_graded(
                &|wo| mf.lobe(&wi, wo).map_or(0.0, |l| l.value) * wo.z(),
                alpha,
                24,
                8,
            );
            assert!((a - expect).abs() < tol, "alpha {alpha}: {a}");
            assert!(a <= 1.0);
        }
    }
}

#[test]
fn sampling_densities_match_the_sampled_distribution() {
    // Stratified samples of a normal / direction, compared with quadrature of the reported density:
    // E[m_x], E[m_z] under the samples must equal integral pdf(m) m_x dm etc.
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        let mf = Microfacet::new(d, Masking::HeightCorrelated, 0.3, 0.5);
        let wi = Direction::from_spherical(0.9, 0.4);
        let n = 300;
        let (mut ex, mut ez) = (0.0, 0.0);
        for i in 0..n {
            for j in 0..n {
                let u = [(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64];
                let (m, pdf) = mf.sample_normal(&wi, u).expect("sample");
                assert!(pdf > 0.0 && pdf.is_finite());
                assert!((pdf - mf.pdf_normal(&wi, &m)).abs() <= 1e-12 * pdf);
                ex += m.x();
                ez += m.z();
            }
        }
        let (ex, ez) = (ex / (n * n) as f64, ez / (n * n) as f64);
        let mass = hemisphere_graded(&|m| mf.pdf_normal(&wi, m), 0.3, 24, 128);
        let qx = hemisphere_graded(&|m| mf.pdf_normal(&wi, m) * m.x(), 0.3, 24, 128);
        let qz = hemisphere_graded(&|m| mf.pdf_normal(&wi, m) * m.z(), 0.3, 24, 128);
        assert!((mass - 1.0).abs() < 1e-5, "{d:?} mass {mass}");
        assert!(
            (ex - qx).abs() < 2e-4 && (ez - qz).abs() < 2e-4,
            "{d:?}: ({ex}, {ez}) vs ({qx}, {qz})"
        );
    }
}

#[test]
fn delta_switch_preserves_reflected_power() {
    // Just above the threshold the lobe's albedo (integrated by sampling) must match, to O(alpha^2), the delta
    // reflectance reported just below it.
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        for masking in [Masking::Separable, Masking::HeightCorrelated] {
            let eta = Spectral::Constant(0.35);
            let k = Spectral::Constant(2.714);
            let above =
                Conductor::new(d, masking, 1.0001e-3, 1.0001e-3, eta.clone(), k.clone()).expect("valid");
            let below = Conductor::new(d, masking, 0.9999e-3, 0.9999e-3, eta, k).expect("valid");
            assert!(!above.has_delta_lobe() && below.has_delta_lobe());
            // The agreement degrades like (alpha tan(theta_i))^2 towards grazing incidence (6e-4 at 89 degrees).
            for (theta_deg, tol) in [
                (0.0, 1e-5),
                (30.0, 1e-5),
                (60.0, 1e-5),
                (80.0, 1e-4),
                (89.0, 1e-3),
            ] {
                let wi = Direction::from_spherical_deg(theta_deg, 20.0);
                let lobe = albedo_sampled(
                    above.microfacet(),
                    &wi,
                    &|wo| above.eval(&wi, wo, Wavelength::DEFAULT).expect("constant"),
                    64,
                );
                let delta = below
                    .delta_lobe(&wi, Wavelength::DEFAULT)
                    .expect("constant")
                    .expect("delta")
                    .reflectance;
                assert!(
                    (lobe - delta).abs() < tol * delta,
                    "{d:?} {masking:?} {theta_deg}: {lobe} vs {delta}"
                );
                assert_eq!(
                    below.eval(&wi, &wi.reflect_about_normal(), Wavelength::DEFAULT),
                    Ok(0.0)
                );
            }
        }
    }
}

// ----------------------------------------------------------------------------------------------------------
// Energy

#[test]
fn plastic_albedo_is_bounded() {
    // Worst case: a white base (albedo 1). Coat part integrated by stratified microfacet sampling, base part by
    // Gauss-Legendre x trapezoid, delta part analytically.
    let wl = Wavelength::DEFAULT;
    let mut worst: (f64, String) = (0.0, String::new());
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        for masking in [Masking::Separable, Masking::HeightCorrelated] {
            let alphas = [
                (0.0005, 0.0005),
                (0.02, 0.02),
                (0.1, 0.1),
                (0.2, 0.2),
                (0.35, 0.35),
                (0.6, 0.6),
                (1.0, 1.0),
                (0.03, 0.3),
                (0.1, 1.0),
            ];
            for &(ax, ay) in &alphas {
                for &ior in &[1.2, 1.49, 2.5, 4.0] {
                    let p = Plastic::new(
                        d,
                        masking,
                        ax,
                        ay,
                        Spectral::Constant(ior),
                        Spectral::Constant(1.0),
                    )
                    .expect("valid");
                    let phis: &[f64] = if ax == ay { &[0.0] } else { &[0.0, 90.0] };
                    for &theta_deg in &[0.0, 40.0, 60.0, 70.0, 76.0, 82.0, 86.0, 89.0] {
                        for &phi in phis {
                            let wi = Direction::from_spherical_deg(theta_deg, phi);
                            let diffuse = albedo_smooth(&|wo| p.eval_diffuse(&wi, wo, wl).expect("c"), 24, 4);
                            let coat = |wo: &Direction| {
                                p.eval(&wi, wo, wl).expect("c") - p.eval_diffuse(&wi, wo, wl).expect("c")
                            };
                            let spec = albedo_sampled(p.microfacet(), &wi, &coat, 40);
                            let delta = p.delta_lobe(&wi, wl).expect("c").map_or(0.0, |d| d.reflectance);
                            let total = diffuse + spec + delta;
                            if total > worst.0 {
                                worst = (
                                    total,
                                    format!(
                                        "{d:?} {masking:?} alpha ({ax}, {ay}) ior {ior} wi ({theta_deg}, {phi})"
                                    ),
                                );
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(worst.0 <= 1.0, "plastic albedo {} > 1 at {}", worst.0, worst.1);
    // The bound is not vacuous: the worst case comes close to 1.
    assert!(worst.0 > 0.97, "{worst:?}");
}

#[test]
fn plastic_diffuse_albedo_follows_the_derivation() {
    // Diffuse albedo = COAT_BOUND albedo (1 - Fbar)(1 - F(cos_i)) / (ior^2 - albedo (ior^2 - 1 + Fbar)).
    let (ior, rho) = (1.49, 0.6);
    let p = Plastic::new(
        Distribution::Ggx,
        Masking::Separable,
        0.2,
        0.2,
        Spectral::Constant(ior),
        Spectral::Constant(rho),
    )
    .expect("valid");
    let fbar = fresnel::dielectric_hemispherical_average(ior);
    for theta_deg in [0.0, 45.0, 80.0] {
        let wi = Direction::from_spherical_deg(theta_deg, 0.0);
        let a = albedo_smooth(
            &|wo| p.eval_diffuse(&wi, wo, Wavelength::DEFAULT).expect("c"),
            64,
            4,
        );
        let n2 = ior * ior;
        let expect = gonio_brdf::models::plastic::COAT_BOUND
            * rho
            * (1.0 - fbar)
            * (1.0 - fresnel::dielectric(wi.z(), ior))
            / (n2 - rho * (n2 - 1.0 + fbar));
        assert!((a - expect).abs() < 1e-10, "{theta_deg}: {a} vs {expect}");
    }
}

#[test]
fn lambertian_phong_and_oren_nayar_albedos() {
    let wl = Wavelength::DEFAULT;
    let lam = Lambertian::new(Spectral::Constant(0.7)).expect("valid");
    let wi = Direction::from_spherical_deg(30.0, 0.0);
    let a = albedo_smooth(&|wo| lam.eval(&wi, wo, wl).expect("c"), 16, 4);
    assert!((a - 0.7).abs() < 1e-12, "{a}");
    // Normalised Phong: the lobe alone has albedo exactly rho_s at normal incidence (integral of cos^(n+1)).
    let phong = Phong::new(Spectral::Constant(0.0), Spectral::Constant(0.5), 20.0).expect("valid");
    let n = Direction::NORMAL;
    let a = hemisphere_graded(&|wo| phong.eval(&n, wo, wl).expect("c") * wo.z(), 0.2, 24, 4);
    assert!((a - 0.5).abs() < 1e-9, "{a}");
    // Oren-Nayar at normal incidence: the B term vanishes (s = 0), albedo = rho A.
    let on = OrenNayar::new(Spectral::Constant(0.8), 20.0).expect("valid");
    let (a_coef, _) = on.coefficients();
    let a = albedo_smooth(&|wo| on.eval(&n, wo, wl).expect("c"), 16, 4);
    assert!((a - 0.8 * a_coef).abs() < 1e-12, "{a}");
}

#[test]
fn model_sampling_is_consistent_with_eval() {
    // E[f cos / pdf] over stratified samples equals the albedo from quadrature, for models with smooth lobes.
    let wl = Wavelength::DEFAULT;
    let wi = Direction::from_spherical_deg(35.0, 10.0);
    let models: Vec<(&str, Material)> = vec![
        (
            "lambertian",
            Material::Lambertian(Lambertian::new(Spectral::Constant(0.5)).expect("v")),
        ),
        (
            "oren-nayar",
            Material::OrenNayar(OrenNayar::new(Spectral::Constant(0.5), 30.0).expect("v")),
        ),
        (
            "phong",
            Material::Phong(Phong::new(Spectral::Constant(0.3), Spectral::Constant(0.4), 10.0).expect("v")),
        ),
        (
            "conductor",
            Material::Conductor(
                Conductor::new(
                    Distribution::Beckmann,
                    Masking::HeightCorrelated,
                    0.4,
                    0.25,
                    Spectral::Constant(0.35),
                    Spectral::Constant(2.7),
                )
                .expect("v"),
            ),
        ),
        (
            "plastic",
            Material::Plastic(
                Plastic::new(
                    Distribution::Ggx,
                    Masking::Separable,
                    0.4,
                    0.4,
                    Spectral::Constant(1.5),
                    Spectral::Constant(0.5),
                )
                .expect("v"),
            ),
        ),
    ];
    for (name, m) in &models {
        let n = 300;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let u = [(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64];
                let s = m.sample(&wi, u, wl).expect("c").expect("model samples");
                assert!(s.pdf_per_sr > 0.0 && s.pdf_per_sr.is_finite(), "{name}");
                if s.wo.z() > 0.0 {
                    sum += m.eval(&wi, &s.wo, wl).expect("c") * s.wo.z() / s.pdf_per_sr;
                }
            }
        }
        let sampled = sum / (n * n) as f64;
        let quad = hemisphere_graded(&|wo| m.eval(&wi, wo, wl).expect("c") * wo.z(), 0.05, 32, 256);
        assert!(
            (sampled - quad).abs() < 2e-3 * quad,
            "{name}: sampled {sampled} vs quadrature {quad}"
        );
    }
}

// ----------------------------------------------------------------------------------------------------------
// Properties over adversarial directions

fn direction() -> impl Strategy<Value = Direction> {
    prop_oneof![
        (0.0..FRAC_PI_2, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(t, p)),
        (0.0..1e-9f64, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(t, p)),
        (0.0..1e-9f64, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(FRAC_PI_2 - t, p)),
        (-PI..PI).prop_map(|p| Direction::from_spherical_deg(90.0, p.to_degrees())),
        (FRAC_PI_2..PI, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(t, p)),
        Just(Direction::NORMAL),
    ]
}

/// A pair (wi, wo) that is deliberately often degenerate: equal, mirror images, or independent.
fn direction_pair() -> impl Strategy<Value = (Direction, Direction)> {
    prop_oneof![
        (direction(), direction()),
        direction().prop_map(|w| (w, w)),
        direction().prop_map(|w| (w, w.reflect_about_normal())),
    ]
}

fn alpha() -> impl Strategy<Value = f64> {
    (-4.0..=0.0f64).prop_map(|e| 10f64.powf(e))
}

fn distribution() -> impl Strategy<Value = Distribution> {
    prop_oneof![Just(Distribution::Ggx), Just(Distribution::Beckmann)]
}

fn masking() -> impl Strategy<Value = Masking> {
    prop_oneof![Just(Masking::Separable), Just(Masking::HeightCorrelated)]
}

fn model() -> impl Strategy<Value = Material> {
    prop_oneof![
        (0.0..=1.0f64).prop_map(|r| Material::Lambertian(Lambertian::new(Spectral::Constant(r)).expect("v"))),
        (0.0..=1.0f64, 0.0..=90.0f64)
            .prop_map(|(r, s)| Material::OrenNayar(OrenNayar::new(Spectral::Constant(r), s).expect("v"))),
        (0.0..=0.5f64, 0.0..=0.5f64, 0.0..=1e5f64).prop_map(|(d, s, n)| Material::Phong(
            Phong::new(Spectral::Constant(d), Spectral::Constant(s), n).expect("v")
        )),
        (
            distribution(),
            masking(),
            alpha(),
            alpha(),
            0.05..5.0f64,
            0.0..10.0f64
        )
            .prop_map(|(d, m, ax, ay, eta, k)| {
                Material::Conductor(
                    Conductor::new(d, m, ax, ay, Spectral::Constant(eta), Spectral::Constant(k)).expect("v"),
                )
            }),
        (
            distribution(),
            masking(),
            alpha(),
            0.1..=10.0f64,
            1.0..=4.0f64,
            0.0..=1.0f64
        )
            .prop_map(|(d, m, ax, ratio, ior, r)| {
                let ay = (ax * ratio).min(1.0);
                Material::Plastic(
                    Plastic::new(d, m, ax, ay, Spectral::Constant(ior), Spectral::Constant(r)).expect("v"),
                )
            }),
        (0.05..5.0f64, 0.0..10.0f64).prop_map(|(eta, k)| Material::Mirror(
            Mirror::new(Spectral::Constant(eta), Spectral::Constant(k)).expect("v")
        )),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    #[test]
    fn every_model_is_finite_non_negative_reciprocal_and_dark_below_the_horizon(
        m in model(), (wi, wo) in direction_pair()
    ) {
        let wl = Wavelength::DEFAULT;
        let f = m.eval(&wi, &wo, wl).expect("constant parameters");
        let g = m.eval(&wo, &wi, wl).expect("constant parameters");
        prop_assert!(f.is_finite() && f >= 0.0, "{m:?} f({wi:?}, {wo:?}) = {f}");
        prop_assert!((f - g).abs() <= 1e-12 * f.abs().max(g.abs()), "{m:?}: {f} vs {g}");
        if wi.z() <= 0.0 || wo.z() <= 0.0 {
            prop_assert_eq!(f, 0.0);
        }
        if let Some(d) = m.delta_lobe(&wi, wl).expect("constant") {
            prop_assert!(m.has_delta_lobe());
            prop_assert!((0.0..=1.0).contains(&d.reflectance), "{d:?}");
        }
    }

    #[test]
    fn sampling_gives_unit_directions_and_positive_densities(m in model(), wi in direction(), u0 in 0.0..1.0f64, u1 in 0.0..1.0f64) {
        if let Some(s) = m.sample(&wi, [u0, u1], Wavelength::DEFAULT).expect("constant") {
            let len = (s.wo.x().powi(2) + s.wo.y().powi(2) + s.wo.z().powi(2)).sqrt();
            prop_assert!((len - 1.0).abs() < 1e-12);
            prop_assert!(s.pdf_per_sr > 0.0 && s.pdf_per_sr.is_finite(), "{m:?}: {s:?}");
        }
    }
}

#[test]
fn resolved_materials_evaluate_identically() {
    for name in Material::preset_names() {
        let m = Material::preset(name).expect("preset");
        for wl in [400.0, 480.0, 550.0, 633.0, 700.0] {
            let r = m.at_wavelength(nm(wl)).expect("inside the tables");
            assert!(r.is_spectrally_flat());
            for (a, b) in [
                ((10.0, 0.0), (40.0, 180.0)),
                ((60.0, 30.0), (60.0, 210.0)),
                ((0.0, 0.0), (75.0, 90.0)),
            ] {
                let wi = Direction::from_spherical_deg(a.0, a.1);
                let wo = Direction::from_spherical_deg(b.0, b.1);
                assert_eq!(
                    m.eval(&wi, &wo, nm(wl)),
                    r.eval(&wi, &wo, nm(wl)),
                    "{name} at {wl}"
                );
                assert_eq!(
                    m.delta_lobe(&wi, nm(wl)),
                    r.delta_lobe(&wi, nm(wl)),
                    "{name} at {wl}"
                );
            }
        }
    }
}
