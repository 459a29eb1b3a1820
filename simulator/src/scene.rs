//! The seam between the simulated devices and the simulated optics.
//!
//! The device emulators (motion controllers, filter wheel, power meter) know where every axis really is and which
//! filter is in the beam; the optics know what power that puts on the photodiode. A [`Scene`] answers that one
//! question. `crate::optics::Optics` is the faithful scene built on gonio-brdf; [`UniformScene`] is a stand-in
//! for protocol tests that do not care about light.

use std::fmt::Debug;

/// Physical angles of the instrument's axes (degrees), as defined in gonio-instrument's module documentation
/// (after zero offset and direction are applied). Absent axes (the in-plane geometry has no tilt) are 0.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    pub light_deg: f64,
    pub detector_deg: f64,
    pub tilt_deg: f64,
    pub rotation_deg: f64,
}

/// What the filter wheel puts in the beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Centre wavelength (nm); `None` at the opaque blank.
    pub band_nm: Option<f64>,
    /// Transmission of the filter (0 for the blank).
    pub transmission: f64,
}

impl Band {
    pub const BLANK: Band = Band {
        band_nm: None,
        transmission: 0.0,
    };
}

/// Optical power reaching the detector.
pub trait Scene: Send + Sync + Debug {
    /// Power on the photodiode (watts) with the axes at `pose`, the filter `band` in the beam, at simulated time
    /// `t_s` seconds since the simulation started (sources drift). Never negative, never NaN.
    fn detector_power_w(&self, pose: &Pose, band: &Band, t_s: f64) -> f64;

    /// The power at one `pose` and `band` at each instant of `times_s`, into `out` (cleared first): exactly
    /// what [`Scene::detector_power_w`] gives at each. The power meter averages several samples of a pose at
    /// rest; a scene whose geometry is costly (the optics' aperture integral) overrides this to compute what does
    /// not depend on time once.
    fn detector_power_series_w(&self, pose: &Pose, band: &Band, times_s: &[f64], out: &mut Vec<f64>) {
        out.clear();
        out.extend(times_s.iter().map(|&t| self.detector_power_w(pose, band, t)));
    }
}

/// A scene in which the detector sees a fixed power whenever a filter (not the blank) is in the beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UniformScene {
    pub power_w: f64,
}

impl Scene for UniformScene {
    fn detector_power_w(&self, _pose: &Pose, band: &Band, _t_s: f64) -> f64 {
        if band.band_nm.is_some() {
            self.power_w * band.transmission
        } else {
            0.0
        }
    }
}
