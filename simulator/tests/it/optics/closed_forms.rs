//! Readings against closed forms: a Lambertian sample's projected solid angle, a mirror's Fresnel reflectance
//! (with and without beam divergence), and gold's normal-incidence reflectance and rough lobe.

use std::f64::consts::PI;

use gonio_brdf::{Brdf, Direction, Material};
use gonio_simulator::scene::Scene;

use super::{BAND_550, beta_of, brute_cone, instrument, material, pose, quiet, sample, wl};

/// Exact unpolarised conductor Fresnel reflectance, written from the reference document.
fn fresnel_conductor(cos_t: f64, eta: f64, k: f64) -> f64 {
    let c = cos_t;
    let s2 = 1.0 - c * c;
    let e2k2 = eta * eta - k * k;
    let a2b2 = ((e2k2 - s2).powi(2) + 4.0 * eta * eta * k * k).sqrt();
    let a = ((a2b2 + e2k2 - s2) / 2.0).sqrt();
    let rs = (a2b2 + c * c - 2.0 * a * c) / (a2b2 + c * c + 2.0 * a * c);
    let rp = rs * (c * c * a2b2 + s2 * s2 - 2.0 * a * c * s2) / (c * c * a2b2 + s2 * s2 + 2.0 * a * c * s2);
    (rs + rp) / 2.0
}

#[test]
fn lambertian_power_is_albedo_over_pi_times_the_projected_solid_angle() {
    let inst = instrument();
    let optics = quiet(
        &inst,
        sample(material("[material]\nmodel = \"lambertian\"\nalbedo = 0.8"), 25.0),
    );
    let beta = beta_of(&inst);
    for p in [
        pose(30.0, -50.0, 10.0, 20.0),
        pose(-20.0, 60.0, -35.0, 140.0),
        pose(45.0, -45.0, 0.0, 0.0),
    ] {
        let r = optics.reading(&p, &BAND_550, 0.0).expect("reading");
        assert_eq!(r.intercepted_fraction, 1.0);
        // Projected solid angle of the tilted cone, by brute force.
        let proj = brute_cone(&r.wo, beta, 400, 256, &mut |w| w.z());
        let expect = 1e-3 * 0.5 * 0.8 / PI * proj;
        assert!(
            (r.power_w - expect).abs() < 1e-9 * expect,
            "{p:?}: {} vs {expect}",
            r.power_w
        );
        assert!((r.truth_point_sr - 0.8 / PI).abs() < 1e-15);
        // The measurement equation's Omega cos(theta_o) exceeds the cone's projected solid angle
        // pi sin^2(beta) cos(theta_o) by the factor 2 / (1 + cos beta): what an ideal measurement reports.
        let reported = 0.8 / PI * (1.0 + beta.cos()) / 2.0;
        assert!((r.truth_aperture_sr - reported).abs() < 1e-12 * reported);
        // The integral of a Lambertian sample costs one evaluation.
        assert_eq!(r.evaluations, 1);
        assert!(r.integration_error_w <= 1e-12 * r.power_w);
        assert_eq!(optics.detector_power_w(&p, &BAND_550, 0.0), r.power_w);
    }
}

#[test]
fn mirror_reflects_fresnel_times_the_beam_into_the_aperture_and_nothing_elsewhere() {
    let inst = instrument();
    let optics = quiet(&inst, sample(Material::preset("mirror").expect("preset"), 25.0));
    // Aluminium at 550 nm: 0.959 + 6.687i (preset table node).
    for (light, tilt, rotation) in [(30.0, 0.0, 0.0), (50.0, 15.0, 40.0), (-70.0, -10.0, 100.0)] {
        // In-plane specular geometry: detector at -light for zero tilt; with tilt, find the mirror pose by
        // reflecting the source direction about the normal in the lab.
        let mut p = pose(light, -light, tilt, rotation);
        let r0 = optics.reading(&p, &BAND_550, 0.0).expect("reading");
        if tilt != 0.0 {
            // Use the sample-frame mirror direction through the truth API instead of a pose.
            let wi = r0.wi;
            let t = optics
                .truth_aperture(&wi, &wi.reflect_about_normal(), wl(550.0))
                .expect("truth");
            let f = fresnel_conductor(wi.z(), 0.959, 6.687);
            assert!((t.delta - f).abs() < 1e-12, "{} vs {f}", t.delta);
            assert_eq!(t.integral, 0.0);
            continue;
        }
        let f = fresnel_conductor(f64::to_radians(light).cos(), 0.959, 6.687);
        assert!(r0.specular_in_aperture);
        let expect = 1e-3 * 0.5 * f;
        assert!(
            (r0.power_w - expect).abs() < 1e-12 * expect,
            "{} vs {expect}",
            r0.power_w
        );
        // One degree off the mirror direction (the aperture's half-angle is 0.57 degrees): nothing.
        p.detector_deg -= 1.0;
        let r1 = optics.reading(&p, &BAND_550, 0.0).expect("reading");
        assert!(!r1.specular_in_aperture);
        assert_eq!(r1.power_w, 0.0);
        assert_eq!(r1.evaluations, 0);
    }
}

#[test]
fn mirror_with_a_divergent_beam_fades_across_the_aperture_edge() {
    let mut inst = instrument();
    inst.source.divergence_deg = 0.4; // half-angle 0.2 deg, aperture half-angle 0.573 deg
    let optics = quiet(&inst, sample(Material::preset("mirror").expect("preset"), 25.0));
    let beta_deg = beta_of(&inst).to_degrees();
    let full = optics
        .reading(&pose(30.0, -30.0, 0.0, 0.0), &BAND_550, 0.0)
        .expect("reading")
        .power_w;
    let mut last = full;
    // Offsets of the detector from the mirror direction: inside, across the edge (beta - 0.2 .. beta + 0.2), out.
    for k in 0..=20 {
        let off = beta_deg - 0.25 + 0.025 * k as f64;
        let p = optics
            .reading(&pose(30.0, -30.0 - off, 0.0, 0.0), &BAND_550, 0.0)
            .expect("reading")
            .power_w;
        assert!(p <= last + 1e-18, "power must fall monotonically across the edge");
        if off < beta_deg - 0.2 {
            assert!((p - full).abs() < 1e-12 * full);
        } else if off > beta_deg + 0.2 {
            assert_eq!(p, 0.0);
        } else if (off - beta_deg).abs() < 0.01 {
            // Centred on the edge: about half of the small cone is in (the edge is curved: slightly less).
            assert!(p > 0.4 * full && p < 0.5 * full, "{p} vs {full}");
        }
        last = p;
    }
}

#[test]
fn gold_at_normal_incidence() {
    let inst = instrument();
    // Polished gold (alpha below the delta switch-over): the reflected power at normal incidence is R0 exactly.
    let smooth = material(
        "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"height-correlated\"\nalpha = 1e-4\n\
         eta = { 450 = 1.509, 550 = 0.350, 650 = 0.168 }\nk = { 450 = 1.879, 550 = 2.714, 650 = 3.138 }",
    );
    let optics = quiet(&inst, sample(smooth, 25.0));
    let (eta, k): (f64, f64) = (0.350, 2.714);
    let r0 = ((eta - 1.0) * (eta - 1.0) + k * k) / ((eta + 1.0) * (eta + 1.0) + k * k);
    assert!((r0 - 0.847).abs() < 1e-3);
    let t = optics
        .truth_aperture(&Direction::NORMAL, &Direction::NORMAL, wl(550.0))
        .expect("truth");
    assert!((t.delta - r0).abs() < 1e-12, "{} vs {r0}", t.delta);
    let omega = optics.aperture_solid_angle_sr();
    assert!((t.average_sr - r0 / omega).abs() < 1e-9 * t.average_sr);

    // Rough gold (the preset, alpha 0.08): the aperture average at near-normal incidence against brute force,
    // through a pose: light +6, detector -6 (12 degrees apart, beyond the retro block), tilt 0 puts the specular
    // peak at the aperture's centre with theta_i = theta_o = 6 deg.
    let gold = Material::preset("gold").expect("preset");
    let resolved = gold.at_wavelength(wl(550.0)).expect("in range");
    let optics = quiet(&inst, sample(gold, 25.0));
    let r = optics
        .reading(&pose(6.0, -6.0, 0.0, 0.0), &BAND_550, 0.0)
        .expect("reading");
    assert!(r.specular_in_aperture);
    assert!((r.wi.theta().to_degrees() - 6.0).abs() < 1e-9 && (r.wo.theta().to_degrees() - 6.0).abs() < 1e-9);
    let wi = r.wi;
    let bf = brute_cone(&r.wo, beta_of(&inst), 400, 256, &mut |w| {
        resolved.eval(&wi, w, wl(550.0)).expect("eval") * w.z()
    });
    let expect = 1e-3 * 0.5 * bf;
    assert!(
        (r.power_w - expect).abs() < 1e-6 * expect,
        "{} vs {expect}",
        r.power_w
    );
    assert!(r.integration_error_w <= 1e-6 * r.power_w);
    // The point value at the specular peak is higher than the aperture average (the lobe curves down).
    assert!(r.truth_point_sr > r.truth_aperture_sr);
}
