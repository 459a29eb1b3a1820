//! Angular classes of a point, for summaries that must not hide the specular region behind the diffuse bulk:
//! near the specular direction the BRDF changes fastest and the aperture, pointing and stray light matter
//! most; at grazing angles the footprint and the cosine do. The classes (issue 29's accuracy table, the
//! report's uncertainty summary) are, in this order of precedence:
//! - `grazing`: theta_i or theta_o at or beyond [`GRAZING_THETA_DEG`];
//! - `specular`: within [`NEAR_SPECULAR_DEG`] of the mirror direction of the incidence;
//! - `near-specular`: within [`OFF_SPECULAR_DEG`];
//! - `off-specular`: beyond it.

use gonio_brdf::Direction;

use crate::iso::directions;
use crate::points::Point;

/// A theta (incidence or outgoing) at or beyond this is grazing, degrees.
pub const GRAZING_THETA_DEG: f64 = 70.0;
/// The specular class's radius about the mirror direction, degrees.
pub const NEAR_SPECULAR_DEG: f64 = 2.0;
/// The near-specular class's outer radius, degrees.
pub const OFF_SPECULAR_DEG: f64 = 15.0;

/// A point's angular class.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum AngularClass {
    Specular,
    NearSpecular,
    OffSpecular,
    Grazing,
}

impl AngularClass {
    /// Every class, in the order summaries list them.
    pub const ALL: [AngularClass; 4] = [
        AngularClass::Specular,
        AngularClass::NearSpecular,
        AngularClass::OffSpecular,
        AngularClass::Grazing,
    ];

    /// The class's name in tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            AngularClass::Specular => "specular",
            AngularClass::NearSpecular => "near-specular",
            AngularClass::OffSpecular => "off-specular",
            AngularClass::Grazing => "grazing",
        }
    }

    /// What the class holds, for a reader.
    pub fn description(self) -> String {
        match self {
            AngularClass::Specular => format!("within {NEAR_SPECULAR_DEG} deg of specular"),
            AngularClass::NearSpecular => {
                format!("{NEAR_SPECULAR_DEG} to {OFF_SPECULAR_DEG} deg from specular")
            }
            AngularClass::OffSpecular => format!("beyond {OFF_SPECULAR_DEG} deg from specular"),
            AngularClass::Grazing => format!("theta_i or theta_o >= {GRAZING_THETA_DEG} deg"),
        }
    }

    /// The class of a point's nominal geometry.
    pub fn of(p: &Point) -> AngularClass {
        AngularClass::of_geometry(p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg)
    }

    /// The class of a geometry (sample-frame angles in degrees).
    pub fn of_geometry(theta_i_deg: f64, phi_i_deg: f64, theta_o_deg: f64, phi_o_deg: f64) -> AngularClass {
        if theta_i_deg.abs() >= GRAZING_THETA_DEG || theta_o_deg.abs() >= GRAZING_THETA_DEG {
            return AngularClass::Grazing;
        }
        let wi = Direction::from_spherical_deg(theta_i_deg, phi_i_deg);
        let wo = Direction::from_spherical_deg(theta_o_deg, phi_o_deg);
        let from_specular = wo.angle_to(&wi.reflect_about_normal()).to_degrees();
        if from_specular <= NEAR_SPECULAR_DEG {
            AngularClass::Specular
        } else if from_specular <= OFF_SPECULAR_DEG {
            AngularClass::NearSpecular
        } else {
            AngularClass::OffSpecular
        }
    }
}

/// The angle between the outgoing direction and the incidence's mirror direction, degrees.
pub fn specular_offset_deg(p: &Point) -> f64 {
    let (wi, wo) = directions(p);
    wo.angle_to(&wi.reflect_about_normal()).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(theta_i: f64, phi_i: f64, theta_o: f64, phi_o: f64) -> Point {
        Point::at(550.0, [theta_i, phi_i, theta_o, phi_o], 0.1)
    }

    #[test]
    fn classes_follow_the_distance_to_the_mirror_direction() {
        // The mirror direction of (30, 0) is (30, 180).
        assert_eq!(
            AngularClass::of(&at(30.0, 0.0, 30.0, 180.0)),
            AngularClass::Specular
        );
        assert!(specular_offset_deg(&at(30.0, 0.0, 30.0, 180.0)) < 1e-9);
        assert_eq!(
            AngularClass::of(&at(30.0, 0.0, 31.5, 180.0)),
            AngularClass::Specular
        );
        assert_eq!(
            AngularClass::of(&at(30.0, 0.0, 40.0, 180.0)),
            AngularClass::NearSpecular
        );
        // Same theta_o on the source's side: 60 deg away.
        assert_eq!(
            AngularClass::of(&at(30.0, 0.0, 30.0, 0.0)),
            AngularClass::OffSpecular
        );
        assert!((specular_offset_deg(&at(30.0, 0.0, 30.0, 0.0)) - 60.0).abs() < 1e-9);
        // Normal incidence: the mirror direction is the normal, whatever the azimuths.
        assert_eq!(AngularClass::of(&at(0.0, 0.0, 1.0, 90.0)), AngularClass::Specular);
        // Grazing takes precedence, even at the specular direction.
        assert_eq!(
            AngularClass::of(&at(75.0, 0.0, 75.0, 180.0)),
            AngularClass::Grazing
        );
        assert_eq!(
            AngularClass::of(&at(10.0, 0.0, 70.0, 90.0)),
            AngularClass::Grazing
        );
    }
}
