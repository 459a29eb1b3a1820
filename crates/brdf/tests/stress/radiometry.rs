//! Solid angles, projected solid angles and radiance conversions for aperture half-angles from 1e-6 to 0.5 rad,
//! against independent forms, including cones on and below the horizon.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::Direction;
use gonio_brdf::radiometry::{
    aperture_solid_angle_sr, cone_solid_angle_sr, irradiance_from_radiance_w_per_m2,
    projected_solid_angle_sr, radiance_from_irradiance_w_per_m2_sr,
};

use super::Failures;

#[test]
fn solid_angles_and_radiance_conversions_from_1e6_to_half_a_radian() {
    let mut fails = Failures::default();
    for k in 0..=60 {
        // Half-angles log-spaced from 1e-6 to 0.5 rad.
        let beta = 1e-6 * (0.5f64 / 1e-6).powf(k as f64 / 60.0);
        let cone = cone_solid_angle_sr(beta);
        let aperture = aperture_solid_angle_sr(beta.tan(), 1.0);
        let aperture_mm = aperture_solid_angle_sr(250.0 * beta.tan(), 250.0);
        // Independent: 2 pi (1 - cos b) by its series for small b, by the identity otherwise.
        let reference = if beta < 1e-3 {
            let b2 = beta * beta;
            PI * b2 * (1.0 - b2 / 12.0 + b2 * b2 / 360.0)
        } else {
            2.0 * PI * (1.0 - beta.cos())
        };
        let tol = if beta < 1e-3 {
            1e-15
        } else {
            1e-16 / (beta * beta) + 1e-15
        };
        for (what, v) in [
            ("cone", cone),
            ("aperture", aperture),
            ("aperture mm", aperture_mm),
        ] {
            // Written so that a NaN fails too.
            if (v - reference).abs().is_nan() || (v - reference).abs() > tol * reference * 4.0 {
                fails.add(format!("{what} beta {beta}: {v} vs {reference}"));
            }
        }
        for &t in &[0.0, 1e-12, 0.8, FRAC_PI_2 - beta - 1e-9] {
            let axis = Direction::from_spherical(t, 0.4);
            let psa = projected_solid_angle_sr(&axis, beta);
            let expect = PI * beta.sin().powi(2) * axis.z();
            if (psa - expect).abs() > 1e-14 * expect {
                fails.add(format!("projected beta {beta} theta {t}: {psa} vs {expect}"));
            }
            for radiance in [1e-15, 1.0, 1e6] {
                let e = irradiance_from_radiance_w_per_m2(radiance, &axis, beta);
                let back = radiance_from_irradiance_w_per_m2_sr(e, &axis, beta);
                if back.is_none_or(|l| (l - radiance).abs() > 1e-14 * radiance) {
                    fails.add(format!(
                        "radiance round trip beta {beta} theta {t}: {radiance} -> {back:?}"
                    ));
                }
            }
        }
        // A cone on the horizon (half above), one just below it, one entirely below: finite, >= 0, and None
        // where no radiance can produce irradiance.
        let on = projected_solid_angle_sr(&Direction::from_spherical_deg(90.0, 0.0), beta);
        if !(on.is_finite() && on > 0.0) {
            fails.add(format!("horizon cone beta {beta}: {on}"));
        }
        let below = Direction::from_spherical(FRAC_PI_2 + 2.0 * beta, 0.0);
        if projected_solid_angle_sr(&below, beta) != 0.0
            || radiance_from_irradiance_w_per_m2_sr(1.0, &below, beta).is_some()
        {
            fails.add(format!("cone below the horizon beta {beta}"));
        }
    }
    fails.assert_none("radiometry");
}
