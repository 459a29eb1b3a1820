//! Forward kinematics of the reference geometry: physical axis angles -> directions in the sample frame.
//!
//! Written from the module documentation of `gonio-instrument` ("The reference geometry"), independently of the
//! scheduler's inverse kinematics, so that a mistake on one side shows up as a disagreement with the other:
//! - lab frame X, Y horizontal, Z up; an arm at physical angle `a` points along `(cos a, sin a, 0)` (the light arm
//!   towards the source, the detector arm towards the detector);
//! - at tilt 0, rotation 0 the sample normal is lab +X, the sample's x axis lab +Y, its y axis lab +Z;
//! - tilt `t` turns the sample about lab Y: normal `n = (cos t, 0, sin t)`, y axis `(-sin t, 0, cos t)`, x axis lab Y;
//! - rotation `r` then turns it about its normal: `x' = cos r x + sin r y`, `y' = -sin r x + cos r y`;
//! - a lab vector `v` has sample-frame components `(v . x', v . y', v . n)`.
//!
//! Worked example (the unit tests check it): tilt 0, rotation 0, light at +30 deg, detector at -30 deg. The source
//! direction is lab `(cos 30, sin 30, 0)`; `x' = +Y` gives `sin 30`, `y' = +Z` gives 0, `n = +X` gives `cos 30`, so
//! `wi = (sin 30, 0, cos 30)` (theta_i = 30 deg, phi_i = 0) and `wo = (-sin 30, 0, cos 30)` (theta_o = 30 deg,
//! phi_o = 180 deg): the specular pair.

use gonio_brdf::Direction;
use gonio_brdf::geometry::sin_cos_deg;

use crate::scene::Pose;

/// A vector in the lab frame (X, Y horizontal, Z up).
pub type LabVector = [f64; 3];

/// The sample's axes expressed in the lab frame, for a given tilt and rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleFrame {
    /// The sample's x axis (x').
    pub x_lab: LabVector,
    /// The sample's y axis (y').
    pub y_lab: LabVector,
    /// The sample normal (n).
    pub normal_lab: LabVector,
}

impl SampleFrame {
    /// The sample frame at physical tilt and rotation angles (degrees).
    pub fn new(tilt_deg: f64, rotation_deg: f64) -> SampleFrame {
        let (st, ct) = sin_cos_deg(tilt_deg);
        let (sr, cr) = sin_cos_deg(rotation_deg);
        // After tilt: x = lab Y, y = (-sin t, 0, cos t), n = (cos t, 0, sin t).
        let x = [0.0, 1.0, 0.0];
        let y = [-st, 0.0, ct];
        let normal_lab = [ct, 0.0, st];
        // Rotation about the normal.
        let x_lab = [
            cr * x[0] + sr * y[0],
            cr * x[1] + sr * y[1],
            cr * x[2] + sr * y[2],
        ];
        let y_lab = [
            -sr * x[0] + cr * y[0],
            -sr * x[1] + cr * y[1],
            -sr * x[2] + cr * y[2],
        ];
        SampleFrame {
            x_lab,
            y_lab,
            normal_lab,
        }
    }

    /// Sample-frame components `(v . x', v . y', v . n)` of a lab vector.
    pub fn to_sample(&self, v: &LabVector) -> [f64; 3] {
        [dot(v, &self.x_lab), dot(v, &self.y_lab), dot(v, &self.normal_lab)]
    }

    /// The lab vector with sample-frame components `s`.
    pub fn to_lab(&self, s: &[f64; 3]) -> LabVector {
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            *o = s[0] * self.x_lab[k] + s[1] * self.y_lab[k] + s[2] * self.normal_lab[k];
        }
        out
    }
}

/// The lab direction of an arm at physical angle `angle_deg` (exact at multiples of 90 degrees).
pub fn arm_direction_lab(angle_deg: f64) -> LabVector {
    let (s, c) = sin_cos_deg(angle_deg);
    [c, s, 0.0]
}

/// Everything the optics need to know about one pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseGeometry {
    /// Towards the source, sample frame (may lie below the horizon: then the sample is lit from behind).
    pub wi: Direction,
    /// Towards the detector centre, sample frame.
    pub wo: Direction,
    /// Towards the source, lab frame.
    pub source_lab: LabVector,
    /// Towards the detector centre, lab frame.
    pub detector_lab: LabVector,
    pub frame: SampleFrame,
}

impl PoseGeometry {
    /// Angle between the two arms (radians, in [0, pi]), computed without `acos`.
    pub fn arm_separation_rad(&self) -> f64 {
        angle_between(&self.source_lab, &self.detector_lab)
    }
}

/// Forward kinematics: the directions in the sample frame and in the lab for a pose.
pub fn forward(pose: &Pose) -> PoseGeometry {
    let frame = SampleFrame::new(pose.tilt_deg, pose.rotation_deg);
    let source_lab = arm_direction_lab(pose.light_deg);
    let detector_lab = arm_direction_lab(pose.detector_deg);
    PoseGeometry {
        wi: direction_from(frame.to_sample(&source_lab)),
        wo: direction_from(frame.to_sample(&detector_lab)),
        source_lab,
        detector_lab,
        frame,
    }
}

/// A unit vector as a `Direction`. The inputs here are rotations of unit vectors, never zero; the fallback only
/// guards against non-finite input angles.
fn direction_from(v: [f64; 3]) -> Direction {
    Direction::new(v[0], v[1], v[2]).unwrap_or(Direction::NORMAL)
}

pub(crate) fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Angle between two unit vectors, `2 asin(|a - b| / 2)` or its complement: accurate near 0 and pi.
pub(crate) fn angle_between(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    if dot(a, b) >= 0.0 {
        let d = (a[0] - b[0]).hypot(a[1] - b[1]).hypot(a[2] - b[2]);
        2.0 * (d / 2.0).min(1.0).asin()
    } else {
        let s = (a[0] + b[0]).hypot(a[1] + b[1]).hypot(a[2] + b[2]);
        std::f64::consts::PI - 2.0 * (s / 2.0).min(1.0).asin()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(light_deg: f64, detector_deg: f64, tilt_deg: f64, rotation_deg: f64) -> Pose {
        Pose {
            light_deg,
            detector_deg,
            tilt_deg,
            rotation_deg,
        }
    }

    fn close(d: &Direction, v: [f64; 3]) -> bool {
        (d.x() - v[0]).abs() < 1e-15 && (d.y() - v[1]).abs() < 1e-15 && (d.z() - v[2]).abs() < 1e-15
    }

    #[test]
    fn in_plane_specular_pair_at_zero_tilt() {
        // Worked in the module doc: light +30, detector -30, tilt 0, rotation 0.
        let g = forward(&pose(30.0, -30.0, 0.0, 0.0));
        let (s, c) = (0.5, 3f64.sqrt() / 2.0);
        assert!(close(&g.wi, [s, 0.0, c]), "{:?}", g.wi);
        assert!(close(&g.wo, [-s, 0.0, c]), "{:?}", g.wo);
        assert!((g.arm_separation_rad() - 60f64.to_radians()).abs() < 1e-15);
    }

    #[test]
    fn arm_at_zero_is_the_normal_at_zero_tilt() {
        let g = forward(&pose(0.0, 90.0, 0.0, 0.0));
        assert_eq!(g.wi, Direction::NORMAL);
        // Detector at +90: lab +Y = the sample's x axis, on the horizon.
        assert!(close(&g.wo, [1.0, 0.0, 0.0]));
    }

    #[test]
    fn tilt_moves_the_normal_up_and_the_source_to_negative_y() {
        // Tilt 20: n = (cos 20, 0, sin 20), y = (-sin 20, 0, cos 20), x = lab Y. A source along lab +X has
        // components (0, -sin 20, cos 20): theta_i = 20 deg at phi_i = -90 deg.
        let g = forward(&pose(0.0, 40.0, 20.0, 0.0));
        let (s, c) = 20f64.to_radians().sin_cos();
        assert!(close(&g.wi, [0.0, -s, c]), "{:?}", g.wi);
        // Detector at +40: lab (cos 40, sin 40, 0) -> (sin 40, -cos 40 sin 20, cos 40 cos 20).
        let (s40, c40) = 40f64.to_radians().sin_cos();
        assert!(close(&g.wo, [s40, -c40 * s, c40 * c]), "{:?}", g.wo);
    }

    #[test]
    fn rotation_turns_the_in_plane_azimuth() {
        // Rotation 90 at tilt 0: x' = y = lab +Z, y' = -x = lab -Y. A source at light +30, lab (cos30, sin30, 0),
        // has components (0, -sin 30, cos 30): phi_i = -90 deg. A rotation by +r moves the azimuth by -r.
        let g = forward(&pose(30.0, -50.0, 0.0, 90.0));
        assert!(close(&g.wi, [0.0, -0.5, 3f64.sqrt() / 2.0]), "{:?}", g.wi);
        let (s50, c50) = 50f64.to_radians().sin_cos();
        assert!(close(&g.wo, [0.0, s50, c50]), "{:?}", g.wo);
    }

    #[test]
    fn tilt_and_rotation_together_match_hand_worked_vectors() {
        // Tilt 90, rotation 30: n = lab +Z, y = lab -X, x = lab +Y;
        // x' = cos30 (0,1,0) + sin30 (-1,0,0) = (-1/2, cos30, 0); y' = -sin30 (0,1,0) + cos30 (-1,0,0).
        // Light at 0 (lab +X): components (-1/2, -cos30, 0) -> on the horizon at phi = -120 deg.
        let g = forward(&pose(0.0, 90.0, 90.0, 30.0));
        let c30 = 3f64.sqrt() / 2.0;
        assert!(close(&g.wi, [-0.5, -c30, 0.0]), "{:?}", g.wi);
        // Detector at +90 (lab +Y): (cos30, -1/2, 0).
        assert!(close(&g.wo, [c30, -0.5, 0.0]), "{:?}", g.wo);
    }

    #[test]
    fn frame_is_orthonormal_and_round_trips() {
        for &(t, r) in &[(0.0, 0.0), (17.0, -33.0), (-80.0, 170.0), (45.0, 45.0)] {
            let f = SampleFrame::new(t, r);
            for (a, b, expect) in [
                (f.x_lab, f.x_lab, 1.0),
                (f.y_lab, f.y_lab, 1.0),
                (f.normal_lab, f.normal_lab, 1.0),
                (f.x_lab, f.y_lab, 0.0),
                (f.x_lab, f.normal_lab, 0.0),
                (f.y_lab, f.normal_lab, 0.0),
            ] {
                assert!((dot(&a, &b) - expect).abs() < 1e-15);
            }
            // Right-handed: x' cross y' = n.
            let cr = [
                f.x_lab[1] * f.y_lab[2] - f.x_lab[2] * f.y_lab[1],
                f.x_lab[2] * f.y_lab[0] - f.x_lab[0] * f.y_lab[2],
                f.x_lab[0] * f.y_lab[1] - f.x_lab[1] * f.y_lab[0],
            ];
            assert!(angle_between(&cr, &f.normal_lab) < 1e-15);
            let v = [0.3, -0.4, 0.5];
            let back = f.to_lab(&f.to_sample(&v));
            assert!((0..3).all(|k| (back[k] - v[k]).abs() < 1e-15));
        }
    }
}
