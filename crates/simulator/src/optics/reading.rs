//! One reading, split where the time enters: everything a pose and a band decide with the axes and the wheel at
//! rest (geometry, retro-blocking, the direct beam or the footprint and the collected aperture integral), then
//! the source at each instant (drift, noise). Kept apart from the aperture integration so that what happens
//! between the source and the photodiode (the beam on the sample, light reaching the detector, the detector
//! itself) has one place to grow.

use gonio_brdf::Brdf;

use crate::kinematics;
use crate::scene::{Band, Pose, Scene};

use super::imperfect::Geometry;
use super::{OpticalReading, Optics, OpticsError, cap};

/// A reading without its instant: [`Optics::at_rest`].
#[derive(Debug, Clone, Copy)]
struct AtRest {
    /// The reading's time-independent fields (the powers are filled in per instant).
    out: OpticalReading,
    /// Filter transmission (0 at the blank).
    transmission: f64,
    light: Light,
}

/// How the source's power reaches the detector at a pose at rest.
#[derive(Debug, Clone, Copy)]
enum Light {
    /// Blank, no band, or the beam blocked by the detector's body.
    Dark,
    /// No sample: this fraction of the beam enters the aperture.
    DirectBeam { fraction: f64 },
    /// Off the sample: the intercepted fraction times the collected aperture integral (delta lobe included).
    Sample {
        intercepted: f64,
        collected: f64,
        integral_error: f64,
    },
}

impl Optics {
    /// One reading: the pose's geometry, the footprint, the aperture integral and the source at time `t_s`.
    pub fn reading(&self, pose: &Pose, band: &Band, t_s: f64) -> Result<OpticalReading, OpticsError> {
        Ok(self.at_time(&self.at_rest(pose, band)?, t_s))
    }

    /// Everything of a reading that does not depend on time: with the axes and the wheel at rest, the averaged
    /// samples of one meter reading differ only by the source (drift, noise), not by this.
    fn at_rest(&self, pose: &Pose, band: &Band) -> Result<AtRest, OpticsError> {
        let g = self.geometry_of(pose);
        let Geometry {
            pose: geometry,
            detector_arm_lab,
            spot_mm,
            ..
        } = g;
        let blocked = geometry.arm_separation_rad() < self.retro_block_rad;
        let mirror = geometry.wi.reflect_about_normal();
        let specular_in_aperture =
            geometry.wi.z() > 0.0 && mirror.angle_to(&geometry.wo) <= self.aperture_half_rad;
        let transmission = if band.band_nm.is_some() {
            band.transmission.max(0.0)
        } else {
            0.0
        };
        let mut out = OpticalReading {
            power_w: 0.0,
            noiseless_power_w: 0.0,
            integration_error_w: 0.0,
            incident_power_w: 0.0,
            intercepted_fraction: 0.0,
            truth_point_sr: 0.0,
            truth_aperture_sr: 0.0,
            wi: geometry.wi,
            wo: geometry.wo,
            spot_mm,
            overfilled_sample: false,
            overfilled_field: false,
            beam_blocked_by_detector: blocked,
            specular_in_aperture,
            evaluations: 0,
        };
        let (Some(nm), true) = (band.band_nm, band.transmission > 0.0) else {
            return Ok(AtRest {
                out,
                transmission,
                light: Light::Dark,
            });
        };
        if !self.sample_mounted() {
            // No sample: the detector sees the beam itself when it faces the source, nothing otherwise.
            let off_axis = kinematics::angle_between(&detector_arm_lab, &neg(&geometry.source_lab));
            let fraction = cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, off_axis);
            out.intercepted_fraction = fraction;
            return Ok(AtRest {
                out,
                transmission,
                light: Light::DirectBeam { fraction },
            });
        }
        let r = self.resolved(nm)?;
        let fp = self.footprint_of(&g);
        out.intercepted_fraction = fp.intercepted_fraction;
        out.overfilled_sample = fp.overfilled_sample;
        out.overfilled_field = fp.overfilled_field;
        let (wi_m, wo_m) = (self.to_material(&geometry.wi), self.to_material(&geometry.wo));
        out.truth_point_sr = r
            .material
            .eval(&wi_m, &wo_m, r.wavelength)
            .map_err(|source| OpticsError::Spectrum { band_nm: nm, source })?;
        let truth = self.aperture_truth(&r, &geometry.wi, &geometry.wo)?;
        out.truth_aperture_sr = truth.average_sr;
        out.evaluations = truth.evaluations;
        let light = if blocked {
            Light::Dark
        } else {
            Light::Sample {
                intercepted: fp.intercepted_fraction,
                collected: truth.integral + truth.delta,
                integral_error: truth.integral_error,
            }
        };
        Ok(AtRest {
            out,
            transmission,
            light,
        })
    }

    /// A reading at rest completed with the source at time `t_s`.
    fn at_time(&self, rest: &AtRest, t_s: f64) -> OpticalReading {
        // The source at this instant, computed once: drifted power and noise factor (exactly 1 when off).
        let drifted_w = self.source.drifted_power_w(t_s);
        let noise = self.source.noise_factor(t_s);
        let transmission = rest.transmission;
        let mut out = rest.out;
        out.incident_power_w = drifted_w * transmission * noise;
        match rest.light {
            Light::Dark => {}
            Light::DirectBeam { fraction } => {
                out.noiseless_power_w = drifted_w * transmission * fraction;
                out.power_w = out.incident_power_w * fraction;
            }
            Light::Sample {
                intercepted,
                collected,
                integral_error,
            } => {
                let on_sample = drifted_w * transmission * intercepted;
                out.noiseless_power_w = (on_sample * collected).max(0.0);
                out.power_w = (out.noiseless_power_w * noise).max(0.0);
                out.integration_error_w = on_sample * integral_error;
            }
        }
        out
    }
}

fn neg(v: &[f64; 3]) -> [f64; 3] {
    [-v[0], -v[1], -v[2]]
}

impl Scene for Optics {
    /// The reading's `power_w`; 0 (with a warning) if the material cannot be evaluated at the band.
    fn detector_power_w(&self, pose: &Pose, band: &Band, t_s: f64) -> f64 {
        match self.reading(pose, band, t_s) {
            Ok(r) if r.power_w.is_finite() => r.power_w,
            Ok(_) => 0.0,
            Err(e) => {
                tracing::warn!(error = %e, "optics cannot evaluate the sample; reporting no light");
                0.0
            }
        }
    }

    /// The geometry once, the source at each instant; values as [`Scene::detector_power_w`] gives them.
    fn detector_power_series_w(&self, pose: &Pose, band: &Band, times_s: &[f64], out: &mut Vec<f64>) {
        out.clear();
        match self.at_rest(pose, band) {
            Ok(rest) => out.extend(times_s.iter().map(|&t| {
                let p = self.at_time(&rest, t).power_w;
                if p.is_finite() { p } else { 0.0 }
            })),
            Err(e) => {
                tracing::warn!(error = %e, "optics cannot evaluate the sample; reporting no light");
                out.resize(times_s.len(), 0.0);
            }
        }
    }
}
