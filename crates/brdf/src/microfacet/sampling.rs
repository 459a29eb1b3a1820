//! Importance sampling: microfacet normals (GGX visible normals, Beckmann slopes) and the reflected
//! directions, with their densities.

use super::*;

impl Microfacet {
    /// Draws a microfacet normal for light arriving from `wi` (above the horizon), with its density in the
    /// measure of `m` (1/sr). GGX: the distribution of visible normals `G1(wi, m) max(0, wi.m) D(m) / cos_i`
    /// (Heitz 2018); Beckmann: `D(m) cos(theta_m)` (Gaussian slopes). `None` for `wi` at or below the horizon.
    pub fn sample_normal(&self, wi: &Direction, u: [f64; 2]) -> Option<(Direction, f64)> {
        if wi.z() <= 0.0 {
            return None;
        }
        let (ax, ay) = (self.alpha_x, self.alpha_y);
        let u0 = u[0].clamp(0.0, 1.0 - f64::EPSILON);
        let u1 = u[1].clamp(0.0, 1.0);
        let m = match self.distribution {
            Distribution::Ggx => {
                // Stretch to the hemisphere configuration (alpha = 1).
                let vh = Direction::new(ax * wi.x(), ay * wi.y(), wi.z())?;
                let lensq = vh.x() * vh.x() + vh.y() * vh.y();
                let t1 = if lensq > 0.0 {
                    let inv = 1.0 / lensq.sqrt();
                    [-vh.y() * inv, vh.x() * inv, 0.0]
                } else {
                    [1.0, 0.0, 0.0]
                };
                let v = [vh.x(), vh.y(), vh.z()];
                let t2 = cross(v, t1);
                // A point on the disk, warped towards the visible half.
                let r = u0.sqrt();
                let phi = 2.0 * PI * u1;
                let p1 = r * phi.cos();
                let mut p2 = r * phi.sin();
                let s = 0.5 * (1.0 + vh.z());
                p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
                let pn = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
                let nh = [
                    p1 * t1[0] + p2 * t2[0] + pn * v[0],
                    p1 * t1[1] + p2 * t2[1] + pn * v[1],
                    p1 * t1[2] + p2 * t2[2] + pn * v[2],
                ];
                // Unstretch.
                Direction::new(ax * nh[0], ay * nh[1], nh[2].max(0.0))?
            }
            Distribution::Beckmann => {
                // Slopes are Gaussian with density exp(-(sx^2/ax^2 + sy^2/ay^2)) / (pi ax ay).
                let r = (-(1.0 - u0).ln()).max(0.0).sqrt();
                let phi = 2.0 * PI * u1;
                let sx = ax * r * phi.cos();
                let sy = ay * r * phi.sin();
                Direction::new(-sx, -sy, 1.0)?
            }
        };
        let pdf = self.pdf_normal(wi, &m);
        Some((m, pdf))
    }

    /// Density of [`Microfacet::sample_normal`] at `m`, in 1/sr.
    pub fn pdf_normal(&self, wi: &Direction, m: &Direction) -> f64 {
        match self.distribution {
            Distribution::Ggx => {
                if wi.z() <= 0.0 {
                    return 0.0;
                }
                let wm = wi.dot(m);
                if wm <= 0.0 {
                    return 0.0;
                }
                self.g1(wi, m) * wm * self.d(m) / wi.z()
            }
            Distribution::Beckmann => self.d(m) * m.z().max(0.0),
        }
    }

    /// Draws an outgoing direction by reflecting `wi` about a sampled normal. The density is in the measure of
    /// `wo` (1/sr): `pdf_m / (4 |wi . m|)`. The direction may fall at or below the horizon, where the BRDF is 0:
    /// such samples contribute nothing and keep estimators of `integral f cos d wo` unbiased.
    pub fn sample_reflection(&self, wi: &Direction, u: [f64; 2]) -> Option<DirectionSample> {
        let (m, pdf_m) = self.sample_normal(wi, u)?;
        let wm = wi.dot(&m);
        let wo = wi.reflect_about(&m);
        let pdf = pdf_m / (4.0 * wm.abs().max(f64::MIN_POSITIVE));
        Some(DirectionSample {
            wo,
            pdf_per_sr: if pdf.is_finite() && pdf > 0.0 {
                pdf
            } else {
                f64::MAX
            },
        })
    }

    /// Density of [`Microfacet::sample_reflection`] at `wo` above the horizon, in 1/sr.
    pub fn pdf_reflection(&self, wi: &Direction, wo: &Direction) -> f64 {
        if wi.z() <= 0.0 || wo.z() <= 0.0 {
            return 0.0;
        }
        let Some(h) = Direction::new(wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z()) else {
            return 0.0;
        };
        let wh = wo.dot(&h);
        if wh <= 0.0 {
            return 0.0;
        }
        self.pdf_normal(wi, &h) / (4.0 * wh)
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
