//! A dry-run's hidden truth for run.json: the simulated instrument's imperfections as the simulator drew them
//! from the stored instrument file and its seed. It goes to the run record and nowhere else: the engine, the
//! drivers and the calibration never see it (crates/engine/tests/it/layering.rs keeps the simulator inside the rig).

use gonio_instrument::{Instrument, InstrumentFile};
use gonio_results::provenance::{
    ActualAxisRecord, ActualHardwareRecord, AxisTruthRecord, BeamTruthRecord, DetectorTruthRecord,
    FilterTruthRecord, FiltersTruthRecord, GeometryTruthRecord, RangeTruthRecord, SampleTruthRecord,
    SeatingRecord, SimulatorTruth, SourceTruthRecord,
};
use gonio_simulator::imperfections::HiddenTruth;

/// The hidden imperfections of the simulated instrument described by `instrument_toml`, for a dry-run's
/// run.json; `None` for a run on hardware, an ideal instrument, or a text that no longer parses. `mountings` is
/// how many of the sample's mountings to list (0 is the first; the run made at most one per calibration reading).
pub fn simulator_truth(instrument_toml: &str, dry_run: bool, mountings: usize) -> Option<SimulatorTruth> {
    if !dry_run {
        return None;
    }
    let file = InstrumentFile::parse(instrument_toml, "<stored instrument file>").ok()?;
    let hidden = HiddenTruth::draw(&file);
    let real = HiddenTruth::real_instrument(&file, hidden.as_ref());
    let actual = actual_record(&file.instrument, &real);
    match hidden {
        Some(hidden) => Some(SimulatorTruth {
            actual,
            ..record(&hidden, mountings)
        }),
        None => actual.map(|actual| SimulatorTruth {
            seed: file.simulator.seed,
            geometry: None,
            detector: None,
            source: None,
            sample: None,
            filters: None,
            beam: None,
            actual: Some(actual),
        }),
    }
}

/// Where the real hardware differs from what the file claims (the hidden timing draws and `[simulator.actual]`
/// together), for run.json; None when nothing does.
fn actual_record(claimed: &Instrument, real: &Instrument) -> Option<ActualHardwareRecord> {
    let differs = |a: f64, b: f64| (a != b).then_some(b);
    let wheel_seconds_per_position = match (&claimed.filter_wheel, &real.filter_wheel) {
        (Some(c), Some(r)) => differs(c.seconds_per_position, r.seconds_per_position),
        _ => None,
    };
    let axes: Vec<ActualAxisRecord> = claimed
        .axes
        .iter()
        .zip(&real.axes)
        .map(|(c, r)| ActualAxisRecord {
            name: c.name.clone(),
            max_speed_deg_s: differs(c.max_speed_deg_s, r.max_speed_deg_s),
            accel_deg_s2: differs(c.accel_deg_s2, r.accel_deg_s2),
            settle_s: differs(c.settle_s, r.settle_s),
            backlash_deg: differs(c.backlash_deg, r.backlash_deg),
        })
        .filter(|a| {
            a.max_speed_deg_s.is_some()
                || a.accel_deg_s2.is_some()
                || a.settle_s.is_some()
                || a.backlash_deg.is_some()
        })
        .collect();
    let detector_dark_current_a = differs(claimed.detector.dark_current_a, real.detector.dark_current_a);
    let source_relative_noise = differs(claimed.source.relative_noise, real.source.relative_noise);
    let reply_latency_ms: std::collections::BTreeMap<String, f64> = claimed
        .devices
        .iter()
        .zip(&real.devices)
        .filter_map(|(c, r)| {
            let (said, is) = (
                c.reply_latency_ms.unwrap_or(0.0),
                r.reply_latency_ms.unwrap_or(0.0),
            );
            differs(said, is).map(|ms| (c.name.clone(), ms))
        })
        .collect();
    let position_sampled_ms: std::collections::BTreeMap<String, f64> = claimed
        .devices
        .iter()
        .zip(&real.devices)
        .filter_map(|(c, r)| {
            let is = r.position_sampled_ms.unwrap_or(0.0);
            // A file silent on it claims nothing: the real instant is the truth to hold a measurement against.
            match c.position_sampled_ms {
                Some(said) => differs(said, is),
                None => (is != 0.0).then_some(is),
            }
            .map(|ms| (c.name.clone(), ms))
        })
        .collect();
    (wheel_seconds_per_position.is_some()
        || !axes.is_empty()
        || detector_dark_current_a.is_some()
        || source_relative_noise.is_some()
        || !reply_latency_ms.is_empty()
        || !position_sampled_ms.is_empty())
    .then_some(ActualHardwareRecord {
        wheel_seconds_per_position,
        axes,
        detector_dark_current_a,
        source_relative_noise,
        reply_latency_ms,
        position_sampled_ms,
    })
}

fn record(hidden: &HiddenTruth, mountings: usize) -> SimulatorTruth {
    SimulatorTruth {
        actual: None,
        seed: hidden.seed,
        geometry: hidden.geometry.as_ref().map(|g| GeometryTruthRecord {
            axes: g
                .axes
                .iter()
                .map(|a| AxisTruthRecord {
                    // The role's name as the instrument file spells it (kebab-case).
                    role: serde_json::to_value(a.role)
                        .ok()
                        .and_then(|v| v.as_str().map(str::to_string))
                        .unwrap_or_default(),
                    zero_offset_deg: a.zero_offset_deg,
                    encoder_amplitude_deg: a.encoder_amplitude_deg,
                    encoder_harmonic: a.encoder_harmonic,
                    encoder_phase_deg: a.encoder_phase_deg,
                })
                .collect(),
            sample_tilt_x_deg: g.sample_tilt.x_deg,
            sample_tilt_y_deg: g.sample_tilt.y_deg,
            eccentricity_x_mm: g.eccentricity_mm[0],
            eccentricity_y_mm: g.eccentricity_mm[1],
            aperture_radius_error_mm: g.aperture_radius_error_mm,
            detector_distance_error_mm: g.detector_distance_error_mm,
            seatings: (0..=mountings as u64)
                .map(|index| {
                    let t = g.seating_tilt(index);
                    SeatingRecord {
                        index,
                        tilt_x_deg: t.x_deg,
                        tilt_y_deg: t.y_deg,
                    }
                })
                .collect(),
        }),
        detector: hidden.detector.as_ref().map(|d| DetectorTruthRecord {
            ranges: d
                .ranges
                .iter()
                .map(|r| RangeTruthRecord {
                    gain: r.gain,
                    nonlinearity: r.nonlinearity,
                    offset_fs: r.offset_fs,
                })
                .collect(),
            saturation_current_a: d.saturation_current_a,
            amplifier_noise_a_per_rthz: d.amplifier_noise_a_per_rthz,
            signature_peak_sr: d.signature.peak_sr,
            signature_width_deg: d.signature.width_deg,
            signature_floor_sr: d.signature.floor_sr,
            ambient_a: d.ambient_a,
            ambient_variation: d.ambient_variation,
            ambient_period_s: d.ambient_period_s,
            ambient_phase_deg: d.ambient_phase_deg,
            reading_delay_s: d.reading_delay_s,
        }),
        source: hidden.source.as_ref().map(|s| SourceTruthRecord {
            warmup_fraction: s.warmup_fraction,
            warmup_time_s: s.warmup_time_s,
            random_walk_per_rthour: s.random_walk_per_rthour,
            flicker_rms: s.flicker_rms,
        }),
        sample: hidden.sample.as_ref().map(|s| SampleTruthRecord {
            gradient_x: s.gradient[0],
            gradient_y: s.gradient[1],
            radial: s.radial,
        }),
        filters: hidden.filters.as_ref().map(|f| FiltersTruthRecord {
            cavities: f.cavities,
            source_temperature_k: f.source_temperature_k,
            out_of_band_transmission: f.out_of_band_transmission,
            leakage_range_nm: f.leakage_range_nm,
            filters: f
                .filters
                .iter()
                .map(|t| FilterTruthRecord {
                    position: t.position,
                    nominal_nm: t.nominal_nm,
                    nominal_bandwidth_nm: t.nominal_bandwidth_nm,
                    centre_nm: t.centre_nm,
                    bandwidth_nm: t.bandwidth_nm,
                })
                .collect(),
        }),
        beam: hidden.beam.as_ref().map(|b| BeamTruthRecord {
            profile: match b.profile {
                gonio_instrument::BeamProfile::TopHat => "top-hat".into(),
                gonio_instrument::BeamProfile::Gaussian => "gaussian".into(),
            },
            gaussian_radius_mm: b.gaussian_radius_mm,
            pointing_in_plane_deg: b.pointing_deg[0],
            pointing_vertical_deg: b.pointing_deg[1],
            source_distance_mm: b.source_distance_mm,
            divergence_deg: b.divergence_deg,
            nominal_divergence_deg: b.nominal_divergence_deg,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REALISTIC: &str = include_str!("../../../../config/instruments/realistic.toml");

    #[test]
    fn only_an_imperfect_dry_run_has_a_hidden_truth() {
        let t = simulator_truth(REALISTIC, true, 3).expect("realistic dry-run");
        let g = t.geometry.expect("geometry");
        assert_eq!(g.axes.len(), 4);
        assert_eq!(g.axes[0].role, "light-arm");
        assert_eq!(g.seatings.len(), 4, "mountings 0..=3");
        let f = t.filters.expect("filters");
        assert_eq!(f.filters.len(), 5, "realistic.toml's five bands");
        assert!(f.filters.iter().all(|b| b.centre_nm != b.nominal_nm));
        assert_eq!(
            simulator_truth(REALISTIC, false, 3),
            None,
            "hardware: nothing to tell"
        );
        assert_eq!(
            simulator_truth(gonio_instrument::SIMULATED_INSTRUMENT_TOML, true, 3),
            None
        );
        assert_eq!(simulator_truth("not toml [", true, 3), None);
        // The same stored text gives the same values: run.json is a function of the store.
        assert_eq!(
            simulator_truth(REALISTIC, true, 3).and_then(|t| t.geometry),
            Some(g)
        );
    }
}
