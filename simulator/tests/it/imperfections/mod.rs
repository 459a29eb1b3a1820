//! The imperfect instrument against independent expectations. Each geometric effect is switched on ALONE on the
//! ideal simulated instrument; the test takes its hidden value from the public accessor and predicts the true
//! directions and the reading with formulas written here from the reference geometry of
//! crates/instrument/src/lib.rs (not with the simulator's kinematics). Here too: the ideal instrument is
//! untouched by an all-zero table, and the hidden values are fixed by the seed.
//!
//! `geometry`, `detector`, `source`, `sample`, `filters`, `beam`: one test per effect. This file: the shared set-up and the hidden truth
//! itself.

mod beam;
mod detector;
mod filters;
mod geometry;
mod sample;
mod source;

use crate::common;
use std::path::Path;
use std::sync::Arc;

use gonio_brdf::Material;
use gonio_instrument::{AxisRole, GeometryImperfections, InstrumentFile};
use gonio_simulator::SimInstrument;
use gonio_simulator::imperfections::{GeometryTruth, HiddenTruth};
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::{Band, Pose, UniformScene};

const BAND_550: Band = Band {
    band_nm: Some(550.0),
    transmission: 0.5,
};

/// The ideal simulated instrument with `geometry` as its only imperfections, on `seed`.
fn file_with(geometry: GeometryImperfections, seed: u64) -> InstrumentFile {
    let mut file = InstrumentFile::simulated();
    file.simulator.seed = seed;
    file.simulator.imperfections.geometry = geometry;
    file
}

fn lambertian() -> Material {
    Material::from_document(
        "[material]\nmodel = \"lambertian\"\nalbedo = 0.8",
        "test",
        Path::new("."),
    )
    .expect("valid material")
}

/// Optics of a Lambertian sample with drift and noise off, on `file`'s hidden truth.
fn optics(file: &InstrumentFile) -> Optics {
    optics_of_radius(file, 25.0)
}

fn optics_of_radius(file: &InstrumentFile, radius_mm: f64) -> Optics {
    optics_of(file, lambertian(), radius_mm)
}

/// Optics of a sample of `material` and radius `radius_mm` with drift and noise off, on `file`'s hidden truth.
fn optics_of(file: &InstrumentFile, material: Material, radius_mm: f64) -> Optics {
    Optics::new(
        &file.instrument,
        SampleSpec {
            material,
            radius_mm,
            orientation_deg: 0.0,
        },
        file.simulator.seed,
    )
    .expect("optics")
    .with_source_noise(false)
    .with_source_drift(false)
    .with_hidden_truth(HiddenTruth::draw(file).as_ref())
}

fn geometry_truth(file: &InstrumentFile) -> GeometryTruth {
    HiddenTruth::draw(file)
        .and_then(|h| h.geometry)
        .expect("geometry imperfections on")
}

fn pose(light_deg: f64, detector_deg: f64, tilt_deg: f64, rotation_deg: f64) -> Pose {
    Pose {
        light_deg,
        detector_deg,
        tilt_deg,
        rotation_deg,
    }
}

#[test]
fn an_all_zero_table_is_the_ideal_instrument_bit_for_bit() {
    let ideal = InstrumentFile::simulated();
    let text = format!(
        "{}\n[simulator.imperfections.geometry]\nzero_offset_sd_deg = 0.0\nsample_tilt_sd_deg = 0.0\n\
         reseat_tilt_sd_deg = 0.0\neccentricity_sd_mm = 0.0\nencoder_error_amplitude_deg = 0.0\n\
         encoder_error_harmonic = 3\n[simulator.imperfections.beam]\nprofile = \"top-hat\"\n\
         gaussian_radius_mm = 1.0\npointing_sd_deg = 0.0\nsource_distance_mm = 400.0\ndivergence_sd_deg = 0.0\n",
        gonio_instrument::SIMULATED_INSTRUMENT_TOML
    );
    let zero = InstrumentFile::parse(&text, "zero.toml").expect("valid");
    assert!(HiddenTruth::draw(&zero).is_none() && HiddenTruth::draw(&ideal).is_none());
    let (a, b) = (optics(&ideal), optics(&zero));
    // Optics that were never given a hidden truth, as every caller built them before this existed.
    let plain = Optics::new(
        &ideal.instrument,
        SampleSpec {
            material: lambertian(),
            radius_mm: 25.0,
            orientation_deg: 0.0,
        },
        1,
    )
    .expect("optics")
    .with_source_noise(false)
    .with_source_drift(false);
    for p in [
        pose(30.0, -50.0, 10.0, 20.0),
        pose(-20.0, 60.0, -35.0, 140.0),
        pose(80.0, -85.0, 0.0, 0.0),
        pose(-90.0, 90.0, 0.0, 0.0),
    ] {
        let r = plain.reading(&p, &BAND_550, 3.0).expect("reading");
        assert_eq!(a.reading(&p, &BAND_550, 3.0).expect("reading"), r);
        assert_eq!(b.reading(&p, &BAND_550, 3.0).expect("reading"), r);
    }
    // Removing and putting back the sample changes nothing on the ideal instrument.
    b.set_sample_mounted(false);
    b.set_sample_mounted(true);
    let p = pose(30.0, -50.0, 10.0, 20.0);
    assert_eq!(
        b.reading(&p, &BAND_550, 3.0).expect("reading"),
        plain.reading(&p, &BAND_550, 3.0).expect("reading")
    );
}

#[tokio::test]
async fn the_seed_fixes_the_hidden_values_and_another_seed_changes_them() {
    let realistic = InstrumentFile::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/instruments/realistic.toml"),
    )
    .expect("realistic.toml loads");
    let scene = Arc::new(UniformScene { power_w: 1e-4 });
    let build = |file: &InstrumentFile| SimInstrument::new(file, scene.clone(), 1.0).expect("instrument");
    let a = build(&realistic);
    let b = build(&realistic);
    let truth = a.hidden_truth().expect("realistic instrument has hidden values");
    assert_eq!(
        Some(truth),
        b.hidden_truth(),
        "same file, same seed: same instrument"
    );
    let g = truth.geometry.as_ref().expect("geometry on");
    assert_eq!(g.axes.len(), 4);
    assert!(
        g.axes
            .iter()
            .all(|a| a.zero_offset_deg != 0.0 && a.encoder_amplitude_deg == 0.005)
    );
    assert!(g.eccentricity_mm != [0.0, 0.0] && !g.sample_tilt.is_zero());
    assert_ne!(g.seating_tilt(0), g.seating_tilt(1));

    let mut other = realistic.clone();
    other.simulator.seed += 1;
    let c = build(&other);
    let h = c
        .hidden_truth()
        .expect("hidden values")
        .geometry
        .as_ref()
        .expect("geometry");
    assert_ne!(h.sample_tilt, g.sample_tilt);
    assert_ne!(h.eccentricity_mm, g.eccentricity_mm);
    assert!(
        h.axes
            .iter()
            .zip(&g.axes)
            .all(|(x, y)| x.zero_offset_deg != y.zero_offset_deg)
    );
    assert_ne!(h.seating_tilt(0), g.seating_tilt(0));

    assert!(build(&InstrumentFile::simulated()).hidden_truth().is_none());
}

#[test]
fn switching_one_effect_on_does_not_change_another_s_draw() {
    let base = GeometryImperfections {
        zero_offset_sd_deg: 0.02,
        ..Default::default()
    };
    let both = GeometryImperfections {
        eccentricity_sd_mm: 0.1,
        ..base.clone()
    };
    let a = geometry_truth(&file_with(base, 5));
    let b = geometry_truth(&file_with(both, 5));
    assert_eq!(a.axes, b.axes);
}

#[tokio::test]
async fn a_bad_magnitude_is_a_typed_error_naming_its_key() {
    let mut file = InstrumentFile::simulated();
    file.simulator.imperfections.geometry.eccentricity_sd_mm = -0.1;
    let err = SimInstrument::new(&file, Arc::new(UniformScene { power_w: 1e-4 }), 1.0).expect_err("refused");
    assert!(
        matches!(err, gonio_simulator::SimError::Imperfections(_)),
        "{err:?}"
    );
    assert!(err.to_string().contains("eccentricity_sd_mm"), "{err}");
    let text = gonio_instrument::SIMULATED_INSTRUMENT_TOML.to_string()
        + "\n[simulator.imperfections.geometry]\nzero_offset_sd_deg = nan\n";
    let err = InstrumentFile::parse(&text, "bad.toml")
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("zero_offset_sd_deg") && err.contains("bad.toml"),
        "{err}"
    );
    let text = gonio_instrument::SIMULATED_INSTRUMENT_TOML.to_string()
        + "\n[simulator.imperfections.geometry]\nwobble_deg = 1.0\n";
    let err = InstrumentFile::parse(&text, "bad.toml")
        .expect_err("unknown key")
        .to_string();
    assert!(err.contains("wobble_deg"), "{err}");
}

/// Every role of the simulated instrument, in its file's order.
fn roles() -> Vec<AxisRole> {
    InstrumentFile::simulated()
        .instrument
        .axes
        .iter()
        .map(|a| a.role)
        .collect()
}

#[test]
fn the_simulated_instrument_has_the_four_roles() {
    assert_eq!(
        roles(),
        [
            AxisRole::LightArm,
            AxisRole::DetectorArm,
            AxisRole::SampleTilt,
            AxisRole::SampleRotation
        ]
    );
}
