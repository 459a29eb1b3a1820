//! One reading, split where the time enters: everything a pose and a band decide with the axes and the wheel at
//! rest (geometry, retro-blocking, the direct beam or the footprint and the collected aperture integral), then
//! the source at each instant (drift, noise). Kept apart from the aperture integration so that what happens
//! between the source and the photodiode (the beam on the sample, light reaching the detector, the detector
//! itself) has one place to grow.

use gonio_brdf::Brdf;

use crate::kinematics;
use crate::scene::{Band, Pose, Scene};

use super::geometry::Geometry;
use super::{OpticalReading, Optics, OpticsError};

/// A reading without its instant: [`Optics::at_rest`].
#[derive(Debug, Clone, Copy)]
struct AtRest {
    /// The reading's time-independent fields (the powers are filled in per instant).
    out: OpticalReading,
    /// Filter transmission (0 at the blank).
    transmission: f64,
    light: Light,
    /// Fraction of the beam reaching the detector by other paths (the instrument signature; 0 on the ideal
    /// instrument, with the filter closed, or with the beam blocked).
    stray_fraction: f64,
    /// A finite band's factor on the light (crate::optics::spectral) and its total weight `∫ W`, the factor on
    /// spectrally flat light; both 1 for a single wavelength.
    filter_factor: f64,
    filter_total: f64,
    /// Relative change of the light by the beam's profile and true divergence (crate::imperfections::beam;
    /// 0 with the ideal beam).
    beam_rel: f64,
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
        // The detector head blocks the beam when its arm is near the source's: the arms' directions, not the
        // viewing direction from the beam's spot (with the holder empty and the beam grazing the sample's plane,
        // that spot is far away and the direction from it means nothing).
        let blocked =
            kinematics::angle_between(&geometry.source_lab, &detector_arm_lab) < self.retro_block_rad;
        let mirror = geometry.wi.reflect_about_normal();
        let specular_in_aperture =
            geometry.wi.z() > 0.0 && mirror.angle_to(&geometry.wo) <= self.aperture_half_rad;
        // A finite band (crate::imperfections::filters) passes its total weight `∫ W` of the single wavelength's
        // power: part of the filter's transmission.
        let spectral = band.band_nm.and_then(|nm| self.spectral_band(nm));
        let filter_total = spectral.map_or(1.0, |b| b.total);
        let transmission = if band.band_nm.is_some() {
            band.transmission.max(0.0) * filter_total
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
            stray_power_w: 0.0,
            sample_factor: 1.0,
        };
        let stray_fraction = if band.band_nm.is_some() && transmission > 0.0 && !blocked {
            self.stray_fraction(&detector_arm_lab, &geometry.source_lab)
        } else {
            0.0
        };
        let (Some(nm), true) = (band.band_nm, band.transmission > 0.0) else {
            return Ok(AtRest {
                out,
                transmission,
                light: Light::Dark,
                stray_fraction,
                filter_factor: filter_total,
                filter_total,
                beam_rel: 0.0,
            });
        };
        if !self.sample_mounted() {
            // No sample: the detector sees the beam itself when it faces the source, nothing otherwise.
            let off_axis = kinematics::angle_between(&detector_arm_lab, &neg(&geometry.source_lab));
            let (fraction, nominal) = self.direct_fraction(&g, off_axis);
            out.intercepted_fraction = fraction;
            return Ok(AtRest {
                out,
                transmission,
                light: Light::DirectBeam { fraction },
                stray_fraction,
                filter_factor: filter_total,
                filter_total,
                beam_rel: relative(fraction, nominal),
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
        out.sample_factor = self.sample_factor(&g);
        // The band's spectral weighting of the sample, relative to its total (the transmission has that).
        let ratios = match spectral {
            Some(b) if !blocked => self.band_ratios(b, &r, &wi_m, &wo_m)?,
            _ => super::spectral::BandRatios {
                regular: 1.0,
                delta: 1.0,
            },
        };
        // The delta lobe as the true beam delivers it into the aperture (crate::imperfections::beam).
        let (regular, delta) = (truth.integral * ratios.regular, truth.delta_beam * ratios.delta);
        let line = truth.integral + truth.delta_beam;
        let filter_factor = if line != 0.0 {
            filter_total * (regular + delta) / line
        } else {
            filter_total
        };
        let light = if blocked {
            Light::Dark
        } else {
            Light::Sample {
                intercepted: fp.intercepted_fraction,
                collected: (regular + delta) * out.sample_factor,
                integral_error: truth.integral_error * ratios.regular * out.sample_factor,
            }
        };
        let beam_rel = if self.beam.is_some() {
            // Against the ideal beam at the same (true) geometry: a top hat's footprint, the nominal divergence.
            let top_hat = match self.beam.as_ref().and_then(|b| b.gaussian_mm) {
                Some(_) => self.footprint_top_hat(&g).intercepted_fraction,
                None => fp.intercepted_fraction,
            };
            relative(
                fp.intercepted_fraction * (truth.integral + truth.delta_beam),
                top_hat * (truth.integral + truth.delta),
            )
        } else {
            0.0
        };
        Ok(AtRest {
            out,
            transmission,
            light,
            stray_fraction,
            filter_factor,
            filter_total,
            beam_rel,
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
        if rest.stray_fraction > 0.0 {
            // The signature rides on the beam: drift and noise as the beam has them.
            let stray_w = drifted_w * transmission * rest.stray_fraction;
            out.stray_power_w = stray_w * noise;
            out.noiseless_power_w += stray_w;
            out.power_w += out.stray_power_w;
        }
        out
    }
}

/// `a / b - 1`, 0 when `b` is 0 or either is not finite.
fn relative(a: f64, b: f64) -> f64 {
    if b != 0.0 && a.is_finite() && b.is_finite() {
        a / b - 1.0
    } else {
        0.0
    }
}

fn neg(v: &[f64; 3]) -> [f64; 3] {
    [-v[0], -v[1], -v[2]]
}

impl Optics {
    /// Record what the imperfections did to a reading at rest sampled at `times_s` with `powers_w`, whose
    /// stray-light parts sum to `stray_sum_w` (crate::imperfections::effects); nothing on the ideal instrument.
    fn record_effects(&self, rest: &AtRest, times_s: &[f64], powers_w: &[f64], stray_sum_w: f64) {
        if self.hidden.is_none() || times_s.is_empty() {
            return;
        }
        let n = times_s.len() as f64;
        let (mut slow, mut fast) = (0.0, 0.0);
        for &t in times_s {
            let (s, f) = self.source.imperfection_factors(t);
            slow += s;
            fast += f;
        }
        let out = &rest.out;
        let ((theta_i, phi_i), (theta_o, phi_o)) = (out.wi.to_spherical_deg(), out.wo.to_spherical_deg());
        let effects = crate::imperfections::OpticsEffects {
            true_theta_i_deg: theta_i,
            true_phi_i_deg: phi_i,
            true_theta_o_deg: theta_o,
            true_phi_o_deg: phi_o,
            true_aperture_sr: out.truth_aperture_sr,
            intercepted_fraction: out.intercepted_fraction,
            sample_factor: out.sample_factor,
            power_w: powers_w.iter().sum::<f64>() / n,
            stray_power_w: stray_sum_w / n,
            source_slow_factor: slow / n,
            source_flicker_factor: fast / n,
            filter_factor: rest.filter_factor,
            filter_total: rest.filter_total,
            beam_fraction_rel: rest.beam_rel,
        };
        *self.last_effects.lock().unwrap_or_else(|e| e.into_inner()) = Some(effects);
    }

    /// What the imperfections did to the last reading (hidden truth, for the dry-run's record and tests); `None`
    /// on the ideal instrument or before any reading.
    pub fn last_effects(&self) -> Option<crate::imperfections::OpticsEffects> {
        *self.last_effects.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Scene for Optics {
    /// The reading's `power_w`; 0 (with a warning) if the material cannot be evaluated at the band.
    fn detector_power_w(&self, pose: &Pose, band: &Band, t_s: f64) -> f64 {
        match self.at_rest(pose, band) {
            Ok(rest) => {
                let r = self.at_time(&rest, t_s);
                let p = if r.power_w.is_finite() { r.power_w } else { 0.0 };
                self.record_effects(&rest, &[t_s], &[p], r.stray_power_w);
                p
            }
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
            Ok(rest) => {
                let mut stray_sum_w = 0.0;
                out.extend(times_s.iter().map(|&t| {
                    let r = self.at_time(&rest, t);
                    stray_sum_w += r.stray_power_w;
                    if r.power_w.is_finite() { r.power_w } else { 0.0 }
                }));
                self.record_effects(&rest, times_s, out, stray_sum_w);
            }
            Err(e) => {
                tracing::warn!(error = %e, "optics cannot evaluate the sample; reporting no light");
                out.resize(times_s.len(), 0.0);
            }
        }
    }
}
