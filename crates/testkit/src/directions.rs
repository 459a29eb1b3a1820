//! Hostile directions for the numerical stress suites (the BRDF models and kinematics alike): polar angles at
//! the pole and the horizon and 1e-9 and 1e-12 away from both, below the horizon down to the nadir, and ordinary
//! values, at azimuths on and 1e-12 off the axes and negative ones.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use gonio_brdf::Direction;

/// Polar angles (radians).
pub const THETAS: [f64; 14] = [
    0.0,
    1e-12,
    1e-9,
    0.3,
    0.4,
    FRAC_PI_4,
    1.2,
    FRAC_PI_2 - 1e-9,
    FRAC_PI_2 - 1e-12,
    FRAC_PI_2,
    FRAC_PI_2 + 1e-12,
    2.0,
    2.5,
    PI,
];

/// Azimuths (radians).
pub const PHIS: [f64; 6] = [0.0, 1e-12, FRAC_PI_2, PI, -2.0, -2.5];

/// Every polar angle at every azimuth, then directions on and just above the horizon through the degree
/// constructor (which puts z = 0 exactly on it).
pub fn hostile_directions() -> Vec<Direction> {
    let mut v = Vec::with_capacity(THETAS.len() * PHIS.len() + 4);
    for &t in &THETAS {
        for &p in &PHIS {
            v.push(Direction::from_spherical(t, p));
        }
    }
    v.push(Direction::from_spherical_deg(90.0, 0.0));
    v.push(Direction::from_spherical_deg(90.0, 33.0));
    v.push(Direction::from_spherical_deg(90.0 - 1e-10, 0.0));
    v.push(Direction::from_spherical_deg(90.0 - 1e-12, 0.0));
    v
}
