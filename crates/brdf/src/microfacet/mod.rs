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
//!   tests/stress/energy.rs, `alpha_clamp_and_delta_switch_are_continuous_in_reflected_power`).
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
//!   simulator's optics (simulator/src/optics/truth.rs, `aperture_truth`) does NOT do so yet: it puts
//!   the whole delta inside (spread only by the source's divergence), so its reading at the mirror direction
//!   still jumps by the GGX tail fraction above (3.8% at alpha 1e-3 for its 0.01 rad aperture; 4e-4 at the
//!   1e-4 clamp). Off the mirror direction the two sides also differ in how the source's divergence enters
//!   (the lobe side ignores it), so a fully continuous switch would need the same divergence treatment on
//!   both sides.
//! - The switch needs both alphas below the threshold: a lobe that is narrow in one direction only stays a lobe.

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use crate::brdf::DirectionSample;
use crate::geometry::Direction;

mod delta;
mod sampling;

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
}

#[cfg(test)]
mod tests;
