//! Normalised (energy-conserving, reciprocal) Phong:
//! `f = rho_d / pi + rho_s (n + 2) / (2 pi) max(0, dot(wo, reflect(wi)))^n`,
//! where `reflect(wi)` is the mirror direction of `wi` about the normal. With `rho_d + rho_s <= 1` the directional
//! albedo is <= 1 (the specular lobe's albedo is at most rho_s, reached at normal incidence).
//! `dot(wo, reflect(wi)) = z_i z_o - (x_i x_o + y_i y_o)` is symmetric in wi and wo, so the model is reciprocal.

use std::f64::consts::PI;

use crate::brdf::{Brdf, DirectionSample};
use crate::geometry::Direction;
use crate::models::{ParamError, check_range, choose, pdf_cosine, sample_cosine};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

/// Largest accepted exponent (a lobe about 1.4 milliradian wide).
pub const EXPONENT_MAX: f64 = 1e6;

#[derive(Debug, Clone, PartialEq)]
pub struct Phong {
    diffuse: Spectral,
    specular: Spectral,
    exponent: f64,
}

impl Phong {
    /// `diffuse`, `specular` in [0, 1] with `diffuse + specular <= 1` at every wavelength; `exponent` in
    /// [0, 1e6].
    pub fn new(diffuse: Spectral, specular: Spectral, exponent: f64) -> Result<Phong, ParamError> {
        check_range("diffuse", &diffuse, 0.0, 1.0, "diffuse reflectance")?;
        check_range("specular", &specular, 0.0, 1.0, "specular reflectance")?;
        if !(0.0..=EXPONENT_MAX).contains(&exponent) {
            return Err(ParamError::new(
                "exponent",
                format!("exponent must be in [0, {EXPONENT_MAX}], got {exponent}"),
            ));
        }
        // The sum is piecewise linear between the union of both tables' nodes: checking every node suffices.
        let mut nodes: Vec<f64> = Vec::new();
        for s in [&diffuse, &specular] {
            if let Spectral::Table(t) = s {
                nodes.extend(t.iter().map(|&(nm, _)| nm));
            }
        }
        if nodes.is_empty() {
            nodes.push(crate::spectrum::Wavelength::DEFAULT.nm());
        }
        for nm in nodes {
            let Ok(wl) = Wavelength::from_nm(nm) else { continue };
            // Outside either table's range the sum is undefined (evaluation there is an error anyway).
            if let (Ok(d), Ok(s)) = (diffuse.at(wl), specular.at(wl))
                && d + s > 1.0 + 1e-12
            {
                return Err(ParamError::new(
                    "specular",
                    format!(
                        "diffuse + specular must be <= 1 for energy conservation, got {d} + {s} = {} at {nm} nm",
                        d + s
                    ),
                ));
            }
        }
        Ok(Phong {
            diffuse,
            specular,
            exponent,
        })
    }

    pub fn diffuse(&self) -> &Spectral {
        &self.diffuse
    }
    pub fn specular(&self) -> &Spectral {
        &self.specular
    }
    pub fn exponent(&self) -> f64 {
        self.exponent
    }

    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Phong, SpectrumError> {
        Ok(Phong {
            diffuse: self.diffuse.resolved(wavelength)?,
            specular: self.specular.resolved(wavelength)?,
            exponent: self.exponent,
        })
    }

    /// The specular lobe's shape `(n + 2)/(2 pi) cos^n` at cosine `c` to the mirror direction (0 for c <= 0).
    fn lobe(&self, c: f64) -> f64 {
        if c <= 0.0 {
            return 0.0;
        }
        (self.exponent + 2.0) / (2.0 * PI) * c.min(1.0).powf(self.exponent)
    }
}

impl Brdf for Phong {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        let rd = self.diffuse.at(wavelength)?;
        let rs = self.specular.at(wavelength)?;
        if wi.z() <= 0.0 || wo.z() <= 0.0 {
            return Ok(0.0);
        }
        let c = wi.z() * wo.z() - (wi.x() * wo.x() + wi.y() * wo.y());
        Ok(rd / PI + rs * self.lobe(c))
    }

    fn is_isotropic(&self) -> bool {
        true
    }

    fn is_spectrally_flat(&self) -> bool {
        self.diffuse.is_constant() && self.specular.is_constant()
    }

    /// A mixture of cosine sampling (for the diffuse part) and sampling of the lobe with density
    /// `(n + 1)/(2 pi) cos^n` of the angle to `reflect(wi)`; the mixture weight follows the two reflectances.
    /// The returned density is the mixture's. Lobe samples may fall below the horizon, where `eval` is 0.
    fn sample(
        &self,
        wi: &Direction,
        u: [f64; 2],
        wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        let rd = self.diffuse.at(wavelength)?;
        let rs = self.specular.at(wavelength)?;
        let p_spec = if rd + rs > 0.0 {
            (rs / (rd + rs)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let r = wi.reflect_about_normal();
        let (spec, u0) = choose(u[0], p_spec);
        let wo = if spec {
            // cos(angle to r) = u^(1/(n+1)).
            let cos_a = u0.powf(1.0 / (self.exponent + 1.0));
            let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
            let phi = 2.0 * PI * u[1];
            let (t1, t2) = orthonormal_basis(&r);
            let v = [
                sin_a * phi.cos() * t1[0] + sin_a * phi.sin() * t2[0] + cos_a * r.x(),
                sin_a * phi.cos() * t1[1] + sin_a * phi.sin() * t2[1] + cos_a * r.y(),
                sin_a * phi.cos() * t1[2] + sin_a * phi.sin() * t2[2] + cos_a * r.z(),
            ];
            Direction::new(v[0], v[1], v[2]).unwrap_or(r)
        } else {
            sample_cosine([u0, u[1]]).wo
        };
        let c = wo.dot(&r);
        let pdf_lobe = if c > 0.0 {
            (self.exponent + 1.0) / (2.0 * PI) * c.min(1.0).powf(self.exponent)
        } else {
            0.0
        };
        let pdf = p_spec * pdf_lobe + (1.0 - p_spec) * pdf_cosine(&wo);
        Ok(Some(DirectionSample {
            wo,
            pdf_per_sr: if pdf > 0.0 { pdf } else { f64::MIN_POSITIVE },
        }))
    }

    /// The angle at which the lobe falls to about 1/e of its peak: `sqrt(2 / (n + 2))` radians, for
    /// exponents large enough to make a lobe (n >= 1).
    fn lobe_width(&self) -> Option<f64> {
        (self.exponent >= 1.0).then(|| (2.0 / (self.exponent + 2.0)).sqrt())
    }
}

/// Two unit vectors completing `n` to an orthonormal basis (Duff et al. 2017, branch-free up to the sign).
fn orthonormal_basis(n: &Direction) -> ([f64; 3], [f64; 3]) {
    let sign = 1.0f64.copysign(n.z());
    let a = -1.0 / (sign + n.z());
    let b = n.x() * n.y() * a;
    (
        [1.0 + sign * n.x() * n.x() * a, sign * b, -sign * n.x()],
        [b, sign + n.y() * n.y() * a, -n.y()],
    )
}
