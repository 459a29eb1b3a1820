//! Acquisition: the meter's configuration for a band (one builder), one reading of the detector with its
//! standard uncertainty, and the measurement equation as a pure function. No campaign, no store: a campaign's
//! run loop uses it, and so can a console or an alignment scan.
//!
//! The measurement equation ([`brdf_of_reading`]) takes everything it depends on as arguments (the instrument
//! description, the sample's radius, the readings, the normalisation, the directions) and returns the BRDF
//! with its standard uncertainty, or why the reading is not a valid measurement. Absolute:
//! `f = (S - S_dark) / (P Omega cos theta_o)` with `P` the net direct beam; relative: the reference sample's
//! transfer in place of `P Omega cos theta_o` (`gonio_brdf::measurement`).

use gonio_brdf::measurement::{
    AbsoluteReadings, BrdfValue, Footprint, MeasurementError, MeasurementGeometry, Reading, RelativeReadings,
    ValidityLimits, absolute_brdf, relative_brdf,
};
use gonio_brdf::{Brdf, Direction, Wavelength};
use gonio_campaign::{Acquisition, Range};
use gonio_driver::{DetectorConfig, ErrorKind, PowerRange, PowerReading};
use gonio_instrument::Instrument;

use crate::motion::{Device, Motion, MotionError};

/// A reading's noise from the instrument file's figures (those `gonio selftest` measures and writes): each of
/// the reading's `averaging` samples carries the shot noise of its photocurrent (the light's plus the head's
/// dark current), the Johnson noise of the range's feedback resistor and the converter's quantisation
/// (gonio_instrument::meter_noise: the PM100's own figures), and the source's white relative noise; the
/// samples are independent, so the reading's variance is a sample's over `averaging`. Without a responsivity
/// in the file the currents are unknown: the source's noise and the quantisation, in watts, remain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadingNoise {
    /// A/W at the band; `None` when the file has no responsivity.
    pub responsivity_a_per_w: Option<f64>,
    pub dark_current_a: f64,
    /// The head's excess current noise density (A/sqrt(Hz)): the file's `amplifier_noise_a_per_rthz`.
    pub amplifier_noise_a_per_rthz: f64,
    pub source_relative_noise: f64,
    pub averaging: u32,
}

impl ReadingNoise {
    /// The noise of readings at `nm` averaged over `averaging` samples on `instrument`.
    pub fn new(instrument: &Instrument, nm: f64, averaging: u32) -> ReadingNoise {
        let responsivity = gonio_instrument::responsivity::Responsivity::from_detector(&instrument.detector)
            .ok()
            .map(|r| r.at(nm))
            .filter(|r| r.is_finite() && *r > 0.0);
        ReadingNoise {
            responsivity_a_per_w: responsivity,
            dark_current_a: instrument.detector.dark_current_a.max(0.0),
            amplifier_noise_a_per_rthz: instrument.detector.amplifier_noise_a_per_rthz.max(0.0),
            source_relative_noise: instrument.source.relative_noise.max(0.0),
            averaging: averaging.max(1),
        }
    }

    /// The standard deviation of a reading of `power_w` on a range of full scale `range_w` (W).
    pub fn std_w(&self, power_w: f64, range_w: f64) -> f64 {
        use gonio_instrument::meter_noise::{amplifier_a2, johnson_a2, lsb, shot_a2};
        let n = f64::from(self.averaging);
        let source = self.source_relative_noise * power_w.abs();
        let per_sample_w2 = match self.responsivity_a_per_w {
            Some(r) => {
                let current_a = power_w.abs() * r + self.dark_current_a;
                let full_scale_a = range_w.abs() * r;
                let meter_a2 = shot_a2(current_a)
                    + johnson_a2(full_scale_a)
                    + amplifier_a2(self.amplifier_noise_a_per_rthz)
                    + lsb(full_scale_a).powi(2) / 12.0;
                meter_a2 / (r * r) + source * source
            }
            None => lsb(range_w.abs()).powi(2) / 12.0 + source * source,
        };
        (per_sample_w2 / n).sqrt()
    }
}

/// The meter's configuration for a reading at `nm` with a campaign's acquisition settings.
pub fn meter_config(nm: f64, acquisition: &Acquisition) -> DetectorConfig {
    DetectorConfig {
        wavelength_nm: nm,
        averaging: acquisition.averaging,
        range: match acquisition.range {
            Range::Auto => PowerRange::Auto,
            Range::FixedW(w) => PowerRange::Fixed { full_scale_w: w },
        },
    }
}

/// One reading of the detector: power, its standard uncertainty, and whether the meter was overloaded (W).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeterReading {
    pub power_w: f64,
    pub std_w: f64,
    pub overload: bool,
    /// Index into the instrument's `ranges_w` of the range it was read on ([`range_index`]).
    pub range: Option<usize>,
}

/// A meter's reading with its standard uncertainty, the reading's noise ([`ReadingNoise`]). Under auto-range the
/// meter may report its largest range; the range that sets the noise is the smallest of `ranges_w` (the
/// instrument's ranges, W) holding the reading, which is what auto-ranging settles on.
pub fn meter_reading(r: &PowerReading, ranges_w: &[f64], range: Range, noise: &ReadingNoise) -> MeterReading {
    let range_w = match range {
        Range::Auto => ranges_w
            .iter()
            .copied()
            .find(|fs| *fs > r.power_w.abs())
            .unwrap_or(r.range_w)
            .min(r.range_w),
        Range::FixedW(_) => r.range_w,
    };
    let std_w = noise.std_w(r.power_w, range_w);
    MeterReading {
        power_w: r.power_w,
        std_w,
        overload: r.overload,
        range: range_index(r, ranges_w, range),
    }
}

/// The index into the instrument's `ranges_w` of the range a reading was taken on. Under auto-range the meter's
/// reported range need not be the one in use (it may be its largest, or the last one set by hand), so it is the
/// smallest of `ranges_w` holding the reading, which is what auto-ranging settles on (a reading within 1 % of a
/// full scale may be on either: crate::characterise::ranges::near_range_boundary); a fixed range is the one
/// reported. `None` when no range of the file matches.
pub fn range_index(r: &PowerReading, ranges_w: &[f64], range: Range) -> Option<usize> {
    let reported = ranges_w
        .iter()
        .position(|fs| (fs - r.range_w).abs() <= 1e-9 * fs.abs());
    match range {
        Range::Auto => auto_range_index(r.power_w, ranges_w).or(reported),
        Range::FixedW(_) => reported,
    }
}

/// The range auto-ranging settles on for a reading of `power_w`: the smallest of `ranges_w` holding it.
pub fn auto_range_index(power_w: f64, ranges_w: &[f64]) -> Option<usize> {
    ranges_w.iter().position(|fs| *fs > power_w.abs())
}

/// The meter configured for readings at `nm` unless `configured_nm` says it is (supervised); `configured_nm`
/// is updated. What [`read`] does first: a sweep does it before its motion starts, so that no arc passes while
/// the meter is being set up.
pub async fn configure(
    motion: &Motion<'_>,
    nm: f64,
    acquisition: &Acquisition,
    configured_nm: &mut Option<f64>,
) -> Result<(), MotionError> {
    if *configured_nm != Some(nm) {
        let det = motion.rig().detector();
        let config = meter_config(nm, acquisition);
        motion
            .device(Device::Detector, "configure the detector", || {
                det.configure(config)
            })
            .await?;
        *configured_nm = Some(nm);
    }
    Ok(())
}

/// One supervised reading at `nm` (the meter configured for it first unless `configured_nm` says it is; a meter
/// that was reconnected is configured again, since it is back at its defaults). `configured_nm` is updated.
pub async fn read(
    motion: &Motion<'_>,
    nm: f64,
    acquisition: &Acquisition,
    configured_nm: &mut Option<f64>,
) -> Result<MeterReading, MotionError> {
    let det = motion.rig().detector();
    let config = meter_config(nm, acquisition);
    configure(motion, nm, acquisition, configured_nm).await?;
    let r = motion
        .device(Device::Detector, "read the detector", || async {
            let r = det.read_power().await;
            if let Err(e) = &r
                && matches!(e.kind(), ErrorKind::Disconnected | ErrorKind::Unavailable)
            {
                det.configure(config).await?;
            }
            r
        })
        .await?;
    let instrument = &motion.rig().file().instrument;
    let noise = ReadingNoise::new(instrument, nm, acquisition.averaging);
    Ok(meter_reading(
        &r,
        &instrument.detector.ranges_w,
        acquisition.range,
        &noise,
    ))
}

/// What a sample reading is normalised by.
#[derive(Debug, Clone, Copy)]
pub enum Normalisation<'a> {
    /// The direct beam (net of its dark), read with the sample out of the beam.
    Absolute,
    /// A reference sample read at a reference geometry: `transfer` carries that reading to the measured
    /// geometry (`f_ref(g_r) cos(theta_o,r) / cos(theta_o)`), with the reference's calibration uncertainty.
    Relative {
        transfer: &'a dyn Brdf,
        reference_brdf_rel_std: f64,
    },
}

/// Everything the measurement equation depends on besides the readings.
#[derive(Debug, Clone, Copy)]
pub struct EquationInputs<'a> {
    pub instrument: &'a Instrument,
    pub sample_radius_mm: f64,
    pub normalisation: Normalisation<'a>,
    pub band_nm: f64,
    pub wi: Direction,
    pub wo: Direction,
}

/// The measurement equation: the BRDF (1/sr) and its standard uncertainty from a net-able signal, its dark and
/// the normalisation reading (net direct beam, or net reference signal) at the time of the reading. Pure.
pub fn brdf_of_reading(
    inputs: &EquationInputs<'_>,
    signal: Reading,
    dark: Reading,
    norm: Reading,
) -> Result<BrdfValue, MeasurementError> {
    let inst = inputs.instrument;
    // Positioning: the arms' arrival tolerance (where they stopped is read back and accounted for when the
    // campaign completes, crate::budget).
    let geometry = MeasurementGeometry {
        wi: inputs.wi,
        wo: inputs.wo,
        angle_std_rad: inst.arrival_u_deg().to_radians(),
    };
    let footprint = Footprint {
        beam_radius_mm: inst.source.beam_radius_mm,
        sample_radius_mm: inputs.sample_radius_mm,
        detector_field_radius_mm: Some(inst.detector.field_radius_mm),
    };
    let limits = ValidityLimits {
        min_cos_theta_o: inst.safety.grazing_limit_deg.to_radians().cos(),
    };
    match inputs.normalisation {
        Normalisation::Relative {
            transfer,
            reference_brdf_rel_std,
        } => {
            let wavelength = Wavelength::from_nm(inputs.band_nm).map_err(MeasurementError::Reference)?;
            relative_brdf(
                &RelativeReadings {
                    signal,
                    signal_dark: dark,
                    reference: norm,
                    reference_dark: Reading::exact(0.0),
                    reference_brdf_rel_std,
                },
                transfer,
                wavelength,
                &geometry,
                &footprint,
                &limits,
            )
        }
        Normalisation::Absolute => {
            let omega = gonio_brdf::radiometry::aperture_solid_angle_sr(
                inst.detector.aperture_radius_mm,
                inst.detector.distance_mm,
            );
            absolute_brdf(
                &AbsoluteReadings {
                    signal,
                    signal_dark: dark,
                    direct_beam: norm,
                    direct_beam_dark: Reading::exact(0.0),
                    detector_solid_angle_sr: omega,
                    detector_solid_angle_std_sr: omega * inst.detector.solid_angle_u(),
                },
                &geometry,
                &footprint,
                &limits,
            )
        }
    }
}

/// The point's flag for a refused measurement.
pub fn flag_for(e: &MeasurementError) -> String {
    match e {
        MeasurementError::OverfillsSample { .. } | MeasurementError::OverfillsDetectorField { .. } => {
            "overfilled".into()
        }
        MeasurementError::GrazingDetector { .. } => "grazing".into(),
        MeasurementError::SourceBelowHorizon { .. } => "below-horizon".into(),
        MeasurementError::NoDirectBeam { .. } => "no-direct-beam".into(),
        MeasurementError::NoReferenceSignal { .. } => "no-reference-signal".into(),
        other => format!("invalid: {other}"),
    }
}

#[cfg(test)]
mod tests;
