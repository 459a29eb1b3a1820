//! Numerical stability stress suite for the kinematics (issue 7): inverse kinematics on hostile direction pairs
//! (polar angles exactly 0 and 90 degrees and within 1e-12 of them, `wi == wo`, `wi == mirror(wo)`, antipodal and
//! nearly antipodal pairs, nearly parallel pairs), for the reference and the in-plane geometry.
//!
//! Required: every call returns either poses or a typed error (no panic); every pose is finite and within the
//! axis limits; forward kinematics of every pose gives back the requested directions to 1e-9 rad; the
//! degree-edge representation (`Geometry`) round-trips.

use crate::common;

use common::simulated;
use gonio_brdf::geometry::Direction;
use gonio_instrument::{AxisRole, GeometryKind};
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_testkit::directions::hostile_directions;

fn pairs() -> Vec<(Direction, Direction)> {
    let dirs = hostile_directions();
    let mut v = Vec::new();
    for wi in &dirs {
        for wo in &dirs {
            v.push((*wi, *wo));
        }
        v.push((*wi, wi.reflect_about_normal()));
        v.push((*wi, wi.neg()));
        v.push((*wi, wi.rotate_z(1e-12)));
        v.push((*wi, wi.neg().rotate_z(1e-9)));
    }
    v
}

fn check(kin: &Kinematics, in_plane: bool, failures: &mut Vec<String>) {
    let inst = simulated();
    let hints = [Pose::new(0.0, 0.0, 0.0, 0.0), Pose::new(40.0, -30.0, 20.0, 100.0)];
    for (wi, wo) in pairs() {
        for hint in &hints {
            let Ok(poses) = kin.solutions(&wi, &wo, hint) else {
                // A typed refusal (out of plane, axis limits) is an acceptable answer to a hostile request.
                continue;
            };
            for pose in poses {
                let values = [
                    pose.light_deg,
                    pose.detector_deg,
                    pose.tilt_deg,
                    pose.rotation_deg,
                ];
                if values.iter().any(|v| !v.is_finite()) {
                    failures.push(format!("{wi:?} {wo:?}: non-finite pose {pose:?}"));
                    continue;
                }
                for role in [
                    AxisRole::LightArm,
                    AxisRole::DetectorArm,
                    AxisRole::SampleTilt,
                    AxisRole::SampleRotation,
                ] {
                    if let Some(axis) = inst.axis(role)
                        && !(in_plane && role == AxisRole::SampleTilt)
                    {
                        let v = pose.get(role);
                        if v < axis.min_deg - 1e-9 || v > axis.max_deg + 1e-9 {
                            failures.push(format!(
                                "{wi:?} {wo:?}: {role:?} at {v} outside limits in {pose:?}"
                            ));
                        }
                    }
                }
                let (a, b) = kin.forward(&pose);
                let (ea, eb) = (a.angle_to(&wi), b.angle_to(&wo));
                if ea > 1e-9 || eb > 1e-9 {
                    failures.push(format!(
                        "{wi:?} {wo:?}: forward of {pose:?} misses by {ea:e}, {eb:e} rad"
                    ));
                }
            }
        }
        // The degree-edge representation round-trips (phi is 0 at the pole by convention: compare directions).
        let g = Geometry::from_directions(&wi, &wo);
        let (a, b) = g.directions();
        if a.angle_to(&wi) > 1e-14 || b.angle_to(&wo) > 1e-14 {
            failures.push(format!("{wi:?} {wo:?}: Geometry {g:?} round trip"));
        }
    }
}

#[test]
fn inverse_kinematics_round_trips_on_hostile_pairs() {
    let mut failures = Vec::new();
    check(&Kinematics::new(&simulated()), false, &mut failures);
    let mut inst = simulated();
    inst.geometry = GeometryKind::InPlane;
    inst.axes.retain(|a| a.role != AxisRole::SampleTilt);
    check(&Kinematics::new(&inst), true, &mut failures);
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.iter().take(20).cloned().collect::<Vec<_>>().join("\n")
    );
}
