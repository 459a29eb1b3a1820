//! run.json's `simulator_truth`: what a dry-run's simulated instrument was really like (the hidden values of its
//! `[simulator.imperfections]`, drawn from its seed), so that a test or a person can attribute an error. Absent on
//! the ideal instrument and on real hardware. The simulator computes the values; the daemon's rig copies them
//! here (this crate depends on gonio-brdf only, so the record is its own type).

use serde::{Deserialize, Serialize};

/// The hidden values of a dry-run's instrument.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimulatorTruth {
    /// `[simulator] seed`, from which they were drawn.
    pub seed: u64,
    /// Geometry; absent when that group is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<GeometryTruthRecord>,
    /// Detector; absent when that group is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<DetectorTruthRecord>,
    /// Source; absent when that group is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceTruthRecord>,
    /// Sample; absent when that group is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample: Option<SampleTruthRecord>,
    /// Filters; absent when the bands are single wavelengths.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filters: Option<FiltersTruthRecord>,
    /// Beam; absent when that group is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beam: Option<BeamTruthRecord>,
    /// The hardware as it really is where it differs from the instrument file (`[simulator.actual]`); absent
    /// when nothing differs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub actual: Option<ActualHardwareRecord>,
}

/// What the simulated hardware really does where the instrument file claims otherwise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActualHardwareRecord {
    /// The wheel's real time per position (s); absent when as claimed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_seconds_per_position: Option<f64>,
    /// The axes that differ, each with only the keys that do.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub axes: Vec<ActualAxisRecord>,
    /// The detector head's real dark current (A); absent when as claimed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector_dark_current_a: Option<f64>,
    /// The source's real white relative noise; absent when as claimed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_relative_noise: Option<f64>,
    /// The devices whose real time to answer a query differs from the file's `reply_latency_ms` (ms), by name.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub reply_latency_ms: std::collections::BTreeMap<String, f64>,
    /// The devices whose real instant of taking a reported position (after the query was sent) differs from the
    /// file's `position_sampled_ms` (ms), by name.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub position_sampled_ms: std::collections::BTreeMap<String, f64>,
}

/// One axis's real limits where they differ from the file (deg/s, deg/s^2, s, deg).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActualAxisRecord {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed_deg_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel_deg_s2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settle_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backlash_deg: Option<f64>,
}

/// The filters' actual bands (model: simulator/src/imperfections/filters.rs): an N-cavity passband
/// `1 / (1 + x^(2N))` about each actual centre with its actual width, plus the blocking's floor over the
/// photodiode's range, weighted by a Planck source and the photodiode's responsivity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FiltersTruthRecord {
    pub cavities: u32,
    pub source_temperature_k: f64,
    pub out_of_band_transmission: f64,
    pub leakage_range_nm: [f64; 2],
    pub filters: Vec<FilterTruthRecord>,
}

/// One filter's nominal and actual band (nm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilterTruthRecord {
    pub position: u8,
    pub nominal_nm: f64,
    pub nominal_bandwidth_nm: f64,
    pub centre_nm: f64,
    pub bandwidth_nm: f64,
}

/// The beam as it really is (model: simulator/src/imperfections/beam.rs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BeamTruthRecord {
    /// "top-hat" or "gaussian".
    pub profile: String,
    /// The Gaussian's 1/e^2 radius (mm); 0 for the top hat.
    pub gaussian_radius_mm: f64,
    /// The pointing error: in the arms' plane (towards increasing arm angle) and vertical (degrees).
    pub pointing_in_plane_deg: f64,
    pub pointing_vertical_deg: f64,
    /// From the source's output to the arms' axis (mm).
    pub source_distance_mm: f64,
    /// The true full divergence angle and the nominal one (degrees).
    pub divergence_deg: f64,
    pub nominal_divergence_deg: f64,
}

/// The sample's non-uniformity (model: simulator/src/imperfections/sample.rs): its BRDF is the
/// material's times `1 + (gradient_x x + gradient_y y) / R + radial (x^2 + y^2) / R^2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleTruthRecord {
    pub gradient_x: f64,
    pub gradient_y: f64,
    pub radial: f64,
}

/// Zero: the field is left out of run.json.
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// The detector's imperfections (models: simulator/src/imperfections/detector.rs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectorTruthRecord {
    /// Per range of the meter, smallest first.
    pub ranges: Vec<RangeTruthRecord>,
    /// The photodiode's saturation current (A); 0: none.
    pub saturation_current_a: f64,
    /// Amplifier excess current noise density (A/sqrt(Hz)).
    pub amplifier_noise_a_per_rthz: f64,
    /// The instrument signature `peak / (1 + (alpha / width)^2) + floor` (1/sr; width in degrees).
    pub signature_peak_sr: f64,
    pub signature_width_deg: f64,
    pub signature_floor_sr: f64,
    /// Ambient light: `a (1 + v sin(2 pi t / period + phase))` (A).
    pub ambient_a: f64,
    pub ambient_variation: f64,
    pub ambient_period_s: f64,
    pub ambient_phase_deg: f64,
    /// How long after a request the meter starts integrating a reading (s).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub reading_delay_s: f64,
}

/// One range's hidden errors: a true current `I` reads `I (1 + gain) (1 + nonlinearity I / I_fs) + offset_fs
/// I_fs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RangeTruthRecord {
    pub gain: f64,
    pub nonlinearity: f64,
    pub offset_fs: f64,
}

/// The source's imperfections (models: simulator/src/imperfections/source.rs). The random walk's path and
/// the flicker's phases are drawn from the seed; their effect on each point is in that point's truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceTruthRecord {
    pub warmup_fraction: f64,
    pub warmup_time_s: f64,
    pub random_walk_per_rthour: f64,
    pub flicker_rms: f64,
}

/// The geometric imperfections (models: simulator/src/imperfections/geometry.rs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeometryTruthRecord {
    /// Per axis, in the instrument file's order.
    pub axes: Vec<AxisTruthRecord>,
    /// Fixed tilt of the sample normal from the rotation axis: components towards the stage's x' and y' (degrees).
    pub sample_tilt_x_deg: f64,
    pub sample_tilt_y_deg: f64,
    /// Where the arms' rotation axis crosses the horizontal plane through the sample centre (lab X, Y; mm).
    pub eccentricity_x_mm: f64,
    pub eccentricity_y_mm: f64,
    /// The detector aperture's true radius and its distance from the arms' axis less the file's (mm): the
    /// solid angle the absolute equation takes from the file is off by these (absent from runs before them).
    #[serde(default)]
    pub aperture_radius_error_mm: f64,
    #[serde(default)]
    pub detector_distance_error_mm: f64,
    /// The sample's mountings: index 0 the first, one more per removal. One per calibration reading of the run
    /// is listed (an upper bound on the removals it made).
    pub seatings: Vec<SeatingRecord>,
}

/// One axis's hidden errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisTruthRecord {
    /// light-arm, detector-arm, sample-tilt, sample-rotation.
    pub role: String,
    /// True zero minus the zero the instrument file states (degrees).
    pub zero_offset_deg: f64,
    pub encoder_amplitude_deg: f64,
    pub encoder_harmonic: u32,
    pub encoder_phase_deg: f64,
}

/// The extra tilt of one mounting of the sample (degrees, towards the stage's x' and y').
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeatingRecord {
    pub index: u64,
    pub tilt_x_deg: f64,
    pub tilt_y_deg: f64,
}
