//! What the console reports: the instrument's state at one instant, and the meter's readings. Serialised as the
//! HTTP API's JSON (every quantity's unit in its name).

use gonio_instrument::AxisRole;
use serde::{Deserialize, Serialize};

/// One axis as its controller reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisState {
    /// The instrument file's name for the axis.
    pub name: String,
    /// Its role (`light-arm`, `detector-arm`, `sample-tilt`, `sample-rotation`).
    pub role: AxisRole,
    /// Read-back position, physical degrees (None when the controller did not answer).
    pub position_deg: Option<f64>,
    pub referenced: Option<bool>,
    pub moving: Option<bool>,
    /// The controller's fault in its own words, or why it could not be asked.
    pub fault: Option<String>,
    pub min_deg: f64,
    pub max_deg: f64,
}

/// The filter wheel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WheelState {
    /// Current position (1-based; None when the wheel did not answer).
    pub position: Option<u8>,
    /// The band of the filter there (None: the blank, or unknown).
    pub band_nm: Option<f64>,
    pub fault: Option<String>,
    /// Every position of the wheel as the instrument file lists it.
    pub filters: Vec<FilterSlot>,
}

/// One position of the filter wheel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilterSlot {
    pub position: u8,
    /// Centre wavelength (nm); None for the blank.
    pub band_nm: Option<f64>,
}

/// One device's identity and whether it answered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceHealth {
    pub name: String,
    pub identity: String,
    /// True when the device answered every question of this state.
    pub ok: bool,
}

/// One meter reading taken through the console.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConsoleReading {
    /// Instrument clock (s since the instrument was connected; the simulated clock in a dry-run).
    pub t_s: f64,
    /// Wall clock (s since the Unix epoch) when the meter returned the reading.
    pub unix_s: f64,
    pub power_w: f64,
    /// Full scale of the meter's range for this reading (W).
    pub range_w: f64,
    /// At or beyond full scale: not a valid measurement.
    pub overload: bool,
    /// The wavelength the meter's responsivity was set for (nm): the filter's band, or
    /// [`super::UNFILTERED_NM`] with the blank or no band filter in the beam.
    pub wavelength_nm: f64,
    /// The band filter in the beam (None: none).
    pub band_nm: Option<f64>,
    pub filter_position: Option<u8>,
    /// Each axis's read-back position when the reading was taken.
    pub axes: Vec<AxisPosition>,
}

/// Where one axis is (read back from its controller).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisPosition {
    pub name: String,
    /// Physical degrees.
    pub position_deg: f64,
}

/// The whole instrument at one instant (`gonio ctl state`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InstrumentState {
    /// The instrument file's name.
    pub instrument: String,
    pub dry_run: bool,
    pub axes: Vec<AxisState>,
    pub wheel: Option<WheelState>,
    /// A reading taken for this state (None when the meter did not answer; the reason is in `devices`).
    pub meter: Option<ConsoleReading>,
    pub devices: Vec<DeviceHealth>,
}
