//! The measurement equation as a pure function, against the equation written out by hand; the meter's
//! configuration and the reading's uncertainty.

use std::time::SystemTime;

use gonio_brdf::models::Lambertian;
use gonio_brdf::{Direction, Spectral};
use gonio_instrument::InstrumentFile;

use super::*;

fn inputs<'a>(
    instrument: &'a Instrument,
    normalisation: Normalisation<'a>,
    wo_deg: (f64, f64),
) -> EquationInputs<'a> {
    EquationInputs {
        instrument,
        sample_radius_mm: 12.5,
        normalisation,
        band_nm: 550.0,
        wi: Direction::from_spherical_deg(0.0, 0.0),
        wo: Direction::from_spherical_deg(wo_deg.0, wo_deg.1),
    }
}

#[test]
fn absolute_equation_is_the_net_signal_over_beam_solid_angle_and_cosine() {
    let file = InstrumentFile::simulated();
    let inst = &file.instrument;
    let (s, s_dark, beam) = (2.0e-6, 1.5e-8, 1.2e-3);
    let v = brdf_of_reading(
        &inputs(inst, Normalisation::Absolute, (30.0, 180.0)),
        Reading::exact(s),
        Reading::exact(s_dark),
        Reading::exact(beam),
    )
    .expect("a valid geometry");
    // The detector's solid angle from the cone's half-angle, written independently of the radiometry module.
    let (r, d) = (inst.detector.aperture_radius_mm, inst.detector.distance_mm);
    let omega = 2.0 * std::f64::consts::PI * (1.0 - d / d.hypot(r));
    let expected = (s - s_dark) / (beam * omega * 30f64.to_radians().cos());
    assert!(
        (v.value_per_sr - expected).abs() <= 1e-9 * expected,
        "{} vs {expected}",
        v.value_per_sr
    );
    // Exact readings still carry the solid angle's calibration and the positioning: at least the former, as
    // the file states it (the ideal instrument's is exact: its positioning alone).
    let rel = v.std_per_sr / v.value_per_sr;
    assert!((0.0..0.01).contains(&rel), "relative uncertainty {rel}");
    let mut stated = inst.clone();
    stated.detector.solid_angle_u = Some(2e-3);
    let w = brdf_of_reading(
        &inputs(&stated, Normalisation::Absolute, (30.0, 180.0)),
        Reading::exact(s),
        Reading::exact(s_dark),
        Reading::exact(beam),
    )
    .expect("a valid geometry");
    let rel = w.std_per_sr / w.value_per_sr;
    assert!((2e-3..0.01).contains(&rel), "relative uncertainty {rel}");
    assert!((w.budget.scale_per_sr / w.value_per_sr - 2e-3).abs() < 1e-12);
}

#[test]
fn relative_equation_carries_the_reference_transfer() {
    let file = InstrumentFile::simulated();
    let inst = &file.instrument;
    let transfer = Lambertian::new(Spectral::Constant(0.5)).expect("albedo");
    let (s, s_dark, reference) = (3.0e-6, 1.0e-8, 4.0e-6);
    let relative = Normalisation::Relative {
        transfer: &transfer,
        reference_brdf_rel_std: 0.01,
    };
    let v = brdf_of_reading(
        &inputs(inst, relative, (45.0, 180.0)),
        Reading::exact(s),
        Reading::exact(s_dark),
        Reading::exact(reference),
    )
    .expect("a valid geometry");
    let expected = 0.5 / std::f64::consts::PI * (s - s_dark) / reference;
    assert!((v.value_per_sr - expected).abs() <= 1e-9 * expected);
    // The reference's own calibration dominates the budget.
    assert!(v.std_per_sr / v.value_per_sr >= 0.01);
}

#[test]
fn refused_geometries_are_flagged_not_valued() {
    let file = InstrumentFile::simulated();
    let inst = &file.instrument;
    let grazing = 0.5 * (inst.safety.grazing_limit_deg + 90.0);
    let e = brdf_of_reading(
        &inputs(inst, Normalisation::Absolute, (grazing, 180.0)),
        Reading::exact(1e-6),
        Reading::exact(0.0),
        Reading::exact(1e-3),
    )
    .expect_err("beyond the grazing limit");
    assert_eq!(flag_for(&e), "grazing");
    let e = brdf_of_reading(
        &inputs(inst, Normalisation::Absolute, (30.0, 180.0)),
        Reading::exact(1e-6),
        Reading::exact(0.0),
        Reading::exact(0.0),
    )
    .expect_err("no direct beam");
    assert_eq!(flag_for(&e), "no-direct-beam");
}

fn reading(power_w: f64, range_w: f64) -> PowerReading {
    PowerReading {
        power_w,
        range_w,
        overload: false,
        timestamp: SystemTime::UNIX_EPOCH,
    }
}

#[test]
fn a_reading_is_resolved_on_the_smallest_range_holding_it_under_auto_range() {
    let ranges = [5.0e-8, 5.0e-7, 5.0e-6, 5.0e-5];
    let noise = ReadingNoise {
        responsivity_a_per_w: None,
        dark_current_a: 0.0,
        amplifier_noise_a_per_rthz: 0.0,
        source_relative_noise: 0.0,
        averaging: 3,
    };
    // Quantisation alone: one count of the range over sqrt(12) per sample, averaged over 3 samples.
    let m = meter_reading(&reading(3.0e-6, 5.0e-5), &ranges, Range::Auto, &noise);
    let expected = 5.0e-6 / 65_536.0 / 36f64.sqrt();
    assert!(
        (m.std_w - expected).abs() <= 1e-12 * expected,
        "{} vs {expected}",
        m.std_w
    );
    // A fixed range is resolved on the range the meter reports.
    let m = meter_reading(&reading(3.0e-6, 5.0e-5), &ranges, Range::FixedW(5.0e-5), &noise);
    let expected = 5.0e-5 / 65_536.0 / 36f64.sqrt();
    assert!((m.std_w - expected).abs() <= 1e-12 * expected);
}

#[test]
fn the_reading_noise_is_the_files_figures_averaged_over_the_samples() {
    let file = InstrumentFile::simulated();
    let inst = &file.instrument;
    let noise = ReadingNoise::new(inst, 550.0, 10);
    let r = 0.29; // A/W at 550 nm in simulated.toml
    assert_eq!(noise.responsivity_a_per_w, Some(r));
    let (p, fs) = (3.0e-4, 5.0e-4);
    // Written out: shot of the photocurrent and the dark current over half the sample rate, Johnson noise of a
    // 2 V full-scale transimpedance at 295 K, one count over sqrt(12), the source's 1e-4: per sample, then / 10.
    let bandwidth = 1.0 / (2.0 * 0.003);
    let i = p * r + inst.detector.dark_current_a;
    let shot = 2.0 * 1.602_176_634e-19 * i * bandwidth;
    let johnson = 4.0 * 1.380_649e-23 * 295.0 * bandwidth * (fs * r) / 2.0;
    let quantisation = (fs * r / 65_536.0).powi(2) / 12.0;
    let source = (inst.source.relative_noise * p).powi(2);
    let expected = (((shot + johnson + quantisation) / (r * r) + source) / 10.0).sqrt();
    let got = noise.std_w(p, fs);
    assert!((got - expected).abs() <= 1e-9 * expected, "{got} vs {expected}");
    // The source's noise dominates a bright reading; four times the samples halve it.
    assert!(got > inst.source.relative_noise * p / 10f64.sqrt());
    let more = ReadingNoise::new(inst, 550.0, 40).std_w(p, fs);
    assert!((more / got - 0.5).abs() < 1e-9);
}

#[test]
fn the_heads_amplifier_noise_from_the_file_is_in_a_low_ranges_reading() {
    let mut file = InstrumentFile::simulated();
    let r = 0.29; // A/W at 550 nm in simulated.toml
    // A dim reading (1 nW) on the lowest range (50 nW), where the feedback resistor's Johnson noise is smallest.
    let (p, fs) = (1.0e-9, 5.0e-8);
    let without = ReadingNoise::new(&file.instrument, 550.0, 10).std_w(p, fs);
    file.instrument.detector.amplifier_noise_a_per_rthz = 2.0e-14;
    let with = ReadingNoise::new(&file.instrument, 550.0, 10).std_w(p, fs);
    // 20 fA/sqrt(Hz) over the sample's 1 / (2 x 3 ms) bandwidth, in W through the responsivity, over 10 samples.
    let amplifier_w2 = (2.0e-14f64.powi(2) * (1.0 / 0.006)) / (r * r) / 10.0;
    assert!(
        ((with * with - without * without) / amplifier_w2 - 1.0).abs() < 1e-9,
        "{with} against {without}"
    );
    // There it is larger than the shot and Johnson noise it adds to: the reading's noise grows by more than 40 %.
    assert!(with > 1.4 * without, "{with} against {without}");
    // A bright reading on a high range hardly feels it.
    let (p, fs) = (3.0e-4, 5.0e-4);
    file.instrument.detector.amplifier_noise_a_per_rthz = 0.0;
    let bright = ReadingNoise::new(&file.instrument, 550.0, 10).std_w(p, fs);
    file.instrument.detector.amplifier_noise_a_per_rthz = 2.0e-14;
    let bright_with = ReadingNoise::new(&file.instrument, 550.0, 10).std_w(p, fs);
    assert!(bright_with / bright - 1.0 < 1e-6);
}

#[test]
fn the_meter_is_configured_from_the_acquisition_settings() {
    let acquisition = Acquisition {
        averaging: 300,
        calibration_averaging: 300,
        range: Range::FixedW(5.0e-6),
        extra_settle_s: 0.0,
        retries: 2,
    };
    let c = meter_config(633.0, &acquisition);
    assert_eq!(c.wavelength_nm, 633.0);
    assert_eq!(c.averaging, 300);
    assert_eq!(c.range, PowerRange::Fixed { full_scale_w: 5.0e-6 });
}
