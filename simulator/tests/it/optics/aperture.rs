//! The aperture integral against a brute-force rule written here: every preset over random geometries, Oren-Nayar
//! apertures straddling its kinks, and the aperture average tending to the point value.

use gonio_brdf::{Brdf, Direction, Material};
use gonio_testkit::rng::XorShift;

use super::{BAND_550, beta_of, brute_cone, instrument, pose, quiet, random_geometry, sample, wl};

/// Random geometries over every preset, at the instrument's aperture and at a five times larger one: the adaptive
/// aperture integral must agree with a brute-force rule to 1e-6 relative, and say so in its own error estimate.
#[test]
fn aperture_integral_meets_the_tolerance_over_all_presets_and_random_geometries() {
    let mut uniform = XorShift::new(0x1234_5678_9ABC_DEF0).into_uniform();
    for aperture_mm in [2.5, 12.5] {
        let mut inst = instrument();
        inst.detector.aperture_radius_mm = aperture_mm;
        let beta = beta_of(&inst);
        for name in [
            "mirror",
            "white-styrofoam",
            "construction-paper",
            "coloured-plastic",
            "gold",
            "spectralon",
        ] {
            let m = Material::preset(name).expect("preset");
            for nm in [450.0, 650.0] {
                let resolved = m.at_wavelength(wl(nm)).expect("in range");
                let optics = quiet(&inst, sample(m.clone(), 25.0));
                for case in 0..5 {
                    let (wi, wo) = random_geometry(&mut uniform, beta, case % 2 == 0);
                    let t = optics.truth_aperture(&wi, &wo, wl(nm)).expect("truth");
                    let bf = brute_cone(&wo, beta, 200, 512, &mut |w| {
                        resolved.eval(&wi, w, wl(nm)).expect("eval") * w.z()
                    });
                    let scale = bf.abs().max(1e-300);
                    assert!(
                        (t.integral - bf).abs() <= 1e-6 * scale,
                        "{name} {nm} nm beta {beta}: wi {:?} wo {:?}: {} vs brute force {bf} ({:e} relative, {} evaluations)",
                        wi.to_spherical_deg(),
                        wo.to_spherical_deg(),
                        t.integral,
                        (t.integral - bf) / scale,
                        t.evaluations
                    );
                    assert!(
                        t.integral_error <= 1e-6 * scale + 1e-300,
                        "{name}: error estimate {}",
                        t.integral_error
                    );
                }
            }
        }
    }
}

#[test]
fn aperture_average_tends_to_the_point_value_as_the_aperture_shrinks() {
    let gold = Material::preset("gold").expect("preset");
    let p = pose(40.0, -25.0, 0.0, 0.0); // 15 degrees off specular: on the lobe's flank
    let mut gaps = Vec::new();
    for aperture_mm in [10.0, 2.5, 0.625] {
        let mut inst = instrument();
        inst.detector.aperture_radius_mm = aperture_mm;
        let optics = quiet(&inst, sample(gold.clone(), 25.0));
        let r = optics.reading(&p, &BAND_550, 0.0).expect("reading");
        gaps.push((r.truth_aperture_sr - r.truth_point_sr).abs() / r.truth_point_sr);
    }
    // A smooth function's average over a disc differs from its centre value by O(beta^2): each quartering of
    // the radius divides the gap by about 16.
    assert!(gaps[0] > 1e-4, "{gaps:?}");
    for w in gaps.windows(2) {
        let ratio = w[0] / w[1];
        assert!(ratio > 12.0 && ratio < 20.0, "{gaps:?}");
    }
}

/// Oren-Nayar has two kinks (cos(phi_o - phi_i) = 0 and theta_o = theta_i): apertures straddling them must still
/// meet the tolerance, which the smooth tensor rules cannot guarantee there.
#[test]
fn oren_nayar_kinks_across_the_aperture_meet_the_tolerance() {
    let m = Material::preset("construction-paper").expect("preset");
    let resolved = m.at_wavelength(wl(650.0)).expect("in range");
    for aperture_mm in [2.5, 12.5] {
        let mut inst = instrument();
        inst.detector.aperture_radius_mm = aperture_mm;
        let beta = beta_of(&inst);
        let optics = quiet(&inst, sample(m.clone(), 25.0));
        let wi = Direction::from_spherical_deg(40.0, 0.0);
        for (theta_o, phi_o) in [
            (30.0, 90.0),
            (30.0, 90.3),
            (40.0, 60.0),
            (39.8, 20.0),
            (40.2, 89.9),
        ] {
            let wo = Direction::from_spherical_deg(theta_o, phi_o);
            let t = optics.truth_aperture(&wi, &wo, wl(650.0)).expect("truth");
            let bf = brute_cone(&wo, beta, 800, 1024, &mut |w| {
                resolved.eval(&wi, w, wl(650.0)).expect("eval") * w.z()
            });
            assert!(
                (t.integral - bf).abs() <= 1e-6 * bf,
                "beta {beta} wo ({theta_o}, {phi_o}): {} vs {bf} ({:e})",
                t.integral,
                (t.integral - bf) / bf
            );
        }
    }
}
