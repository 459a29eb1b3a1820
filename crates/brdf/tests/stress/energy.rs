//! Energy: directional albedo at most 1 for random models up to grazing, Oren-Nayar's sharp bound at albedo 1,
//! and reflected power continuous across the roughness clamp and the delta switch-over.

use std::f64::consts::FRAC_PI_2;

use gonio_brdf::integrate::{Region, Rule, Tolerance, directional_albedo, integrate_adaptive};
use gonio_brdf::microfacet::{ALPHA_DELTA, ALPHA_MIN, Distribution, Masking};
use gonio_brdf::models::{Conductor, OrenNayar};
use gonio_brdf::{Brdf, Direction};

use super::models::random_model;
use super::{Failures, Rng, WL, c, large};

/// Directional albedo <= 1 + integration error for random models of every kind (albedo 1, k >> eta, alpha
/// 1e-6..1, anisotropy), at incidences from the pole to within 1e-9 rad of the horizon.
#[test]
fn random_models_conserve_energy() {
    let per_kind = if large() { 12 } else { 2 };
    let mut r = Rng(4);
    let mut fails = Failures::default();
    let incidences = [0.0, 1e-12, 1.0, 1.4, 1.5533, FRAC_PI_2 - 1e-9];
    for kind in 0..6 {
        for _ in 0..per_kind {
            let (name, m) = random_model(kind, &mut r);
            for &t in &incidences {
                let wi = Direction::from_spherical(t, 0.7);
                let a = directional_albedo(&m, &wi, WL, 1e-5).expect("constant parameters");
                // Energy <= 1 + the integration tolerance asked (1e-5) or the estimated error if larger. The
                // tolerance matters: Oren-Nayar at rho 1 (sup exactly 1, grazing) at theta_i = pi/2 - 1e-9 integrates
                // to 1.0000017 with an estimated error of 4.6e-7; its kink at theta_o = theta_i, 1e-9 rad from the
                // horizon, defeats the error estimate by a factor of about 4.
                if !(a.value.is_finite() && a.value >= 0.0 && a.value <= 1.0 + a.error.max(1e-5) + 1e-9)
                    || a.error > 1e-3
                {
                    fails.add(format!("{name} at theta_i {t}: albedo {a:?}"));
                }
            }
        }
    }
    fails.assert_none("energy");
}

/// Regression (Oren-Nayar): the classic model exceeded albedo 1 at rho = 1 near grazing (1.0021 at sigma 17.4 deg,
/// theta_i 88 deg; sup 1.0152 at sigma 11.4 deg). Normalised now; the bound A + B/2 <= 1 is sharp, so the albedo
/// must approach but never pass 1.
#[test]
fn oren_nayar_at_albedo_one_stays_below_one_at_grazing() {
    for sigma in [5.0, 11.4, 17.4, 18.0] {
        let m = OrenNayar::new(c(1.0), sigma).expect("valid");
        let mut last = 0.0;
        for theta_deg in [0.0, 45.0, 80.0, 88.0, 89.9] {
            let wi = Direction::from_spherical_deg(theta_deg, 0.0);
            let a = directional_albedo(&m, &wi, WL, 1e-9).expect("flat");
            assert!(a.value <= 1.0 + a.error, "sigma {sigma} theta {theta_deg}: {a:?}");
            // G(theta_i) grows monotonically with incidence.
            assert!(
                a.value >= last - 1e-9,
                "sigma {sigma} theta {theta_deg}: {a:?} < {last}"
            );
            last = a.value;
        }
        // The supremum is 1 (reached at grazing): 89.9 deg is within 2e-3 of it.
        assert!(last > 0.998, "sigma {sigma}: {last}");
    }
}

/// Below the clamp (1e-4) every alpha gives the same model bit for bit; below the switch-over (1e-3, both alphas)
/// the lobe is a delta whose reflectance `F G` equals, to O(alpha^2), the power the narrowest lobe reflects.
/// Checked as the total reflected power (directional albedo, delta included) and as the power reflected into a
/// small cone around the mirror direction, just above and just below the switch, for both distributions and
/// maskings, conductor and plastic, at incidences up to 85 deg.
#[test]
fn alpha_clamp_and_delta_switch_are_continuous_in_reflected_power() {
    let wl = WL;
    for d in [Distribution::Ggx, Distribution::Beckmann] {
        for mm in [Masking::Separable, Masking::HeightCorrelated] {
            let cond = |a: f64| Conductor::new(d, mm, a, a, c(0.35), c(2.714)).expect("valid");
            // Clamp: identical below 1e-4.
            let at_clamp = cond(ALPHA_MIN);
            for a in [1e-6, 1e-5, 5e-5] {
                let m = cond(a);
                assert_eq!(m.microfacet(), at_clamp.microfacet(), "alpha {a}");
                for t in [0.0, 0.7, 1.4] {
                    let wi = Direction::from_spherical(t, 0.3);
                    assert_eq!(m.delta_lobe(&wi, wl), at_clamp.delta_lobe(&wi, wl));
                }
            }
            for theta_deg in [0.0, 30.0, 60.0, 85.0] {
                let wi = Direction::from_spherical_deg(theta_deg, 20.0);
                let above = cond(ALPHA_DELTA * (1.0 + 1e-9));
                let below = cond(ALPHA_DELTA * (1.0 - 1e-9));
                assert!(!above.has_delta_lobe() && below.has_delta_lobe());
                let a_above = directional_albedo(&above, &wi, wl, 1e-8).expect("flat");
                let a_below = directional_albedo(&below, &wi, wl, 1e-8).expect("flat");
                let rel = (a_above.value - a_below.value).abs() / a_below.value;
                assert!(
                    rel < 1e-5 + a_above.error / a_below.value,
                    "{d:?} {mm:?} theta {theta_deg}: lobe {a_above:?} vs delta {a_below:?}"
                );
                // Power into a cone about the mirror direction (a detector aperture of half-angle beta). The delta
                // puts all of F G inside; the lobe just above the switch puts inside all but its tail beyond beta.
                // Beckmann's tail is exp(-(beta/2)^2/alpha^2): nothing; GGX's is a power law: at normal incidence
                // the fraction of the lobe with tan(theta_h) > t is alpha^2 / (alpha^2 + t^2), t = tan(beta/2)
                // (1.6e-3 for beta = 0.05 rad, 3.8% for the simulated instrument's 0.01 rad). That jump is real
                // and documented in microfacet/mod.rs; it is checked here to be exactly the tail, nothing more.
                let mirror = wi.reflect_about_normal();
                for beta in [0.01, 0.05] {
                    let cone = integrate_adaptive(
                        |w: &Direction| above.eval(&wi, w, wl).map(|f| f * w.z().max(0.0)),
                        &Region::cone(mirror, beta),
                        Rule::LobeAdapted {
                            lobe_width_rad: ALPHA_DELTA,
                            n_per_panel: 8,
                            n_azimuth: 16,
                        },
                        Tolerance::relative(1e-9),
                    )
                    .expect("flat");
                    let delta = below
                        .delta_lobe(&wi, wl)
                        .expect("flat")
                        .map_or(0.0, |l| l.reflectance);
                    let ratio = cone.value / delta;
                    match d {
                        Distribution::Beckmann => assert!(
                            (ratio - 1.0).abs() < 1e-5,
                            "{d:?} {mm:?} theta {theta_deg} beta {beta}: cone {cone:?} vs delta {delta}"
                        ),
                        Distribution::Ggx => {
                            let t2 = (0.5 * beta).tan().powi(2);
                            let a2 = ALPHA_DELTA * ALPHA_DELTA;
                            let inside = 1.0 - a2 / (a2 + t2);
                            if theta_deg == 0.0 {
                                assert!(
                                    (ratio - inside).abs() < 1e-4,
                                    "{d:?} {mm:?} beta {beta}: ratio {ratio} vs GGX tail prediction {inside}"
                                );
                            }
                            assert!(ratio <= 1.0 + 1e-9, "{d:?} {mm:?} theta {theta_deg}: {ratio}");
                        }
                    }
                }
            }
        }
    }
}
