//! Forward and inverse kinematics: sample-frame geometry <-> physical axis angles.
//!
//! Implemented from the reference geometry documented in `gonio_instrument` (module doc). Summary of the maths:
//! at tilt `t` and rotation `r` the sample axes, in lab coordinates, are
//! `n = (cos t, 0, sin t)`, `ex = (0, 1, 0)`, `ey = (-sin t, 0, cos t)`, `x' = cos r ex + sin r ey`,
//! `y' = -sin r ex + cos r ey`; an arm at angle `a` points along `(cos a, sin a, 0)`.
//!
//! Inverse: both arms lie in the lab's horizontal plane, so the lab vertical `Z` is perpendicular to `wi` and
//! `wo`. Seen from the sample, `Z = (cos t sin r, cos t cos r, sin t)`; hence `Z = ±normalize(wi x wo)` gives
//! the tilt `t = asin(Z.z)` and rotation `r = atan2(Z.x, Z.y)`. The lab `X` and `Y` axes seen from the sample are
//! `X = (-sin t sin r, -sin t cos r, cos t)` and `Y = (cos r, -sin r, 0)`, and each arm angle is
//! `atan2(w . Y, w . X)`.
//!
//! Several axis solutions exist for one geometry:
//! - the sign of `Z` (`(t, r) -> (-t, r + 180)`): this negates both arm angles, so it is the mirror image of the
//!   arrangement and swaps which arm is at the larger angle;
//! - the tilt branch `(t, r) -> (180 - t, r + 180)`, which adds 180 degrees to both arms;
//! - each angle modulo 360 degrees, where an axis travels more than a turn.
//!
//! [`Kinematics::solutions`] lists every one that lies within the axis limits; the planner picks the valid one
//! that is cheapest to reach from the current pose (see `crate::schedule`).
//!
//! Singular poses, and what is done there:
//! - `wi` parallel to `wo` (retro-reflection, always forbidden by `retro_block_deg` but still solvable): the arm
//!   plane may be any plane containing `wi`; the one nearest the hint pose's arm plane is used;
//! - `Z` along the sample normal (both directions on the horizon): the rotation is undefined; the hint's
//!   rotation is kept;
//! - a direction at the pole (normal incidence or exitance): its phi is undefined and [`Geometry`] reports it as
//!   0 (the `gonio_brdf::geometry` convention). Round trips compare directions, so they hold there too.
//!
//! The in-plane geometry has no tilt axis: `Z` must be perpendicular to the normal, i.e. `wi`, `wo` and the
//! normal must be coplanar; otherwise the request is rejected with [`KinematicsError::OutOfPlane`].

use gonio_brdf::geometry::{Direction, sin_cos_deg};
use gonio_instrument::{AxisRole, GeometryKind, Instrument};

/// A pair of directions in the sample frame, in degrees (the edge representation of plans and CSV files).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
}

impl Geometry {
    pub fn new(theta_i_deg: f64, phi_i_deg: f64, theta_o_deg: f64, phi_o_deg: f64) -> Geometry {
        Geometry {
            theta_i_deg,
            phi_i_deg,
            theta_o_deg,
            phi_o_deg,
        }
    }

    /// (wi, wo), exact at multiples of 90 degrees.
    pub fn directions(&self) -> (Direction, Direction) {
        (
            Direction::from_spherical_deg(self.theta_i_deg, self.phi_i_deg),
            Direction::from_spherical_deg(self.theta_o_deg, self.phi_o_deg),
        )
    }

    /// From directions; phi in (-180, 180], and 0 at the pole.
    pub fn from_directions(wi: &Direction, wo: &Direction) -> Geometry {
        let (ti, pi) = wi.to_spherical_deg();
        let (to, po) = wo.to_spherical_deg();
        Geometry {
            theta_i_deg: ti,
            phi_i_deg: pi,
            theta_o_deg: to,
            phi_o_deg: po,
        }
    }

    /// The Helmholtz reciprocal: source and detector exchanged.
    pub fn reciprocal(&self) -> Geometry {
        Geometry {
            theta_i_deg: self.theta_o_deg,
            phi_i_deg: self.phi_o_deg,
            theta_o_deg: self.theta_i_deg,
            phi_o_deg: self.phi_i_deg,
        }
    }

    /// |phi_o - phi_i| folded into [0, 180] degrees (0 when either direction is at the pole).
    pub fn delta_phi_deg(&self) -> f64 {
        if self.theta_i_deg == 0.0 || self.theta_o_deg == 0.0 {
            return 0.0;
        }
        let d = (self.phi_o_deg - self.phi_i_deg).rem_euclid(360.0);
        if d > 180.0 { 360.0 - d } else { d }
    }

    /// Largest angle between the directions of two geometries (degrees): how far apart they are physically.
    pub fn max_direction_angle_deg(&self, other: &Geometry) -> f64 {
        let (a_i, a_o) = self.directions();
        let (b_i, b_o) = other.directions();
        a_i.angle_to(&b_i).max(a_o.angle_to(&b_o)).to_degrees()
    }
}

/// Physical angles (degrees) of the four axis roles. `tilt_deg` is 0 on an in-plane instrument.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub light_deg: f64,
    pub detector_deg: f64,
    pub tilt_deg: f64,
    pub rotation_deg: f64,
}

/// The roles in the order [`Pose::get`] and the time model index them.
pub const ROLES: [AxisRole; 4] = [
    AxisRole::LightArm,
    AxisRole::DetectorArm,
    AxisRole::SampleTilt,
    AxisRole::SampleRotation,
];

impl Pose {
    pub fn new(light_deg: f64, detector_deg: f64, tilt_deg: f64, rotation_deg: f64) -> Pose {
        Pose {
            light_deg,
            detector_deg,
            tilt_deg,
            rotation_deg,
        }
    }

    pub fn get(&self, role: AxisRole) -> f64 {
        match role {
            AxisRole::LightArm => self.light_deg,
            AxisRole::DetectorArm => self.detector_deg,
            AxisRole::SampleTilt => self.tilt_deg,
            AxisRole::SampleRotation => self.rotation_deg,
        }
    }

    pub fn set(&mut self, role: AxisRole, value_deg: f64) {
        match role {
            AxisRole::LightArm => self.light_deg = value_deg,
            AxisRole::DetectorArm => self.detector_deg = value_deg,
            AxisRole::SampleTilt => self.tilt_deg = value_deg,
            AxisRole::SampleRotation => self.rotation_deg = value_deg,
        }
    }

    /// Angular distance between the arms (degrees, in [0, 180]): the angle between source and detector.
    pub fn arm_separation_deg(&self) -> f64 {
        circular_distance_deg(self.light_deg - self.detector_deg)
    }
}

/// |x| folded onto the circle: the distance from x to the nearest multiple of 360 degrees.
pub fn circular_distance_deg(x: f64) -> f64 {
    let r = x.rem_euclid(360.0);
    r.min(360.0 - r)
}

/// Why no axis solution exists.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KinematicsError {
    /// The in-plane instrument cannot tilt the sample.
    #[error(
        "the in-plane geometry cannot reach this pair of directions: it lies {deviation_deg:.3} degrees out of \
         the plane through the normal"
    )]
    OutOfPlane { deviation_deg: f64 },
    /// Every solution puts some axis outside its limits.
    #[error("every axis solution puts an axis outside its limits (first: {axis} at {angle_deg:.3} degrees)")]
    AxisLimits { axis: String, angle_deg: f64 },
}

/// The limits of one role's axis, physical degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Range {
    min_deg: f64,
    max_deg: f64,
}

/// Solves between geometries and poses for one instrument.
#[derive(Debug, Clone)]
pub struct Kinematics {
    kind: GeometryKind,
    /// Limits per role, in [`ROLES`] order; `None` for the missing tilt of an in-plane instrument.
    ranges: [Option<Range>; 4],
    names: [String; 4],
}

/// Cross product of two directions, computed as `a x (b - a)` so that it keeps its digits when a ~ b.
fn cross(a: &Direction, b: &Direction) -> [f64; 3] {
    let d = [b.x() - a.x(), b.y() - a.y(), b.z() - a.z()];
    [
        a.y() * d[2] - a.z() * d[1],
        a.z() * d[0] - a.x() * d[2],
        a.x() * d[1] - a.y() * d[0],
    ]
}

fn norm(v: [f64; 3]) -> f64 {
    v[0].hypot(v[1]).hypot(v[2])
}

fn dot(a: [f64; 3], w: &Direction) -> f64 {
    a[0] * w.x() + a[1] * w.y() + a[2] * w.z()
}

/// Below this |wi x wo| (sine of the angle between them) the arm plane is taken as undetermined.
const PARALLEL_SIN: f64 = 1e-12;
/// In-plane requests may be out of the plane by this much (sine of the angle) from rounding alone.
const IN_PLANE_SIN: f64 = 1e-9;

impl Kinematics {
    pub fn new(instrument: &Instrument) -> Kinematics {
        let mut ranges = [None; 4];
        let mut names: [String; 4] = Default::default();
        for (k, role) in ROLES.iter().enumerate() {
            if let Some(axis) = instrument.axis(*role) {
                ranges[k] = Some(Range {
                    min_deg: axis.min_deg,
                    max_deg: axis.max_deg,
                });
                names[k] = axis.name.clone();
            }
        }
        Kinematics {
            kind: instrument.geometry,
            ranges,
            names,
        }
    }

    pub fn kind(&self) -> GeometryKind {
        self.kind
    }

    /// The sample-frame directions (wi, wo) the arms point along at this pose.
    pub fn forward(&self, pose: &Pose) -> (Direction, Direction) {
        let tilt = if self.kind == GeometryKind::InPlane {
            0.0
        } else {
            pose.tilt_deg
        };
        let (st, ct) = sin_cos_deg(tilt);
        let (sr, cr) = sin_cos_deg(pose.rotation_deg);
        // Lab X and Y axes in sample coordinates (see the module doc); lab Z does not enter: arms are horizontal.
        let lab_x = [-st * sr, -st * cr, ct];
        let lab_y = [cr, -sr, 0.0];
        let arm = |a_deg: f64| {
            let (sa, ca) = sin_cos_deg(a_deg);
            let v = [
                ca * lab_x[0] + sa * lab_y[0],
                ca * lab_x[1] + sa * lab_y[1],
                ca * lab_x[2] + sa * lab_y[2],
            ];
            // A unit vector by construction; `new` only renormalises rounding.
            Direction::new(v[0], v[1], v[2]).unwrap_or(Direction::NORMAL)
        };
        (arm(pose.light_deg), arm(pose.detector_deg))
    }

    pub fn forward_geometry(&self, pose: &Pose) -> Geometry {
        let (wi, wo) = self.forward(pose);
        Geometry::from_directions(&wi, &wo)
    }

    /// Lab vertical seen from the sample at the hint pose: used to resolve singular requests.
    fn hint_vertical(&self, hint: &Pose) -> [f64; 3] {
        let tilt = if self.kind == GeometryKind::InPlane {
            0.0
        } else {
            hint.tilt_deg
        };
        let (st, ct) = sin_cos_deg(tilt);
        let (sr, cr) = sin_cos_deg(hint.rotation_deg);
        [ct * sr, ct * cr, st]
    }

    /// The unit lab vertical seen from the sample (up to sign) for this pair of directions.
    fn vertical(&self, wi: &Direction, wo: &Direction, hint: &Pose) -> Result<[f64; 3], KinematicsError> {
        let c = cross(wi, wo);
        let n = norm(c);
        let mut z = if n > PARALLEL_SIN {
            [c[0] / n, c[1] / n, c[2] / n]
        } else {
            // Parallel directions: any plane through wi. Take the hint's vertical, made perpendicular to wi
            // (and, in-plane, to the normal too).
            let h = if self.kind == GeometryKind::InPlane {
                let h = self.hint_vertical(hint);
                [h[0], h[1], 0.0]
            } else {
                self.hint_vertical(hint)
            };
            // The component of h perpendicular to wi, as wi x (h x wi) rather than h - (h . wi) wi: when h is nearly
            // parallel to wi the subtraction cancels (1 - 1 = 0 where the true value is 1e-18), leaving an arm plane
            // that misses wi by up to its elevation (tests/it/stress.rs: wi 1e-9 rad above the horizon, forward
            // kinematics 1e-9 rad off). The double cross product has no cancellation.
            let w = [wi.x(), wi.y(), wi.z()];
            let c = [
                h[1] * w[2] - h[2] * w[1],
                h[2] * w[0] - h[0] * w[2],
                h[0] * w[1] - h[1] * w[0],
            ];
            let mut p = [
                w[1] * c[2] - w[2] * c[1],
                w[2] * c[0] - w[0] * c[2],
                w[0] * c[1] - w[1] * c[0],
            ];
            if self.kind == GeometryKind::InPlane {
                // Perpendicular to both wi and the normal: wi x n, unless wi is the normal itself.
                let q = [wi.y(), -wi.x(), 0.0];
                if norm(q) > PARALLEL_SIN {
                    let s = if q[0] * h[0] + q[1] * h[1] >= 0.0 {
                        1.0
                    } else {
                        -1.0
                    };
                    p = [s * q[0], s * q[1], 0.0];
                } else {
                    p = h;
                }
            }
            if norm(p) <= PARALLEL_SIN {
                // The hint's vertical is along wi: any perpendicular will do.
                let e = if wi.x().abs() < 0.5 {
                    [1.0, 0.0, 0.0]
                } else {
                    [0.0, 1.0, 0.0]
                };
                let d = dot(e, wi);
                p = [e[0] - d * wi.x(), e[1] - d * wi.y(), e[2] - d * wi.z()];
            }
            let n = norm(p);
            [p[0] / n, p[1] / n, p[2] / n]
        };
        if self.kind == GeometryKind::InPlane {
            if z[2].abs() > IN_PLANE_SIN {
                return Err(KinematicsError::OutOfPlane {
                    deviation_deg: z[2].abs().min(1.0).asin().to_degrees(),
                });
            }
            let h = z[0].hypot(z[1]);
            z = [z[0] / h, z[1] / h, 0.0];
        }
        Ok(z)
    }

    /// The raw branches (light, detector, tilt, rotation) before limits and turns.
    fn branches(
        &self,
        wi: &Direction,
        wo: &Direction,
        hint: &Pose,
    ) -> Result<Vec<[f64; 4]>, KinematicsError> {
        let z = self.vertical(wi, wo, hint)?;
        let mut raw = Vec::with_capacity(4);
        for sign in [1.0, -1.0] {
            let zs = [sign * z[0], sign * z[1], sign * z[2]];
            let h = zs[0].hypot(zs[1]);
            let tilt = if self.kind == GeometryKind::InPlane {
                0.0
            } else {
                zs[2].atan2(h).to_degrees()
            };
            let rotation = if h <= PARALLEL_SIN {
                hint.rotation_deg
            } else {
                zs[0].atan2(zs[1]).to_degrees()
            };
            raw.push((tilt, rotation));
            if self.kind == GeometryKind::Reference {
                raw.push((180.0 - tilt, rotation + 180.0));
            }
        }
        Ok(raw
            .into_iter()
            .map(|(tilt, rotation)| {
                let (st, ct) = sin_cos_deg(tilt);
                let (sr, cr) = sin_cos_deg(rotation);
                let lab_x = [-st * sr, -st * cr, ct];
                let lab_y = [cr, -sr, 0.0];
                let light = dot(lab_y, wi).atan2(dot(lab_x, wi)).to_degrees();
                let detector = dot(lab_y, wo).atan2(dot(lab_x, wo)).to_degrees();
                [light, detector, tilt, rotation]
            })
            .collect())
    }

    /// All poses within the limits for the raw branches (each axis at every turn within its range).
    fn within_limits(&self, raw: &[[f64; 4]], out: &mut Vec<Pose>) -> Option<(usize, f64)> {
        let mut first_violation: Option<(usize, f64)> = None;
        'branch: for angles in raw {
            let mut choices: Vec<Vec<f64>> = Vec::with_capacity(4);
            for (k, angle) in angles.iter().enumerate() {
                match self.ranges[k] {
                    None => choices.push(vec![0.0]),
                    Some(range) => {
                        let c = turns_within(*angle, range);
                        if c.is_empty() {
                            first_violation.get_or_insert((k, *angle));
                            continue 'branch;
                        }
                        choices.push(c);
                    }
                }
            }
            for l in &choices[0] {
                for d in &choices[1] {
                    for t in &choices[2] {
                        for r in &choices[3] {
                            let pose = Pose::new(*l, *d, *t, *r);
                            if !out.contains(&pose) {
                                out.push(pose);
                            }
                        }
                    }
                }
            }
        }
        first_violation
    }

    /// Every axis solution for (wi, wo) within the axis limits. `hint` resolves singular requests (see the
    /// module doc); an axis that travels more than a turn yields one solution per turn within its limits.
    pub fn solutions(
        &self,
        wi: &Direction,
        wo: &Direction,
        hint: &Pose,
    ) -> Result<Vec<Pose>, KinematicsError> {
        let raw = self.branches(wi, wo, hint)?;
        let mut out = Vec::new();
        let violation = self.within_limits(&raw, &mut out);
        if out.is_empty() {
            let (k, angle) = violation.unwrap_or((0, f64::NAN));
            return Err(KinematicsError::AxisLimits {
                axis: self.names[k].clone(),
                angle_deg: angle,
            });
        }
        Ok(out)
    }

    /// Every solution for an isotropic request: only (theta_i, theta_o, delta_phi) matter, so the sample rotation
    /// is held at `rotation_deg` and phi_i follows from it. Returns each pose with the geometry it measures
    /// (the request turned about the normal).
    pub fn isotropic_solutions(
        &self,
        wi: &Direction,
        wo: &Direction,
        rotation_deg: f64,
        hint: &Pose,
    ) -> Result<Vec<(Pose, Geometry)>, KinematicsError> {
        if let Some(range) = self.ranges[3]
            && turns_within(rotation_deg, range).is_empty()
        {
            return Err(KinematicsError::AxisLimits {
                axis: self.names[3].clone(),
                angle_deg: rotation_deg,
            });
        }
        let raw = self.branches(wi, wo, hint)?;
        // Holding the rotation at `rotation_deg` instead of the branch's own rotation turns every sample-frame
        // azimuth by (branch rotation - rotation_deg) and changes nothing else.
        let held: Vec<[f64; 4]> = raw.iter().map(|a| [a[0], a[1], a[2], rotation_deg]).collect();
        let free = Kinematics {
            kind: self.kind,
            ranges: [self.ranges[0], self.ranges[1], self.ranges[2], None],
            names: self.names.clone(),
        };
        let mut out = Vec::new();
        for (angles, held_angles) in raw.iter().zip(&held) {
            let mut poses = Vec::new();
            free.within_limits(std::slice::from_ref(held_angles), &mut poses);
            let turn = (angles[3] - rotation_deg).to_radians();
            let geometry = Geometry::from_directions(&wi.rotate_z(turn), &wo.rotate_z(turn));
            for p in poses {
                out.push((Pose { rotation_deg, ..p }, geometry));
            }
        }
        if out.is_empty() {
            let mut dummy = Vec::new();
            let (k, angle) = free.within_limits(&held, &mut dummy).unwrap_or((0, f64::NAN));
            return Err(KinematicsError::AxisLimits {
                axis: self.names[k].clone(),
                angle_deg: angle,
            });
        }
        Ok(out)
    }
}

/// Every `angle + 360 k` within the range (a small tolerance absorbs rounding at the limits).
fn turns_within(angle: f64, range: Range) -> Vec<f64> {
    const EPS: f64 = 1e-9;
    let mut out = Vec::new();
    let k_min = ((range.min_deg - EPS - angle) / 360.0).ceil() as i64;
    let k_max = ((range.max_deg + EPS - angle) / 360.0).floor() as i64;
    if k_max - k_min > 4 {
        // A range of many turns: no real instrument; keep the turns nearest zero.
        let k0 = (-angle / 360.0).round() as i64;
        for k in (k0 - 2)..=(k0 + 2) {
            out.push((angle + 360.0 * k as f64).clamp(range.min_deg, range.max_deg));
        }
        return out;
    }
    for k in k_min..=k_max {
        out.push((angle + 360.0 * k as f64).clamp(range.min_deg, range.max_deg));
    }
    out
}
