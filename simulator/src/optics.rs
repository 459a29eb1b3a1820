//! The instrument's optics: what power reaches the photodiode for a pose, a filter band and a sample.
//!
//! # The model (shared/reference/radiometry-and-materials.md, "Measurement equation")
//! `P_s = P_i(t) T eta_footprint [ ∫_aperture f(wi, w) cos(theta_w) d omega + F(theta_i) eta_delta ]` where
//! - `P_i(t)` is the source power with its slow drift and (when enabled) its relative noise ([`source`]);
//! - `T` is the filter's transmission; the blank gives 0;
//! - `eta_footprint` is the fraction of the beam that lands on the sample inside the detector's field of view
//!   ([`footprint`], exact closed form: the footprint grows as 1/cos(theta_i) and spills past the sample's edge;
//!   [`footprint_offset`] when the spot is off-centre on an imperfect instrument; [`footprint_gaussian`] for a
//!   Gaussian beam, crate::imperfections::beam);
//! - the integral runs over the detector's circular aperture seen from the sample centre: a cone about `wo` of
//!   half-angle `atan(r/d)` ([`aperture`], computed as cheaply as the tolerance allows, with an error estimate);
//! - an ideal specular (delta) lobe of reflectance `F` is added analytically: `eta_delta` is the fraction of the
//!   beam's divergence cone (full angle `divergence_deg`, top hat) that enters the aperture ([`cap`]); with zero
//!   divergence it is 1 or 0 (with the imperfect beam's true divergence, or its Gaussian spread over the
//!   aperture, crate::imperfections::beam);
//! - when the detector arm is within `safety.retro_block_deg` of the light arm, the detector's body blocks the
//!   incident beam: `P_s = 0` and the reading says so.
//!
//! Spectral treatment: on the ideal instrument each band is treated at its centre wavelength, where the material
//! is resolved once (`Material::at_wavelength`) and cached; nothing is integrated over the band. With
//! `[simulator.imperfections.filters]` a band has a width, a shifted centre and leakage: a reading integrates
//! BRDF x transmission x source spectrum x responsivity over it ([`spectral`], model in
//! crate::imperfections::filters); the aperture integral stays at the centre wavelength, scaled by the point
//! BRDF's spectrum.
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
//! mirror reflection, as a divergence cone from the sample centre. A Gaussian beam (crate::imperfections::beam)
//! is not: its tails beyond the aperture are lost, in the direct beam and in a mirror's reflection alike.
//!
//! # Cost
//! A Lambertian sample costs one BRDF evaluation per reading (its integral is `f` times the exact projected solid
//! angle of the cone); smooth models a few to a few tens; a lobe on or near the aperture adaptively more; a delta
//! lobe none. A cone across the horizon (near grazing) is integrated over its part above the horizon only, where
//! the integrand stays smooth: tens to a hundred or so evaluations for Oren-Nayar (a few thousand when its
//! azimuthal kink crosses the cone), 200 to 1000 for a grazing microfacet lobe. No random number is drawn when the
//! noise is off.
//!
//! # Where the code is
//! Here: the public types, the optics' construction and settings, the source's power. One reading, at rest then at
//! an instant: `reading.rs`, on the pose's geometry as `geometry.rs` holds it. The ground truth and the aperture
//! integral behind the power: `truth.rs`, which takes its integration plan from `strategy.rs` and the material per
//! band, in its own frame, from `resolved.rs`. The physics they use: [`source`], [`footprint`], [`aperture`],
//! [`cap`].

pub mod aperture;
mod beam;
pub mod cap;
pub mod footprint;
pub mod footprint_gaussian;
pub mod footprint_offset;
mod geometry;
mod imperfect;
mod reading;
mod resolved;
pub mod source;
mod spectral;
mod strategy;
mod truth;

use std::sync::RwLock;
use std::sync::atomic::{AtomicBool, Ordering};

use gonio_brdf::material::Material;
use gonio_brdf::radiometry::{aperture_half_angle_rad, aperture_solid_angle_sr};
use gonio_brdf::{Brdf, Direction, SpectrumError};
use gonio_instrument::Instrument;

use crate::imperfections::HiddenTruth;
use crate::scene::{Band, Pose};
use imperfect::Seating;
use resolved::Resolved;
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
    /// `[instrument.detector] responsivity_a_per_w` cannot be read (it weights a finite filter band).
    #[error("{0}")]
    Responsivity(String),
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
    /// Incident direction in the sample frame (towards the source) as the sample really sees it: the nominal one
    /// on the ideal instrument, the true one (crate::imperfections) on an imperfect one. The truth fields are
    /// computed here.
    pub wi: Direction,
    /// Outgoing direction in the sample frame (from the beam's spot towards the detector centre), nominal or true
    /// as `wi`.
    pub wo: Direction,
    /// The beam's centre on the sample (sample x, y; mm): 0, 0 unless the arms' axis misses the sample centre
    /// (then the footprint is clipped about it: [`footprint_offset`]).
    pub spot_mm: [f64; 2],
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
    /// The sample's reflectance factor averaged over the beam's footprint (crate::imperfections::sample): 1 on
    /// an even sample. The truth fields are the material's, without it.
    pub sample_factor: f64,
    /// Part of `power_w` that is stray light (the instrument signature, crate::imperfections::detector): 0 on
    /// the ideal instrument (W).
    pub stray_power_w: f64,
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
    /// The same with the instrument's true beam (profile, divergence: crate::imperfections::beam): what a
    /// reading collects; equal to `delta` when the beam is ideal. The truth (`average_sr`) uses `delta`.
    pub delta_beam: f64,
    /// `(integral + delta) / (Omega_d cos(theta_o))` (1/sr); 0 when `wo` is below the horizon.
    pub average_sr: f64,
    pub evaluations: u32,
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
    /// The instrument's hidden imperfections; `None` on the ideal instrument ([`Optics::with_hidden_truth`]).
    hidden: Option<std::sync::Arc<HiddenTruth>>,
    /// The true beam (crate::imperfections::beam); `None` when it is the ideal one.
    beam: Option<beam::BeamOptics>,
    /// The instrument signature (crate::imperfections::detector); `None` on the ideal instrument.
    signature: Option<crate::imperfections::Signature>,
    /// What the imperfections did to the last reading (recorded only on an imperfect instrument).
    last_effects: std::sync::Mutex<Option<crate::imperfections::OpticsEffects>>,
    /// The sample's current mounting (re-seating draws a new tilt each time it goes back).
    seating: RwLock<Seating>,
    /// Which object on the holder this is, for its seatings (crate::imperfections::GeometryTruth's
    /// `object_seating_tilt`): 0 the sample, [`Optics::ALIGNMENT_MIRROR`] the alignment mirror.
    object: u64,
    /// Distance from the arms' axis to the detector's aperture (mm): eccentricity moves the viewing direction.
    detector_distance_mm: f64,
    /// The aperture's radius and distance (mm) as the instrument file states them; the hidden truth's differ.
    nominal_aperture_mm: [f64; 2],
    material: Material,
    bands: RwLock<Vec<std::sync::Arc<Resolved>>>,
    /// The photodiode's responsivity, which weights a finite band (crate::imperfections::filters).
    responsivity: crate::responsivity::Responsivity,
    /// The filters' finite bands (crate::optics::spectral); empty on the ideal instrument: single wavelengths.
    spectral: Vec<std::sync::Arc<spectral::SpectralBand>>,
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
            hidden: None,
            beam: None,
            signature: None,
            last_effects: std::sync::Mutex::new(None),
            seating: RwLock::new(Seating::default()),
            object: 0,
            detector_distance_mm: det.distance_mm,
            nominal_aperture_mm: [det.aperture_radius_mm, det.distance_mm],
            material: sample.material,
            bands: RwLock::new(Vec::new()),
            responsivity: crate::responsivity::Responsivity::from_detector(det)
                .map_err(|e| OpticsError::Responsivity(e.0))?,
            spectral: Vec::new(),
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

    /// Mount or unmount the sample (unmounted: the detector sees only the direct beam, for calibration). Putting
    /// it back starts a new mounting, with its own re-seating tilt on an imperfect instrument.
    pub fn set_sample_mounted(&self, mounted: bool) {
        let was = self.swap_mounted(mounted);
        self.note_mounted(was, mounted);
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

    /// Beam power at the sample position at time `t_s` in `band`, drift and noise included (W; through a finite
    /// band, as the meter set to the band's nominal wavelength counts it: crate::imperfections::filters).
    pub fn incident_power_w(&self, band: &Band, t_s: f64) -> f64 {
        if band.band_nm.is_none() {
            return 0.0;
        }
        let filter_total = band
            .band_nm
            .and_then(|nm| self.spectral_band(nm))
            .map_or(1.0, |b| b.total);
        self.source.drifted_power_w(t_s)
            * band.transmission.max(0.0)
            * filter_total
            * self.source.noise_factor(t_s)
    }

    /// What the detector reads looking straight into the source with no sample: the beam power at that time and
    /// band times the fraction of the divergence cone inside the aperture (1 for this instrument; less for a
    /// Gaussian beam whose tails miss the aperture, crate::imperfections::beam).
    pub fn direct_beam_power_w(&self, band: &Band, t_s: f64) -> f64 {
        self.incident_power_w(band, t_s) * self.lobe_fraction(0.0, false)
    }
}
