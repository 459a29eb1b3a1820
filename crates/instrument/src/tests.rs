//! Unit tests of the instrument description: the embedded file, parsing and every validation rule.

use super::*;

#[test]
fn embedded_simulated_instrument_is_valid() {
    let file = InstrumentFile::parse(SIMULATED_INSTRUMENT_TOML, "simulated.toml").expect("valid");
    assert_eq!(file.instrument.geometry, GeometryKind::Reference);
    assert_eq!(file.instrument.axes.len(), 4);
    assert!(file.instrument.bands_nm().len() >= 3);
}

#[test]
fn unknown_key_is_named_with_its_line() {
    let text = SIMULATED_INSTRUMENT_TOML.replacen("[instrument.source]", "[instrument.source]\nbogus = 1", 1);
    let err = InstrumentFile::parse(&text, "x.toml").expect_err("unknown key");
    let msg = err.to_string();
    assert!(msg.contains("bogus") && msg.contains("line"), "{msg}");
}

#[test]
fn axis_calibration_round_trips() {
    let file = InstrumentFile::simulated();
    let mut axis = file.instrument.axes[0].clone();
    axis.zero_offset_deg = 12.5;
    axis.direction = -1;
    let p = axis.controller_from_physical_deg(30.0);
    assert_eq!(p, -17.5);
    assert_eq!(axis.physical_from_controller_deg(p), 30.0);
}

#[test]
fn the_realistic_instrument_loads_and_has_geometry_imperfections() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/instruments/realistic.toml");
    let file = InstrumentFile::load(&path).expect("realistic.toml is valid");
    assert!(!file.simulator.imperfections.is_ideal());
    assert!(file.simulator.imperfections.geometry.zero_offset_sd_deg > 0.0);
    // The ideal instrument states none.
    assert!(InstrumentFile::simulated().simulator.imperfections.is_ideal());
}

#[test]
fn a_finite_band_needs_its_shape_and_source_and_a_sane_range() {
    for (table, key) in [
        ("centre_sd_nm = 1.0\nsource_temperature_k = 3000.0", "cavities"),
        ("cavities = 3", "source_temperature_k"),
        (
            "cavities = 3\nsource_temperature_k = 3000.0\nleakage_range_nm = [900.0, 400.0]",
            "leakage_range_nm",
        ),
        (
            "cavities = 3\nsource_temperature_k = 3000.0\nout_of_band_transmission = 0.5",
            "out_of_band",
        ),
    ] {
        let text = format!("{SIMULATED_INSTRUMENT_TOML}\n[simulator.imperfections.filters]\n{table}\n");
        let msg = InstrumentFile::parse(&text, "f.toml")
            .expect_err(table)
            .to_string();
        assert!(msg.contains("filters") && msg.contains(key), "{table}: {msg}");
    }
    let ok = format!(
        "{SIMULATED_INSTRUMENT_TOML}\n[simulator.imperfections.filters]\ncavities = 3\nsource_temperature_k = 3000.0\n"
    );
    let file = InstrumentFile::parse(&ok, "f.toml").expect("valid");
    assert!(!file.simulator.imperfections.is_ideal());
    assert_eq!(
        file.simulator.imperfections.filters.leakage_range_nm,
        [400.0, 1100.0]
    );
}

#[test]
fn the_beam_group_needs_its_width_and_distance_and_knows_its_profiles() {
    let parse = |table: &str| {
        InstrumentFile::parse(
            &format!("{SIMULATED_INSTRUMENT_TOML}\n[simulator.imperfections.beam]\n{table}\n"),
            "x.toml",
        )
    };
    let file = parse("profile = \"gaussian\"\ngaussian_radius_mm = 1.2").expect("valid");
    assert_eq!(file.simulator.imperfections.beam.profile, BeamProfile::Gaussian);
    assert!(!file.simulator.imperfections.is_ideal());
    for (table, key) in [
        ("profile = \"gaussian\"", "gaussian_radius_mm"),
        ("pointing_sd_deg = 0.01", "source_distance_mm"),
        ("divergence_sd_deg = -0.01", "divergence_sd_deg"),
        ("profile = \"donut\"", "donut"),
    ] {
        let msg = parse(table).expect_err(table).to_string();
        assert!(msg.contains(key), "{table}: {msg}");
    }
    // A top hat with no pointing or divergence error is the ideal beam, whatever else the table states.
    let file =
        parse("profile = \"top-hat\"\ngaussian_radius_mm = 1.0\nsource_distance_mm = 400.0").expect("valid");
    assert!(file.simulator.imperfections.is_ideal());
}

#[test]
fn a_bad_imperfection_is_refused_with_the_file_and_the_key() {
    let text = format!(
        "{SIMULATED_INSTRUMENT_TOML}\n[simulator.imperfections.geometry]\nreseat_tilt_sd_deg = -0.01\n"
    );
    let msg = InstrumentFile::parse(&text, "x.toml")
        .expect_err("negative")
        .to_string();
    assert!(
        msg.contains("x.toml") && msg.contains("reseat_tilt_sd_deg"),
        "{msg}"
    );
}

#[test]
fn the_leakage_figures_are_checked_and_default_to_a_catalogue_filter_and_a_halogen_lamp() {
    let file = InstrumentFile::parse(SIMULATED_INSTRUMENT_TOML, "simulated.toml").expect("valid");
    let wheel = file.instrument.filter_wheel.as_ref().expect("wheel");
    assert!(
        wheel
            .positions
            .iter()
            .filter(|p| !p.blank)
            .all(|p| p.out_of_band_transmission == Some(0.0))
    );
    let mut bare = wheel.positions[0].clone();
    bare.out_of_band_transmission = None;
    assert_eq!(bare.out_of_band_transmission(), DEFAULT_OUT_OF_BAND_TRANSMISSION);
    assert_eq!(
        file.instrument.source.colour_temperature_k(),
        DEFAULT_COLOUR_TEMPERATURE_K
    );

    let text = SIMULATED_INSTRUMENT_TOML.replacen(
        "out_of_band_transmission = 0.0",
        "out_of_band_transmission = 2.0",
        1,
    );
    let msg = InstrumentFile::parse(&text, "x.toml")
        .expect_err("above 1")
        .to_string();
    assert!(
        msg.contains("out_of_band_transmission") && msg.contains("position 1"),
        "{msg}"
    );
    let text = SIMULATED_INSTRUMENT_TOML.replacen(
        "[instrument.source]",
        "[instrument.source]\ncolour_temperature_k = 30.0",
        1,
    );
    let msg = InstrumentFile::parse(&text, "x.toml")
        .expect_err("too cold")
        .to_string();
    assert!(msg.contains("colour_temperature_k"), "{msg}");
}

#[test]
fn an_instrument_kept_without_its_filter_imperfections_states_filters_that_do_not_leak_or_widen() {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/instruments/realistic.toml"),
    )
    .expect("realistic.toml");
    let blocking = |kept: &str| -> Vec<Option<f64>> {
        let file = InstrumentFile::parse(kept, "variant").expect("valid");
        file.instrument
            .filter_wheel
            .expect("wheel")
            .positions
            .iter()
            .filter(|p| p.band_nm.is_some())
            .map(|p| p.out_of_band_transmission)
            .collect()
    };
    let widths = |kept: &str| -> Vec<Option<f64>> {
        let file = InstrumentFile::parse(kept, "variant").expect("valid");
        let wheel = file.instrument.filter_wheel.expect("wheel");
        wheel
            .positions
            .iter()
            .filter(|p| p.band_nm.is_some())
            .map(|p| p.bandwidth_nm)
            .collect()
    };
    let geometry = crate::imperfections::keep_only_groups(&text, &["geometry"]).expect("kept");
    let b = blocking(&geometry);
    assert!(!b.is_empty() && b.iter().all(|t| *t == Some(0.0)), "{b:?}");
    let w = widths(&geometry);
    assert!(!w.is_empty() && w.iter().all(|b| *b == Some(0.0)), "{w:?}");
    let filters = crate::imperfections::keep_only_groups(&text, &["geometry", "filters"]).expect("kept");
    assert!(blocking(&filters).iter().all(|t| *t == Some(1.0e-5)));
    assert!(widths(&filters).iter().all(|b| *b == Some(10.0)));
}

#[test]
fn the_heads_amplifier_noise_is_a_current_density_defaulting_to_none() {
    let file = InstrumentFile::parse(SIMULATED_INSTRUMENT_TOML, "simulated.toml").expect("valid");
    assert_eq!(file.instrument.detector.amplifier_noise_a_per_rthz, 0.0);
    let with = |v: &str| {
        SIMULATED_INSTRUMENT_TOML.replacen(
            "[instrument.detector]",
            &format!("[instrument.detector]\namplifier_noise_a_per_rthz = {v}"),
            1,
        )
    };
    let file = InstrumentFile::parse(&with("2.0e-14"), "x.toml").expect("20 fA/sqrt(Hz)");
    assert_eq!(file.instrument.detector.amplifier_noise_a_per_rthz, 2.0e-14);
    for bad in ["-1e-14", "0.5", "nan"] {
        let msg = InstrumentFile::parse(&with(bad), "x.toml")
            .expect_err(bad)
            .to_string();
        assert!(msg.contains("amplifier_noise_a_per_rthz"), "{bad}: {msg}");
    }
}
