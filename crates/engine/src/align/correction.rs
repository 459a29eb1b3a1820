//! A calibration applied to campaigns: each planned pose replaced by the one at which the calibrated model
//! (crate::align::model) puts the beam and the detector where the plan's nominal kinematics meant them.
//!
//! The plan's pose says which sample-frame directions (towards the source, towards the detector) the point
//! measures, through the nominal kinematics. The corrected pose is the least-squares solution of "the model's
//! directions at the corrected pose = those directions" (six components, one unknown per axis the instrument
//! has), by Gauss-Newton from the planned pose with a numerical Jacobian: the errors are hundredths of a degree,
//! so two or three steps reach 1e-9 rad.

use gonio_instrument::{AxisRole, GeometryKind, Instrument};
use gonio_scheduler::kinematics::{Kinematics, Pose};

use super::model::{Dimensions, GeometryParams, Model};

/// The model's parameters as a calibration states them, and the kinematics the plans use.
#[derive(Debug, Clone)]
pub struct PoseCorrection {
    model: Model,
    kinematics: Kinematics,
    roles: Vec<AxisRole>,
}

/// Largest correction accepted (deg): beyond it the calibration does not describe this instrument's errors.
pub const MAX_CORRECTION_DEG: f64 = 1.0;

impl PoseCorrection {
    pub fn new(instrument: &Instrument, params: GeometryParams) -> PoseCorrection {
        let mut roles = vec![AxisRole::LightArm, AxisRole::DetectorArm];
        if instrument.geometry == GeometryKind::Reference {
            roles.push(AxisRole::SampleTilt);
        }
        roles.push(AxisRole::SampleRotation);
        PoseCorrection {
            model: Model {
                p: params,
                dims: Dimensions {
                    detector_distance_mm: instrument.detector.distance_mm,
                },
            },
            kinematics: Kinematics::new(instrument),
            roles,
        }
    }

    /// The sample-frame directions towards the source and the detector at `pose`, by the calibrated model;
    /// `None` where it has none.
    pub fn directions(&self, pose: &Pose) -> Option<(gonio_brdf::Direction, gonio_brdf::Direction)> {
        let (a, b) = self.model.directions(pose)?;
        Some((
            gonio_brdf::Direction::new(a[0], a[1], a[2])?,
            gonio_brdf::Direction::new(b[0], b[1], b[2])?,
        ))
    }

    /// The pose to command for `planned` (module doc); `planned` itself, with a warning in the log, when the model
    /// has no answer near it or the correction would exceed [`MAX_CORRECTION_DEG`] on some axis.
    pub fn correct(&self, planned: &Pose) -> Pose {
        let (wi, wo) = self.kinematics.forward(planned);
        let target = [wi.x(), wi.y(), wi.z(), wo.x(), wo.y(), wo.z()];
        let residual = |p: &Pose| -> Option<[f64; 6]> {
            let (a, b) = self.model.directions(p)?;
            let v = [a[0], a[1], a[2], b[0], b[1], b[2]];
            let mut r = [0.0; 6];
            for k in 0..6 {
                r[k] = v[k] - target[k];
            }
            Some(r)
        };
        let mut pose = *planned;
        for _ in 0..6 {
            let Some(r0) = residual(&pose) else {
                return uncorrected(planned);
            };
            if r0.iter().all(|v| v.abs() < 1e-12) {
                break;
            }
            // Jacobian (6 x n) by forward differences of 1e-6 deg.
            let h = 1e-6;
            let mut jac: Vec<[f64; 6]> = Vec::with_capacity(self.roles.len());
            for &role in &self.roles {
                let mut q = pose;
                q.set(role, pose.get(role) + h);
                let Some(r1) = residual(&q) else {
                    return uncorrected(planned);
                };
                let mut col = [0.0; 6];
                for k in 0..6 {
                    col[k] = (r1[k] - r0[k]) / h;
                }
                jac.push(col);
            }
            let n = jac.len();
            let mut a = vec![vec![0.0; n]; n];
            let mut g = vec![0.0; n];
            for i in 0..n {
                for j in 0..n {
                    a[i][j] = (0..6).map(|k| jac[i][k] * jac[j][k]).sum();
                }
                g[i] = (0..6).map(|k| jac[i][k] * r0[k]).sum();
            }
            let Some(l) = gonio_results::fit::lm::cholesky(&a) else {
                return uncorrected(planned);
            };
            let step = gonio_results::fit::lm::cholesky_solve(&l, &g);
            for (i, &role) in self.roles.iter().enumerate() {
                pose.set(role, pose.get(role) - step[i]);
            }
        }
        let too_far = self.roles.iter().any(|&r| {
            let d = (pose.get(r) - planned.get(r)).abs();
            d.is_nan() || d > MAX_CORRECTION_DEG
        });
        if too_far {
            tracing::warn!(
                "alignment: the correction of pose {planned:?} would exceed {MAX_CORRECTION_DEG} deg on an axis \
                 ({pose:?}); the planned pose is used"
            );
            *planned
        } else {
            pose
        }
    }
}

/// The planned pose, when the model has no answer near it (logged: the point is then measured uncorrected).
fn uncorrected(planned: &Pose) -> Pose {
    tracing::warn!(
        "alignment: no corrected pose near {planned:?} (the model has no answer there); the planned pose is used"
    );
    *planned
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest component of the difference between the directions `planned` means (nominal kinematics) and
    /// those the calibrated model gives at `pose`.
    fn miss(c: &PoseCorrection, kin: &Kinematics, planned: &Pose, pose: &Pose) -> f64 {
        let (wi, wo) = kin.forward(planned);
        let (a, b) = c.model.directions(pose).expect("directions");
        [
            wi.x() - a[0],
            wi.y() - a[1],
            wi.z() - a[2],
            wo.x() - b[0],
            wo.y() - b[1],
            wo.z() - b[2],
        ]
        .iter()
        .fold(0.0, |m, v| m.max(v.abs()))
    }

    fn instrument() -> Instrument {
        gonio_instrument::InstrumentFile::simulated().instrument
    }

    #[test]
    fn with_no_errors_the_model_is_the_nominal_kinematics() {
        let inst = instrument();
        let c = PoseCorrection::new(&inst, GeometryParams::default());
        let kin = Kinematics::new(&inst);
        for pose in [
            Pose::new(30.0, -50.0, 10.0, 20.0),
            Pose::new(-60.0, 45.0, -5.0, 170.0),
        ] {
            let d = miss(&c, &kin, &pose, &pose);
            assert!(d < 1e-12, "{pose:?}: {d}");
            assert_eq!(c.correct(&pose), pose);
        }
    }

    #[test]
    fn the_corrected_pose_gives_the_planned_directions_on_the_calibrated_instrument() {
        let inst = instrument();
        let p = GeometryParams {
            beam_deg: 0.02,
            detector_zero_deg: -0.015,
            tilt_zero_deg: 0.01,
            sample_tilt_x_deg: 0.04,
            sample_tilt_y_deg: -0.03,
            eccentricity_x_mm: 0.1,
            ..Default::default()
        };
        let c = PoseCorrection::new(&inst, p);
        let kin = Kinematics::new(&inst);
        let planned = Pose::new(-40.0, 25.0, 3.0, 30.0);
        let corrected = c.correct(&planned);
        assert_ne!(corrected, planned);
        let d = miss(&c, &kin, &planned, &corrected);
        assert!(d < 1e-9, "{d}");
    }
}
