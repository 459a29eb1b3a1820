//! The filter wheel: its positions, each a band (centre, width and their uncertainties, transmission and
//! blocking) or the opaque blank the darks are read through.

use serde::{Deserialize, Serialize};

/// A filter wheel selecting wavelength bands; one position may be an opaque blank for dark readings.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FilterWheel {
    pub device: String,
    /// Time to turn by one position (s) at `speed`. Users of real FW102C wheels report about 1 s per position at
    /// speed 1 and about 2 s at speed 0.
    pub seconds_per_position: f64,
    /// The wheel's speed mode, which the driver sets at start-up: 1 fast (the default), 0 slow (twice the time
    /// per position).
    #[serde(default = "default_wheel_speed")]
    pub speed: u8,
    pub positions: Vec<FilterPosition>,
}

fn default_wheel_speed() -> u8 {
    1
}

impl FilterWheel {
    /// Gives every filter (not the blank) a passband `bandwidth_nm` wide (FWHM, nm): the ideal file's filters
    /// pass a single wavelength, and what a finite band does (its leak, its centroid, the simulator's passband)
    /// is studied on them made catalogue filters, 10 nm wide.
    pub fn set_bandwidths_nm(&mut self, bandwidth_nm: f64) {
        for p in self.positions.iter_mut().filter(|p| !p.blank) {
            p.bandwidth_nm = Some(bandwidth_nm);
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FilterPosition {
    /// Wheel position, 1-based as the FW102C counts.
    pub position: u8,
    /// Centre wavelength (nm); absent for the blank.
    #[serde(default)]
    pub band_nm: Option<f64>,
    /// Full width at half maximum (nm).
    #[serde(default)]
    pub bandwidth_nm: Option<f64>,
    /// Standard uncertainty of the centre wavelength (nm): a catalogue's "+-2 nm" read as two standard
    /// deviations is 1.0. What the band component of each point's uncertainty is made of (the sample's
    /// spectral slope times this); absent: [`DEFAULT_FILTER_CENTRE_U_NM`].
    #[serde(default)]
    pub centre_u_nm: Option<f64>,
    /// Standard uncertainty of the full width at half maximum (nm), read like `centre_u_nm`; absent:
    /// [`DEFAULT_FILTER_BANDWIDTH_U_NM`]. The light a filter leaks is reckoned against its band's width, so this
    /// is the relative uncertainty of the leakage correction (crate::leakage).
    #[serde(default)]
    pub bandwidth_u_nm: Option<f64>,
    /// Transmission of the filter in its band (0..1).
    #[serde(default = "unit")]
    pub transmission: f64,
    /// Absolute transmission outside the band, where the detector is sensitive: the datasheet's blocking
    /// (optical density 5 is 1e-5); absent: [`DEFAULT_OUT_OF_BAND_TRANSMISSION`]. What each point's leakage
    /// uncertainty is made of (crate::leakage).
    #[serde(default)]
    pub out_of_band_transmission: Option<f64>,
    /// True for the opaque blank.
    #[serde(default)]
    pub blank: bool,
}

fn unit() -> f64 {
    1.0
}

/// A filter's centre-wavelength standard uncertainty when the instrument file does not state it (nm): the
/// +-2 nm tolerance catalogue bandpass filters of 10 nm are sold with, read as two standard deviations.
pub const DEFAULT_FILTER_CENTRE_U_NM: f64 = 1.0;

/// A filter's width standard uncertainty when the instrument file does not state it (nm): catalogue bandpass
/// filters of 10 nm are sold with the same +-2 nm tolerance on the width as on the centre.
pub const DEFAULT_FILTER_BANDWIDTH_U_NM: f64 = 1.0;

/// A filter's blocking when the instrument file does not state it: hard-coated catalogue bandpass filters are
/// sold with an optical density above 5 outside their band (Thorlabs, "Hard-Coated UV/VIS Bandpass Filters").
pub const DEFAULT_OUT_OF_BAND_TRANSMISSION: f64 = 1.0e-5;

impl FilterPosition {
    /// The centre wavelength's standard uncertainty (nm): the file's, else [`DEFAULT_FILTER_CENTRE_U_NM`].
    pub fn centre_u_nm(&self) -> f64 {
        self.centre_u_nm.unwrap_or(DEFAULT_FILTER_CENTRE_U_NM)
    }

    /// The width's standard uncertainty (nm): the file's, else [`DEFAULT_FILTER_BANDWIDTH_U_NM`].
    pub fn bandwidth_u_nm(&self) -> f64 {
        self.bandwidth_u_nm.unwrap_or(DEFAULT_FILTER_BANDWIDTH_U_NM)
    }

    /// The absolute transmission outside the band: the file's, else [`DEFAULT_OUT_OF_BAND_TRANSMISSION`].
    pub fn out_of_band_transmission(&self) -> f64 {
        self.out_of_band_transmission
            .unwrap_or(DEFAULT_OUT_OF_BAND_TRANSMISSION)
    }
}
