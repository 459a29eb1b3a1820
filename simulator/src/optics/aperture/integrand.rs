//! The integrand as the rules see it: `f(w) max(0, cos theta_w)` times the Jacobian of the integration
//! variables, (rho, phi) about the cone's axis or latitude coordinates on the part above the horizon, counting
//! BRDF evaluations. One place for the change of variables, so that every rule integrates the same thing.

use gonio_brdf::Direction;

use super::latitude::{Latitude, Row};
use super::{ApertureFunction, Cone};

/// The integration variables: (rho, phi) about the axis, or latitude coordinates for the part of a cone above
/// the horizon.
#[derive(Debug, Clone)]
pub(super) enum Coordinates {
    Polar,
    Latitude(Box<Latitude>),
}

/// Everything an integration needs, counting evaluations.
pub(super) struct Integrand<'a, F: ApertureFunction> {
    pub(super) cone: &'a Cone,
    pub(super) f: &'a mut F,
    pub(super) evaluations: u32,
    pub(super) coordinates: Coordinates,
}

impl<F: ApertureFunction> Integrand<'_, F> {
    /// The integrand at (u, v): `f(w) max(0, cos theta_w) sin rho` at (rho, phi), or the latitude integrand at
    /// (v, tau) (sigma = sigma(v)).
    pub(super) fn at(&mut self, u: f64, v: f64) -> f64 {
        match &self.coordinates {
            Coordinates::Polar => {
                let (sr, cr) = u.sin_cos();
                let (sp, cp) = v.sin_cos();
                self.at_trig(sr, cr, sp, cp)
            }
            Coordinates::Latitude(lat) => {
                let (sigma, jacobian) = lat.sigma(u);
                let row = lat.row(sigma);
                jacobian * row_value(&mut *self.f, &mut self.evaluations, lat, &row, v)
            }
        }
    }

    pub(super) fn at_trig(&mut self, sr: f64, cr: f64, sp: f64, cp: f64) -> f64 {
        let w = self.cone.direction(sr, cr, sp, cp);
        if w[2] <= 0.0 {
            return 0.0;
        }
        let Some(dir) = Direction::new(w[0], w[1], w[2]) else {
            return 0.0;
        };
        self.evaluations += 1;
        self.f.f(&dir) * dir.z() * sr
    }

    /// The latitude integrand at tau in a row, without the sigma map's Jacobian.
    pub(super) fn at_row(&mut self, lat: &Latitude, row: &Row, tau: f64) -> f64 {
        row_value(&mut *self.f, &mut self.evaluations, lat, row, tau)
    }
}

/// [`Integrand::at_row`] on the integrand's parts, so that the latitude can be borrowed from the integrand.
fn row_value<F: ApertureFunction>(
    f: &mut F,
    evaluations: &mut u32,
    lat: &Latitude,
    row: &Row,
    tau: f64,
) -> f64 {
    if row.weight <= 0.0 {
        return 0.0;
    }
    match lat.point(row, tau) {
        Some((dir, jacobian)) if dir.z() > 0.0 => {
            *evaluations += 1;
            f.f(&dir) * row.weight * jacobian
        }
        _ => 0.0,
    }
}
