//! [`Geometry`]: one pose as the optics compute with it (directions, the spot, the field's centre, the arms'
//! axis).
//!
//! Its own module beneath the parts that build it (the imperfect instrument's true geometry) and those that adjust
//! or read it (the beam's pointing, the reading), so that none of them reaches into another for the type.

use crate::kinematics::{LabVector, PoseGeometry};

/// One pose as the optics compute with it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Geometry {
    /// Directions from the spot, in the (true) sample frame.
    pub pose: PoseGeometry,
    /// The detector arm's own direction (for the direct beam, with no sample), lab.
    pub detector_arm_lab: LabVector,
    /// The beam's centre on the sample (sample x, y; mm).
    pub spot_mm: [f64; 2],
    /// The centre of the detector's field of view on the sample (sample x, y; mm).
    pub field_centre_mm: [f64; 2],
    /// The beam's centre on the sample plane, lab (mm): the origin unless the geometry or the beam moves it.
    pub spot_lab: LabVector,
    /// Where the arms' axis crosses the horizontal plane through the sample centre, lab (mm).
    pub axis_lab: LabVector,
}
