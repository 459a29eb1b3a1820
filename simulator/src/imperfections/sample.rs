//! The sample's non-uniformity: its reflectance varies over its area, so the reading depends on where the beam
//! lands and on how large its footprint is.
//!
//! # Model (magnitudes from `[simulator.imperfections.sample]`)
//! The sample's BRDF at a point `(x, y)` of its surface (sample frame, mm; it turns with the sample) is the
//! material's times `m(x, y) = 1 + (g_x x + g_y y) / R + q (x^2 + y^2) / R^2`, R the sample's radius: a linear
//! gradient (each component `N(0, gradient_sd)`, the change from the centre to the edge) and a radial change
//! (`q ~ N(0, radial_sd)`, centre to rim). The shape of the BRDF does not change, only its level.
//!
//! A reading sees `m` averaged over the beam's footprint. The (top-hat) beam of radius `r_b` lights an ellipse
//! of semi-axes `a = r_b / cos(theta_i)` and `b = r_b` centred on the spot `c`; the mean of `m` over it is exactly
//! `1 + g.c / R + q (|c|^2 + (a^2 + b^2) / 4) / R^2` (the mean of x^2 over an ellipse is a^2/4 along its axis,
//! whatever its orientation). So a footprint that grows towards grazing sees a different mean, and a spot off
//! the centre (eccentricity, the beam's pointing) sees the gradient. A Gaussian beam (crate::imperfections::beam,
//! 1/e^2 radius w) weights the footprint by its profile; its second moments are those of the uniform ellipse
//! with `a = w / cos(theta_i)`, `b = w`, so the same closed form gives the weighted mean with those semi-axes. Approximation: the mean is over the whole footprint, also where
//! it spills past the sample's edge or the detector's field (those points are flagged `overfilled`).

use gonio_instrument::SampleImperfections;
use serde::Serialize;

use super::draw::Draws;

/// The hidden non-uniformity of one sample (drawn from the instrument's seed: "the sample that is mounted").
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SampleTruth {
    /// Linear gradient: relative change from the centre to the edge along the sample's x and y.
    pub gradient: [f64; 2],
    /// Radial change from the centre to the rim (relative).
    pub radial: f64,
}

impl SampleTruth {
    pub fn draw(settings: &SampleImperfections, seed: u64) -> SampleTruth {
        let draws = Draws::new(seed);
        let (gx, gy) = draws.normal_pair("sample-gradient", 0);
        let (q, _) = draws.normal_pair("sample-radial", 0);
        SampleTruth {
            gradient: [settings.gradient_sd * gx, settings.gradient_sd * gy],
            radial: settings.radial_sd * q,
        }
    }

    /// The mean of `m` over a footprint centred on `spot_mm` (sample x, y) with semi-axes `a_mm`, `b_mm`, on a
    /// sample of radius `radius_mm` (module doc).
    pub fn footprint_mean(&self, spot_mm: [f64; 2], a_mm: f64, b_mm: f64, radius_mm: f64) -> f64 {
        if radius_mm.is_nan() || radius_mm <= 0.0 || !a_mm.is_finite() || !b_mm.is_finite() {
            return 1.0;
        }
        let [cx, cy] = spot_mm;
        let linear = (self.gradient[0] * cx + self.gradient[1] * cy) / radius_mm;
        let second_moment = cx * cx + cy * cy + 0.25 * (a_mm * a_mm + b_mm * b_mm);
        1.0 + linear + self.radial * second_moment / (radius_mm * radius_mm)
    }

    pub fn is_ideal(&self) -> bool {
        self.gradient == [0.0, 0.0] && self.radial == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_footprint_mean_is_the_mean_of_m_over_the_ellipse() {
        let t = SampleTruth {
            gradient: [0.01, -0.02],
            radial: 0.03,
        };
        // Brute force over a tilted, off-centre ellipse: the closed form holds for any orientation.
        let (c, a, b, r, tilt) = ([1.0, -2.0], 4.0, 1.5, 12.5, 0.7f64);
        let m = |x: f64, y: f64| 1.0 + (0.01 * x - 0.02 * y) / r + 0.03 * (x * x + y * y) / (r * r);
        let (mut sum, mut n) = (0.0, 0u32);
        let steps = 400;
        for i in 0..steps {
            for j in 0..steps {
                let u = -1.0 + 2.0 * (f64::from(i) + 0.5) / f64::from(steps);
                let v = -1.0 + 2.0 * (f64::from(j) + 0.5) / f64::from(steps);
                if u * u + v * v > 1.0 {
                    continue;
                }
                let (ex, ey) = (a * u, b * v);
                let (x, y) = (
                    c[0] + ex * tilt.cos() - ey * tilt.sin(),
                    c[1] + ex * tilt.sin() + ey * tilt.cos(),
                );
                sum += m(x, y);
                n += 1;
            }
        }
        let brute = sum / f64::from(n);
        assert!((t.footprint_mean(c, a, b, r) - brute).abs() < 1e-6, "{brute}");
    }
}
