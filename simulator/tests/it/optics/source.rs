//! The source over time: noise off repeats exactly, seeded noise reproduces, drift is slow, and a series of
//! samples at rest is bit for bit the readings at each instant.

use gonio_brdf::Material;
use gonio_simulator::optics::Optics;
use gonio_simulator::scene::{Band, Scene};

use super::{BAND_550, instrument, pose, sample};

#[test]
fn noise_off_repeats_exactly_and_seeded_noise_reproduces() {
    let inst = instrument(); // relative_noise 1e-4, drift 0.2 %/h
    let m = Material::preset("construction-paper").expect("preset");
    let p = pose(30.0, -45.0, 5.0, 10.0);
    let band = Band {
        band_nm: Some(650.0),
        transmission: 0.5,
    };
    let off = Optics::new(&inst, sample(m.clone(), 25.0), 7)
        .expect("optics")
        .with_source_noise(false);
    let a = off.reading(&p, &band, 100.0).expect("reading");
    let b = off.reading(&p, &band, 100.0).expect("reading");
    assert_eq!(a, b);
    assert_eq!(a.power_w, a.noiseless_power_w);

    // Drift off too, so that only the noise depends on the seed.
    let n1 = Optics::new(&inst, sample(m.clone(), 25.0), 7)
        .expect("optics")
        .with_source_drift(false);
    let n2 = Optics::new(&inst, sample(m.clone(), 25.0), 7)
        .expect("optics")
        .with_source_drift(false);
    let n3 = Optics::new(&inst, sample(m, 25.0), 8)
        .expect("optics")
        .with_source_drift(false);
    let mut differs = 0;
    for i in 0..50 {
        let t = 10.0 + i as f64 * 0.3;
        let (x, y, z) = (
            n1.reading(&p, &band, t).expect("reading"),
            n2.reading(&p, &band, t).expect("reading"),
            n3.reading(&p, &band, t).expect("reading"),
        );
        assert_eq!(x, y);
        assert_eq!(x.noiseless_power_w, z.noiseless_power_w);
        if x.power_w != z.power_w {
            differs += 1;
        }
        // Relative noise of 1e-4: readings stay within 6 sigma of the noiseless value.
        assert!((x.power_w / x.noiseless_power_w - 1.0).abs() < 6e-4);
    }
    assert_eq!(differs, 50);
}

#[test]
fn a_series_at_rest_is_exactly_the_readings_at_each_instant() {
    // The power meter averages several samples of a pose at rest through `detector_power_series_w`, which computes
    // the geometry once: every value must be bit-identical to a separate `detector_power_w` at that instant, with
    // the source's drift and noise on (so that the instants really differ).
    let inst = instrument();
    let glossy = Optics::new(
        &inst,
        sample(Material::preset("coloured-plastic").expect("preset"), 12.5),
        11,
    )
    .expect("optics");
    let times: Vec<f64> = (0..10).map(|k| 1234.5 + (k as f64 + 0.5) * 0.003).collect();
    let facing = Optics::direct_beam_pose(-90.0);
    let cases = [
        // Specular geometry (lobe inside the aperture), off-specular, the blank, and retro-reflection (blocked).
        (pose(-30.0, 30.0, 0.0, 0.0), BAND_550),
        (pose(-60.0, 10.0, 3.0, 20.0), BAND_550),
        (pose(-30.0, 30.0, 0.0, 0.0), Band::BLANK),
        (pose(-30.0, -29.5, 0.0, 0.0), BAND_550),
    ];
    let mut series = Vec::new();
    for (p, band) in cases {
        glossy.detector_power_series_w(&p, &band, &times, &mut series);
        let singles: Vec<f64> = times
            .iter()
            .map(|&t| glossy.detector_power_w(&p, &band, t))
            .collect();
        assert_eq!(series.len(), times.len());
        for (a, b) in series.iter().zip(&singles) {
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "{p:?} {band:?}: {series:?} vs {singles:?}"
            );
        }
    }
    // The lit case is really noisy: the instants differ.
    glossy.detector_power_series_w(&cases[0].0, &BAND_550, &times, &mut series);
    assert!(
        series.iter().any(|p| *p != series[0]) && series[0] > 0.0,
        "{series:?}"
    );
    // No sample: the direct beam, same rule.
    glossy.set_sample_mounted(false);
    let p = facing;
    glossy.detector_power_series_w(&p, &BAND_550, &times, &mut series);
    for (a, &t) in series.iter().zip(&times) {
        assert_eq!(a.to_bits(), glossy.detector_power_w(&p, &BAND_550, t).to_bits());
    }
    assert!(series[0] > 0.0);
}

#[test]
fn source_drift_moves_the_power_slowly() {
    let inst = instrument();
    let optics = Optics::new(
        &inst,
        sample(Material::preset("spectralon").expect("preset"), 25.0),
        3,
    )
    .expect("optics")
    .with_source_noise(false);
    let band = BAND_550;
    let p0 = optics.direct_beam_power_w(&band, 0.0);
    assert_eq!(p0, 1e-3 * 0.5);
    let p1 = optics.direct_beam_power_w(&band, 1.0);
    let p_late = optics.direct_beam_power_w(&band, 4.0 * 3600.0);
    // At most 0.2 % per hour.
    assert!((p1 / p0 - 1.0).abs() <= 0.002 / 3600.0 * (1.0 + 1e-9));
    assert!((p_late / p0 - 1.0).abs() <= 4.0 * 0.002);
    assert!(p_late != p0);
}
