//! The ground truth and the aperture integral behind a reading's power, in the material's frame: the point value
//! `f(wi, wo)`, and the regular part integrated over the detector's aperture cone plus the delta lobe's share
//! (the divergence cone inside the aperture, [`super::cap`]; with the true beam too, crate::imperfections::beam).

use gonio_brdf::{Brdf, Direction, Wavelength};

use super::aperture::{self, Cone, ConeIntegral, Features, Plan};
use super::resolved::{RegularPart, Resolved};
use super::{ApertureTruth, Optics, OpticsError};

impl Optics {
    /// f(wi, wo) at a band's centre wavelength, regular part (1/sr): the point ground truth for validation grids.
    /// Directions are in the sample frame.
    pub fn truth(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, OpticsError> {
        let r = self.resolved(wavelength.nm())?;
        let (wi_m, wo_m) = (self.to_material(wi), self.to_material(wo));
        r.material
            .eval(&wi_m, &wo_m, r.wavelength)
            .map_err(|source| OpticsError::Spectrum {
                band_nm: r.band_nm,
                source,
            })
    }

    /// The aperture-averaged ground truth for the detector centred on `wo` (sample frame), as a reading would
    /// report it with the beam fully intercepted.
    pub fn truth_aperture(
        &self,
        wi: &Direction,
        wo: &Direction,
        wavelength: Wavelength,
    ) -> Result<ApertureTruth, OpticsError> {
        let r = self.resolved(wavelength.nm())?;
        self.aperture_truth(&r, wi, wo)
    }

    /// The regular aperture integral and the delta lobe, in the material's frame.
    pub(super) fn aperture_truth(
        &self,
        r: &Resolved,
        wi: &Direction,
        wo: &Direction,
    ) -> Result<ApertureTruth, OpticsError> {
        let (wi_m, wo_m) = (self.to_material(wi), self.to_material(wo));
        let cone = Cone::new(wo_m, self.aperture_half_rad);
        let err = |source| OpticsError::Spectrum {
            band_nm: r.band_nm,
            source,
        };
        let integral = if wi_m.z() <= 0.0 || r.regular == RegularPart::Zero {
            ConeIntegral {
                value: 0.0,
                error: 0.0,
                evaluations: 0,
            }
        } else {
            // Constant over the upper hemisphere (Lambertian): one evaluation at a direction above the horizon
            // times the exact projected solid angle of the cone, clipped to the upper hemisphere if the cone
            // crosses the horizon (then with an error estimate of its own).
            let (plan, features) = if r.regular == RegularPart::Flat {
                (Plan::Flat, Features::default())
            } else {
                self.plan(r.regular, &wi_m, &cone)
            };
            let mut failure = None;
            let mut f = |w: &Direction| match r.material.eval(&wi_m, w, r.wavelength) {
                Ok(v) => v,
                Err(e) => {
                    failure = Some(e);
                    0.0
                }
            };
            let result = aperture::integrate(&cone, &mut f, plan, &features, self.tolerance);
            if let Some(e) = failure {
                return Err(err(e));
            }
            result
        };
        let (delta, delta_beam) = match r.material.delta_lobe(&wi_m, r.wavelength).map_err(err)? {
            Some(lobe) if wi_m.z() > 0.0 => {
                let g = wi_m.reflect_about_normal().angle_to(&wo_m);
                let nominal = lobe.reflectance * self.lobe_fraction(g, true);
                // The true beam's share (crate::imperfections::beam); the same value when it is ideal.
                let true_beam = if self.beam.is_some() {
                    lobe.reflectance * self.lobe_fraction(g, false)
                } else {
                    nominal
                };
                (nominal, true_beam)
            }
            _ => (0.0, 0.0),
        };
        let denominator = self.aperture_sr * wo_m.z();
        let average_sr = if wo_m.z() > 0.0 {
            (integral.value + delta) / denominator
        } else {
            0.0
        };
        Ok(ApertureTruth {
            integral: integral.value,
            integral_error: integral.error,
            delta,
            delta_beam,
            average_sr,
            evaluations: integral.evaluations,
        })
    }
}
