//! The sample's non-uniformity against its model written out here (module doc of
//! simulator/src/imperfections/sample.rs): the reading on an uneven sample over the reading on an even
//! one is the mean of `m` over the beam's footprint, an ellipse of semi-axes r_b / cos(theta_i) and r_b about the
//! spot.

use gonio_instrument::{GeometryImperfections, InstrumentFile, SampleImperfections};

use super::{BAND_550, optics, pose};

/// Beam and sample radii of config/instruments/simulated.toml and of `optics` (mm).
const BEAM_MM: f64 = 1.5;
const SAMPLE_MM: f64 = 25.0;

fn file(sample: SampleImperfections, geometry: GeometryImperfections) -> InstrumentFile {
    let mut f = InstrumentFile::simulated();
    f.simulator.seed = 21;
    f.simulator.imperfections.sample = sample;
    f.simulator.imperfections.geometry = geometry;
    f
}

/// `m` averaged over the footprint, written out from the model.
fn mean_m(gradient: [f64; 2], radial: f64, spot: [f64; 2], theta_i_rad: f64) -> f64 {
    let a = BEAM_MM / theta_i_rad.cos();
    let second = spot[0] * spot[0] + spot[1] * spot[1] + (a * a + BEAM_MM * BEAM_MM) / 4.0;
    1.0 + (gradient[0] * spot[0] + gradient[1] * spot[1]) / SAMPLE_MM
        + radial * second / (SAMPLE_MM * SAMPLE_MM)
}

#[test]
fn a_larger_footprint_sees_a_different_mean() {
    let uneven = SampleImperfections {
        gradient_sd: 0.02,
        radial_sd: 0.05,
    };
    let even = optics(&InstrumentFile::simulated());
    let f = file(uneven, GeometryImperfections::default());
    let o = optics(&f);
    let truth = gonio_simulator::imperfections::HiddenTruth::draw(&f)
        .and_then(|h| h.sample)
        .expect("sample truth");
    let mut ratios = Vec::new();
    for theta_i in [0.0, 40.0, 70.0, 80.0] {
        // In-plane, detector 30 degrees off the mirror direction on the other side.
        let p = pose(theta_i, -(theta_i - 30.0f64).abs().max(10.0), 0.0, 0.0);
        let r0 = even.reading(&p, &BAND_550, 5.0).expect("reading");
        let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
        // The spot is the centre on this geometry: only the radial term and the footprint's size act.
        let expected = mean_m(truth.gradient, truth.radial, [0.0, 0.0], r0.wi.theta());
        let ratio = r1.power_w / r0.power_w;
        assert!(
            (ratio - expected).abs() < 1e-12,
            "theta_i {theta_i}: {ratio} vs {expected}"
        );
        assert_eq!(
            r1.truth_aperture_sr, r0.truth_aperture_sr,
            "the truth is the material's"
        );
        ratios.push(ratio);
    }
    assert!(
        (ratios[3] - ratios[0]).abs() > 1e-4,
        "the grazing footprint's mean differs: {ratios:?}"
    );
}

#[test]
fn an_off_centre_spot_sees_the_gradient() {
    let uneven = SampleImperfections {
        gradient_sd: 0.05,
        radial_sd: 0.02,
    };
    let geometry = GeometryImperfections {
        eccentricity_sd_mm: 2.0,
        ..Default::default()
    };
    let both = file(uneven, geometry.clone());
    let (o, geometric_only) = (
        optics(&both),
        optics(&file(SampleImperfections::default(), geometry)),
    );
    let truth = gonio_simulator::imperfections::HiddenTruth::draw(&both)
        .and_then(|h| h.sample)
        .expect("sample truth");
    for p in [pose(30.0, -40.0, 0.0, 0.0), pose(55.0, -20.0, 10.0, 70.0)] {
        let r0 = geometric_only.reading(&p, &BAND_550, 5.0).expect("reading");
        let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
        assert!(r1.spot_mm != [0.0, 0.0], "the eccentricity moves the spot");
        let expected = mean_m(truth.gradient, truth.radial, r1.spot_mm, r1.wi.theta());
        let ratio = r1.power_w / r0.power_w;
        assert!((ratio - expected).abs() < 1e-12, "{ratio} vs {expected}");
        assert!((r1.sample_factor - expected).abs() < 1e-12);
    }
}
