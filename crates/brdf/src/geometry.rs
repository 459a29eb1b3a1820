//! Directions in the sample frame, and the angle parameterisations a BRDF is written in.
//!
//! Frame: z is the surface normal, x and y lie in the surface. `wi` points from the sample towards the source,
//! `wo` towards the detector. theta is measured from the normal, phi around it from +x towards +y.
//! Angles are radians everywhere in this module; degrees exist only in the `*_deg` constructors meant for the
//! edges of the program (configuration files, command line).
//!
//! Numerical care (see shared/reference/radiometry-and-materials.md):
//! - `sin^2(theta)` is `x^2 + y^2`, never `1 - z^2`, so that it keeps its digits near the pole;
//! - at the pole phi is undefined and is defined as 0 (cos phi = 1, sin phi = 0);
//! - the angle between two unit vectors uses `2 asin(|a - b| / 2)`, never `acos(dot)`.

use std::f64::consts::{FRAC_PI_2, PI};

/// A unit vector in the sample frame. Construct it through one of the constructors, which normalise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Direction {
    x: f64,
    y: f64,
    z: f64,
}

impl Direction {
    /// The surface normal, +z.
    pub const NORMAL: Direction = Direction {
        x: 0.0,
        y: 0.0,
        z: 1.0,
    };

    /// A direction from Cartesian components; normalised. Returns `None` for a zero or non-finite vector.
    pub fn new(x: f64, y: f64, z: f64) -> Option<Direction> {
        let norm = x.hypot(y).hypot(z);
        if !norm.is_finite() || norm == 0.0 {
            return None;
        }
        Some(Direction {
            x: x / norm,
            y: y / norm,
            z: z / norm,
        })
    }

    /// A direction from spherical angles in radians. At theta = 0 the result is exactly the normal
    /// whatever phi is.
    pub fn from_spherical(theta: f64, phi: f64) -> Direction {
        let (sin_t, cos_t) = theta.sin_cos();
        let (sin_p, cos_p) = phi.sin_cos();
        Direction {
            x: sin_t * cos_p,
            y: sin_t * sin_p,
            z: cos_t,
        }
    }

    /// A direction from spherical angles in degrees, exact at multiples of 90 degrees: 90 degrees lies
    /// exactly on the horizon (z = 0), not 6e-17 above it as `cos(to_radians(90))` would put it.
    pub fn from_spherical_deg(theta_deg: f64, phi_deg: f64) -> Direction {
        let (sin_t, cos_t) = sin_cos_deg(theta_deg);
        let (sin_p, cos_p) = sin_cos_deg(phi_deg);
        Direction {
            x: sin_t * cos_p,
            y: sin_t * sin_p,
            z: cos_t,
        }
    }

    pub fn x(&self) -> f64 {
        self.x
    }
    pub fn y(&self) -> f64 {
        self.y
    }
    pub fn z(&self) -> f64 {
        self.z
    }

    /// cos(theta): the component along the normal.
    pub fn cos_theta(&self) -> f64 {
        self.z
    }

    /// sin^2(theta) computed from the in-plane components (accurate near the pole).
    pub fn sin2_theta(&self) -> f64 {
        self.x * self.x + self.y * self.y
    }

    pub fn sin_theta(&self) -> f64 {
        self.x.hypot(self.y)
    }

    /// tan^2(theta); infinite on the horizon.
    pub fn tan2_theta(&self) -> f64 {
        self.sin2_theta() / (self.z * self.z)
    }

    /// (cos phi, sin phi), with phi := 0 at the pole.
    pub fn cos_sin_phi(&self) -> (f64, f64) {
        let s = self.sin_theta();
        if s == 0.0 {
            (1.0, 0.0)
        } else {
            ((self.x / s).clamp(-1.0, 1.0), (self.y / s).clamp(-1.0, 1.0))
        }
    }

    /// Polar angle in [0, pi], exact at the pole and on the horizon.
    pub fn theta(&self) -> f64 {
        self.sin_theta().atan2(self.z)
    }

    /// Azimuth in (-pi, pi]; 0 at the pole.
    pub fn phi(&self) -> f64 {
        if self.x == 0.0 && self.y == 0.0 {
            0.0
        } else {
            self.y.atan2(self.x)
        }
    }

    /// (theta, phi) in radians.
    pub fn to_spherical(&self) -> (f64, f64) {
        (self.theta(), self.phi())
    }

    /// (theta, phi) in degrees, for output at the edges of the program.
    pub fn to_spherical_deg(&self) -> (f64, f64) {
        (self.theta().to_degrees(), self.phi().to_degrees())
    }

    /// True when the direction is strictly above the surface (cos theta > 0).
    pub fn is_above_horizon(&self) -> bool {
        self.z > 0.0
    }

    pub fn dot(&self, other: &Direction) -> f64 {
        self.x * other.x + self.y * other.y + self.z * other.z
    }

    pub fn cross(&self, other: &Direction) -> [f64; 3] {
        [
            self.y * other.z - self.z * other.y,
            self.z * other.x - self.x * other.z,
            self.x * other.y - self.y * other.x,
        ]
    }

    pub fn neg(&self) -> Direction {
        Direction {
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }

    /// The mirror image about the normal: the direction of ideal specular reflection of `self`.
    pub fn reflect_about_normal(&self) -> Direction {
        Direction {
            x: -self.x,
            y: -self.y,
            z: self.z,
        }
    }

    /// Reflection of `self` about an arbitrary unit vector `m`: `2 (self . m) m - self`.
    pub fn reflect_about(&self, m: &Direction) -> Direction {
        let d = 2.0 * self.dot(m);
        // Renormalise: the result is unit up to rounding; keeping it exactly unit keeps later asin/acos safe.
        Direction::new(d * m.x - self.x, d * m.y - self.y, d * m.z - self.z).unwrap_or(*self)
    }

    /// Angle between two unit vectors in [0, pi], accurate for nearly equal and nearly opposite vectors.
    pub fn angle_to(&self, other: &Direction) -> f64 {
        if self.dot(other) >= 0.0 {
            let d = (self.x - other.x).hypot(self.y - other.y).hypot(self.z - other.z);
            2.0 * (d / 2.0).min(1.0).asin()
        } else {
            let s = (self.x + other.x).hypot(self.y + other.y).hypot(self.z + other.z);
            PI - 2.0 * (s / 2.0).min(1.0).asin()
        }
    }

    /// Rotation about the z axis by `angle` radians.
    pub fn rotate_z(&self, angle: f64) -> Direction {
        let (s, c) = angle.sin_cos();
        Direction {
            x: c * self.x - s * self.y,
            y: s * self.x + c * self.y,
            z: self.z,
        }
    }

    /// Rotation about the y axis by `angle` radians.
    pub fn rotate_y(&self, angle: f64) -> Direction {
        let (s, c) = angle.sin_cos();
        Direction {
            x: c * self.x + s * self.z,
            y: self.y,
            z: -s * self.x + c * self.z,
        }
    }
}

/// The normalised half vector `normalize(wi + wo)`. `None` when wi and wo are opposite.
pub fn half_vector(wi: &Direction, wo: &Direction) -> Option<Direction> {
    Direction::new(wi.x + wo.x, wi.y + wo.y, wi.z + wo.z)
}

/// sin and cos of an angle in degrees, exact at multiples of 90 degrees.
pub fn sin_cos_deg(deg: f64) -> (f64, f64) {
    // rem_euclid without its fmod for the usual angles: for |deg| < 360, deg % 360 is deg itself (exact), so
    // this is the same computation, bit for bit, at a fraction of the cost (`gonio brdf eval` calls this four
    // times per line).
    let r = if deg.abs() < 360.0 {
        if deg < 0.0 { deg + 360.0 } else { deg }
    } else {
        deg.rem_euclid(360.0)
    };
    if r == 0.0 {
        (0.0, 1.0)
    } else if r == 90.0 {
        (1.0, 0.0)
    } else if r == 180.0 {
        (0.0, -1.0)
    } else if r == 270.0 {
        (-1.0, 0.0)
    } else {
        deg.to_radians().sin_cos()
    }
}

/// Rusinkiewicz half/difference angles, all radians: theta_h, phi_h of the half vector, and theta_d, phi_d of
/// `wi` expressed in the frame where the half vector is the pole.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HalfDiff {
    pub theta_h: f64,
    pub phi_h: f64,
    pub theta_d: f64,
    pub phi_d: f64,
}

impl HalfDiff {
    /// From a pair of directions. `None` when wi and wo are opposite (the half vector is undefined).
    pub fn from_directions(wi: &Direction, wo: &Direction) -> Option<HalfDiff> {
        let h = half_vector(wi, wo)?;
        let (theta_h, phi_h) = h.to_spherical();
        // The difference vector: wi rotated by -phi_h about z, then by -theta_h about y.
        let d = wi.rotate_z(-phi_h).rotate_y(-theta_h);
        let (theta_d, phi_d) = d.to_spherical();
        Some(HalfDiff {
            theta_h,
            phi_h,
            theta_d,
            phi_d,
        })
    }

    /// Back to (wi, wo): the inverse of [`HalfDiff::from_directions`].
    pub fn to_directions(&self) -> (Direction, Direction) {
        let d = Direction::from_spherical(self.theta_d, self.phi_d);
        let wi = d.rotate_y(self.theta_h).rotate_z(self.phi_h);
        let h = Direction::from_spherical(self.theta_h, self.phi_h);
        let wo = wi.reflect_about(&h);
        (wi, wo)
    }
}

/// The isotropic reduction: an isotropic BRDF depends only on (theta_i, theta_o, |phi_o - phi_i|).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IsotropicAngles {
    pub theta_i: f64,
    pub theta_o: f64,
    /// |phi_o - phi_i| folded into [0, pi].
    pub delta_phi: f64,
}

impl IsotropicAngles {
    pub fn from_directions(wi: &Direction, wo: &Direction) -> IsotropicAngles {
        let delta = (wo.phi() - wi.phi()).rem_euclid(2.0 * PI);
        let delta_phi = if delta > PI { 2.0 * PI - delta } else { delta };
        IsotropicAngles {
            theta_i: wi.theta(),
            theta_o: wo.theta(),
            delta_phi,
        }
    }

    /// A canonical pair of directions with these angles: wi in the x-z plane at phi = 0.
    pub fn to_directions(&self) -> (Direction, Direction) {
        (
            Direction::from_spherical(self.theta_i, 0.0),
            Direction::from_spherical(self.theta_o, self.delta_phi),
        )
    }

    /// The reciprocity swap: (theta_i, theta_o, dphi) -> (theta_o, theta_i, dphi).
    pub fn swapped(&self) -> IsotropicAngles {
        IsotropicAngles {
            theta_i: self.theta_o,
            theta_o: self.theta_i,
            delta_phi: self.delta_phi,
        }
    }
}

/// The reciprocity swap of a direction pair: measuring f(wi, wo) also gives f(wo, wi).
pub fn reciprocal(wi: &Direction, wo: &Direction) -> (Direction, Direction) {
    (*wo, *wi)
}

/// Largest angle considered "the horizon" when folding rounding: anything at or below is not lit.
pub const HORIZON: f64 = FRAC_PI_2;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn pole_is_exact_and_phi_is_zero() {
        let d = Direction::from_spherical(0.0, 1.234);
        assert_eq!(d, Direction::NORMAL);
        assert_eq!(d.phi(), 0.0);
        assert_eq!(d.cos_sin_phi(), (1.0, 0.0));
        assert_eq!(d.theta(), 0.0);
    }

    #[test]
    fn horizon_in_degrees_is_exact() {
        let d = Direction::from_spherical_deg(90.0, 30.0);
        assert_eq!(d.z(), 0.0);
        assert_eq!(d.theta(), FRAC_PI_2);
        assert!(!d.is_above_horizon());
    }

    #[test]
    fn angle_between_nearly_equal_vectors_keeps_digits() {
        let a = Direction::from_spherical(0.3, 0.1);
        let b = Direction::from_spherical(0.3 + 1e-9, 0.1);
        let angle = a.angle_to(&b);
        assert!((angle - 1e-9).abs() < 1e-15, "{angle}");
        // acos(dot) would have returned 0 or ~2e-8 here.
        let c = Direction::from_spherical(0.3, 0.1).neg();
        assert!((a.angle_to(&c) - PI).abs() < 1e-15);
    }

    #[test]
    fn half_diff_of_specular_pair_has_zero_theta_h() {
        let wi = Direction::from_spherical(0.7, 0.2);
        let wo = wi.reflect_about_normal();
        let hd = HalfDiff::from_directions(&wi, &wo).expect("half vector");
        assert!(hd.theta_h.abs() < 1e-15);
        assert!((hd.theta_d - 0.7).abs() < 1e-14);
    }

    fn direction_strategy() -> impl Strategy<Value = Direction> {
        prop_oneof![
            // Generic directions on the upper hemisphere.
            (0.0..FRAC_PI_2, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(t, p)),
            // Near the pole and near the horizon.
            (0.0..1e-9f64, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(t, p)),
            (0.0..1e-9f64, -PI..PI).prop_map(|(t, p)| Direction::from_spherical(FRAC_PI_2 - t, p)),
            Just(Direction::NORMAL),
        ]
    }

    proptest! {
        #[test]
        fn spherical_round_trip(theta in 1e-6..(FRAC_PI_2 - 1e-6), phi in (-PI + 1e-9)..(PI - 1e-9)) {
            let d = Direction::from_spherical(theta, phi);
            let (t, p) = d.to_spherical();
            prop_assert!((t - theta).abs() < 1e-13);
            prop_assert!((p - phi).abs() < 1e-12);
        }

        #[test]
        fn half_diff_round_trip(wi in direction_strategy(), wo in direction_strategy()) {
            if let Some(hd) = HalfDiff::from_directions(&wi, &wo) {
                let (wi2, wo2) = hd.to_directions();
                prop_assert!(wi.angle_to(&wi2) < 1e-9, "wi {:?} -> {:?}", wi, wi2);
                prop_assert!(wo.angle_to(&wo2) < 1e-9, "wo {:?} -> {:?}", wo, wo2);
            }
        }

        #[test]
        fn isotropic_reduction_is_invariant_under_rotation(wi in direction_strategy(), wo in direction_strategy(),
                                                             rot in -PI..PI) {
            let a = IsotropicAngles::from_directions(&wi, &wo);
            let b = IsotropicAngles::from_directions(&wi.rotate_z(rot), &wo.rotate_z(rot));
            prop_assert!((a.theta_i - b.theta_i).abs() < 1e-12);
            prop_assert!((a.theta_o - b.theta_o).abs() < 1e-12);
            // delta_phi is ill-conditioned when either direction is at the pole; there it does not matter.
            if wi.sin_theta() > 1e-6 && wo.sin_theta() > 1e-6 {
                prop_assert!((a.delta_phi - b.delta_phi).abs() < 1e-9);
            }
        }

        #[test]
        fn angle_to_is_symmetric_and_bounded(a in direction_strategy(), b in direction_strategy()) {
            let ab = a.angle_to(&b);
            prop_assert!((0.0..=PI).contains(&ab));
            prop_assert_eq!(ab, b.angle_to(&a));
        }
    }
}
