//! What the imperfections did to the last reading, for attributing a dry-run point's error (issue 16: "the
//! ground truth of a dry-run adds, per point, what each effect did"). The optics and the meter each keep their
//! last reading's record when the instrument is imperfect (nothing is recorded on the ideal instrument); the
//! engine's dry-run holder (crates/engine/src/rig/dry_run.rs) reads both right after the point's reading and
//! stores them beside the point as truth, like the point BRDF: tests and run records see them, the engine only
//! carries them.

use serde::Serialize;

/// The optical side of one reading (the sample's optics).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OpticsEffects {
    /// True incident and outgoing directions in the sample frame (degrees), after the geometric errors.
    pub true_theta_i_deg: f64,
    pub true_phi_i_deg: f64,
    pub true_theta_o_deg: f64,
    pub true_phi_o_deg: f64,
    /// The aperture-averaged BRDF at the TRUE geometry (1/sr): compare with the nominal geometry's.
    pub true_aperture_sr: f64,
    /// Fraction of the beam landing on the sample inside the field of view at the true geometry.
    pub intercepted_fraction: f64,
    /// Mean power on the detector over the reading's samples, and its stray-light part (W).
    pub power_w: f64,
    pub stray_power_w: f64,
    /// The sample's reflectance factor averaged over the footprint (crate::imperfections::sample; 1 when even).
    pub sample_factor: f64,
    /// The source's imperfection factors over the reading (means): warm-up and random walk, flicker.
    pub source_slow_factor: f64,
    pub source_flicker_factor: f64,
    /// The finite band's factor on this reading's light against a single wavelength at the band's centre
    /// (crate::optics::spectral), and its factor on spectrally flat light (`∫ W`, what a direct-beam or
    /// reference reading through the same filter sees); both 1 on the ideal instrument.
    pub filter_factor: f64,
    pub filter_total: f64,
    /// Relative change of the light reaching the detector by the beam's profile and true divergence, against
    /// the ideal (top-hat, nominal-divergence) beam at the same true geometry: the intercepted fraction and a
    /// delta lobe's share, or the direct beam's fraction (crate::imperfections::beam; 0 with the ideal beam).
    /// The beam's pointing acts through the true directions above.
    pub beam_fraction_rel: f64,
}

/// The meter's side of one reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MeterEffects {
    /// Full scale of the range used (W at the wavelength set).
    pub range_w: f64,
    /// Mean photocurrent of the light (beam and stray light) before saturation (A).
    pub light_a: f64,
    /// Ambient light's photocurrent (A).
    pub ambient_a: f64,
    /// Relative change of the current by the photodiode's saturation.
    pub saturation_rel: f64,
    /// Relative change of the reported current by the range's gain, nonlinearity and offset.
    pub meter_rel: f64,
}
