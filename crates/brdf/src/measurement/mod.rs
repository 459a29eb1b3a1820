//! The measurement equation: from detector readings to a BRDF value with its standard uncertainty.
//!
//! Absolute method (Nicodemus; ASTM E1392 / E2387), with a direct-beam reading `P` of the incident power:
//! `f = (S - S_dark) / ((P - P_dark) * Omega_d * cos(theta_o))`.
//! Relative method, against a reference sample whose BRDF `f_ref` is known (including its angular shape):
//! `f = f_ref(wi, wo) * (S - S_dark) / (S_ref - S_dark_ref)`, reference measured at the same geometry.
//!
//! Both assume a collimated beam fully intercepted by the sample and a detector that sees the whole illuminated
//! spot. Geometries where that fails are refused with a typed [`MeasurementError`], never returned as numbers:
//! a detector too close to grazing (`cos(theta_o)` below [`ValidityLimits::min_cos_theta_o`]), an incidence at
//! or below the horizon, and a beam footprint (semi-major axis `beam_radius / cos(theta_i)`, the beam's
//! foreshortening) larger than the sample or the detector's field of view. Non-finite inputs, negative
//! uncertainties, a non-positive solid angle and a non-positive net direct-beam or reference signal are refused.
//!
//! Standard uncertainty is propagated to first order with independent inputs (GUM): signal, dark, direct beam,
//! direct-beam dark, detector solid angle, and the angle uncertainty through `cos(theta_o)` (absolute) or through
//! the reference's angular shape (relative, by central differences of `f_ref`). The budget is returned per input.
//!
//! Specular (delta) samples: with a finite aperture, the absolute equation measures the BRDF averaged over the
//! detector's solid angle (weighted by cos theta_o): for a mirror it returns `R / (Omega_d cos theta_o)` when the
//! mirror direction lies inside the aperture, a number that depends on the aperture and is not a point value of f.

use crate::brdf::Brdf;
use crate::geometry::Direction;
use crate::spectrum::{SpectrumError, Wavelength};

/// One reading of a detector (or of the incident beam), in watts, with its standard uncertainty in watts.
/// Any consistent unit works as long as all readings of one equation share it; the names say watts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    pub value_w: f64,
    pub std_w: f64,
}

impl Reading {
    pub fn new(value_w: f64, std_w: f64) -> Reading {
        Reading { value_w, std_w }
    }

    /// A reading with no uncertainty.
    pub fn exact(value_w: f64) -> Reading {
        Reading { value_w, std_w: 0.0 }
    }
}

/// The directions of one measurement and the standard uncertainty of the polar angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasurementGeometry {
    /// Towards the source.
    pub wi: Direction,
    /// Towards the detector.
    pub wo: Direction,
    /// Standard uncertainty of theta_i and of theta_o (radians), e.g. from the goniometer's positioning.
    pub angle_std_rad: f64,
}

/// Sizes that decide whether the illuminated spot stays on the sample and in the detector's view (millimetres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Radius of the collimated beam, perpendicular to its axis.
    pub beam_radius_mm: f64,
    /// Radius of the (circular, centred) sample.
    pub sample_radius_mm: f64,
    /// Radius of the detector's field of view on the sample, measured perpendicular to its line of sight;
    /// `None` when the detector sees the whole sample. The check is conservative: the field's projection on the
    /// sample is an ellipse whose smaller semi-axis is this radius, and the footprint must fit inside that.
    pub detector_field_radius_mm: Option<f64>,
}

/// Limits of validity, configurable per instrument.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValidityLimits {
    /// Smallest accepted cos(theta_o). Default cos(85 deg).
    pub min_cos_theta_o: f64,
}

impl Default for ValidityLimits {
    fn default() -> Self {
        ValidityLimits {
            min_cos_theta_o: 85.0f64.to_radians().cos(),
        }
    }
}

/// Readings for the absolute method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AbsoluteReadings {
    /// Detector reading on the sample.
    pub signal: Reading,
    /// Detector reading with the source blocked.
    pub signal_dark: Reading,
    /// Detector reading of the direct beam (the incident power P_i).
    pub direct_beam: Reading,
    /// Dark reading for the direct beam.
    pub direct_beam_dark: Reading,
    /// Detector solid angle seen from the sample, sr.
    pub detector_solid_angle_sr: f64,
    /// Its standard uncertainty, sr.
    pub detector_solid_angle_std_sr: f64,
}

/// Readings for the relative method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativeReadings {
    pub signal: Reading,
    pub signal_dark: Reading,
    /// Detector reading on the reference sample at the same geometry.
    pub reference: Reading,
    /// Dark reading for the reference.
    pub reference_dark: Reading,
    /// Relative standard uncertainty of the reference's known BRDF (its calibration), dimensionless.
    pub reference_brdf_rel_std: f64,
}

/// Contributions to the standard uncertainty, each in 1/sr (their root sum of squares is the total).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UncertaintyBudget {
    pub signal_per_sr: f64,
    pub signal_dark_per_sr: f64,
    /// Direct beam (absolute) or reference reading (relative).
    pub normalisation_per_sr: f64,
    /// Dark of the direct beam (absolute) or of the reference (relative).
    pub normalisation_dark_per_sr: f64,
    /// Detector solid angle (absolute) or reference calibration (relative).
    pub scale_per_sr: f64,
    /// Angle uncertainty.
    pub angles_per_sr: f64,
}

impl UncertaintyBudget {
    fn total(&self) -> f64 {
        [
            self.signal_per_sr,
            self.signal_dark_per_sr,
            self.normalisation_per_sr,
            self.normalisation_dark_per_sr,
            self.scale_per_sr,
            self.angles_per_sr,
        ]
        .iter()
        .map(|c| c * c)
        .sum::<f64>()
        .sqrt()
    }
}

/// A measured BRDF value in 1/sr with its combined standard uncertainty (k = 1) and the budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrdfValue {
    pub value_per_sr: f64,
    pub std_per_sr: f64,
    pub budget: UncertaintyBudget,
}

/// Why the measurement equation refuses a measurement.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeasurementError {
    /// An input is NaN or infinite.
    #[error("measurement input `{field}` is not finite ({value})")]
    NonFinite { field: &'static str, value: f64 },
    /// A standard uncertainty or a size is negative.
    #[error("measurement input `{field}` must not be negative, got {value}")]
    Negative { field: &'static str, value: f64 },
    /// The detector is too close to grazing for the equation to be trusted.
    #[error(
        "detector at cos(theta_o) = {cos_theta_o:.6} is below the limit {min_cos_theta_o:.6} (too close to grazing)"
    )]
    GrazingDetector { cos_theta_o: f64, min_cos_theta_o: f64 },
    /// The source is at or below the sample's horizon.
    #[error("source at cos(theta_i) = {cos_theta_i} is at or below the horizon")]
    SourceBelowHorizon { cos_theta_i: f64 },
    /// The beam footprint is larger than the sample.
    #[error(
        "beam footprint {footprint_mm:.4} mm (beam radius / cos(theta_i)) overfills the sample (radius {sample_radius_mm} mm)"
    )]
    OverfillsSample {
        footprint_mm: f64,
        sample_radius_mm: f64,
    },
    /// The beam footprint is larger than what the detector sees.
    #[error(
        "beam footprint {footprint_mm:.4} mm (beam radius / cos(theta_i)) overfills the detector's field of view (radius {field_radius_mm} mm)"
    )]
    OverfillsDetectorField { footprint_mm: f64, field_radius_mm: f64 },
    /// Direct beam minus its dark is not positive: no incident power to normalise by.
    #[error("net direct-beam reading {net_w} W is not positive")]
    NoDirectBeam { net_w: f64 },
    /// Reference minus its dark is not positive.
    #[error("net reference reading {net_w} W is not positive")]
    NoReferenceSignal { net_w: f64 },
    /// The detector solid angle is not positive.
    #[error("detector solid angle {solid_angle_sr} sr is not positive")]
    BadSolidAngle { solid_angle_sr: f64 },
    /// The reference BRDF cannot be evaluated at this wavelength.
    #[error("reference BRDF: {0}")]
    Reference(#[from] SpectrumError),
    /// The reference BRDF is zero, negative or not finite at this geometry.
    #[error("reference BRDF is {value_per_sr} 1/sr at this geometry; it must be positive and finite")]
    BadReferenceValue { value_per_sr: f64 },
}

fn finite(field: &'static str, value: f64) -> Result<f64, MeasurementError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(MeasurementError::NonFinite { field, value })
    }
}

fn non_negative(field: &'static str, value: f64) -> Result<f64, MeasurementError> {
    finite(field, value)?;
    if value < 0.0 {
        Err(MeasurementError::Negative { field, value })
    } else {
        Ok(value)
    }
}

fn reading(
    field: &'static str,
    std_field: &'static str,
    r: &Reading,
) -> Result<(f64, f64), MeasurementError> {
    Ok((finite(field, r.value_w)?, non_negative(std_field, r.std_w)?))
}

/// Checks the geometry and the footprint; returns (cos theta_i, cos theta_o).
fn check_geometry(
    geometry: &MeasurementGeometry,
    footprint: &Footprint,
    limits: &ValidityLimits,
) -> Result<(f64, f64), MeasurementError> {
    non_negative("angle_std_rad", geometry.angle_std_rad)?;
    let min_cos = finite("min_cos_theta_o", limits.min_cos_theta_o)?;
    // A direction built from a NaN angle (e.g. "nan" in a plan file) has NaN components, and NaN passes every
    // `<`/`<=` test below: refuse it by name here (found by tests/stress/measurement.rs; it used to surface
    // only as a non-finite "result").
    let cos_i = finite("wi.cos_theta", geometry.wi.cos_theta())?;
    let cos_o = finite("wo.cos_theta", geometry.wo.cos_theta())?;
    finite("wi.sin_theta", geometry.wi.sin_theta())?;
    finite("wo.sin_theta", geometry.wo.sin_theta())?;
    if cos_o < min_cos || cos_o <= 0.0 {
        return Err(MeasurementError::GrazingDetector {
            cos_theta_o: cos_o,
            min_cos_theta_o: min_cos,
        });
    }
    if cos_i <= 0.0 {
        return Err(MeasurementError::SourceBelowHorizon { cos_theta_i: cos_i });
    }
    let beam = non_negative("beam_radius_mm", footprint.beam_radius_mm)?;
    let sample = non_negative("sample_radius_mm", footprint.sample_radius_mm)?;
    let footprint_mm = beam / cos_i;
    if footprint_mm > sample {
        return Err(MeasurementError::OverfillsSample {
            footprint_mm,
            sample_radius_mm: sample,
        });
    }
    if let Some(field) = footprint.detector_field_radius_mm {
        let field = non_negative("detector_field_radius_mm", field)?;
        if footprint_mm > field {
            return Err(MeasurementError::OverfillsDetectorField {
                footprint_mm,
                field_radius_mm: field,
            });
        }
    }
    Ok((cos_i, cos_o))
}

/// The absolute measurement equation `f = (S - S_dark) / ((P - P_dark) Omega_d cos theta_o)` with its uncertainty.
///
/// With a finite aperture the result is the cos-weighted average of f over the detector's solid angle; for a
/// mirror (a delta lobe) it is `R / (Omega_d cos theta_o)` inside the aperture, not a point value.
pub fn absolute_brdf(
    readings: &AbsoluteReadings,
    geometry: &MeasurementGeometry,
    footprint: &Footprint,
    limits: &ValidityLimits,
) -> Result<BrdfValue, MeasurementError> {
    let (s, u_s) = reading("signal.value_w", "signal.std_w", &readings.signal)?;
    let (sd, u_sd) = reading("signal_dark.value_w", "signal_dark.std_w", &readings.signal_dark)?;
    let (p, u_p) = reading("direct_beam.value_w", "direct_beam.std_w", &readings.direct_beam)?;
    let (pd, u_pd) = reading(
        "direct_beam_dark.value_w",
        "direct_beam_dark.std_w",
        &readings.direct_beam_dark,
    )?;
    let omega = finite("detector_solid_angle_sr", readings.detector_solid_angle_sr)?;
    let u_omega = non_negative(
        "detector_solid_angle_std_sr",
        readings.detector_solid_angle_std_sr,
    )?;
    let (_, cos_o) = check_geometry(geometry, footprint, limits)?;
    if omega <= 0.0 {
        return Err(MeasurementError::BadSolidAngle {
            solid_angle_sr: omega,
        });
    }
    let net_signal = s - sd;
    let net_direct = p - pd;
    if net_direct <= 0.0 {
        return Err(MeasurementError::NoDirectBeam { net_w: net_direct });
    }
    let denominator = net_direct * omega * cos_o;
    let f = net_signal / denominator;
    // Partial derivatives: df/dS = 1/den = -df/dS_dark; df/dP = -f/P_net = -df/dP_dark; df/dOmega = -f/Omega;
    // df/dtheta_o = f tan(theta_o), tan from the direction's components (accurate near the pole).
    let tan_o = geometry.wo.sin_theta() / cos_o;
    let budget = UncertaintyBudget {
        signal_per_sr: u_s / denominator,
        signal_dark_per_sr: u_sd / denominator,
        normalisation_per_sr: (f / net_direct * u_p).abs(),
        normalisation_dark_per_sr: (f / net_direct * u_pd).abs(),
        scale_per_sr: (f / omega * u_omega).abs(),
        angles_per_sr: (f * tan_o * geometry.angle_std_rad).abs(),
    };
    finish(f, budget)
}

/// The relative measurement equation `f = f_ref(wi, wo) (S - S_dark) / (S_ref - S_dark_ref)` with its uncertainty.
///
/// `reference` describes the reference sample's BRDF including its angular shape (real white standards are not
/// Lambertian at high angles). The angle uncertainty enters through the reference's slope, estimated by central
/// differences in theta_i and theta_o.
pub fn relative_brdf(
    readings: &RelativeReadings,
    reference: &dyn Brdf,
    wavelength: Wavelength,
    geometry: &MeasurementGeometry,
    footprint: &Footprint,
    limits: &ValidityLimits,
) -> Result<BrdfValue, MeasurementError> {
    let (s, u_s) = reading("signal.value_w", "signal.std_w", &readings.signal)?;
    let (sd, u_sd) = reading("signal_dark.value_w", "signal_dark.std_w", &readings.signal_dark)?;
    let (r, u_r) = reading("reference.value_w", "reference.std_w", &readings.reference)?;
    let (rd, u_rd) = reading(
        "reference_dark.value_w",
        "reference_dark.std_w",
        &readings.reference_dark,
    )?;
    let u_cal = non_negative("reference_brdf_rel_std", readings.reference_brdf_rel_std)?;
    check_geometry(geometry, footprint, limits)?;
    let net_reference = r - rd;
    if net_reference <= 0.0 {
        return Err(MeasurementError::NoReferenceSignal { net_w: net_reference });
    }
    let f_ref = reference.eval(&geometry.wi, &geometry.wo, wavelength)?;
    if !f_ref.is_finite() || f_ref <= 0.0 {
        return Err(MeasurementError::BadReferenceValue { value_per_sr: f_ref });
    }
    let ratio = (s - sd) / net_reference;
    let f = f_ref * ratio;
    let slope_i = polar_slope(reference, geometry, wavelength, Which::Incident)?;
    let slope_o = polar_slope(reference, geometry, wavelength, Which::Outgoing)?;
    let u_angle = geometry.angle_std_rad;
    let budget = UncertaintyBudget {
        signal_per_sr: (f_ref / net_reference * u_s).abs(),
        signal_dark_per_sr: (f_ref / net_reference * u_sd).abs(),
        normalisation_per_sr: (f / net_reference * u_r).abs(),
        normalisation_dark_per_sr: (f / net_reference * u_rd).abs(),
        scale_per_sr: (f * u_cal).abs(),
        angles_per_sr: (ratio * u_angle).abs() * slope_i.hypot(slope_o),
    };
    finish(f, budget)
}

fn finish(f: f64, budget: UncertaintyBudget) -> Result<BrdfValue, MeasurementError> {
    let value_per_sr = finite("result (1/sr)", f)?;
    let std_per_sr = finite("result uncertainty (1/sr)", budget.total())?;
    Ok(BrdfValue {
        value_per_sr,
        std_per_sr,
        budget,
    })
}

#[derive(Debug, Clone, Copy)]
enum Which {
    Incident,
    Outgoing,
}

/// d f_ref / d theta (1/sr per radian) for the polar angle of wi or wo, by a central difference in the plane
/// containing the direction and the normal. The step is one-sided near the pole and the horizon.
fn polar_slope(
    reference: &dyn Brdf,
    geometry: &MeasurementGeometry,
    wavelength: Wavelength,
    which: Which,
) -> Result<f64, MeasurementError> {
    const STEP_RAD: f64 = 1e-5;
    let moved = |d: &Direction, delta: f64| -> Direction {
        let (theta, phi) = d.to_spherical();
        Direction::from_spherical(theta + delta, phi)
    };
    let d = match which {
        Which::Incident => geometry.wi,
        Which::Outgoing => geometry.wo,
    };
    let theta = d.theta();
    let lo = (theta - STEP_RAD).max(0.0);
    let hi = (theta + STEP_RAD)
        .min(std::f64::consts::FRAC_PI_2 - STEP_RAD)
        .max(theta);
    if hi <= lo {
        return Ok(0.0);
    }
    let eval_at = |delta: f64| -> Result<f64, SpectrumError> {
        let moved_d = moved(&d, delta);
        match which {
            Which::Incident => reference.eval(&moved_d, &geometry.wo, wavelength),
            Which::Outgoing => reference.eval(&geometry.wi, &moved_d, wavelength),
        }
    };
    let f_hi = eval_at(hi - theta)?;
    let f_lo = eval_at(lo - theta)?;
    let slope = (f_hi - f_lo) / (hi - lo);
    Ok(if slope.is_finite() { slope } else { 0.0 })
}

#[cfg(test)]
mod tests;
