//! The geometric imperfections: where the axes, the sample and the arms' axis really are, and the true geometry
//! of a pose they make.
//!
//! # Models (lab frame and axis conventions of crates/instrument/src/lib.rs, "The reference geometry")
//! - **Zero offset**: each axis's true physical angle is `a_true = a_nominal + delta_zero`, where `a_nominal` is
//!   what the controller's position means by the instrument file's `zero_offset_deg` and `direction`, and
//!   `delta_zero ~ N(0, zero_offset_sd_deg)`, one draw per axis. Homing to a switch repeats the same wrong zero,
//!   so the offset is fixed for the instrument.
//! - **Periodic encoder error**: a rotary encoder whose disc is mounted off-centre (or whose scale has a cyclic
//!   error) reads `a_true + A sin(k a + phi)`; the controller servoes the reading onto the target, so the axis
//!   really stands at `a_true = a_nominal + delta_zero - A sin(k a_nominal + phi)`. The sign is absorbed in the
//!   drawn phase; the simulator uses `+ A sin(k a_nominal + phi)` (A and k from the file, phi uniform per axis;
//!   `a_nominal` in place of the reading's argument is exact to second order in A).
//! - **Sample tilt (wedge, mounting)**: the sample's normal is not the stage's rotation axis. The sample frame is
//!   the stage frame turned by a small rotation fixed to the rotating stage: a tilt vector `(t_x, t_y)` (degrees,
//!   components along the stage's x' and y', each `N(0, sample_tilt_sd_deg)`) tips the normal by
//!   `tau = |t|` towards azimuth `alpha = atan2(t_y, t_x)`: rotation by `tau` about `u = (-sin alpha, cos alpha,
//!   0)` (stage coordinates, Rodrigues' formula), which takes `n = (0, 0, 1)` to
//!   `(sin tau cos alpha, sin tau sin alpha, cos tau)`. Because it turns with the stage, the normal precesses
//!   about the rotation axis as the sample rotates: the wobble.
//! - **Re-seating**: every mounting `k` (0 the first; one more each time the sample goes back after a direct-beam
//!   reading) adds its own tilt vector, each component `N(0, reseat_tilt_sd_deg)`, drawn from (seed, k). The
//!   sample frame is `R_tilt R_seat(k)` applied to the stage frame.
//! - **Eccentricity**: the arms turn about a vertical axis through `C = (c_x, c_y, 0)` (mm, lab; each component
//!   `N(0, eccentricity_sd_mm)`) instead of through the sample centre O, where the stage's axes meet the sample
//!   surface. The collimated beam still runs along the source arm's direction `s` and through C (the arm is
//!   aligned on its own axis), so it lands on the sample plane (through O, normal `n`) at
//!   `P = C - (C.n / s.n) s`: the spot moves, the incidence direction does not. The detector's aperture centre
//!   is at `D = C + d o` (d = detector distance, o its arm direction), so the sample sees it along
//!   `wo = (D - P) / |D - P|`, not `o`, and the detector's field is centred on `Q = C - (C.n / o.n) o`.
//! - **The aperture's size**: its true radius is the file's `aperture_radius_mm` plus `N(0,
//!   aperture_radius_sd_mm)` and its true distance (d above) the file's `distance_mm` plus `N(0,
//!   detector_distance_sd_mm)`, one draw each: the solid angle the detector really subtends, which the absolute
//!   equation takes from the file (crate::optics::imperfect).
//!
//! The true geometry of a pose is these applied in turn: axis angles -> stage frame (crate::kinematics) -> sample
//! frame -> arms' lab vectors about C -> directions and spot in the sample frame.

use gonio_brdf::Direction;
use gonio_instrument::{AxisRole, GeometryImperfections};
use serde::Serialize;

use super::draw::Draws;
use crate::kinematics::{LabVector, SampleFrame, arm_direction_lab, dot};
use crate::scene::Pose;

/// The hidden errors of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisTruth {
    pub role: AxisRole,
    /// True zero minus the zero the instrument file states (degrees, physical sense).
    pub zero_offset_deg: f64,
    /// Amplitude of the periodic encoder error (degrees).
    pub encoder_amplitude_deg: f64,
    /// Its cycles per revolution.
    pub encoder_harmonic: u32,
    /// Its phase (degrees).
    pub encoder_phase_deg: f64,
}

impl AxisTruth {
    /// The true physical angle for the angle the controller believes (degrees).
    pub fn true_deg(&self, nominal_deg: f64) -> f64 {
        let mut a = nominal_deg + self.zero_offset_deg;
        if self.encoder_amplitude_deg != 0.0 {
            let arg = f64::from(self.encoder_harmonic) * nominal_deg + self.encoder_phase_deg;
            a += self.encoder_amplitude_deg * arg.to_radians().sin();
        }
        a
    }
}

/// A small tilt of the sample's normal: components towards the stage's x' and y' (degrees).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Tilt {
    pub x_deg: f64,
    pub y_deg: f64,
}

impl Tilt {
    pub fn is_zero(&self) -> bool {
        self.x_deg == 0.0 && self.y_deg == 0.0
    }

    /// The rotation (stage coordinates, row-major) that tips the normal by this tilt (module doc).
    fn rotation(&self) -> [[f64; 3]; 3] {
        let tau = self.x_deg.hypot(self.y_deg).to_radians();
        if tau == 0.0 {
            return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        }
        let alpha = self.y_deg.atan2(self.x_deg);
        let u = [-alpha.sin(), alpha.cos(), 0.0];
        let (s, c) = tau.sin_cos();
        let k = 1.0 - c;
        // Rodrigues: R = c I + s [u]x + k u u^T.
        [
            [
                c + k * u[0] * u[0],
                k * u[0] * u[1] - s * u[2],
                k * u[0] * u[2] + s * u[1],
            ],
            [
                k * u[1] * u[0] + s * u[2],
                c + k * u[1] * u[1],
                k * u[1] * u[2] - s * u[0],
            ],
            [
                k * u[2] * u[0] - s * u[1],
                k * u[2] * u[1] + s * u[0],
                c + k * u[2] * u[2],
            ],
        ]
    }
}

/// The hidden geometric values of one instrument (drawn from its seed) and how to draw the re-seatings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GeometryTruth {
    /// One entry per axis of the instrument file, in its order.
    pub axes: Vec<AxisTruth>,
    /// The fixed tilt of the sample normal from the rotation axis.
    pub sample_tilt: Tilt,
    /// The arms' rotation axis: where it crosses the horizontal plane through the sample centre (mm, lab X, Y).
    pub eccentricity_mm: [f64; 2],
    /// Standard deviation of each component of a mounting's tilt (degrees), from the file.
    pub reseat_tilt_sd_deg: f64,
    /// The detector aperture's true radius less the file's (mm).
    pub aperture_radius_error_mm: f64,
    /// The aperture's true distance from the arms' axis less the file's (mm).
    pub detector_distance_error_mm: f64,
    #[serde(skip)]
    draws: Draws,
}

impl GeometryTruth {
    /// Draw the hidden values for `roles` (the instrument's axes, in file order) from `seed`.
    pub fn draw(settings: &GeometryImperfections, roles: &[AxisRole], seed: u64) -> GeometryTruth {
        let draws = Draws::new(seed);
        let axes = roles
            .iter()
            .map(|&role| {
                let label = role_label(role);
                AxisTruth {
                    role,
                    zero_offset_deg: settings.zero_offset_sd_deg * draws.normal_pair("zero", label).0,
                    encoder_amplitude_deg: settings.encoder_error_amplitude_deg,
                    encoder_harmonic: settings.harmonic(),
                    encoder_phase_deg: if settings.encoder_error_amplitude_deg == 0.0 {
                        0.0
                    } else {
                        draws.phase_deg("encoder", label)
                    },
                }
            })
            .collect();
        let (tx, ty) = draws.normal_pair("sample-tilt", 0);
        let (ex, ey) = draws.normal_pair("eccentricity", 0);
        let (ar, ad) = draws.normal_pair("aperture", 0);
        GeometryTruth {
            axes,
            sample_tilt: Tilt {
                x_deg: settings.sample_tilt_sd_deg * tx,
                y_deg: settings.sample_tilt_sd_deg * ty,
            },
            eccentricity_mm: [settings.eccentricity_sd_mm * ex, settings.eccentricity_sd_mm * ey],
            reseat_tilt_sd_deg: settings.reseat_tilt_sd_deg,
            aperture_radius_error_mm: settings.aperture_radius_sd_mm * ar,
            detector_distance_error_mm: settings.detector_distance_sd_mm * ad,
            draws,
        }
    }

    /// True when nothing is off: the true geometry is the nominal one.
    pub fn is_ideal(&self) -> bool {
        self.axes
            .iter()
            .all(|a| a.zero_offset_deg == 0.0 && a.encoder_amplitude_deg == 0.0)
            && self.sample_tilt.is_zero()
            && self.eccentricity_mm == [0.0, 0.0]
            && self.reseat_tilt_sd_deg == 0.0
            && self.aperture_radius_error_mm == 0.0
            && self.detector_distance_error_mm == 0.0
    }

    /// The extra tilt of the sample's `k`-th mounting (0: the first).
    pub fn seating_tilt(&self, k: u64) -> Tilt {
        self.object_seating_tilt(0, k)
    }

    /// The extra tilt of the `k`-th mounting of holder object `object`: 0 the sample (and its reference), 1
    /// the alignment mirror. Each object seats in its own way: a mirror's mountings are not the sample's.
    pub fn object_seating_tilt(&self, object: u64, k: u64) -> Tilt {
        if self.reseat_tilt_sd_deg == 0.0 {
            return Tilt::default();
        }
        // Object 0 keeps the draws it always had; another object's draws are its own.
        let (a, b) = self.draws.normal_pair("seating", (object << 40) ^ k);
        Tilt {
            x_deg: self.reseat_tilt_sd_deg * a,
            y_deg: self.reseat_tilt_sd_deg * b,
        }
    }

    /// The true axis angles for the pose the controllers believe.
    pub fn true_pose(&self, nominal: &Pose) -> Pose {
        let mut p = *nominal;
        for a in &self.axes {
            let slot = match a.role {
                AxisRole::LightArm => &mut p.light_deg,
                AxisRole::DetectorArm => &mut p.detector_deg,
                AxisRole::SampleTilt => &mut p.tilt_deg,
                AxisRole::SampleRotation => &mut p.rotation_deg,
            };
            *slot = a.true_deg(*slot);
        }
        p
    }

    /// The true geometry of the pose the controllers believe, with the sample in its mounting `seating`, the
    /// detector's aperture `detector_distance_mm` from the arms' axis.
    pub fn true_geometry(&self, nominal: &Pose, seating: &Tilt, detector_distance_mm: f64) -> TrueGeometry {
        let pose = self.true_pose(nominal);
        let stage = SampleFrame::new(pose.tilt_deg, pose.rotation_deg);
        let frame = tilted(&stage, &self.sample_tilt.rotation(), &seating.rotation());
        let source_lab = arm_direction_lab(pose.light_deg);
        let detector_lab = arm_direction_lab(pose.detector_deg);
        let n = frame.normal_lab;
        let c = [self.eccentricity_mm[0], self.eccentricity_mm[1], 0.0];
        // Where a line through C along `v` meets the sample plane (through O, normal n); C itself when parallel.
        let on_plane = |v: &LabVector| -> LabVector {
            let vn = dot(v, &n);
            let t = if vn != 0.0 { -dot(&c, &n) / vn } else { 0.0 };
            [c[0] + t * v[0], c[1] + t * v[1], c[2] + t * v[2]]
        };
        let spot = on_plane(&source_lab);
        let field = on_plane(&detector_lab);
        let viewed_lab = if c == [0.0, 0.0, 0.0] {
            detector_lab
        } else {
            let d = [
                c[0] + detector_distance_mm * detector_lab[0] - spot[0],
                c[1] + detector_distance_mm * detector_lab[1] - spot[1],
                c[2] + detector_distance_mm * detector_lab[2] - spot[2],
            ];
            let len = dot(&d, &d).sqrt();
            [d[0] / len, d[1] / len, d[2] / len]
        };
        let spot_s = frame.to_sample(&spot);
        let field_s = frame.to_sample(&field);
        TrueGeometry {
            pose,
            wi: unit(frame.to_sample(&source_lab)),
            wo: unit(frame.to_sample(&viewed_lab)),
            source_lab,
            detector_lab: viewed_lab,
            detector_arm_lab: detector_lab,
            frame,
            spot_mm: [spot_s[0], spot_s[1]],
            field_centre_mm: [field_s[0], field_s[1]],
        }
    }
}

/// What the sample and the arms really do at one pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueGeometry {
    /// The true axis angles (degrees).
    pub pose: Pose,
    /// Towards the source, true sample frame.
    pub wi: Direction,
    /// From the beam's spot towards the detector's aperture centre, true sample frame.
    pub wo: Direction,
    /// Towards the source, lab.
    pub source_lab: LabVector,
    /// From the spot towards the detector's aperture centre, lab.
    pub detector_lab: LabVector,
    /// The detector arm's direction (its optical axis through the arms' axis), lab: what a direct-beam reading
    /// (no sample) lines up with the beam.
    pub detector_arm_lab: LabVector,
    /// The sample's own axes in the lab.
    pub frame: SampleFrame,
    /// The beam's centre on the sample (sample x, y; mm from the sample centre).
    pub spot_mm: [f64; 2],
    /// The centre of the detector's field of view on the sample (sample x, y; mm).
    pub field_centre_mm: [f64; 2],
}

/// The stage frame turned by `tilt` then `seat` (stage coordinates): columns of `tilt * seat` give the sample's
/// axes in stage coordinates.
fn tilted(stage: &SampleFrame, tilt: &[[f64; 3]; 3], seat: &[[f64; 3]; 3]) -> SampleFrame {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| tilt[i][k] * seat[k][j]).sum();
        }
    }
    let column = |j: usize| [m[0][j], m[1][j], m[2][j]];
    SampleFrame {
        x_lab: stage.to_lab(&column(0)),
        y_lab: stage.to_lab(&column(1)),
        normal_lab: stage.to_lab(&column(2)),
    }
}

fn unit(v: [f64; 3]) -> Direction {
    Direction::new(v[0], v[1], v[2]).unwrap_or(Direction::NORMAL)
}

/// A stable index per role, so that one axis's draw does not depend on the others.
fn role_label(role: AxisRole) -> u64 {
    match role {
        AxisRole::LightArm => 1,
        AxisRole::DetectorArm => 2,
        AxisRole::SampleTilt => 3,
        AxisRole::SampleRotation => 4,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tilt_rotation_takes_the_normal_where_the_doc_says() {
        let t = Tilt {
            x_deg: 0.3,
            y_deg: -0.4,
        };
        let r = t.rotation();
        let tau = 0.5f64.to_radians();
        let alpha = (-0.4f64).atan2(0.3);
        let n = [r[0][2], r[1][2], r[2][2]];
        let expect = [tau.sin() * alpha.cos(), tau.sin() * alpha.sin(), tau.cos()];
        assert!((0..3).all(|k| (n[k] - expect[k]).abs() < 1e-15), "{n:?}");
    }

    #[test]
    fn ideal_truth_is_the_nominal_kinematics() {
        let truth = GeometryTruth::draw(&GeometryImperfections::default(), &[AxisRole::LightArm], 3);
        assert!(truth.is_ideal());
        let pose = Pose {
            light_deg: 30.0,
            detector_deg: -50.0,
            tilt_deg: 10.0,
            rotation_deg: 20.0,
        };
        let g = truth.true_geometry(&pose, &Tilt::default(), 250.0);
        let nominal = crate::kinematics::forward(&pose);
        assert_eq!((g.wi, g.wo), (nominal.wi, nominal.wo));
        assert_eq!(g.spot_mm, [0.0, 0.0]);
    }
}
