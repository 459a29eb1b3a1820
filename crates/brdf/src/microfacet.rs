//! Microfacet distributions (GGX / Trowbridge-Reitz and Beckmann, anisotropic), Smith masking-shadowing and
//! importance sampling, as defined in shared/reference/radiometry-and-materials.md ("Models").
//!
//! Everything is written in Cartesian components of unit vectors in the sample frame: `alpha_x` is the roughness
//! along the sample's x axis, `alpha_y` along y. Nothing divides by a cosine before testing it, `sin^2` is
//! `x^2 + y^2`, and there is no trigonometry of angles, so the pole and the horizon need no special cases.
//!
//! # Roughness limits and the delta switch-over
//! - Every alpha is clamped to `>= ALPHA_MIN` (1e-4) on construction (a NaN becomes `ALPHA_MIN`): below that the
//!   lobe is narrower than any goniometer can resolve and `D` at the pole (1/(pi alpha^2)) approaches overflow
//!   territory in products.
//! - When BOTH alphas are below `ALPHA_DELTA` (1e-3), [`Microfacet::is_delta`] is true and the models that own
//!   the lobe (conductor, plastic) switch to a delta treatment: their pointwise `eval` leaves the lobe out (it is
//!   0) and `delta_lobe` reports, for incidence `wi`, the reflectance `F(cos theta_i) * G(wi, mirror(wi), n)`,
//!   where `G` is this model's masking-shadowing evaluated with the (clamped) alphas at the macro normal
//!   ([`Microfacet::delta_masking`]). That is the exact limit of the lobe's directional albedo
//!   `integral f cos(theta_o) d wo` as the lobe narrows (D concentrates at the normal, where the half vector is
//!   the normal and `wi . h = cos theta_i`), so the total reflected power is continuous across the switch: it
//!   changes by O(alpha^2) ~ 1e-6 relative (tests `delta_switch_preserves_reflected_power` and, in
//!   tests/stress.rs, `alpha_clamp_and_delta_switch_are_continuous_in_reflected_power`).
//!   The power inside a finite aperture of half-angle beta around the mirror direction is continuous to the
//!   same order for Beckmann (Gaussian tail) but NOT for GGX, whose power-law tail puts a fraction
//!   `alpha^2 / (alpha^2 + tan^2(beta/2))` of the lobe outside the aperture (at normal incidence): at alpha = 1e-3
//!   that is 1.6e-3 for beta = 0.05 rad and 3.8% for a 0.01 rad aperture; the delta puts it all inside. (Found by
//!   the stress suite; an earlier version of this comment claimed O(alpha^2) for the aperture too.)
//!   Only the pointwise values are discontinuous, as they must be: a lobe of width 1e-3 rad has a peak of
//!   ~3e5 1/sr, a delta has none.
//!   [`Microfacet::delta_cone_fraction`] gives the part of the delta lobe that the clamped roughness would put
//!   inside a cone about the mirror direction (paraxial, exact at normal incidence for GGX); it matches the
//!   aperture integral of the lobe just above the switch to 4e-6 (test
//!   `delta_cone_fraction_matches_the_lobe_just_above_the_switch`). A consumer that multiplies the delta's
//!   reflectance by it sees an aperture power continuous across the switch on the mirror direction. The
//!   simulator's optics (crates/simulator/src/optics.rs, `aperture_truth`) does NOT do so yet: it puts the whole delta
//!   inside (spread only by the source's divergence), so its reading at the mirror direction still jumps by the
//!   GGX tail fraction above (3.8% at alpha 1e-3 for its 0.01 rad aperture; 4e-4 at the 1e-4 clamp). Off the
//!   mirror direction the two sides also differ in how the source's divergence enters (the lobe side ignores
//!   it), so a fully continuous switch would need the same divergence treatment on both sides.
//! - The switch needs both alphas below the threshold: a lobe that is narrow in one direction only stays a lobe.

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use crate::brdf::DirectionSample;
use crate::geometry::Direction;

/// Smallest roughness used: smaller alphas are clamped to this.
pub const ALPHA_MIN: f64 = 1e-4;
/// Below this roughness (in both directions) the lobe is treated as a delta lobe; see the module doc.
pub const ALPHA_DELTA: f64 = 1e-3;

/// The normal distribution function.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Distribution {
    /// GGX / Trowbridge-Reitz.
    Ggx,
    /// Beckmann (Gaussian slopes).
    Beckmann,
}

/// How masking and shadowing are combined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Masking {
    /// `G = G1(wi, h) G1(wo, h)`.
    Separable,
    /// `G = 1 / (1 + Lambda(wi) + Lambda(wo))`, with the same sidedness test.
    HeightCorrelated,
}

impl Distribution {
    pub fn name(&self) -> &'static str {
        match self {
            Distribution::Ggx => "ggx",
            Distribution::Beckmann => "beckmann",
        }
    }
}

impl Masking {
    pub fn name(&self) -> &'static str {
        match self {
            Masking::Separable => "separable",
            Masking::HeightCorrelated => "height-correlated",
        }
    }
}

/// A microfacet distribution with its masking function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Microfacet {
    distribution: Distribution,
    masking: Masking,
    alpha_x: f64,
    alpha_y: f64,
    /// 1 / alpha_x, 1 / alpha_y and 1 / (pi alpha_x alpha_y), derived once for the evaluation hot path.
    inv_alpha_x: f64,
    inv_alpha_y: f64,
    inv_pi_axay: f64,
}

/// What the pointwise microfacet reflection needs besides the Fresnel factor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LobeValue {
    /// `D(h) G / (4 cos theta_i cos theta_o)`, in 1/sr.
    pub value: f64,
    /// Cosine between the half vector and the directions, for the Fresnel factor: `(wi.h + wo.h) / 2`, written
    /// symmetrically so that swapping wi and wo gives the same bits.
    pub cos_d: f64,
}

impl Microfacet {
    /// A distribution with roughness `alpha_x`, `alpha_y`; each clamped to `>= ALPHA_MIN` (NaN -> ALPHA_MIN).
    pub fn new(distribution: Distribution, masking: Masking, alpha_x: f64, alpha_y: f64) -> Microfacet {
        let clamp = |a: f64| if a >= ALPHA_MIN { a } else { ALPHA_MIN };
        let (ax, ay) = (clamp(alpha_x), clamp(alpha_y));
        Microfacet {
            distribution,
            masking,
            alpha_x: ax,
            alpha_y: ay,
            inv_alpha_x: 1.0 / ax,
            inv_alpha_y: 1.0 / ay,
            inv_pi_axay: 1.0 / (PI * ax * ay),
        }
    }

    pub fn distribution(&self) -> Distribution {
        self.distribution
    }
    pub fn masking(&self) -> Masking {
        self.masking
    }
    /// Roughness along x, after clamping.
    pub fn alpha_x(&self) -> f64 {
        self.alpha_x
    }
    /// Roughness along y, after clamping.
    pub fn alpha_y(&self) -> f64 {
        self.alpha_y
    }

    pub fn is_isotropic(&self) -> bool {
        self.alpha_x == self.alpha_y
    }

    /// True when both alphas are below [`ALPHA_DELTA`]: the owner treats the lobe as a delta (module doc).
    pub fn is_delta(&self) -> bool {
        self.alpha_x < ALPHA_DELTA && self.alpha_y < ALPHA_DELTA
    }

    /// The normal distribution `D(m)` in 1/sr (normalised so that `integral D(m) cos(theta_m) dm = 1`);
    /// 0 for `m` at or below the horizon.
    pub fn d(&self, m: &Direction) -> f64 {
        self.d_xyz(m.x(), m.y(), m.z())
    }

    /// `D` of the unit vector (mx, my, mz), for callers that hold raw components.
    fn d_xyz(&self, mx: f64, my: f64, mz: f64) -> f64 {
        if mz <= 0.0 {
            return 0.0;
        }
        let (ax, ay) = (self.alpha_x, self.alpha_y);
        let ex = mx / ax;
        let ey = my / ay;
        match self.distribution {
            Distribution::Ggx => {
                // Cartesian form: no special case at the pole or near the horizon.
                let t = ex * ex + ey * ey + mz * mz;
                1.0 / (PI * ax * ay * t * t)
            }
            Distribution::Beckmann => {
                let mz2 = mz * mz;
                // tan^2(theta) (cos^2 phi / ax^2 + sin^2 phi / ay^2) = (x^2/ax^2 + y^2/ay^2) / z^2.
                let q = (ex * ex + ey * ey) / mz2;
                if q >= 745.0 {
                    // exp(-q) underflows to 0 while mz^4 may also underflow: return the limit, not 0/0.
                    return 0.0;
                }
                (-q).exp() / (PI * ax * ay * mz2 * mz2)
            }
        }
    }

    /// Smith `Lambda(w)`; infinite on the horizon, 0 at the pole.
    pub fn lambda(&self, w: &Direction) -> f64 {
        let z = w.z();
        // alpha(w)^2 tan^2(theta) = (ax^2 x^2 + ay^2 y^2) / z^2.
        let ax_x = self.alpha_x * w.x();
        let ay_y = self.alpha_y * w.y();
        let num = ax_x * ax_x + ay_y * ay_y;
        if num == 0.0 {
            return 0.0;
        }
        if z == 0.0 {
            return f64::INFINITY;
        }
        match self.distribution {
            Distribution::Ggx => {
                let a2t2 = num / (z * z);
                // (-1 + sqrt(1 + x)) / 2 written without cancellation for small x.
                if a2t2.is_infinite() {
                    return f64::INFINITY;
                }
                a2t2 / (2.0 * (1.0 + (1.0 + a2t2).sqrt()))
            }
            Distribution::Beckmann => {
                // a = 1 / (alpha(w) tan(theta)) = |z| / sqrt(ax^2 x^2 + ay^2 y^2).
                let a = z.abs() / num.sqrt();
                if a == 0.0 {
                    return f64::INFINITY;
                }
                // (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)), with erf(a) - 1 = -erfc(a) to keep digits; the
                // difference of two tiny positive terms can round below 0 for large a: clamp.
                let l = 0.5 * (-libm::erfc(a) + (-a * a).exp() / (a * PI.sqrt()));
                l.max(0.0)
            }
        }
    }

    /// Smith `G1(w, m)`: 0 when `w . m` and `cos theta_w` disagree in sign (or either is 0), else
    /// `1 / (1 + Lambda(w))`.
    pub fn g1(&self, w: &Direction, m: &Direction) -> f64 {
        if w.dot(m) * w.z() <= 0.0 {
            return 0.0;
        }
        1.0 / (1.0 + self.lambda(w))
    }

    /// Masking-shadowing `G(wi, wo, m)` of this model ([`Masking`]), with the sidedness test on both directions.
    pub fn g(&self, wi: &Direction, wo: &Direction, m: &Direction) -> f64 {
        self.g_dots(wi, wo, wi.dot(m), wo.dot(m))
    }

    /// `G` given the cosines `wi . m` and `wo . m` (for the sidedness test).
    fn g_dots(&self, wi: &Direction, wo: &Direction, wi_m: f64, wo_m: f64) -> f64 {
        if wi_m * wi.z() <= 0.0 || wo_m * wo.z() <= 0.0 {
            return 0.0;
        }
        let li = self.lambda(wi);
        let lo = self.lambda(wo);
        match self.masking {
            // Products and sums are commutative in IEEE arithmetic: swapping wi and wo gives the same bits.
            Masking::Separable => (1.0 / (1.0 + li)) * (1.0 / (1.0 + lo)),
            Masking::HeightCorrelated => 1.0 / (1.0 + (li + lo)),
        }
    }

    /// The Fresnel-free part of microfacet reflection, `D(h) G / (4 cos_i cos_o)`, and the cosine for the
    /// Fresnel factor. `None` when either direction is at or below the horizon (the BRDF is 0 there).
    pub fn lobe(&self, wi: &Direction, wo: &Direction) -> Option<LobeValue> {
        let (ci, co) = (wi.z(), wo.z());
        if ci <= 0.0 || co <= 0.0 {
            return None;
        }
        // The unnormalised half vector s = wi + wo. Sums and products of swapped operands give the same bits:
        // everything below is exactly reciprocal.
        let (sx, sy, sz) = (wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z());
        let l2 = sx * sx + sy * sy + sz * sz;
        if l2.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let len = l2.sqrt();
        // For unit wi, wo and h = (wi + wo)/|wi + wo|, wi . h = wo . h = |wi + wo| / 2 exactly. Computing the dot
        // products instead only adds rounding, and for nearly opposite directions on the horizon that rounding
        // (~1e-8) can exceed the true value and flip the sidedness test, making f jump between 0 and 1e11 under
        // a rotation about the normal. len / 2 is always positive and exactly reciprocal.
        let cos_d = (0.5 * len).min(1.0);
        let value = match self.distribution {
            Distribution::Ggx => {
                let (num, den) = self.ggx_ratio(wi, wo, sx, sy, sz, l2);
                num / den
            }
            Distribution::Beckmann => {
                let (hx, hy, hz) = (sx / len, sy / len, sz / len);
                let d = self.d_xyz(hx, hy, hz);
                if d == 0.0 {
                    return Some(LobeValue { value: 0.0, cos_d });
                }
                let g = self.g_dots(wi, wo, cos_d, cos_d);
                d * g / (4.0 * (ci * co))
            }
        };
        Some(LobeValue {
            value: if value.is_finite() { value } else { 0.0 },
            cos_d,
        })
    }

    /// For a GGX distribution and a pair above the horizon: the lobe as `(num, den, cos_d)` with
    /// `D(h) G / (4 ci co) = num / den` ([`Microfacet::ggx_ratio`]) and `cos_d` as in [`LobeValue`]; `None`
    /// otherwise (Beckmann, at or below the horizon, opposite directions).
    pub(crate) fn ggx_fraction(&self, wi: &Direction, wo: &Direction) -> Option<(f64, f64, f64)> {
        if self.distribution != Distribution::Ggx || wi.z() <= 0.0 || wo.z() <= 0.0 {
            return None;
        }
        let (sx, sy, sz) = (wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z());
        let l2 = sx * sx + sy * sy + sz * sz;
        if l2.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let cos_d = (0.5 * l2.sqrt()).min(1.0);
        let (num, den) = self.ggx_ratio(wi, wo, sx, sy, sz, l2);
        Some((num, den, cos_d))
    }

    /// The GGX lobe `D(h) G / (4 ci co)` as a ratio `num / den`, for a pair above the horizon with
    /// `s = wi + wo` and `l2 = |s|^2 > 0`; the hot path of `eval`, with no division (the conductor folds its
    /// Fresnel ratio into the same single division). The algebra is exact, only the rounding differs from the
    /// textbook form:
    /// - `D(h) = 1 / (pi ax ay t^2)`, `t = (hx/ax)^2 + (hy/ay)^2 + hz^2 = q / l2` with
    ///   `q = (sx/ax)^2 + (sy/ay)^2 + sz^2` (h = s / |s|);
    /// - Smith `G1(w) = 1 / (1 + Lambda(w)) = 2 cos / (cos + r)`, `r = sqrt(cos^2 + ax^2 x^2 + ay^2 y^2)`; the
    ///   sidedness test passes for every pair above the horizon (wi . h = wo . h = |s|/2 > 0);
    /// - separable: `D G / (4 ci co) = D / ((ci + ri)(co + ro))`; height-correlated:
    ///   `G = 1 / (1 + Lambda_i + Lambda_o) = 2 ci co / (ri co + ro ci)`, so `D G / (4 ci co) = D / (2 (ri co + ro ci))`.
    ///
    /// Sums and products of swapped operands give the same bits: the ratio is exactly reciprocal. Neither part
    /// underflows nor overflows when `l2 > 1e-100` (q >= l2 min(1, 1/alpha^2), l2 <= 4, q <= 4 / ALPHA_MIN^2);
    /// below that (both directions within 1e-50 of the horizon and opposite) the ratio is pre-divided.
    pub(crate) fn ggx_ratio(
        &self,
        wi: &Direction,
        wo: &Direction,
        sx: f64,
        sy: f64,
        sz: f64,
        l2: f64,
    ) -> (f64, f64) {
        let (ci, co) = (wi.z(), wo.z());
        let (ex, ey) = (sx * self.inv_alpha_x, sy * self.inv_alpha_y);
        let q = ex * ex + ey * ey + sz * sz;
        let ri = self.masking_root(wi);
        let ro = self.masking_root(wo);
        let den = match self.masking {
            Masking::Separable => (ci + ri) * (co + ro),
            Masking::HeightCorrelated => 2.0 * (ri * co + ro * ci),
        };
        if l2 > 1e-100 {
            (self.inv_pi_axay * (l2 * l2), (q * q) * den)
        } else {
            let r = l2 / q;
            (self.inv_pi_axay * r * r, den)
        }
    }

    /// `sqrt(z^2 + ax^2 x^2 + ay^2 y^2)` of a unit vector: `|z| sqrt(1 + alpha(w)^2 tan^2 theta)`, the root in the
    /// GGX Smith function written without a division.
    fn masking_root(&self, w: &Direction) -> f64 {
        let (ax, ay) = (self.alpha_x * w.x(), self.alpha_y * w.y());
        (w.z() * w.z() + ax * ax + ay * ay).sqrt()
    }

    /// `G(wi, mirror(wi), n)`: the fraction of the mirror reflection that survives masking and shadowing in the
    /// delta limit (module doc). 0 at or below the horizon.
    pub fn delta_masking(&self, wi: &Direction) -> f64 {
        if wi.z() <= 0.0 {
            return 0.0;
        }
        // Lambda depends on x^2, y^2 and z only: Lambda(mirror(wi)) = Lambda(wi).
        let l = self.lambda(wi);
        match self.masking {
            Masking::Separable => {
                let g1 = 1.0 / (1.0 + l);
                g1 * g1
            }
            Masking::HeightCorrelated => 1.0 / (1.0 + 2.0 * l),
        }
    }

    /// In the delta regime, the fraction of the delta lobe's power that a lobe of this (clamped) roughness puts
    /// inside a cone of half-angle `half_angle_rad` about the mirror direction of `wi`: what a finite detector
    /// aperture centred on the mirror direction collects of it (module doc, "the delta switch-over"); 0 for a
    /// non-positive angle, 1 for `wi` at or below the horizon (no lobe to spread).
    ///
    /// Paraxial (the lobe is narrower than 1e-3 rad): near the mirror direction, a tilt of the microfacet normal
    /// by a slope `m` turns the reflected ray by `2 m` in the plane of incidence and `2 m cos(theta_i)` across it,
    /// so the cone is the slope ellipse `m^T E m <= 1` with semi-axes `t = tan(half/2)` (in plane) and
    /// `t / cos(theta_i)` (across). For GGX, whose slopes follow `1 / (pi ax ay (1 + |A^-1 m|^2)^2)`,
    /// `A = diag(ax, ay)`, the mass inside is exactly `1 / sqrt(det(I + A E A))` (at normal incidence,
    /// `t^2 / (alpha^2 + t^2)`, the CDF of `theta_h`). For Beckmann it is `mean over phi of 1 - exp(-rho(phi)^2)`
    /// in the whitened slopes, by a 64-point periodic trapezoid. Against the aperture integral of a lobe just
    /// above the switch (alpha 1e-3, isotropic and 2:1 anisotropic, theta_i 0-80 deg, apertures 0.003-0.05 rad)
    /// this agrees to 4e-6; the delta alone puts all of it inside, 3.8% too much at alpha 1e-3 for the simulated
    /// instrument's 0.01 rad aperture.
    pub fn delta_cone_fraction(&self, wi: &Direction, half_angle_rad: f64) -> f64 {
        if wi.z() <= 0.0 {
            return 1.0;
        }
        if half_angle_rad.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return 0.0;
        }
        let t = (0.5 * half_angle_rad.min(PI)).tan();
        let c = wi.z().min(1.0);
        // The plane of incidence's direction in the sample plane (any, at the pole).
        let s = (wi.x() * wi.x() + wi.y() * wi.y()).sqrt();
        let (p, q) = if s > 0.0 {
            (wi.x() / s, wi.y() / s)
        } else {
            (1.0, 0.0)
        };
        // E = R diag(1/t^2, c^2/t^2) R^T in the sample frame, then Q = A E A.
        let (e1, e2) = (1.0 / (t * t), c * c / (t * t));
        let (exx, eyy, exy) = (
            e1 * p * p + e2 * q * q,
            e1 * q * q + e2 * p * p,
            (e1 - e2) * p * q,
        );
        let (ax, ay) = (self.alpha_x, self.alpha_y);
        let (qxx, qyy, qxy) = (ax * ax * exx, ay * ay * eyy, ax * ay * exy);
        match self.distribution {
            Distribution::Ggx => {
                let det = (1.0 + qxx) * (1.0 + qyy) - qxy * qxy;
                (1.0 / det.sqrt()).clamp(0.0, 1.0)
            }
            Distribution::Beckmann => {
                // Whitened slopes u = A^-1 m are Gaussian with density exp(-|u|^2) / pi; the ellipse is
                // u^T Q u <= 1, of radius rho(phi)^2 = 1 / (u_phi^T Q u_phi) along the unit vector u_phi.
                const N: usize = 64;
                let mut sum = 0.0;
                for k in 0..N {
                    let (sp, cp) = (2.0 * PI * k as f64 / N as f64).sin_cos();
                    let quad = qxx * cp * cp + 2.0 * qxy * cp * sp + qyy * sp * sp;
                    sum += -(-1.0 / quad).exp_m1();
                }
                (sum / N as f64).clamp(0.0, 1.0)
            }
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    fn mf(d: Distribution, ax: f64, ay: f64) -> Microfacet {
        Microfacet::new(d, Masking::Separable, ax, ay)
    }

    #[test]
    fn beckmann_cartesian_form_matches_the_angular_formula() {
        let m = mf(Distribution::Beckmann, 0.3, 0.15);
        for &(theta, phi) in &[(0.2, 0.3), (0.7, -1.2), (1.2, 2.5)] {
            let w = Direction::from_spherical(theta, phi);
            let t2 = f64::tan(theta).powi(2);
            let e = t2 * (phi.cos().powi(2) / 0.09 + phi.sin().powi(2) / 0.0225);
            let expect = (-e).exp() / (PI * 0.3 * 0.15 * theta.cos().powi(4));
            assert!(
                (m.d(&w) - expect).abs() <= 1e-12 * expect,
                "{} vs {expect}",
                m.d(&w)
            );
        }
    }

    #[test]
    fn lambda_matches_the_reference_formulas() {
        for &(theta, phi) in &[(0.2f64, 0.3f64), (0.9, -1.2), (1.5, 2.5)] {
            let w = Direction::from_spherical(theta, phi);
            let alpha2 = 0.4f64.powi(2) * phi.cos().powi(2) + 0.1f64.powi(2) * phi.sin().powi(2);
            let ggx = mf(Distribution::Ggx, 0.4, 0.1).lambda(&w);
            let expect_ggx = (-1.0 + (1.0 + alpha2 * theta.tan().powi(2)).sqrt()) / 2.0;
            assert!(
                (ggx - expect_ggx).abs() <= 1e-13 * expect_ggx.max(1e-3),
                "{ggx} vs {expect_ggx}"
            );
            let a = 1.0 / (alpha2.sqrt() * theta.tan());
            let expect_b = (libm::erf(a) - 1.0) / 2.0 + (-a * a).exp() / (2.0 * a * PI.sqrt());
            let b = mf(Distribution::Beckmann, 0.4, 0.1).lambda(&w);
            assert!((b - expect_b).abs() <= 1e-13, "{b} vs {expect_b}");
        }
    }

    #[test]
    fn lambda_limits_at_pole_and_horizon() {
        for d in [Distribution::Ggx, Distribution::Beckmann] {
            let m = mf(d, 0.2, 0.2);
            assert_eq!(m.lambda(&Direction::NORMAL), 0.0);
            assert_eq!(
                m.lambda(&Direction::from_spherical_deg(90.0, 10.0)),
                f64::INFINITY
            );
            assert_eq!(
                m.g1(&Direction::from_spherical_deg(90.0, 10.0), &Direction::NORMAL),
                0.0
            );
            let near = Direction::from_spherical(std::f64::consts::FRAC_PI_2 - 1e-9, 0.3);
            let l = m.lambda(&near);
            assert!(l.is_finite() && l > 0.0);
        }
    }

    /// The GGX hot path of `lobe` (unnormalised half vector, division-free Smith roots) against the textbook
    /// `D(h) G(wi, wo, h) / (4 cos_i cos_o)` built from `d` and `g`, over random pairs, roughnesses from the
    /// clamp to 1, anisotropy and both maskings; and exactly reciprocal.
    #[test]
    fn ggx_lobe_matches_the_textbook_form() {
        let mut s: u64 = 3;
        let mut unit = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst: f64 = 0.0;
        for &(ax, ay) in &[
            (1e-4, 1e-4),
            (0.003, 0.003),
            (0.08, 0.08),
            (0.3, 0.05),
            (1.0, 1.0),
            (0.5, 0.9),
        ] {
            for masking in [Masking::Separable, Masking::HeightCorrelated] {
                let m = Microfacet::new(Distribution::Ggx, masking, ax, ay);
                for _ in 0..2000 {
                    let wi = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                    let wo = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                    let Some(h) = Direction::new(wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z()) else {
                        continue;
                    };
                    let expect = m.d(&h) * m.g(&wi, &wo, &h) / (4.0 * wi.z() * wo.z());
                    let got = m.lobe(&wi, &wo).expect("above the horizon").value;
                    let back = m.lobe(&wo, &wi).expect("above the horizon").value;
                    assert_eq!(got.to_bits(), back.to_bits(), "reciprocity");
                    if expect.is_finite() && expect > 1e-300 {
                        worst = worst.max((got - expect).abs() / expect);
                    }
                }
            }
        }
        assert!(worst <= 1e-12, "largest relative difference {worst:e}");
    }

    /// The rough conductor's fused GGX path (Fresnel and lobe as one ratio) against the Fresnel factor times
    /// `lobe`, and reciprocal bit for bit.
    #[test]
    fn fused_ggx_conductor_equals_fresnel_times_lobe() {
        use crate::brdf::Brdf;
        use crate::fresnel;
        use crate::models::Conductor;
        use crate::spectrum::{Spectral, Wavelength};
        let wl = Wavelength::DEFAULT;
        let mut s: u64 = 5;
        let mut unit = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst: f64 = 0.0;
        for &(ax, ay, eta, k) in &[
            (0.08, 0.08, 0.35, 2.714),
            (0.3, 0.05, 1.5, 0.0),
            (1.0, 1.0, 0.05, 20.0),
        ] {
            for masking in [Masking::Separable, Masking::HeightCorrelated] {
                let c = Conductor::new(
                    Distribution::Ggx,
                    masking,
                    ax,
                    ay,
                    Spectral::Constant(eta),
                    Spectral::Constant(k),
                )
                .expect("valid");
                for _ in 0..2000 {
                    let wi = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                    let wo = Direction::from_spherical(unit() * 1.57, unit() * 6.3);
                    let got = c.eval(&wi, &wo, wl).expect("constant");
                    assert_eq!(got.to_bits(), c.eval(&wo, &wi, wl).expect("constant").to_bits());
                    let l = c.microfacet().lobe(&wi, &wo).expect("above the horizon");
                    let expect = fresnel::conductor(l.cos_d, eta, k) * l.value;
                    if expect > 1e-300 {
                        worst = worst.max((got - expect).abs() / expect);
                    }
                }
            }
        }
        assert!(worst <= 1e-13, "largest relative difference {worst:e}");
    }

    /// `delta_cone_fraction` against the aperture integral of the (Fresnel-free) lobe just above the switch,
    /// divided by the delta lobe's masking: what a detector cone about the mirror direction collects.
    #[test]
    fn delta_cone_fraction_matches_the_lobe_just_above_the_switch() {
        use crate::integrate::{Region, Rule, Tolerance, integrate_adaptive};
        for distribution in [Distribution::Ggx, Distribution::Beckmann] {
            for &(ax, ay, theta_deg, phi_deg, beta) in &[
                (1.0, 1.0, 0.0, 0.0, 0.01),
                (1.0, 1.0, 60.0, 20.0, 0.01),
                (1.0, 0.5, 80.0, 30.0, 0.003),
                (1.0, 0.5, 30.0, 90.0, 0.05),
            ] {
                let above = Microfacet::new(
                    distribution,
                    Masking::HeightCorrelated,
                    ALPHA_DELTA * ax * (1.0 + 1e-9),
                    ALPHA_DELTA * ay * (1.0 + 1e-9),
                );
                let wi = Direction::from_spherical_deg(theta_deg, phi_deg);
                let mirror = wi.reflect_about_normal();
                let cone = integrate_adaptive(
                    |w: &Direction| -> Result<f64, ()> {
                        Ok(above.lobe(&wi, w).map_or(0.0, |l| l.value) * w.z().max(0.0))
                    },
                    &Region::cone(mirror, beta),
                    Rule::LobeAdapted {
                        lobe_width_rad: ALPHA_DELTA,
                        n_per_panel: 8,
                        n_azimuth: 16,
                    },
                    Tolerance::relative(1e-9),
                )
                .expect("no error");
                let collected = cone.value / above.delta_masking(&wi);
                let predicted = above.delta_cone_fraction(&wi, beta);
                assert!(
                    (collected - predicted).abs() < 1e-5,
                    "{distribution:?} ({ax}, {ay}) theta {theta_deg} phi {phi_deg} beta {beta}: lobe {collected} vs {predicted}"
                );
            }
        }
        let m = Microfacet::new(Distribution::Ggx, Masking::Separable, 1e-3, 1e-3);
        // Normal incidence: the GGX CDF of theta_h, exactly.
        let t2 = (0.005f64).tan().powi(2);
        assert!((m.delta_cone_fraction(&Direction::NORMAL, 0.01) - t2 / (1e-6 + t2)).abs() < 1e-15);
        assert_eq!(m.delta_cone_fraction(&Direction::NORMAL, 0.0), 0.0);
        assert_eq!(
            m.delta_cone_fraction(&Direction::from_spherical_deg(90.0, 0.0), 0.01),
            1.0
        );
    }

    #[test]
    fn alpha_is_clamped_and_delta_switch_needs_both() {
        let m = mf(Distribution::Ggx, 0.0, f64::NAN);
        assert_eq!((m.alpha_x(), m.alpha_y()), (ALPHA_MIN, ALPHA_MIN));
        assert!(m.is_delta());
        assert!(!mf(Distribution::Ggx, 5e-4, 2e-3).is_delta());
        assert!(!mf(Distribution::Ggx, 1e-3, 1e-3).is_delta());
    }
}
