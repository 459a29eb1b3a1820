//! Overlaps on a sample's reflection: the levels the direct beam cannot give.
//!
//! The direct beam's edge gives every level from the beam's peak down only when the beam's profile is smooth
//! (a Gaussian beam). A top-hat beam through a round aperture falls from a tenth of its peak to nothing within
//! one encoder count of the detector arm, so the smallest ranges see no level they can be compared at. A
//! sample's reflection can: the detector walked through its specular lobe and out into its diffuse part reads
//! every level between the lobe's peak and the diffuse floor, a few hundred nanowatts down to a nanowatt for a
//! glossy sample, up to tens of nanowatts for a white diffuser.

use gonio_scheduler::kinematics::Pose;

use super::CharacteriseError;
use super::meter::{Meter, auto, overlap_range, wheel_to};
use super::ranges::Overlap;
use crate::motion::Motion;

/// The detector's walk about the specular direction (deg): from this far below it to this far above, by this
/// step.
const BELOW_DEG: f64 = 25.0;
const ABOVE_DEG: f64 = 45.0;
const STEP_DEG: f64 = 0.25;

/// Overlaps on the sample in the holder, the light arm at `light_deg` (tilt and rotation 0) and the specular
/// direction at detector angle `specular_deg`, in band `nm` (wheel position `position`).
pub async fn sample_overlaps(
    motion: &mut Motion<'_>,
    meter: &mut Meter,
    light_deg: f64,
    specular_deg: f64,
    nm: f64,
    position: Option<u8>,
) -> Result<Vec<Overlap>, CharacteriseError> {
    let inst = &motion.rig().file().instrument;
    let ranges_w = inst.detector.ranges_w.clone();
    let travel = inst
        .axis(gonio_instrument::AxisRole::DetectorArm)
        .map_or((f64::NEG_INFINITY, f64::INFINITY), |a| (a.min_deg, a.max_deg));
    if let Some(p) = position {
        wheel_to(motion, p).await?;
    }
    let mut out = Vec::new();
    let steps = ((BELOW_DEG + ABOVE_DEG) / STEP_DEG).round() as i32;
    for k in 0..=steps {
        // One way only (increasing detector angle), so that the axis's backlash is taken up the same way.
        let detector_deg = specular_deg - BELOW_DEG + f64::from(k) * STEP_DEG;
        let pose = Pose::new(light_deg, detector_deg, 0.0, 0.0);
        if detector_deg < travel.0 || detector_deg > travel.1 || motion.safe_move(&pose).is_err() {
            continue;
        }
        motion.move_to(&pose).await?;
        let level = meter.read(motion, auto(nm, 10)).await?.power_w;
        if let Some(r) = overlap_range(level, &ranges_w)
            && let Some(o) = meter.overlap(motion, nm, r, &ranges_w).await?
        {
            out.push(o);
        }
    }
    Ok(out)
}
