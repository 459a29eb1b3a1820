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
    // Exact readings still carry the solid angle's calibration and the positioning: at least the former.
    let rel = v.std_per_sr / v.value_per_sr;
    assert!(
        (SOLID_ANGLE_REL_STD..0.01).contains(&rel),
        "relative uncertainty {rel}"
    );
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
    let m = meter_reading(&reading(3.0e-6, 5.0e-5), &ranges, Range::Auto);
    let expected = ((5.0e-6 * READING_RANGE_STD).powi(2) + (3.0e-6 * READING_REL_STD).powi(2)).sqrt();
    assert!((m.std_w - expected).abs() <= 1e-12 * expected);
    // A fixed range is resolved on the range the meter reports.
    let m = meter_reading(&reading(3.0e-6, 5.0e-5), &ranges, Range::FixedW(5.0e-5));
    let expected = ((5.0e-5 * READING_RANGE_STD).powi(2) + (3.0e-6 * READING_REL_STD).powi(2)).sqrt();
    assert!((m.std_w - expected).abs() <= 1e-12 * expected);
}

#[test]
fn the_meter_is_configured_from_the_acquisition_settings() {
    let acquisition = Acquisition {
        averaging: 300,
        range: Range::FixedW(5.0e-6),
        extra_settle_s: 0.0,
        retries: 2,
    };
    let c = meter_config(633.0, &acquisition);
    assert_eq!(c.wavelength_nm, 633.0);
    assert_eq!(c.averaging, 300);
    assert_eq!(c.range, PowerRange::Fixed { full_scale_w: 5.0e-6 });
}
