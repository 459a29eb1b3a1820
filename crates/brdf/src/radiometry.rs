//! Radiometric geometry: solid angles, projected solid angles, radiance <-> irradiance.
//!
//! Lengths passed together must share a unit; the names say millimetres because that is what the instrument
//! files use, but only ratios enter the results. Solid angles are in steradians (sr); the projected solid angle
//! (the integral of cos(theta) over a set of directions, theta from the surface normal) is also in sr.
//!
//! Numerical care: the solid angle of a circular aperture is evaluated as `2 pi r^2 / (s (s + d))`,
//! `s = sqrt(d^2 + r^2)`, which is algebraically `2 pi (1 - d/s)` but keeps full precision for tiny apertures
//! (the textbook form loses ~8 digits at r/d = 1e-4 and everything at r/d = 1e-8).

use std::f64::consts::PI;

use crate::geometry::Direction;

/// Solid angle in sr subtended by a small patch of area `area_mm2` whose normal makes the angle theta with the
/// line of sight (`cos_theta` = its cosine), at distance `distance_mm`: `dA cos(theta) / r^2`.
/// A patch seen from behind (`cos_theta < 0`) subtends nothing: the result is clamped at 0.
pub fn patch_solid_angle_sr(area_mm2: f64, cos_theta: f64, distance_mm: f64) -> f64 {
    area_mm2 * cos_theta.max(0.0) / (distance_mm * distance_mm)
}

/// Solid angle in sr of a circular aperture of radius `radius_mm` seen on its axis from distance `distance_mm`
/// (both >= 0): `2 pi (1 - d/s)` evaluated in the cancellation-free form `2 pi r^2 / (s (s + d))`.
/// At distance 0 the aperture fills a hemisphere (2 pi); a zero radius gives 0.
pub fn aperture_solid_angle_sr(radius_mm: f64, distance_mm: f64) -> f64 {
    let s = distance_mm.hypot(radius_mm);
    if s == 0.0 {
        return 0.0;
    }
    2.0 * PI * radius_mm * radius_mm / (s * (s + distance_mm))
}

/// Half-angle in radians of the cone from a point on the axis to the rim of a circular aperture of radius
/// `radius_mm` at distance `distance_mm`: `atan(r/d)`, computed as `atan2` so that d = 0 gives pi/2.
pub fn aperture_half_angle_rad(radius_mm: f64, distance_mm: f64) -> f64 {
    radius_mm.atan2(distance_mm)
}

/// Solid angle in sr of a circular cone of half-angle `half_angle_rad` in [0, pi]: `2 pi (1 - cos beta)`,
/// evaluated as `4 pi sin^2(beta/2)` so that small cones keep their digits.
pub fn cone_solid_angle_sr(half_angle_rad: f64) -> f64 {
    let s = (0.5 * half_angle_rad).sin();
    4.0 * PI * s * s
}

/// Projected solid angle in sr of a circular cone of half-angle `half_angle_rad` (in [0, pi]) about `axis`,
/// clipped to the upper hemisphere: the integral of `max(cos theta, 0)` over the directions of the cone,
/// theta being measured from the surface normal.
///
/// Exact closed forms are used in every case:
/// - cone entirely above the horizon (`theta_axis + beta <= pi/2`): `pi sin^2(beta) cos(theta_axis)`
///   (the integral of `w` over a cone points along its axis with length `pi sin^2 beta`); about the normal
///   this is `pi sin^2 beta`, and the whole hemisphere gives pi;
/// - cone entirely below the horizon: 0;
/// - cone crossing the horizon, `beta <= pi/2`: the clipped-cap formula (Snyder 1996, as used for sphere and disk
///   lights): with `x = cot beta`, `y = -x cot(theta_axis)`, `q = sin(theta_axis) sqrt(1 - y^2)`:
///   `(cos(theta_axis) acos(y) - x q) sin^2 beta + atan(q / x)`;
/// - `beta > pi/2`: pi minus the complementary cone (about `-axis`, half-angle `pi - beta`).
///
/// For cones crossing the horizon the formula subtracts terms of order beta to get a result of order beta^2:
/// the relative accuracy is about `1e-16 / beta` (1e-13 for a 1 mrad cone), which the tests check against
/// an independent quadrature.
pub fn projected_solid_angle_sr(axis: &Direction, half_angle_rad: f64) -> f64 {
    let beta = half_angle_rad.clamp(0.0, PI);
    if beta > 0.5 * PI {
        return (PI - projected_solid_angle_sr(&axis.neg(), PI - beta)).max(0.0);
    }
    let cos_a = axis.cos_theta();
    let sin_a = axis.sin_theta();
    let (sin_b, cos_b) = beta.sin_cos();
    let sin2_b = sin_b * sin_b;
    // Above the horizon entirely: cos(theta_a + beta) >= 0, i.e. cos_a cos_b >= sin_a sin_b.
    if cos_a * cos_b >= sin_a * sin_b {
        return PI * sin2_b * cos_a;
    }
    // Below entirely: cos(theta_a - beta) <= 0.
    if cos_a * cos_b + sin_a * sin_b <= 0.0 {
        return 0.0;
    }
    // Crossing the horizon: here sin_a > 0 and beta > 0 (otherwise one of the cases above applies).
    let x = cos_b / sin_b;
    let y = (-x * cos_a / sin_a).clamp(-1.0, 1.0);
    let q = sin_a * (1.0 - y * y).max(0.0).sqrt();
    let value = (cos_a * y.acos() - x * q) * sin2_b + q.atan2(x);
    value.max(0.0)
}

/// Irradiance in W/m^2 on the surface produced by a uniform radiance `radiance_w_per_m2_sr` arriving from every
/// direction of a cone (half-angle `half_angle_rad` about `axis`): `E = L * projected solid angle`.
pub fn irradiance_from_radiance_w_per_m2(
    radiance_w_per_m2_sr: f64,
    axis: &Direction,
    half_angle_rad: f64,
) -> f64 {
    radiance_w_per_m2_sr * projected_solid_angle_sr(axis, half_angle_rad)
}

/// The uniform radiance in W/(m^2 sr) over a cone that produces the irradiance `irradiance_w_per_m2`:
/// `L = E / projected solid angle`. `None` when the cone has no projected solid angle (empty, or entirely
/// below the horizon), where no radiance can produce a non-zero irradiance.
pub fn radiance_from_irradiance_w_per_m2_sr(
    irradiance_w_per_m2: f64,
    axis: &Direction,
    half_angle_rad: f64,
) -> Option<f64> {
    let psa = projected_solid_angle_sr(axis, half_angle_rad);
    if psa > 0.0 {
        Some(irradiance_w_per_m2 / psa)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn patch_solid_angle_is_area_cos_over_r2() {
        assert_eq!(patch_solid_angle_sr(2.0, 0.5, 10.0), 0.01);
        assert_eq!(patch_solid_angle_sr(2.0, -0.5, 10.0), 0.0);
    }

    #[test]
    fn aperture_solid_angle_matches_exact_values() {
        // r = d: half-angle 45 degrees, Omega = 2 pi (1 - 1/sqrt 2).
        let exact = 2.0 * PI * (1.0 - std::f64::consts::FRAC_1_SQRT_2);
        assert!(rel(aperture_solid_angle_sr(5.0, 5.0), exact) < 1e-15);
        assert_eq!(aperture_solid_angle_sr(3.0, 0.0), 2.0 * PI);
        assert_eq!(aperture_solid_angle_sr(0.0, 3.0), 0.0);
        assert_eq!(aperture_solid_angle_sr(0.0, 0.0), 0.0);
        // Agrees with the cone formula.
        let beta = aperture_half_angle_rad(1.0, 7.0);
        assert!(rel(aperture_solid_angle_sr(1.0, 7.0), cone_solid_angle_sr(beta)) < 1e-14);
    }

    #[test]
    fn aperture_solid_angle_is_stable_for_tiny_apertures() {
        // r/d = 1e-6: series 2 pi (1 - 1/sqrt(1+e)) with e = t^2 = 1e-12:
        // pi e (1 - 3e/4 + 5e^2/8) is exact to far below f64 precision here.
        let (r, d) = (1e-6, 1.0);
        let e: f64 = 1e-12;
        let reference = PI * e * (1.0 - 0.75 * e + 0.625 * e * e);
        let omega = aperture_solid_angle_sr(r, d);
        assert!(rel(omega, reference) < 1e-15, "{omega} vs {reference}");
        // Small-aperture limit pi r^2 / d^2 (relative difference 3e/4 = 7.5e-13 here).
        assert!(rel(omega, PI * r * r / (d * d)) < 1e-12);
        // The naive form has lost most of its digits; this documents why the stable form exists.
        let naive = 2.0 * PI * (1.0 - d / d.hypot(r));
        assert!(rel(naive, reference) > 1e-6);
        // Scale invariance in the units.
        assert!(rel(aperture_solid_angle_sr(1e-3, 1e3), omega) < 1e-15);
    }

    #[test]
    fn aperture_solid_angle_high_precision_value() {
        // r = 1, d = 10: 2 pi (1 - 10/sqrt(101)), computed with 50-digit decimal arithmetic.
        let reference = 0.031_182_253_554_923_27_f64;
        assert!(rel(aperture_solid_angle_sr(1.0, 10.0), reference) < 1e-15);
    }

    #[test]
    fn half_angle_of_aperture() {
        assert!((aperture_half_angle_rad(1.0, 1.0) - PI / 4.0).abs() < 1e-16);
        assert_eq!(aperture_half_angle_rad(1.0, 0.0), FRAC_PI_2);
    }

    #[test]
    fn projected_solid_angle_exact_cases() {
        assert!(rel(projected_solid_angle_sr(&Direction::NORMAL, FRAC_PI_2), PI) < 1e-15);
        assert!(rel(projected_solid_angle_sr(&Direction::NORMAL, PI), PI) < 1e-15);
        let b: f64 = 0.2;
        assert!(
            rel(
                projected_solid_angle_sr(&Direction::NORMAL, b),
                PI * b.sin().powi(2)
            ) < 1e-15
        );
        let tilted = Direction::from_spherical(0.9, 1.0);
        assert!(
            rel(
                projected_solid_angle_sr(&tilted, b),
                PI * b.sin().powi(2) * 0.9f64.cos()
            ) < 1e-15
        );
        // Axis on the horizon: half the cone is above, beta - sin(beta) cos(beta).
        let horizon = Direction::from_spherical(FRAC_PI_2, 0.3);
        let expected = b - b.sin() * b.cos();
        assert!(rel(projected_solid_angle_sr(&horizon, b), expected) < 1e-13);
        // Entirely below.
        assert_eq!(
            projected_solid_angle_sr(&Direction::from_spherical(2.0, 0.0), 0.1),
            0.0
        );
        // The whole sphere about any axis projects to pi.
        assert!(rel(projected_solid_angle_sr(&tilted, PI), PI) < 1e-15);
    }

    #[test]
    fn projected_solid_angle_is_continuous_through_the_horizon_cases() {
        // Approach the case boundary theta_a + beta = pi/2 from both sides.
        let b = 0.3;
        for eps in [1e-6, 1e-9] {
            let inside = projected_solid_angle_sr(&Direction::from_spherical(FRAC_PI_2 - b - eps, 0.0), b);
            let crossing = projected_solid_angle_sr(&Direction::from_spherical(FRAC_PI_2 - b + eps, 0.0), b);
            assert!(rel(inside, crossing) < 10.0 * eps, "{inside} {crossing}");
        }
    }

    #[test]
    fn radiance_irradiance_round_trip() {
        let axis = Direction::from_spherical(0.4, 0.0);
        let e = irradiance_from_radiance_w_per_m2(3.0, &axis, 0.1);
        let l = radiance_from_irradiance_w_per_m2_sr(e, &axis, 0.1).expect("cone above the horizon");
        assert!(rel(l, 3.0) < 1e-15);
        // Full hemisphere of radiance L gives E = pi L.
        assert!(
            rel(
                irradiance_from_radiance_w_per_m2(2.0, &Direction::NORMAL, FRAC_PI_2),
                2.0 * PI
            ) < 1e-15
        );
        assert_eq!(
            radiance_from_irradiance_w_per_m2_sr(1.0, &Direction::from_spherical(2.5, 0.0), 0.1),
            None
        );
    }
}
