//! The instrument's optics: what power reaches the photodiode for a pose, a filter band and a sample.
//!
//! # The model (shared/reference/radiometry-and-materials.md, "Measurement equation")
//! `P_s = P_i(t) T eta_footprint [ ∫_aperture f(wi, w) cos(theta_w) d omega + F(theta_i) eta_delta ]` where
//! - `P_i(t)` is the source power with its slow drift and (when enabled) its relative noise ([`source`]);
//! - `T` is the filter's transmission; the blank gives 0;
//! - `eta_footprint` is the fraction of the beam that lands on the sample inside the detector's field of view
//!   ([`footprint`], exact closed form: the footprint grows as 1/cos(theta_i) and spills past the sample's edge);
//! - the integral runs over the detector's circular aperture seen from the sample centre: a cone about `wo` of
//!   half-angle `atan(r/d)` ([`aperture`], computed as cheaply as the tolerance allows, with an error estimate);
//! - an ideal specular (delta) lobe of reflectance `F` is added analytically: `eta_delta` is the fraction of the
//!   beam's divergence cone (full angle `divergence_deg`, top hat) that enters the aperture ([`cap`]); with zero
//!   divergence it is 1 or 0;
//! - when the detector arm is within `safety.retro_block_deg` of the light arm, the detector's body blocks the
//!   incident beam: `P_s = 0` and the reading says so.
//!
//! Spectral treatment: the filter bands are narrow (10 nm); each band is treated at its centre wavelength, where
//! the material is resolved once (`Material::at_wavelength`) and cached. Nothing is integrated over the band.
//!
//! Ground truth: every reading carries `f` at the nominal geometry (wi, wo through the sample and detector
//! centres; the regular part only: a delta lobe has no finite point value) and the cos-weighted aperture average
//! `<f>` with `P_s = P_i Omega_d cos(theta_o) <f>` when the beam is fully intercepted (delta lobe included).
//!
//! # Direct-beam (absolute) calibration on this instrument
//! Every plane through the sample centre contains the beam axis, so no tilt or rotation of the stage takes the
//! sample out of the beam: the direct-beam reading needs the sample removed (the operator unmounts it; in the
//! simulator, [`Optics::set_sample_mounted`]`(false)`). The detector arm is then turned to face the light arm,
//! `detector_deg = light_deg ± 180` ([`Optics::direct_beam_pose`]; e.g. light -90, detector +90, both within the
//! simulated arms' limits). With no sample the detector reads the part of the beam that enters its aperture and
//! nothing elsewhere; [`Optics::direct_beam_power_w`] gives the reading of the facing pose directly.
//! Far-field approximation: the beam (radius 1.5 mm) is narrower than the aperture (2.5 mm) and treated, like the
//! mirror reflection, as a divergence cone from the sample centre.
//!
//! # Cost
//! A Lambertian sample costs one BRDF evaluation per reading (its integral is `f` times the exact projected solid
//! angle of the cone); smooth models a few to a few tens; a lobe on or near the aperture adaptively more; a delta
//! lobe none. A cone across the horizon (near grazing) is integrated over its part above the horizon only, where
//! the integrand stays smooth: tens to a hundred or so evaluations for Oren-Nayar (a few thousand when its
//! azimuthal kink crosses the cone), 200 to 1000 for a grazing microfacet lobe. No random number is drawn when the
//! noise is off.

pub mod aperture;
pub mod cap;
pub mod footprint;
pub mod source;

use std::f64::consts::FRAC_PI_2;
use std::sync::RwLock;
use std::sync::atomic::{AtomicBool, Ordering};

use gonio_brdf::material::Material;
use gonio_brdf::radiometry::{aperture_half_angle_rad, aperture_solid_angle_sr};
use gonio_brdf::{Brdf, Direction, SpectrumError, Wavelength};
use gonio_instrument::Instrument;

use crate::kinematics::{self, PoseGeometry};
use crate::scene::{Band, Pose, Scene};
use aperture::{Cone, ConeIntegral, Features, Peak, Plan};
use footprint::Footprint;
use source::SourceModel;

/// The simulated sample: a material, its size and how it is mounted.
#[derive(Debug, Clone)]
pub struct SampleSpec {
    pub material: Material,
    /// Radius of the (circular) sample, mm.
    pub radius_mm: f64,
    /// Rotation of the material's own x axis about the normal, from the sample stage's x axis (degrees).
    /// Matters only for anisotropic materials.
    pub orientation_deg: f64,
}

/// Why the optics cannot be built or cannot answer.
#[derive(Debug, thiserror::Error)]
pub enum OpticsError {
    /// A sample parameter is out of range.
    #[error("sample: {0}")]
    Sample(String),
    /// The relative tolerance must lie in (0, 0.1].
    #[error("optics tolerance must be in (0, 0.1], got {0}")]
    Tolerance(f64),
    /// The material cannot be evaluated at a band's wavelength (its spectral tables do not cover it).
    #[error("sample material at {band_nm} nm: {source}")]
    Spectrum { band_nm: f64, source: SpectrumError },
}

/// Everything one reading knows: the power on the photodiode, its integration error, the ground truth, and what
/// went wrong optically.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpticalReading {
    /// Power on the photodiode (W), with source drift and (when enabled) relative noise.
    pub power_w: f64,
    /// The same without the noise (drift included) (W).
    pub noiseless_power_w: f64,
    /// Estimate of the absolute error of the aperture integral, in watts on `noiseless_power_w`.
    pub integration_error_w: f64,
    /// Beam power arriving at the sample at that time and band (drift and noise included), before footprint
    /// losses (W).
    pub incident_power_w: f64,
    /// Fraction of the beam landing on the sample inside the detector's field of view.
    pub intercepted_fraction: f64,
    /// f(wi, wo) at the nominal geometry (1/sr), regular part (a delta lobe has no point value).
    pub truth_point_sr: f64,
    /// Aperture average <f> (1/sr), delta lobe included, defined by the measurement equation:
    /// `P_s = P_i Omega_d cos(theta_o) <f>` with the beam fully intercepted, i.e. exactly what an ideal noise-free
    /// absolute measurement reports. It includes the equation's own finite-aperture bias: for a Lambertian sample
    /// `<f> = f (1 + cos beta) / 2`, because the cone's projected solid angle is `pi sin^2(beta) cos(theta_o)`,
    /// not `Omega_d cos(theta_o)`. 0 when the detector looks from below the horizon.
    pub truth_aperture_sr: f64,
    /// Nominal incident direction in the sample frame (towards the source).
    pub wi: Direction,
    /// Nominal outgoing direction in the sample frame (towards the detector centre).
    pub wo: Direction,
    /// The footprint spills past the sample's edge.
    pub overfilled_sample: bool,
    /// The footprint spills outside the detector's field of view.
    pub overfilled_field: bool,
    /// The detector's body blocks the incident beam (arms within `retro_block_deg`): `power_w` is 0.
    pub beam_blocked_by_detector: bool,
    /// The mirror direction of `wi` lies inside the aperture cone (whatever the material: for a glossy lobe the
    /// aperture average then differs most from the point value).
    pub specular_in_aperture: bool,
    /// BRDF evaluations spent on this reading.
    pub evaluations: u32,
}

/// An aperture-averaged ground truth for arbitrary directions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApertureTruth {
    /// `∫_aperture f cos d omega` (sr * 1/sr), regular part.
    pub integral: f64,
    /// Estimate of the absolute error of `integral`.
    pub integral_error: f64,
    /// Delta-lobe reflectance times the fraction of the divergence cone inside the aperture.
    pub delta: f64,
    /// `(integral + delta) / (Omega_d cos(theta_o))` (1/sr); 0 when `wo` is below the horizon.
    pub average_sr: f64,
    pub evaluations: u32,
}

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

/// What is known about the regular (non-delta) part of a resolved material.
#[derive(Debug, Clone, Copy, PartialEq)]
enum RegularPart {
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
enum Kinks {
    /// Oren-Nayar: `max(0, cos(phi_o - phi_i))` and `max(cos theta_i, cos theta_o)`, i.e. the vertical plane
    /// perpendicular to wi's azimuth and the cone theta_o = theta_i.
    OrenNayar,
    /// Phong: `max(0, wo . reflect(wi))^n`, the plane perpendicular to the mirror direction.
    Phong,
}

#[derive(Debug)]
struct Resolved {
    band_nm: f64,
    wavelength: Wavelength,
    material: Material,
    regular: RegularPart,
}

/// The faithful scene: a sample of a given material on the instrument's stage.
#[derive(Debug)]
pub struct Optics {
    sample_radius_mm: f64,
    /// cos and sin of the material orientation.
    orientation: (f64, f64),
    isotropic: bool,
    lobe_width: Option<f64>,
    beam_radius_mm: f64,
    field_radius_mm: f64,
    /// Half-angle of the beam's divergence cone (rad).
    divergence_half_rad: f64,
    /// Half-angle and solid angle of the detector's aperture cone.
    aperture_half_rad: f64,
    aperture_sr: f64,
    retro_block_rad: f64,
    tolerance: f64,
    source: SourceModel,
    sample_mounted: AtomicBool,
    material: Material,
    bands: RwLock<Vec<std::sync::Arc<Resolved>>>,
}

impl Optics {
    /// The default relative tolerance of the aperture integral.
    pub const DEFAULT_TOLERANCE: f64 = 1e-6;

    /// The optics of `instrument` with `sample` mounted. The material is resolved at every band the instrument
    /// offers (an error names a band its spectral tables do not cover). Source noise is on when the source has a
    /// `relative_noise`, drift when it has a `drift_per_hour`; `seed` fixes both.
    pub fn new(instrument: &Instrument, sample: SampleSpec, seed: u64) -> Result<Optics, OpticsError> {
        if !(sample.radius_mm.is_finite() && sample.radius_mm > 0.0) {
            return Err(OpticsError::Sample(format!(
                "radius_mm must be > 0, got {}",
                sample.radius_mm
            )));
        }
        if !sample.orientation_deg.is_finite() {
            return Err(OpticsError::Sample(format!(
                "orientation_deg must be finite, got {}",
                sample.orientation_deg
            )));
        }
        let src = &instrument.source;
        let det = &instrument.detector;
        let (so, co) = gonio_brdf::geometry::sin_cos_deg(sample.orientation_deg);
        let optics = Optics {
            sample_radius_mm: sample.radius_mm,
            orientation: (co, so),
            isotropic: sample.material.is_isotropic(),
            lobe_width: sample.material.lobe_width(),
            beam_radius_mm: src.beam_radius_mm,
            field_radius_mm: det.field_radius_mm,
            divergence_half_rad: (0.5 * src.divergence_deg.max(0.0)).to_radians(),
            aperture_half_rad: aperture_half_angle_rad(det.aperture_radius_mm, det.distance_mm),
            aperture_sr: aperture_solid_angle_sr(det.aperture_radius_mm, det.distance_mm),
            retro_block_rad: instrument.safety.retro_block_deg.max(0.0).to_radians(),
            tolerance: Optics::DEFAULT_TOLERANCE,
            source: SourceModel::new(src.power_w, src.drift_per_hour, src.relative_noise, seed),
            sample_mounted: AtomicBool::new(true),
            material: sample.material,
            bands: RwLock::new(Vec::new()),
        };
        for nm in instrument.bands_nm() {
            optics.resolved(nm)?;
        }
        Ok(optics)
    }

    /// Set the relative tolerance of the aperture integral (default 1e-6).
    pub fn with_tolerance(mut self, relative: f64) -> Result<Optics, OpticsError> {
        if relative.is_nan() || relative <= 0.0 || relative > 0.1 {
            return Err(OpticsError::Tolerance(relative));
        }
        self.tolerance = relative;
        Ok(self)
    }

    /// Switch the source's relative noise on or off (it can only be on when the source has a `relative_noise`).
    pub fn with_source_noise(mut self, on: bool) -> Optics {
        self.source.set_noise(on);
        self
    }

    /// Switch the source's drift on or off.
    pub fn with_source_drift(mut self, on: bool) -> Optics {
        self.source.set_drift(on);
        self
    }

    pub fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// Half-angle of the detector's aperture cone seen from the sample centre (rad).
    pub fn aperture_half_angle_rad(&self) -> f64 {
        self.aperture_half_rad
    }

    /// Solid angle of the detector's aperture seen from the sample centre (sr).
    pub fn aperture_solid_angle_sr(&self) -> f64 {
        self.aperture_sr
    }

    /// Mount or unmount the sample (unmounted: the detector sees only the direct beam, for calibration).
    pub fn set_sample_mounted(&self, mounted: bool) {
        self.sample_mounted.store(mounted, Ordering::Relaxed);
    }

    pub fn sample_mounted(&self) -> bool {
        self.sample_mounted.load(Ordering::Relaxed)
    }

    /// The pose for a direct-beam reading with the light arm at `light_deg`: the detector arm opposite
    /// (`light_deg + 180`, wrapped into (-180, 180]), sample stage at zero (it does not matter once the sample is
    /// removed).
    pub fn direct_beam_pose(light_deg: f64) -> Pose {
        let mut d = (light_deg + 180.0).rem_euclid(360.0);
        if d > 180.0 {
            d -= 360.0;
        }
        Pose {
            light_deg,
            detector_deg: d,
            tilt_deg: 0.0,
            rotation_deg: 0.0,
        }
    }

    /// Beam power at the sample position at time `t_s` in `band`, drift and noise included (W).
    pub fn incident_power_w(&self, band: &Band, t_s: f64) -> f64 {
        if band.band_nm.is_none() {
            return 0.0;
        }
        self.source.drifted_power_w(t_s) * band.transmission.max(0.0) * self.source.noise_factor(t_s)
    }

    /// What the detector reads looking straight into the source with no sample: the beam power at that time and
    /// band times the fraction of the divergence cone inside the aperture (1 for this instrument).
    pub fn direct_beam_power_w(&self, band: &Band, t_s: f64) -> f64 {
        self.incident_power_w(band, t_s)
            * cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, 0.0)
    }

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

    /// One reading: the pose's geometry, the footprint, the aperture integral and the source at time `t_s`.
    pub fn reading(&self, pose: &Pose, band: &Band, t_s: f64) -> Result<OpticalReading, OpticsError> {
        Ok(self.at_time(&self.at_rest(pose, band)?, t_s))
    }

    /// Everything of a reading that does not depend on time: with the axes and the wheel at rest, the averaged
    /// samples of one meter reading differ only by the source (drift, noise), not by this.
    fn at_rest(&self, pose: &Pose, band: &Band) -> Result<AtRest, OpticsError> {
        let geometry = kinematics::forward(pose);
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
            let off_axis = kinematics::angle_between(&geometry.detector_lab, &neg(&geometry.source_lab));
            let fraction = cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, off_axis);
            out.intercepted_fraction = fraction;
            return Ok(AtRest {
                out,
                transmission,
                light: Light::DirectBeam { fraction },
            });
        }
        let r = self.resolved(nm)?;
        let fp = self.footprint(&geometry);
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

    fn footprint(&self, g: &PoseGeometry) -> Footprint {
        footprint::footprint(
            self.beam_radius_mm,
            self.sample_radius_mm,
            self.field_radius_mm,
            &g.wi,
            &g.wo,
        )
    }

    /// The regular aperture integral and the delta lobe, in the material's frame.
    fn aperture_truth(
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
        let delta = match r.material.delta_lobe(&wi_m, r.wavelength).map_err(err)? {
            Some(lobe) if wi_m.z() > 0.0 => {
                let g = wi_m.reflect_about_normal().angle_to(&wo_m);
                lobe.reflectance * cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, g)
            }
            _ => 0.0,
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
            average_sr,
            evaluations: integral.evaluations,
        })
    }

    /// Choose the integration strategy from what the model is and where its features lie.
    ///
    /// The BRDF's length scale near the aperture: smooth models without a lobe vary on the scale of a radian; a
    /// lobe of width alpha (in slope) is about 2 alpha wide in outgoing directions around the mirror direction,
    /// and at an angular distance D from its peak a microfacet tail (~ D^-4) varies on the scale D/4; a kink at
    /// distance K from the axis limits the scale to K. The ratio q = beta / scale decides: a kink within 2 beta,
    /// a feature narrower than the aperture (q > 1) or tabulated data go to the adaptive rule (seeded with the
    /// lobe's peak); otherwise the tensor sequence, from the coarsest rule when the aperture is tiny compared
    /// with the scale.
    ///
    /// A cone across the horizon: the integrator works on its part above the horizon in latitude coordinates,
    /// where the horizon is no kink, Oren-Nayar's kinks are coordinate lines cut exactly (theta_o = theta_i, a
    /// circle of latitude: `kink_theta`; cos(phi_o - phi_i) = 0, a meridian: `kink_azimuth`), so they do not count
    /// as kinks here, and a narrow lobe is mapped out (its peak, its width across the plane of incidence, and
    /// where its ridge crosses the cone's rim): Oren-Nayar and a smooth model there always take the tensor
    /// sequence, which falls back to the adaptive rule by itself if it does not converge. Above the horizon the
    /// adaptive rule is told of the Oren-Nayar plane too (`kink_azimuth`) and starts cut along its trace.
    fn plan(&self, regular: RegularPart, wi_m: &Direction, cone: &Cone) -> (Plan, Features) {
        let beta = cone.half_angle;
        let across_horizon = !cone.above_horizon();
        let mirror = wi_m.reflect_about_normal();
        let peak = self.lobe_width.filter(|w| *w > 0.0).map(|w| {
            let width = 2.0 * w;
            // A microfacet lobe is a function of the half vector, which turns by 1 / (cos theta_i + cos theta_o)
            // per unit of out-of-plane angle: narrower across than along near grazing. Phong's is symmetric
            // about the mirror direction.
            let across = match regular {
                RegularPart::Kinked(Kinks::Phong) => (width, 0.0),
                _ => (w * wi_m.z().max(0.0), w),
            };
            Peak {
                direction: mirror,
                width,
                across,
            }
        });
        let mut features = Features {
            peak,
            kink_theta: None,
            kink_azimuth: None,
        };
        let mut scale: f64 = 1.0;
        if let Some(p) = peak {
            let distance = (mirror.angle_to(&cone.axis) - beta).max(0.0);
            scale = scale.min(p.width.max(distance / 4.0));
        }
        match regular {
            RegularPart::Tabulated => return (Plan::Adaptive, features),
            RegularPart::Kinked(k) => {
                let loci = kink_loci(k, wi_m, &cone.axis);
                let mut d = loci.other;
                if let Some((theta, distance)) = loci.latitude {
                    if !across_horizon {
                        d = d.min(distance);
                    } else if distance < 2.0 * beta {
                        features.kink_theta = Some(theta);
                    }
                }
                if let Some(azimuth) = loci.meridian {
                    if loci.other < 2.0 * beta {
                        features.kink_azimuth = Some(azimuth);
                    }
                    // A vertical plane through the normal is a meridian in latitude coordinates, cut exactly
                    // there; above the horizon it stays a kink for the adaptive rule (cut along its trace).
                    if across_horizon {
                        d = f64::INFINITY;
                    }
                }
                if d < 2.0 * beta {
                    return (Plan::Adaptive, features);
                }
                scale = scale.min(d);
            }
            _ => {}
        }
        let q = beta / scale;
        let plan = if q > 1.0 && !across_horizon {
            Plan::Adaptive
        } else if q < 0.03 {
            Plan::Tensor { start: 0 }
        } else if q < 0.3 {
            Plan::Tensor { start: 1 }
        } else {
            Plan::Tensor { start: 3 }
        };
        (plan, features)
    }

    /// A sample-frame direction in the material's own frame (rotated by -orientation about the normal).
    fn to_material(&self, w: &Direction) -> Direction {
        if self.isotropic {
            return *w;
        }
        let (c, s) = self.orientation;
        Direction::new(c * w.x() + s * w.y(), -s * w.x() + c * w.y(), w.z()).unwrap_or(*w)
    }

    /// The material resolved at a band's centre wavelength, cached.
    fn resolved(&self, band_nm: f64) -> Result<std::sync::Arc<Resolved>, OpticsError> {
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

/// Where a model's kinks lie relative to a cone's axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KinkLoci {
    /// Angular distance (rad) from the axis to the nearest kink that is not a circle of latitude.
    other: f64,
    /// When that kink is a vertical plane through the normal: its azimuth (rad) on the axis's side.
    meridian: Option<f64>,
    /// A kink along the circle of latitude theta (rad) that matters near the axis, and its angular distance
    /// from the axis.
    latitude: Option<(f64, f64)>,
}

/// The kink loci of the model near a cone's axis.
fn kink_loci(kinks: Kinks, wi_m: &Direction, axis: &Direction) -> KinkLoci {
    let a = [axis.x(), axis.y(), axis.z()];
    match kinks {
        Kinks::OrenNayar => {
            // Both terms vanish with sin(theta_i) (the azimuth of wi is then meaningless): no kink.
            let s = wi_m.sin_theta();
            if s == 0.0 {
                return KinkLoci {
                    other: f64::INFINITY,
                    meridian: None,
                    latitude: None,
                };
            }
            let n = [wi_m.x() / s, wi_m.y() / s, 0.0];
            let along = kinematics::dot(&a, &n);
            let to_plane = along.abs().min(1.0).asin();
            // Where the axis lies on the side cos(phi_o - phi_i) < 0, the max(0, .) factor is 0 up to the plane,
            // so the theta_o = theta_i kink is invisible there.
            let latitude = (along >= 0.0).then(|| (wi_m.theta(), (axis.theta() - wi_m.theta()).abs()));
            // The plane cos(phi_o - phi_i) = 0 is at the azimuths phi_i +- pi/2: the one the axis lies nearer.
            let across = kinematics::dot(&a, &[-n[1], n[0], 0.0]);
            let meridian = wi_m.phi() + if across >= 0.0 { FRAC_PI_2 } else { -FRAC_PI_2 };
            KinkLoci {
                other: to_plane,
                meridian: Some(meridian),
                latitude,
            }
        }
        Kinks::Phong => {
            let r = wi_m.reflect_about_normal();
            KinkLoci {
                other: kinematics::dot(&a, &[r.x(), r.y(), r.z()]).abs().min(1.0).asin(),
                meridian: None,
                latitude: None,
            }
        }
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
