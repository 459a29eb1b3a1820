//! The engine's own geometric model of a four-axis gonioreflectometer with its small errors, and what it
//! predicts for the alignment's observations (the centres of scans through the direct beam and through a
//! mirror's reflection).
//!
//! # Frame and parameters
//! The lab frame and the axis conventions are crates/instrument/src/lib.rs's ("The reference geometry"). The
//! lab's X axis is *defined* as the sample stage's rotation axis at zero tilt: a rotation of the whole instrument
//! about the arms' axis is not a parameter (nothing on the instrument can see it). The parameters, all small:
//! - `beam_deg` (b): the beam's direction error in the arms' plane: the beam travels along `-s'`, `s'` at arm
//!   angle `L + b` (L the light arm's nominal angle). It is the light arm's zero and the beam's pointing off the
//!   arm's axis together: only their sum acts, and only it can be observed.
//! - `beam_lateral_mm` (h), `beam_vertical_mm` (v): where the beam's line passes the arms' axis C: `h` across
//!   the beam in the arms' plane (towards increasing arm angle), `v` above the arms' plane.
//! - `beam_elevation_deg` (e): the direction towards the source is raised by `e` above the arms' plane.
//! - `detector_zero_deg`, `tilt_zero_deg`: the true angle is the nominal one plus this.
//! - `sample_tilt_x_deg`, `sample_tilt_y_deg`: the reflecting surface's normal tipped from the stage's rotation
//!   axis towards the stage's x' and y' (after rotation; at the nominal rotation angle, so a rotation zero error
//!   turns this vector and is absorbed in it: an isotropic surface cannot tell them apart).
//! - `eccentricity_x_mm`, `eccentricity_y_mm`: where the arms' axis C crosses the horizontal plane through the
//!   sample centre O (where the stage's axes meet the surface).
//! - `light_encoder_sin_deg`, `light_encoder_cos_deg` and the detector's: each arm's once-per-revolution
//!   encoder error (an off-centre disc), the true angle being the nominal one plus `s sin(a) + c cos(a)` (a the
//!   nominal angle), i.e. an amplitude `hypot(s, c)` at the phase `atan2(c, s)`.
//!
//! # Observations
//! - Direct beam (no sample): the detector arm's nominal angle at the centre of a scan through the beam, the
//!   light arm at `L`: the angle at which the aperture centre `C + d o` lies on the beam's line (seen in the arms'
//!   plane), `d` the detector distance.
//! - Mirror, detector scan: the detector's nominal angle at the centre of the reflected beam: the beam's line
//!   meets the mirror plane (through O, normal n) at P, reflects to `m`; the centre is where the reflected ray
//!   crosses the detector's circle of radius d about C.
//! - Mirror, tilt scan: with the detector held, the nominal tilt at which the reflected ray crosses that circle
//!   at the arms' height.

use gonio_scheduler::kinematics::Pose;
use serde::{Deserialize, Serialize};

/// How many parameters the model has.
pub const N_PARAMS: usize = 14;

/// The parameters' names (as the report and the calibration file spell them) and units, in vector order.
pub const PARAM_NAMES: [(&str, &str); N_PARAMS] = [
    ("beam_deg", "deg"),
    ("beam_lateral_mm", "mm"),
    ("beam_elevation_deg", "deg"),
    ("beam_vertical_mm", "mm"),
    ("detector_zero_deg", "deg"),
    ("tilt_zero_deg", "deg"),
    ("sample_tilt_x_deg", "deg"),
    ("sample_tilt_y_deg", "deg"),
    ("eccentricity_x_mm", "mm"),
    ("eccentricity_y_mm", "mm"),
    ("light_encoder_sin_deg", "deg"),
    ("light_encoder_cos_deg", "deg"),
    ("detector_encoder_sin_deg", "deg"),
    ("detector_encoder_cos_deg", "deg"),
];

/// What an instrument with these errors is, as a parameter vector (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct GeometryParams {
    pub beam_deg: f64,
    pub beam_lateral_mm: f64,
    pub beam_elevation_deg: f64,
    pub beam_vertical_mm: f64,
    pub detector_zero_deg: f64,
    pub tilt_zero_deg: f64,
    pub sample_tilt_x_deg: f64,
    pub sample_tilt_y_deg: f64,
    pub eccentricity_x_mm: f64,
    pub eccentricity_y_mm: f64,
    pub light_encoder_sin_deg: f64,
    pub light_encoder_cos_deg: f64,
    pub detector_encoder_sin_deg: f64,
    pub detector_encoder_cos_deg: f64,
}

impl GeometryParams {
    pub fn to_vec(&self) -> [f64; N_PARAMS] {
        [
            self.beam_deg,
            self.beam_lateral_mm,
            self.beam_elevation_deg,
            self.beam_vertical_mm,
            self.detector_zero_deg,
            self.tilt_zero_deg,
            self.sample_tilt_x_deg,
            self.sample_tilt_y_deg,
            self.eccentricity_x_mm,
            self.eccentricity_y_mm,
            self.light_encoder_sin_deg,
            self.light_encoder_cos_deg,
            self.detector_encoder_sin_deg,
            self.detector_encoder_cos_deg,
        ]
    }

    pub fn from_slice(x: &[f64]) -> GeometryParams {
        let g = |k: usize| x.get(k).copied().unwrap_or(0.0);
        GeometryParams {
            beam_deg: g(0),
            beam_lateral_mm: g(1),
            beam_elevation_deg: g(2),
            beam_vertical_mm: g(3),
            detector_zero_deg: g(4),
            tilt_zero_deg: g(5),
            sample_tilt_x_deg: g(6),
            sample_tilt_y_deg: g(7),
            eccentricity_x_mm: g(8),
            eccentricity_y_mm: g(9),
            light_encoder_sin_deg: g(10),
            light_encoder_cos_deg: g(11),
            detector_encoder_sin_deg: g(12),
            detector_encoder_cos_deg: g(13),
        }
    }
}

/// One observation the model predicts: which scan, at which pose of the other axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Observation {
    /// The detector's nominal angle (deg) at the direct beam's centre, the light arm at `light_deg`.
    DirectBeam { light_deg: f64 },
    /// The detector's nominal angle (deg) at a mirror reflection's centre.
    MirrorDetector {
        light_deg: f64,
        tilt_deg: f64,
        rotation_deg: f64,
    },
    /// The tilt's nominal angle (deg) at a mirror reflection's centre, the detector held at `detector_deg`.
    MirrorTilt {
        light_deg: f64,
        detector_deg: f64,
        rotation_deg: f64,
    },
}

type V3 = [f64; 3];

fn dot(a: &V3, b: &V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn add(a: &V3, b: &V3, k: f64) -> V3 {
    [a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2]]
}

fn unit(v: V3) -> V3 {
    let n = dot(&v, &v).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// The instrument's fixed dimensions the model needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dimensions {
    /// From the arms' axis to the detector's aperture (mm).
    pub detector_distance_mm: f64,
}

/// The model with one parameter vector.
#[derive(Debug, Clone, Copy)]
pub struct Model {
    pub p: GeometryParams,
    pub dims: Dimensions,
}

/// The beam as a line: a point on it and the direction it travels (lab).
struct Line {
    point: V3,
    travel: V3,
}

impl Model {
    fn axis(&self) -> V3 {
        [self.p.eccentricity_x_mm, self.p.eccentricity_y_mm, 0.0]
    }

    /// The beam with the light arm at nominal `light_deg`.
    fn beam(&self, light_deg: f64) -> Line {
        let beta = (self.light_true_deg(light_deg) + self.p.beam_deg).to_radians();
        let e = self.p.beam_elevation_deg.to_radians();
        let (sb, cb) = beta.sin_cos();
        let towards_source = [cb * e.cos(), sb * e.cos(), e.sin()];
        let c = self.axis();
        let point = [
            c[0] - self.p.beam_lateral_mm * sb,
            c[1] + self.p.beam_lateral_mm * cb,
            self.p.beam_vertical_mm,
        ];
        Line {
            point,
            travel: [-towards_source[0], -towards_source[1], -towards_source[2]],
        }
    }

    /// The light arm's true angle (before the beam's own error) at nominal `light_deg`.
    fn light_true_deg(&self, light_deg: f64) -> f64 {
        let (s, c) = light_deg.to_radians().sin_cos();
        light_deg + self.p.light_encoder_sin_deg * s + self.p.light_encoder_cos_deg * c
    }

    /// The detector arm's true angle at nominal `detector_deg`.
    fn detector_true_deg(&self, detector_deg: f64) -> f64 {
        let (s, c) = detector_deg.to_radians().sin_cos();
        detector_deg
            + self.p.detector_zero_deg
            + self.p.detector_encoder_sin_deg * s
            + self.p.detector_encoder_cos_deg * c
    }

    /// The nominal detector angle at which the arm truly stands at `true_deg` (the inverse of
    /// [`Model::detector_true_deg`], by fixed-point iteration: the error is a few thousandths of a degree).
    fn detector_nominal_deg(&self, true_deg: f64) -> f64 {
        let mut nominal = true_deg - self.p.detector_zero_deg;
        for _ in 0..6 {
            nominal += true_deg - self.detector_true_deg(nominal);
        }
        wrap_deg(nominal)
    }

    /// The reflecting surface's normal (lab) at nominal tilt and rotation.
    pub fn normal(&self, tilt_deg: f64, rotation_deg: f64) -> V3 {
        let t = (tilt_deg + self.p.tilt_zero_deg).to_radians();
        let r = rotation_deg.to_radians();
        let (st, ct) = t.sin_cos();
        let (sr, cr) = r.sin_cos();
        let n0 = [ct, 0.0, st];
        let xs = [0.0, 1.0, 0.0];
        let ys = [-st, 0.0, ct];
        let xp = add(&[cr * xs[0], cr * xs[1], cr * xs[2]], &ys, sr);
        let yp = add(&[-sr * xs[0], -sr * xs[1], -sr * xs[2]], &ys, cr);
        let tx = self.p.sample_tilt_x_deg.to_radians().tan();
        let ty = self.p.sample_tilt_y_deg.to_radians().tan();
        unit(add(&add(&n0, &xp, tx), &yp, ty))
    }

    /// Where a ray from `from` along `dir` crosses the detector's circle about the arms' axis, in the arms'
    /// plane's projection: (true arm angle in degrees, the ray's height there in mm). None when it never does.
    fn crossing(&self, from: &V3, dir: &V3) -> Option<(f64, f64)> {
        let c = self.axis();
        let (px, py) = (from[0] - c[0], from[1] - c[1]);
        let (mx, my) = (dir[0], dir[1]);
        let a = mx * mx + my * my;
        let b = 2.0 * (px * mx + py * my);
        let cc = px * px + py * py - self.dims.detector_distance_mm.powi(2);
        let disc = b * b - 4.0 * a * cc;
        if a <= 0.0 || disc < 0.0 {
            return None;
        }
        let mu = (-b + disc.sqrt()) / (2.0 * a);
        if mu <= 0.0 {
            return None;
        }
        let q = add(from, dir, mu);
        Some(((q[1] - c[1]).atan2(q[0] - c[0]).to_degrees(), q[2]))
    }

    /// The mirror's reflection of the beam at nominal light, tilt and rotation: (point on the mirror, direction).
    fn reflected(&self, light_deg: f64, tilt_deg: f64, rotation_deg: f64) -> Option<(V3, V3)> {
        let beam = self.beam(light_deg);
        let n = self.normal(tilt_deg, rotation_deg);
        let un = dot(&beam.travel, &n);
        if un >= 0.0 {
            return None; // the beam meets the mirror's back
        }
        let lambda = -dot(&beam.point, &n) / un;
        let p = add(&beam.point, &beam.travel, lambda);
        let m = add(&beam.travel, &n, -2.0 * un);
        Some((p, m))
    }

    /// The model's value of one observation (module doc), or None where the geometry has no answer.
    pub fn predict(&self, obs: &Observation) -> Option<f64> {
        match *obs {
            Observation::DirectBeam { light_deg } => {
                let beta = self.light_true_deg(light_deg) + self.p.beam_deg;
                let h = self.p.beam_lateral_mm / self.dims.detector_distance_mm;
                if h.abs() >= 1.0 {
                    return None;
                }
                let true_deg = wrap_deg(beta + 180.0 - h.asin().to_degrees());
                Some(self.detector_nominal_deg(true_deg))
            }
            Observation::MirrorDetector {
                light_deg,
                tilt_deg,
                rotation_deg,
            } => {
                let (p, m) = self.reflected(light_deg, tilt_deg, rotation_deg)?;
                let (true_deg, _) = self.crossing(&p, &m)?;
                Some(self.detector_nominal_deg(true_deg))
            }
            // The detector stands at the reflection's centre (`detector_deg`, the detector scan's result), so the
            // ray's height is taken where it crosses the detector's circle, whatever the angle recorded.
            Observation::MirrorTilt {
                light_deg,
                detector_deg: _,
                rotation_deg,
            } => {
                // Secant on the tilt: the ray's height at the detector, 0 at the centre. Starts where the
                // nominal geometry puts it (0) and moves by hundredths of a degree.
                let height = |t: f64| -> Option<f64> {
                    let (p, m) = self.reflected(light_deg, t, rotation_deg)?;
                    self.crossing(&p, &m).map(|(_, z)| z)
                };
                let (mut t0, mut t1) = (0.0, 0.01);
                let (mut z0, mut z1) = (height(t0)?, height(t1)?);
                for _ in 0..30 {
                    if z1 == z0 {
                        break;
                    }
                    let t2 = t1 - z1 * (t1 - t0) / (z1 - z0);
                    (t0, z0) = (t1, z1);
                    t1 = t2;
                    z1 = height(t1)?;
                    if (t1 - t0).abs() < 1e-12 {
                        break;
                    }
                }
                (z1.abs() < 1e-6).then_some(t1)
            }
        }
    }

    /// The true sample-frame directions (towards the source, towards the detector's aperture centre from the
    /// beam's spot) of a nominal pose on a surface through O with this model's normal: what a campaign point
    /// really measures. The surface's own x axis is taken as the stage's (a rotation zero is not observable).
    pub fn directions(&self, pose: &Pose) -> Option<(V3, V3)> {
        let beam = self.beam(pose.light_deg);
        let n = self.normal(pose.tilt_deg, pose.rotation_deg);
        let un = dot(&beam.travel, &n);
        if un == 0.0 {
            return None;
        }
        let spot = add(&beam.point, &beam.travel, -dot(&beam.point, &n) / un);
        let c = self.axis();
        let d = self.detector_true_deg(pose.detector_deg).to_radians();
        let aperture = [
            c[0] + self.dims.detector_distance_mm * d.cos(),
            c[1] + self.dims.detector_distance_mm * d.sin(),
            0.0,
        ];
        let wo_lab = unit(add(&aperture, &spot, -1.0));
        let wi_lab = [-beam.travel[0], -beam.travel[1], -beam.travel[2]];
        // The surface frame: the stage's x' made perpendicular to the tipped normal.
        let t = (pose.tilt_deg + self.p.tilt_zero_deg).to_radians();
        let r = pose.rotation_deg.to_radians();
        let (st, ct) = t.sin_cos();
        let (sr, cr) = r.sin_cos();
        let xp = [-sr * st, cr, sr * ct];
        let x = unit(add(&xp, &n, -dot(&xp, &n)));
        let y = [
            n[1] * x[2] - n[2] * x[1],
            n[2] * x[0] - n[0] * x[2],
            n[0] * x[1] - n[1] * x[0],
        ];
        let to_sample = |v: &V3| [dot(v, &x), dot(v, &y), dot(v, &n)];
        Some((to_sample(&wi_lab), to_sample(&wo_lab)))
    }
}

/// An angle wrapped into (-180, 180].
pub fn wrap_deg(a: f64) -> f64 {
    let mut w = (a + 180.0).rem_euclid(360.0) - 180.0;
    if w <= -180.0 {
        w += 360.0;
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(p: GeometryParams) -> Model {
        Model {
            p,
            dims: Dimensions {
                detector_distance_mm: 250.0,
            },
        }
    }

    #[test]
    fn a_perfect_instrument_predicts_the_nominal_positions() {
        let m = model(GeometryParams::default());
        let direct = m.predict(&Observation::DirectBeam { light_deg: -90.0 }).unwrap();
        assert!((direct - 90.0).abs() < 1e-12, "{direct}");
        let det = m
            .predict(&Observation::MirrorDetector {
                light_deg: 30.0,
                tilt_deg: 0.0,
                rotation_deg: 45.0,
            })
            .unwrap();
        assert!((det + 30.0).abs() < 1e-9, "{det}");
        let tilt = m
            .predict(&Observation::MirrorTilt {
                light_deg: 30.0,
                detector_deg: -30.0,
                rotation_deg: 45.0,
            })
            .unwrap();
        assert!(tilt.abs() < 1e-9, "{tilt}");
    }

    #[test]
    fn each_error_moves_the_observations_as_the_geometry_says() {
        // A detector zero error moves every detector centre by minus itself.
        let m = model(GeometryParams {
            detector_zero_deg: 0.02,
            ..Default::default()
        });
        let direct = m.predict(&Observation::DirectBeam { light_deg: -90.0 }).unwrap();
        assert!((direct - (90.0 - 0.02)).abs() < 1e-12);
        // A tilt zero error of +0.03 deg is undone by a nominal tilt of -0.03 deg.
        let m = model(GeometryParams {
            tilt_zero_deg: 0.03,
            ..Default::default()
        });
        let tilt = m
            .predict(&Observation::MirrorTilt {
                light_deg: 30.0,
                detector_deg: -30.0,
                rotation_deg: 0.0,
            })
            .unwrap();
        assert!((tilt + 0.03).abs() < 1e-9, "{tilt}");
        // The normal tipped by 0.05 deg towards the stage's x' (lab +Y at rotation 0) moves the mirror direction
        // by twice that.
        let m = model(GeometryParams {
            sample_tilt_x_deg: 0.05,
            ..Default::default()
        });
        let det = m
            .predict(&Observation::MirrorDetector {
                light_deg: 30.0,
                tilt_deg: 0.0,
                rotation_deg: 0.0,
            })
            .unwrap();
        assert!((det - (-30.0 + 0.1)).abs() < 1e-6, "{det}");
        // At rotation 90 the same tilt points up (x' = lab Z): the tilt scan sees it, the detector does not.
        let tilt = m
            .predict(&Observation::MirrorTilt {
                light_deg: 30.0,
                detector_deg: -30.0,
                rotation_deg: 90.0,
            })
            .unwrap();
        assert!((tilt + 0.05).abs() < 1e-6, "{tilt}");
    }

    #[test]
    fn an_eccentric_axis_moves_the_mirror_peak_with_incidence() {
        // The mirror 0.1 mm behind the arms' axis (C at x = +0.1): the reflection is displaced sideways by
        // 2 c sin(theta), seen from 250 mm as that over d.
        let m = model(GeometryParams {
            eccentricity_x_mm: 0.1,
            ..Default::default()
        });
        for theta in [15.0f64, 45.0] {
            let det = m
                .predict(&Observation::MirrorDetector {
                    light_deg: theta,
                    tilt_deg: 0.0,
                    rotation_deg: 0.0,
                })
                .unwrap();
            let shift = (det + theta).to_radians() * 250.0;
            let expect = 2.0 * 0.1 * theta.to_radians().sin();
            assert!(
                (shift.abs() - expect).abs() < 2e-4,
                "{theta}: {shift} vs {expect}"
            );
        }
    }
}
