//! The illuminated spot: which fraction of the beam lands on the sample and inside the detector's field of view.
//!
//! All three shapes are centred on the sample centre (the instrument's axes meet there) and live in the sample
//! plane (sample-frame x, y):
//! - the beam footprint: a collimated beam of radius `r_b` along `-wi` covers `|p|^2 - (p . wi)^2 <= r_b^2`, an
//!   ellipse of semi-axes `r_b` and `r_b / cos(theta_i)`;
//! - the sample: the disc `|p|^2 <= R^2`;
//! - the detector's field of view: `field_radius_mm` is the radius of the field perpendicular to the detector's
//!   axis, so on the sample it is the ellipse `|p|^2 - (p . wo)^2 <= r_f^2` (semi-axes `r_f`, `r_f / cos(theta_o)`).
//!
//! The (ideal) beam is uniform across its section, so the intercepted fraction is an area ratio (a Gaussian
//! beam's is a weighted one: [`super::footprint_gaussian`]):
//! `area(beam ∩ sample ∩ field) / area(beam)`. Every shape is star-shaped about the centre with squared boundary
//! radius `rho_k^2(phi) = r_k^2 / q_k(phi)`, `q_k = alpha_k + R_k cos(2 phi - delta_k)`, so the area of the
//! intersection is `1/2 ∫ min_k rho_k^2 dphi`. The crossings of two boundaries solve
//! `A + B cos 2phi + C sin 2phi = 0` in closed form, and on each interval between crossings the integral of
//! `1 / (alpha + R cos psi)` has the closed-form antiderivative
//! `(psi - 2 atan(r sin psi / (1 + r cos psi))) / c`, `c = sqrt(alpha^2 - R^2)`, `r = R / (alpha + c)`, which is
//! continuous for all psi. So the fraction is exact to rounding, with no quadrature.

use std::f64::consts::PI;

use gonio_brdf::Direction;

/// What happened to the beam on the sample plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Fraction of the beam power that lands on the sample inside the detector's field of view, in [0, 1].
    pub intercepted_fraction: f64,
    /// Part of the beam falls past the sample's edge.
    pub overfilled_sample: bool,
    /// Part of the beam falls outside the detector's field of view.
    pub overfilled_field: bool,
}

/// A centred star-shaped boundary `rho^2(phi) = r2 / (alpha + rc cos(2 phi - delta))`.
#[derive(Debug, Clone, Copy)]
struct Boundary {
    r2: f64,
    alpha: f64,
    rc: f64,
    delta: f64,
    /// `sqrt(alpha^2 - rc^2)`, computed without cancellation by the caller.
    c: f64,
}

impl Boundary {
    fn disc(radius: f64) -> Boundary {
        Boundary {
            r2: radius * radius,
            alpha: 1.0,
            rc: 0.0,
            delta: 0.0,
            c: 1.0,
        }
    }

    /// The footprint of a cylinder of radius `radius` along direction `w` (sample frame, w.z > 0).
    /// `q = 1 - (wx cos + wy sin)^2 = 1 - s2/2 - ((wx^2 - wy^2) cos 2phi + 2 wx wy sin 2phi) / 2`.
    fn cylinder(radius: f64, w: &Direction) -> Boundary {
        let (wx, wy) = (w.x(), w.y());
        let s2 = w.sin2_theta();
        let b = -(wx * wx - wy * wy) / 2.0;
        let g = -wx * wy;
        // alpha^2 - rc^2 = (alpha - rc)(alpha + rc) = cos^2(theta) * 1.
        Boundary {
            r2: radius * radius,
            alpha: 1.0 - s2 / 2.0,
            rc: s2 / 2.0,
            delta: g.atan2(b),
            c: w.z().abs(),
        }
    }

    fn rho2(&self, phi: f64) -> f64 {
        self.r2 / (self.alpha + self.rc * (2.0 * phi - self.delta).cos())
    }

    /// The coefficients (A, B, C) of `r2_self q_other - r2_other q_self = A + B cos 2phi + C sin 2phi`, which
    /// vanishes where the two boundaries cross.
    fn crossing_coefficients(&self, other: &Boundary) -> (f64, f64, f64) {
        let (bs, gs) = (self.rc * self.delta.cos(), self.rc * self.delta.sin());
        let (bo, go) = (other.rc * other.delta.cos(), other.rc * other.delta.sin());
        (
            self.r2 * other.alpha - other.r2 * self.alpha,
            self.r2 * bo - other.r2 * bs,
            self.r2 * go - other.r2 * gs,
        )
    }

    /// `∫_{phi0}^{phi1} rho^2 dphi` in closed form.
    fn integral_rho2(&self, phi0: f64, phi1: f64) -> f64 {
        let r = self.rc / (self.alpha + self.c);
        let antiderivative = |psi: f64| {
            let (s, c) = psi.sin_cos();
            (psi - 2.0 * (r * s / (1.0 + r * c)).atan()) / self.c
        };
        // d phi = d psi / 2 with psi = 2 phi - delta.
        self.r2 * 0.5 * (antiderivative(2.0 * phi1 - self.delta) - antiderivative(2.0 * phi0 - self.delta))
    }
}

/// Roots in [0, pi) of `A + B cos 2phi + C sin 2phi = 0`.
fn crossings(a: f64, b: f64, c: f64, out: &mut Vec<f64>) {
    let r = b.hypot(c);
    // |A| >= R: no crossing, or a tangency that does not change which boundary is inside.
    if r.is_nan() || r <= a.abs() {
        return;
    }
    let d = c.atan2(b);
    let s = (-a / r).clamp(-1.0, 1.0).acos();
    for two_phi in [d + s, d - s] {
        out.push((two_phi / 2.0).rem_euclid(PI));
    }
}

/// The intercepted fraction for a beam of radius `beam_radius` arriving from `wi`, a sample disc of radius
/// `sample_radius`, and a detector looking from `wo` with field radius `field_radius` (all lengths in the same unit).
/// A beam from below the horizon does not light the front face: fraction 0. When the detector looks from below
/// the horizon, it sees nothing of the front face anyway and the field is left out.
pub fn footprint(
    beam_radius: f64,
    sample_radius: f64,
    field_radius: f64,
    wi: &Direction,
    wo: &Direction,
) -> Footprint {
    if wi.z() <= 0.0 || beam_radius.is_nan() || beam_radius <= 0.0 {
        return Footprint {
            intercepted_fraction: 0.0,
            overfilled_sample: true,
            overfilled_field: false,
        };
    }
    // Fast path (the usual case): the beam's longest semi-axis r_b / cos(theta_i) fits inside the sample disc and
    // inside the field's shortest semi-axis r_f, so nothing is clipped.
    let longest = beam_radius / wi.z();
    if longest <= sample_radius && (wo.z() <= 0.0 || longest <= field_radius) {
        return Footprint {
            intercepted_fraction: 1.0,
            overfilled_sample: false,
            overfilled_field: false,
        };
    }
    let mut shapes = [
        Boundary::cylinder(beam_radius, wi),
        Boundary::disc(sample_radius),
        Boundary::disc(0.0),
    ];
    let n = if wo.z() > 0.0 {
        shapes[2] = Boundary::cylinder(field_radius, wo);
        3
    } else {
        2
    };
    let shapes = &shapes[..n];
    // Breakpoints over one period (every boundary is pi-periodic).
    let mut cuts = Vec::with_capacity(2 + 2 * n * (n - 1) / 2);
    cuts.push(0.0);
    cuts.push(PI);
    for j in 0..n {
        for k in j + 1..n {
            let (a, b, c) = shapes[j].crossing_coefficients(&shapes[k]);
            crossings(a, b, c, &mut cuts);
        }
    }
    cuts.sort_by(f64::total_cmp);
    let mut area = 0.0;
    let mut active = [false; 3];
    for w in cuts.windows(2) {
        let (p0, p1) = (w[0], w[1]);
        if p1 <= p0 {
            continue;
        }
        let mid = 0.5 * (p0 + p1);
        let mut best = 0;
        let mut best_rho2 = f64::INFINITY;
        for (k, s) in shapes.iter().enumerate() {
            let r2 = s.rho2(mid);
            if r2 < best_rho2 {
                best = k;
                best_rho2 = r2;
            }
        }
        active[best] = true;
        // Both halves of the period are equal: integrate [0, pi) and double; area = 1/2 ∫ rho^2.
        area += shapes[best].integral_rho2(p0, p1);
    }
    let beam_area = PI * beam_radius * beam_radius / wi.z();
    // When the beam's own boundary is the innermost everywhere, nothing is lost: exactly 1, not 1 - rounding.
    let fraction = if active[1] || active[2] {
        (area / beam_area).clamp(0.0, 1.0)
    } else {
        1.0
    };
    Footprint {
        intercepted_fraction: fraction,
        overfilled_sample: active[1],
        overfilled_field: active[2],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force area count on a fine grid over the beam ellipse's bounding box.
    fn brute_force(rb: f64, rs: f64, rf: f64, wi: &Direction, wo: &Direction, n: usize) -> f64 {
        let extent = rb / wi.z();
        let h = 2.0 * extent / n as f64;
        let (mut inside_beam, mut inside_all) = (0u64, 0u64);
        for i in 0..n {
            let x = -extent + (i as f64 + 0.5) * h;
            for j in 0..n {
                let y = -extent + (j as f64 + 0.5) * h;
                let r2 = x * x + y * y;
                let pi = x * wi.x() + y * wi.y();
                if r2 - pi * pi > rb * rb {
                    continue;
                }
                inside_beam += 1;
                let po = x * wo.x() + y * wo.y();
                if r2 <= rs * rs && (wo.z() <= 0.0 || r2 - po * po <= rf * rf) {
                    inside_all += 1;
                }
            }
        }
        inside_all as f64 / inside_beam as f64
    }

    #[test]
    fn fully_intercepted_beam_at_normal_incidence() {
        let f = footprint(
            1.5,
            25.0,
            12.0,
            &Direction::NORMAL,
            &Direction::from_spherical_deg(30.0, 0.0),
        );
        assert_eq!(f.intercepted_fraction, 1.0);
        assert!(!f.overfilled_sample && !f.overfilled_field);
    }

    #[test]
    fn circle_clipped_by_smaller_circle_is_the_area_ratio() {
        // Normal incidence and normal viewing: beam circle of radius 2 clipped by the sample of radius 1.
        let f = footprint(2.0, 1.0, 10.0, &Direction::NORMAL, &Direction::NORMAL);
        assert!(
            (f.intercepted_fraction - 0.25).abs() < 1e-15,
            "{}",
            f.intercepted_fraction
        );
        assert!(f.overfilled_sample && !f.overfilled_field);
    }

    #[test]
    fn ellipse_clipped_by_circle_analytic() {
        // Ellipse of semi-axes a = rb/cos(ti) (along the incidence plane) and b = rb, clipped by a circle of radius
        // R with b < R < a. Independent reference: the polar area formula in the ellipse's own axes,
        // A = 4 * 1/2 ∫_0^{pi/2} min(R^2, 1/(cos^2/a^2 + sin^2/b^2)) dphi, by a fine midpoint rule.
        let (rb, rs) = (1.0, 3.0);
        let ti = 80f64.to_radians();
        let wi = Direction::from_spherical(ti, 0.3);
        let f = footprint(rb, rs, 100.0, &wi, &Direction::NORMAL);
        let (a, b) = (rb / ti.cos(), rb);
        let n = 2_000_000;
        let mut area = 0.0;
        for i in 0..n {
            let phi = (i as f64 + 0.5) * (PI / 2.0) / n as f64;
            let (s, c) = phi.sin_cos();
            let rho2 = 1.0 / (c * c / (a * a) + s * s / (b * b));
            area += 0.5 * rho2.min(rs * rs) * (PI / 2.0) / n as f64;
        }
        let expect = 4.0 * area / (PI * a * b);
        assert!(
            (f.intercepted_fraction - expect).abs() < 1e-9,
            "{} vs {expect}",
            f.intercepted_fraction
        );
        assert!(f.overfilled_sample);
    }

    #[test]
    fn grazing_spill_matches_a_brute_force_area_count() {
        let cases = [
            // (rb, rs, rf, theta_i, phi_i, theta_o, phi_o)
            (1.5, 10.0, 12.0, 85.0, 0.0, 30.0, 180.0),
            (1.5, 5.0, 12.0, 80.0, 37.0, 60.0, 200.0),
            (1.5, 25.0, 3.0, 75.0, -20.0, 70.0, 100.0),
            (2.0, 4.0, 5.0, 70.0, 10.0, 75.0, 190.0),
            (1.0, 0.8, 0.9, 20.0, 45.0, 50.0, 0.0),
        ];
        for (rb, rs, rf, ti, pi, to, po) in cases {
            let wi = Direction::from_spherical_deg(ti, pi);
            let wo = Direction::from_spherical_deg(to, po);
            let f = footprint(rb, rs, rf, &wi, &wo);
            let bf = brute_force(rb, rs, rf, &wi, &wo, 2000);
            assert!(
                (f.intercepted_fraction - bf).abs() < 2e-4,
                "case {:?}: {} vs brute force {bf}",
                (rb, rs, rf, ti, pi, to, po),
                f.intercepted_fraction
            );
            assert!(f.intercepted_fraction < 1.0);
        }
    }

    #[test]
    fn below_horizon_beam_lights_nothing() {
        let wi = Direction::from_spherical_deg(100.0, 0.0);
        assert_eq!(
            footprint(1.0, 10.0, 10.0, &wi, &Direction::NORMAL).intercepted_fraction,
            0.0
        );
    }
}
