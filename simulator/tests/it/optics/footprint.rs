//! Where the beam lands and what stops it: the footprint spilling past the sample at grazing incidence (against
//! counted grid cells), the field of view overfilled, and the detector's body blocking the beam.

use gonio_brdf::Material;

use super::{BAND_550, instrument, material, pose, quiet, sample};

#[test]
fn grazing_footprint_spills_past_the_sample_and_the_power_falls_with_it() {
    let inst = instrument();
    let lambert = || material("[material]\nmodel = \"lambertian\"\nalbedo = 0.5");
    let big = quiet(&inst, sample(lambert(), 25.0));
    let small = quiet(&inst, sample(lambert(), 5.0));
    for (light, detector, rotation) in [(80.0, -30.0, 0.0), (84.0, 10.0, 30.0), (-78.0, 40.0, -60.0)] {
        let p = pose(light, detector, 0.0, rotation);
        let rb = big.reading(&p, &BAND_550, 0.0).expect("reading");
        let rs = small.reading(&p, &BAND_550, 0.0).expect("reading");
        // Brute-force area count of the beam ellipse inside the sample and the 12 mm field.
        let (wi, wo) = (rs.wi, rs.wo);
        let count = |r_sample: f64| {
            let (r_beam, r_field) = (1.5, 12.0);
            let extent = r_beam / wi.z();
            let n = 1500;
            let h = 2.0 * extent / n as f64;
            let (mut beam, mut kept) = (0u64, 0u64);
            for i in 0..n {
                for j in 0..n {
                    let (x, y) = (-extent + (i as f64 + 0.5) * h, -extent + (j as f64 + 0.5) * h);
                    let pi = x * wi.x() + y * wi.y();
                    if x * x + y * y - pi * pi > r_beam * r_beam {
                        continue;
                    }
                    beam += 1;
                    let po = x * wo.x() + y * wo.y();
                    if x * x + y * y <= r_sample * r_sample && x * x + y * y - po * po <= r_field * r_field {
                        kept += 1;
                    }
                }
            }
            kept as f64 / beam as f64
        };
        let (f_small, f_big) = (count(5.0), count(25.0));
        assert!(rs.overfilled_sample && !rb.overfilled_sample);
        assert!(f_small < 0.9, "the case must spill: {f_small}");
        assert!(
            (rs.intercepted_fraction - f_small).abs() < 3e-4,
            "{} vs {f_small}",
            rs.intercepted_fraction
        );
        assert!(
            (rb.intercepted_fraction - f_big).abs() < 3e-4,
            "{} vs {f_big}",
            rb.intercepted_fraction
        );
        let ratio = rs.intercepted_fraction / rb.intercepted_fraction;
        assert!((rs.power_w / rb.power_w - ratio).abs() < 1e-12);
    }
}

#[test]
fn field_of_view_overfill_is_flagged() {
    let mut inst = instrument();
    inst.detector.field_radius_mm = 2.0;
    let optics = quiet(
        &inst,
        sample(material("[material]\nmodel = \"lambertian\"\nalbedo = 0.5"), 25.0),
    );
    let r = optics
        .reading(&pose(70.0, -20.0, 0.0, 0.0), &BAND_550, 0.0)
        .expect("reading");
    assert!(r.overfilled_field && !r.overfilled_sample);
    assert!(r.intercepted_fraction < 1.0 && r.intercepted_fraction > 0.3);
}

#[test]
fn detector_blocks_the_beam_near_retro_reflection() {
    let inst = instrument(); // retro_block_deg = 5
    let optics = quiet(
        &inst,
        sample(Material::preset("white-styrofoam").expect("preset"), 25.0),
    );
    let blocked = optics
        .reading(&pose(20.0, 23.0, 0.0, 0.0), &BAND_550, 0.0)
        .expect("reading");
    assert!(blocked.beam_blocked_by_detector);
    assert_eq!(blocked.power_w, 0.0);
    // The ground truth is still there (it is the material's, not the reading's).
    assert!(blocked.truth_point_sr > 0.0);
    let free = optics
        .reading(&pose(20.0, 26.0, 0.0, 0.0), &BAND_550, 0.0)
        .expect("reading");
    assert!(!free.beam_blocked_by_detector);
    assert!(free.power_w > 0.0);
}
