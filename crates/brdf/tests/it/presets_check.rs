//! Every preset obeys the physical laws `gonio brdf check` tests, at every band of the simulated instrument.
//!
//! Regression: gold and coloured-plastic once failed the isotropy check because the microfacet sidedness test
//! used dot products with a rounded half vector; near the horizon, for nearly opposite in-plane directions, the
//! rounding flipped the sign and f jumped between 0 and ~1e11 under a rotation about the normal.

use gonio_brdf::checks::{CheckOptions, check_brdf};
use gonio_brdf::{Brdf, Direction, Material, Wavelength};

#[test]
fn every_preset_passes_the_property_checks_at_every_band() {
    for name in Material::preset_names() {
        let material = Material::preset(name).expect("preset loads");
        for nm in [450.0, 550.0, 650.0] {
            let options = CheckOptions {
                wavelength: Wavelength::from_nm(nm).expect("nm"),
                ..Default::default()
            };
            let report = check_brdf(&material, &options).expect("in range");
            assert!(report.passed(), "{name} at {nm} nm:\n{report}");
        }
    }
}

#[test]
fn grazing_nearly_opposite_pair_is_invariant_under_rotation() {
    let wl = Wavelength::DEFAULT;
    let theta = std::f64::consts::FRAC_PI_2 - 1e-9;
    for name in ["gold", "coloured-plastic"] {
        let material = Material::preset(name).expect("preset");
        let wi = Direction::from_spherical(theta, 0.0);
        let wo = Direction::from_spherical(theta, std::f64::consts::PI);
        let reference = material.eval(&wi, &wo, wl).expect("eval");
        for k in 1..16 {
            let rot = k as f64 * 0.41;
            let value = material
                .eval(&wi.rotate_z(rot), &wo.rotate_z(rot), wl)
                .expect("eval");
            let scale = reference.abs().max(value.abs()).max(1e-300);
            assert!(
                (value - reference).abs() / scale < 1e-6,
                "{name}: {reference} vs {value} at rotation {rot}"
            );
        }
    }
}
