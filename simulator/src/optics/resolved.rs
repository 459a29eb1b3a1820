//! The sample's material as the optics uses it: resolved once per band at its centre wavelength and cached,
//! classified by what is known about its regular part (for the integration strategy), and seen in its own frame
//! (the sample's orientation about the normal).

use gonio_brdf::material::Material;
use gonio_brdf::{Direction, Wavelength};

use super::{Optics, OpticsError};

/// What is known about the regular (non-delta) part of a resolved material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum RegularPart {
    /// Identically zero (ideal mirror, conductor in the delta regime).
    Zero,
    /// Constant over the upper hemisphere (Lambertian).
    Flat,
    /// Smooth (analytic) above the horizon: microfacet models.
    Smooth,
    /// Smooth except on known kink loci, where the tensor rules converge erratically.
    Kinked(Kinks),
    /// Piecewise interpolated data: kinks everywhere.
    Tabulated,
}

/// Where a model's value has a kink (a jump in its first derivative).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Kinks {
    /// Oren-Nayar: `max(0, cos(phi_o - phi_i))` and `max(cos theta_i, cos theta_o)`, i.e. the vertical plane
    /// perpendicular to wi's azimuth and the cone theta_o = theta_i.
    OrenNayar,
    /// Phong: `max(0, wo . reflect(wi))^n`, the plane perpendicular to the mirror direction.
    Phong,
}

#[derive(Debug)]
pub(super) struct Resolved {
    pub(super) band_nm: f64,
    pub(super) wavelength: Wavelength,
    pub(super) material: Material,
    pub(super) regular: RegularPart,
}

impl Optics {
    /// A sample-frame direction in the material's own frame (rotated by -orientation about the normal).
    pub(super) fn to_material(&self, w: &Direction) -> Direction {
        if self.isotropic {
            return *w;
        }
        let (c, s) = self.orientation;
        Direction::new(c * w.x() + s * w.y(), -s * w.x() + c * w.y(), w.z()).unwrap_or(*w)
    }

    /// The material resolved at a band's centre wavelength, cached.
    pub(super) fn resolved(&self, band_nm: f64) -> Result<std::sync::Arc<Resolved>, OpticsError> {
        let find = |v: &Vec<std::sync::Arc<Resolved>>| v.iter().find(|r| r.band_nm == band_nm).cloned();
        if let Some(r) = self.bands.read().ok().as_deref().and_then(find) {
            return Ok(r);
        }
        let err = |source| OpticsError::Spectrum { band_nm, source };
        let wavelength = Wavelength::from_nm(band_nm).map_err(err)?;
        let material = self.material.at_wavelength(wavelength).map_err(err)?;
        let regular = regular_part(&material);
        let r = std::sync::Arc::new(Resolved {
            band_nm,
            wavelength,
            material,
            regular,
        });
        if let Ok(mut v) = self.bands.write() {
            if let Some(existing) = find(&v) {
                return Ok(existing);
            }
            v.push(r.clone());
        }
        Ok(r)
    }
}

fn regular_part(material: &Material) -> RegularPart {
    match material {
        Material::Lambertian(_) => RegularPart::Flat,
        Material::Mirror(_) => RegularPart::Zero,
        Material::Conductor(c) if c.microfacet().is_delta() => RegularPart::Zero,
        Material::Conductor(_) | Material::Plastic(_) => RegularPart::Smooth,
        Material::OrenNayar(_) => RegularPart::Kinked(Kinks::OrenNayar),
        Material::Phong(_) => RegularPart::Kinked(Kinks::Phong),
        Material::Measured(_) => RegularPart::Tabulated,
    }
}
