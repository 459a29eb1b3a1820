//! The absolute measurement equation on simulated perfect readings: the truth back, or the typed refusal that the
//! geometry calls for.

use std::f64::consts::PI;

use gonio_brdf::Direction;
use gonio_brdf::measurement::{
    AbsoluteReadings, Footprint, MeasurementError, MeasurementGeometry, Reading, ValidityLimits,
    absolute_brdf,
};
use gonio_brdf::radiometry::cone_solid_angle_sr;
use gonio_testkit::directions::hostile_directions;

use super::Failures;

/// The absolute measurement equation on simulated perfect readings (`S = f P Omega cos_o` for a known f), at
/// hostile geometries and powers from 1e-15 W to 1 W, apertures from 1e-6 to 0.5 rad: either the truth comes back
/// (to 1e-12) with a finite uncertainty, or the equation refuses with the typed error the geometry calls for.
#[test]
fn measurement_equation_returns_the_truth_or_a_typed_refusal() {
    let f_true = 0.3 / PI;
    let limits = ValidityLimits::default();
    let footprint = Footprint {
        beam_radius_mm: 1.5,
        sample_radius_mm: 25.0,
        detector_field_radius_mm: Some(12.0),
    };
    let mut fails = Failures::default();
    let mut dirs = hostile_directions();
    dirs.push(Direction::from_spherical(f64::NAN, 0.0));
    let powers = [1e-15, 1e-12, 1e-9, 1e-6, 1e-3, 1.0];
    for wi in &dirs {
        for wo in dirs
            .iter()
            .chain([wi.reflect_about_normal(), wi.neg(), *wi].iter())
        {
            let geometry = MeasurementGeometry {
                wi: *wi,
                wo: *wo,
                angle_std_rad: 1e-4,
            };
            for &p in &powers {
                for beta in [1e-6, 1e-3, 0.5] {
                    let omega = cone_solid_angle_sr(beta);
                    let cos_o = wo.z().max(0.0);
                    let readings = AbsoluteReadings {
                        signal: Reading::new(f_true * p * omega * cos_o, 1e-3 * p * omega),
                        signal_dark: Reading::exact(0.0),
                        direct_beam: Reading::new(p, 1e-3 * p),
                        direct_beam_dark: Reading::exact(0.0),
                        detector_solid_angle_sr: omega,
                        detector_solid_angle_std_sr: 1e-3 * omega,
                    };
                    let result = absolute_brdf(&readings, &geometry, &footprint, &limits);
                    let (ci, co) = (wi.z(), wo.z());
                    let expected_refusal = if !(ci.is_finite() && co.is_finite()) {
                        Some("non-finite")
                    } else if co < limits.min_cos_theta_o || co <= 0.0 {
                        Some("grazing")
                    } else if ci <= 0.0 {
                        Some("below")
                    } else if footprint.beam_radius_mm / ci > 12.0 {
                        Some("overfill")
                    } else {
                        None
                    };
                    match (&result, expected_refusal) {
                        (Ok(v), None) => {
                            let rel = (v.value_per_sr - f_true).abs() / f_true;
                            if rel > 1e-12 || !v.std_per_sr.is_finite() || v.std_per_sr < 0.0 {
                                fails.add(format!("{wi:?} {wo:?} P {p} beta {beta}: {v:?}"));
                            }
                        }
                        (Err(MeasurementError::NonFinite { field, .. }), Some("non-finite"))
                            if field.starts_with("wi") || field.starts_with("wo") => {}
                        (Err(MeasurementError::GrazingDetector { .. }), Some("grazing")) => {}
                        (Err(MeasurementError::SourceBelowHorizon { .. }), Some("below")) => {}
                        (
                            Err(
                                MeasurementError::OverfillsSample { .. }
                                | MeasurementError::OverfillsDetectorField { .. },
                            ),
                            Some("overfill"),
                        ) => {}
                        (other, expected) => {
                            fails.add(format!(
                                "{wi:?} {wo:?} P {p}: got {other:?}, expected {expected:?}"
                            ));
                        }
                    }
                }
            }
        }
    }
    fails.assert_none("measurement equation");
}
