//! The sample itself: removed for the direct beam (the detector facing the source), its orientation rotating an
//! anisotropic material's frame, and bad samples and bands refused with a message.

use std::f64::consts::PI;

use gonio_brdf::{Brdf, Direction, Material};
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::{Band, Scene};

use super::{BAND_550, instrument, material, pose, quiet, sample, wl};

#[test]
fn direct_beam_needs_the_sample_removed_and_the_detector_facing_the_source() {
    let inst = instrument();
    let optics = quiet(
        &inst,
        sample(Material::preset("spectralon").expect("preset"), 25.0),
    );
    let facing = Optics::direct_beam_pose(-90.0);
    assert_eq!(facing.detector_deg, 90.0);
    // With the sample in place the detector is behind it: nothing.
    assert_eq!(
        optics.reading(&facing, &BAND_550, 0.0).expect("reading").power_w,
        0.0
    );
    optics.set_sample_mounted(false);
    let r = optics.reading(&facing, &BAND_550, 0.0).expect("reading");
    assert_eq!(r.power_w, 1e-3 * 0.5);
    assert_eq!(r.power_w, optics.direct_beam_power_w(&BAND_550, 0.0));
    // Turned 1 degree away (more than the aperture's half-angle plus the divergence): nothing.
    let mut off = facing;
    off.detector_deg += 1.0;
    assert_eq!(
        optics.reading(&off, &BAND_550, 0.0).expect("reading").power_w,
        0.0
    );
    // Blank: nothing at all.
    assert_eq!(
        optics
            .reading(&facing, &Band::BLANK, 0.0)
            .expect("reading")
            .power_w,
        0.0
    );
    optics.set_sample_mounted(true);
}

#[test]
fn anisotropic_orientation_rotates_the_material_frame() {
    let inst = instrument();
    let aniso = "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"separable\"\n\
                 alpha_x = 0.05\nalpha_y = 0.3\neta = 0.35\nk = 2.714";
    let at = |orientation_deg: f64| {
        let s = SampleSpec {
            material: material(aniso),
            radius_mm: 25.0,
            orientation_deg,
        };
        quiet(&inst, s)
    };
    let wi = Direction::from_spherical_deg(40.0, 0.0);
    let wo = Direction::from_spherical_deg(35.0, 170.0);
    let m = material(aniso);
    // Orientation 90: the material's x axis is the sample's y axis, so sample-frame directions rotated by +90
    // about the normal see what the unrotated material sees.
    let rotated = at(90.0)
        .truth(&wi.rotate_z(PI / 2.0), &wo.rotate_z(PI / 2.0), wl(550.0))
        .expect("truth");
    let direct = m.eval(&wi, &wo, wl(550.0)).expect("eval");
    assert!((rotated - direct).abs() < 1e-12 * direct, "{rotated} vs {direct}");
    let unrotated = at(0.0)
        .truth(&wi.rotate_z(PI / 2.0), &wo.rotate_z(PI / 2.0), wl(550.0))
        .expect("truth");
    assert!((unrotated - direct).abs() > 1e-3 * direct);
}

#[test]
fn bad_samples_and_bands_are_refused_with_a_message() {
    let inst = instrument();
    let err =
        Optics::new(&inst, sample(Material::preset("gold").expect("preset"), 0.0), 1).expect_err("radius 0");
    assert!(err.to_string().contains("radius_mm"), "{err}");
    // A material whose table does not cover the instrument's 450 nm band.
    let narrow = material("[material]\nmodel = \"lambertian\"\nalbedo = { 500 = 0.5, 700 = 0.6 }");
    let err = Optics::new(&inst, sample(narrow, 10.0), 1).expect_err("band outside the table");
    assert!(err.to_string().contains("450"), "{err}");
    let optics = quiet(&inst, sample(Material::preset("gold").expect("preset"), 10.0));
    assert!(
        optics
            .reading(
                &pose(30.0, -30.0, 0.0, 0.0),
                &Band {
                    band_nm: Some(900.0),
                    transmission: 1.0
                },
                0.0
            )
            .is_err()
    );
    assert_eq!(
        optics.detector_power_w(
            &pose(30.0, -30.0, 0.0, 0.0),
            &Band {
                band_nm: Some(900.0),
                transmission: 1.0
            },
            0.0
        ),
        0.0
    );
    assert!(
        Optics::new(&inst, sample(Material::preset("gold").expect("preset"), 10.0), 1)
            .expect("ok")
            .with_tolerance(0.0)
            .is_err()
    );
}
