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
}

/// The geometric imperfections (models: crates/simulator/src/imperfections/geometry.rs).
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
