//! gonio-instrument: the description of a gonioreflectometer, read from an `[instrument]` TOML file.
//!
//! Pure data plus validation. The simulator builds its virtual instrument from it, the scheduler its kinematics,
//! constraints and time model, and the daemon its drivers. All angles are in degrees in the file and in these
//! types (fields end in `_deg`); lengths in millimetres (`_mm`), times in seconds (`_s`), powers in watts (`_w`).
//!
//! # The reference geometry (what the axis angles mean)
//!
//! Lab frame: X horizontal, Y horizontal, Z vertical (up). Both arms turn about Z through the sample.
//! - An arm at physical angle `a` points along `(cos a, sin a, 0)`: the light arm gives the direction towards the
//!   source, the detector arm the direction towards the detector.
//! - Sample stage at tilt `t = 0`, rotation `r = 0`: the sample normal is +X, the sample's x axis is +Y and its
//!   y axis is +Z. So the arms' horizontal plane is the sample's x-z plane (phi = 0 / 180) at zero tilt.
//! - Tilt `t` turns the sample about lab Y (its own x axis at zero rotation) so that the normal becomes
//!   `n = (cos t, 0, sin t)` and the sample's y axis `(-sin t, 0, cos t)`; the sample's x axis stays lab Y.
//! - Rotation `r` then turns the sample about its normal: `x' = cos r x + sin r y`, `y' = -sin r x + cos r y`.
//! - A lab vector `v` has sample-frame components `(v . x', v . y', v . n)`.
//!
//! The `in-plane` geometry has no tilt axis (t = 0 always): only geometries whose incident and outgoing
//! directions lie in one plane through the normal can be reached.
//!
//! Axis calibration: a controller position `p` (degrees, after converting device units) and the physical angle
//! `a` are related by `a = direction * (p - zero_offset_deg)`, so `p = zero_offset_deg + direction * a`.

//!
//! The records and loading are here; [`Instrument::validate`]'s rules in `validate`.

mod actual;
mod filter_wheel;
pub use filter_wheel::{
    DEFAULT_FILTER_BANDWIDTH_U_NM, DEFAULT_FILTER_CENTRE_U_NM, DEFAULT_OUT_OF_BAND_TRANSMISSION,
    FilterPosition, FilterWheel,
};
mod holder;
pub use holder::{DEFAULT_CENTRING_U_MM, DEFAULT_RESEAT_U_DEG, SampleHolder};
pub mod imperfections;
pub mod leakage;
pub mod meter_noise;
pub mod passband;
pub mod responsivity;
pub mod signature;
mod validate;

use std::path::Path;

pub use imperfections::{
    BeamImperfections, BeamProfile, DetectorImperfections, FilterImperfections, GeometryImperfections,
    Imperfections, ImperfectionsError, SampleImperfections, SourceImperfections, TimingImperfections,
};

use serde::{Deserialize, Serialize};

mod quirks;
pub use actual::{Actual, ActualAxis, ActualWheel};
pub use quirks::{Pm100Overrange, Quirks, ZaberBadChecksum};

/// A whole instrument file: `[instrument]`, and for simulated instruments `[simulator]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InstrumentFile {
    pub instrument: Instrument,
    /// Only used when the instrument is simulated: noise and fault settings.
    #[serde(default)]
    pub simulator: SimulatorSettings,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Instrument {
    pub name: String,
    /// Which kinematic geometry the axes form.
    pub geometry: GeometryKind,
    pub devices: Vec<Device>,
    pub axes: Vec<Axis>,
    pub source: Source,
    pub detector: Detector,
    pub filter_wheel: Option<FilterWheel>,
    pub sample_holder: SampleHolder,
    pub safety: Safety,
    /// How well the angles are known while no alignment (`gonio align`) is applied: the standard uncertainty
    /// of the arms' zeros and of the sample's normal (degrees), as the lab's mechanical set-up gives them; what
    /// each point's pointing uncertainty is made of then. Absent: [`DEFAULT_ALIGNMENT_U_DEG`].
    #[serde(default)]
    pub alignment_u_deg: Option<f64>,
}

/// The angles' standard uncertainty without an alignment when the instrument file does not state it (deg):
/// zeros found by eye against the beam and a sample pressed against its holder's face, a few hundredths of a
/// degree each, within the 0.1 degree a reflectance goniometer is typically specified to (Fiorentin & Scroccaro,
/// IEEE Trans. Instrum. Meas. 57(11), 2008).
pub const DEFAULT_ALIGNMENT_U_DEG: f64 = 0.05;

impl Instrument {
    /// The angles' standard uncertainty without an alignment (deg): the file's, else [`DEFAULT_ALIGNMENT_U_DEG`].
    pub fn alignment_u_deg(&self) -> f64 {
        self.alignment_u_deg.unwrap_or(DEFAULT_ALIGNMENT_U_DEG)
    }

    /// Where an axis stops against its target while nothing but the controller says so (deg, standard): its
    /// arrival tolerance as a uniform distribution, the loosest axis's.
    pub fn arrival_u_deg(&self) -> f64 {
        let tolerance = self.axes.iter().map(|a| a.tolerance_deg).fold(0.0f64, f64::max);
        tolerance / 3f64.sqrt()
    }

    /// Where an axis stands against its read-back position (deg, standard): the encoder's resolution as a
    /// uniform distribution one step wide, the coarsest axis's.
    pub fn read_back_u_deg(&self) -> f64 {
        let resolution = self
            .axes
            .iter()
            .map(|a| a.encoder_resolution_deg)
            .fold(0.0f64, f64::max);
        resolution / 12f64.sqrt()
    }
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum GeometryKind {
    /// Light arm, detector arm, sample tilt and sample rotation: any pair of directions.
    Reference,
    /// Light arm, detector arm and sample rotation: in-plane geometries only.
    InPlane,
}

/// A physical device: a controller chain on a serial port, a power meter on USB, a filter wheel.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Device {
    /// Name other tables refer to (e.g. "arms").
    pub name: String,
    pub protocol: Protocol,
    /// Serial port path, e.g. "/dev/ttyUSB0". Absent or "sim" for the embedded simulator, reached in process.
    /// "sim-pty": also the embedded simulator, but a serial device is served on a real pseudo-terminal and
    /// opened by its path like a real port (the whole serial path of real hardware is exercised); a USB device
    /// (the power meter) stays in process. For a USB device, "usb-socket:PATH" reaches it on a Unix socket
    /// instead of the bus (the simulated meter of a separate `gonio sim --link-dir`).
    #[serde(default)]
    pub port: Option<String>,
    /// Serial baud rate; defaults to the protocol's factory setting.
    #[serde(default)]
    pub baud: Option<u32>,
    /// USB vendor id (power meters), e.g. 0x1313.
    #[serde(default)]
    pub usb_vendor_id: Option<u16>,
    /// USB product id (power meters), e.g. 0x8072.
    #[serde(default)]
    pub usb_product_id: Option<u16>,
    /// USB serial number, to pick one of several identical meters.
    #[serde(default)]
    pub usb_serial: Option<String>,
    /// What a motion controller takes to answer a query beyond its reply's time on the line (ms): the
    /// controller's own execution (the SMC100 manual gives about 10 ms for a position query) and the request's
    /// time on the line. `gonio selftest` measures it and `--write` records it; the time model adds it to every
    /// exchange with the device. Absent: none (predictions are then short by that much per exchange on hardware
    /// that takes it).
    #[serde(default)]
    pub reply_latency_ms: Option<f64>,
    /// When a motion controller takes the position it reports, counted from the host's sending of the query
    /// (ms): at least the query's time on the line (about 0.9 ms for an SMC100 `1TP` at 57,600 baud) and at
    /// most that and its reply latency; the simulator's devices take it as the query is sent (0: its request's
    /// time on the line is inside its reply latency). A sweep dates its position reports by it to place its
    /// readings where the arm was; absent, it dates them in the middle of the window between the query's
    /// arrival and the reply's start and counts the window in their timing uncertainty. `gonio selftest`
    /// measures it (the direct beam swept both ways at two speeds) and `--write` records it. What it measures
    /// is the controller's instant less the meter's own delay in starting a reading after its request, which is
    /// what placing the readings needs: below zero (down to -250 ms) when the meter's delay is the longer.
    #[serde(default)]
    pub position_sampled_ms: Option<f64>,
}

/// The `port` value for a simulated device served on a pseudo-terminal (see [`Device::port`]).
pub const SIM_PTY_PORT: &str = "sim-pty";

impl Device {
    /// The line's baud rate: the file's, else the protocol's factory setting (0 for a USB device).
    pub fn line_baud(&self) -> u32 {
        self.baud.unwrap_or_else(|| self.protocol.default_baud())
    }

    /// True when this device is the embedded simulator rather than a real port or USB device.
    pub fn is_simulated(&self) -> bool {
        match &self.port {
            None => self.usb_vendor_id.is_none(),
            Some(p) => p == "sim" || p == SIM_PTY_PORT,
        }
    }

    /// True for `port = "sim-pty"`: simulated, and (for a serial device) served on a pseudo-terminal.
    pub fn is_sim_pty(&self) -> bool {
        self.port.as_deref() == Some(SIM_PTY_PORT)
    }
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    Smc100,
    ZaberAscii,
    Fw102c,
    Pm100,
}

impl Protocol {
    pub fn name(&self) -> &'static str {
        match self {
            Protocol::Smc100 => "smc100",
            Protocol::ZaberAscii => "zaber-ascii",
            Protocol::Fw102c => "fw102c",
            Protocol::Pm100 => "pm100",
        }
    }

    pub fn default_baud(&self) -> u32 {
        match self {
            Protocol::Smc100 => 57_600,
            Protocol::ZaberAscii | Protocol::Fw102c => 115_200,
            Protocol::Pm100 => 0,
        }
    }
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[serde(rename_all = "kebab-case")]
pub enum AxisRole {
    LightArm,
    DetectorArm,
    SampleTilt,
    SampleRotation,
}

/// One motorised rotation axis.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Axis {
    /// Name used in CSV column headers (`<name>_deg`) and messages.
    pub name: String,
    pub role: AxisRole,
    /// Name of the device (controller chain) that drives it.
    pub device: String,
    /// Controller address on the chain: SMC100 address 1..31, Zaber device number 1..99.
    pub address: u8,
    /// Zaber axis number on a multi-axis device (1..); ignored for SMC100.
    #[serde(default = "one")]
    pub zaber_axis: u8,
    /// Degrees per microstep for controllers that count microsteps (Zaber); ignored for SMC100.
    #[serde(default)]
    pub microstep_deg: Option<f64>,
    /// Physical limits of travel.
    pub min_deg: f64,
    pub max_deg: f64,
    pub max_speed_deg_s: f64,
    pub accel_deg_s2: f64,
    /// Mechanical backlash; targets are approached from below by more than this when non-zero.
    #[serde(default)]
    pub backlash_deg: f64,
    /// Resolution of the encoder read-back.
    pub encoder_resolution_deg: f64,
    /// A position read back within this of the target counts as arrived.
    pub tolerance_deg: f64,
    /// Time to wait after arrival for vibrations to die down.
    #[serde(default)]
    pub settle_s: f64,
    /// Controller position of the physical zero.
    #[serde(default)]
    pub zero_offset_deg: f64,
    /// +1 or -1: sense of the controller's positive direction relative to the physical angle.
    #[serde(default = "plus_one")]
    pub direction: i8,
}

impl Axis {
    /// Controller position (degrees) for a physical angle (degrees).
    pub fn controller_from_physical_deg(&self, physical_deg: f64) -> f64 {
        self.zero_offset_deg + f64::from(self.direction) * physical_deg
    }

    /// Physical angle (degrees) for a controller position (degrees).
    pub fn physical_from_controller_deg(&self, controller_deg: f64) -> f64 {
        f64::from(self.direction) * (controller_deg - self.zero_offset_deg)
    }
}

fn one() -> u8 {
    1
}
fn plus_one() -> i8 {
    1
}

/// The light source: a collimated beam.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// Beam power reaching the sample, before any filter (watts).
    pub power_w: f64,
    /// Radius of the collimated beam (mm).
    pub beam_radius_mm: f64,
    /// Full-angle divergence of the beam (degrees); spreads a mirror reflection.
    #[serde(default)]
    pub divergence_deg: f64,
    /// Relative drift of the source power per hour (simulation; e.g. 0.002 = 0.2 %/h).
    #[serde(default)]
    pub drift_per_hour: f64,
    /// Relative standard deviation of the source power from reading to reading (simulation).
    #[serde(default)]
    pub relative_noise: f64,
    /// The source's slow fluctuation (flicker): the relative standard deviation of its power about a straight
    /// line over two minutes, what averaging a reading does not remove and references minutes apart do not
    /// follow. `gonio selftest` measures it on the direct beam; each value's budget carries it (`flicker`).
    /// The simulator does not take it from here: its lamp's flicker is `[simulator.imperfections.source]`.
    #[serde(default)]
    pub flicker_rel: f64,
    /// How well the beam's direction was set along the light arm's axis (deg, standard uncertainty; absent:
    /// the file's `alignment_u_deg`). With `offset_u_mm` it splits the beam's line an alignment observes
    /// between the beam's direction and its offset (gonio_engine::align::beam_split).
    #[serde(default)]
    pub pointing_u_deg: Option<f64>,
    /// How well the beam was centred on the arms' axis (mm, standard uncertainty, across the beam; absent:
    /// [`DEFAULT_BEAM_OFFSET_U_MM`]).
    #[serde(default)]
    pub offset_u_mm: Option<f64>,
    /// The wavelength when there is no filter wheel (nm).
    #[serde(default)]
    pub wavelength_nm: Option<f64>,
    /// The source's spectrum as a black body's colour temperature (K): what weights the light a filter leaks
    /// outside its band (crate::leakage); absent: [`DEFAULT_COLOUR_TEMPERATURE_K`].
    #[serde(default)]
    pub colour_temperature_k: Option<f64>,
}

/// A source's colour temperature when the instrument file does not state it (K): a quartz-tungsten-halogen lamp
/// at its usual operating point (they run at 2800-3400 K).
pub const DEFAULT_COLOUR_TEMPERATURE_K: f64 = 3000.0;

/// How well a beam is centred on the arms' axis when the instrument file does not say (mm, standard
/// uncertainty): against a cross-hair or a pinhole on the axis by eye, about a tenth of a millimetre.
pub const DEFAULT_BEAM_OFFSET_U_MM: f64 = 0.1;

impl Source {
    /// How well the beam's direction was set (deg, standard uncertainty): the file's `pointing_u_deg`, else
    /// `alignment_u_deg` (the instrument's angles as known without an alignment).
    pub fn pointing_u_or(&self, alignment_u_deg: f64) -> f64 {
        self.pointing_u_deg.unwrap_or(alignment_u_deg)
    }

    /// How well the beam was centred on the arms' axis (mm, standard uncertainty): the file's `offset_u_mm`,
    /// else [`DEFAULT_BEAM_OFFSET_U_MM`].
    pub fn offset_u_or_default(&self) -> f64 {
        self.offset_u_mm.unwrap_or(DEFAULT_BEAM_OFFSET_U_MM)
    }

    /// The source's colour temperature (K): the file's, else [`DEFAULT_COLOUR_TEMPERATURE_K`].
    pub fn colour_temperature_k(&self) -> f64 {
        self.colour_temperature_k.unwrap_or(DEFAULT_COLOUR_TEMPERATURE_K)
    }
}

/// The photodiode detector behind a circular aperture.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Detector {
    /// Name of the power meter device.
    pub device: String,
    /// Radius of the limiting aperture (mm).
    pub aperture_radius_mm: f64,
    /// Distance from the sample centre to the aperture (mm).
    pub distance_mm: f64,
    /// Radius of the spot on the sample the detector sees fully (mm): its field of view.
    pub field_radius_mm: f64,
    /// Photodiode responsivity (A/W), a number or a table nm -> A/W. Used by the simulator.
    #[serde(default)]
    pub responsivity_a_per_w: Option<toml::Value>,
    /// Dark current (A); simulation.
    #[serde(default)]
    pub dark_current_a: f64,
    /// Measurement ranges of the power meter (W, full scale), smallest first.
    pub ranges_w: Vec<f64>,
    /// Samples averaged per reading (the PM100 takes about 3 ms per sample).
    #[serde(default = "default_averaging")]
    pub averaging: u32,
    /// Enable the simulated noise terms (shot, Johnson, quantisation).
    #[serde(default)]
    pub noise: bool,
    /// The head's excess input current noise (A/sqrt(Hz)) above the photocurrent's shot noise and the feedback
    /// resistor's Johnson noise: its amplifier's, from the head's datasheet or a dark measurement. It dominates
    /// the lowest ranges, so a value read there carries it in its `signal-noise` until a characterisation
    /// (`gonio align --steps characterisation`) has measured the darks' spread. Absent: 0 (none known).
    #[serde(default)]
    pub amplifier_noise_a_per_rthz: f64,
    /// Relative standard uncertainty of each range's gain (its factory calibration) while no characterisation
    /// (`gonio align`) has measured it; absent: [`DEFAULT_RANGE_GAIN_U`].
    #[serde(default)]
    pub range_gain_u: Option<f64>,
    /// Relative standard uncertainty of the detector's solid angle, from how well the aperture's radius and its
    /// distance are known (`2 u_r / r` and `2 u_d / d` in quadrature); absent: [`DEFAULT_SOLID_ANGLE_U`].
    #[serde(default)]
    pub solid_angle_u: Option<f64>,
    /// The instrument signature (ASTM E2387: what the detector reads with no sample, as a BRDF-equivalent along
    /// the normal, 1/sr) as well as it is known without a characterisation: a standard uncertainty on every value
    /// no measured signature was subtracted from. A number, or a table from the angle between the detector and
    /// the undeviated beam (deg) to the level there (crate::signature). A characterisation (`gonio align --steps
    /// characterisation`) measures the signature and replaces it. Absent: [`DEFAULT_SIGNATURE_U_SR`].
    #[serde(default)]
    pub signature_u_sr: Option<toml::Value>,
    /// The sensor's wavelength limits (nm), which the meter reads from the sensor head and reports for
    /// `SENS:CORR:WAV? MIN` / `MAX`; simulation. Default: 400 to 1100 nm (Thorlabs S120C photodiode sensor).
    #[serde(default = "default_sensor_wavelength_nm")]
    pub sensor_wavelength_nm: [f64; 2],
}

/// A range's gain uncertainty when the instrument file does not state it: Thorlabs' PM100USB datasheet gives
/// the photodiode-current accuracy as +-0.2 % of full scale, read as two standard deviations.
pub const DEFAULT_RANGE_GAIN_U: f64 = 1.0e-3;

/// The solid angle's relative uncertainty when the instrument file does not state it: a 2.5 mm aperture known
/// to 1 um and its 250 mm distance known to 0.1 mm give 0.08 % each, 0.11 % together.
pub const DEFAULT_SOLID_ANGLE_U: f64 = 1.1e-3;

/// The instrument signature's standard uncertainty when the instrument file does not state it (1/sr): Stover,
/// "Optical Scattering" (2nd ed., SPIE 1995), ch. 6, puts a well-baffled scatterometer's signature at 1e-7..1e-5
/// 1/sr away from the beam; an open lab goniometer is taken at the high end.
pub const DEFAULT_SIGNATURE_U_SR: f64 = 1.0e-5;

impl Detector {
    /// Each range's relative gain uncertainty before a characterisation: the file's, else
    /// [`DEFAULT_RANGE_GAIN_U`].
    pub fn range_gain_u(&self) -> f64 {
        self.range_gain_u.unwrap_or(DEFAULT_RANGE_GAIN_U)
    }

    /// The solid angle's relative standard uncertainty: the file's, else [`DEFAULT_SOLID_ANGLE_U`].
    pub fn solid_angle_u(&self) -> f64 {
        self.solid_angle_u.unwrap_or(DEFAULT_SOLID_ANGLE_U)
    }
}

fn default_sensor_wavelength_nm() -> [f64; 2] {
    [400.0, 1100.0]
}

fn default_averaging() -> u32 {
    10
}

/// Limits the scheduler and the daemon enforce.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Safety {
    /// Minimum angle between the two arms at every instant (arm widths plus margin).
    pub min_arm_separation_deg: f64,
    /// The detector blocks the incident beam when it is within this angle of the source direction.
    pub retro_block_deg: f64,
    /// Largest polar angle (from the sample normal) for either direction.
    pub grazing_limit_deg: f64,
}

/// Settings that only the simulated instrument reads.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SimulatorSettings {
    /// Seed for every random draw (noise, faults).
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub faults: Faults,
    /// The instrument's imperfections (magnitudes; the actual values are drawn from `seed`). All off by default:
    /// the ideal instrument. See [`imperfections`].
    #[serde(default)]
    pub imperfections: Imperfections,
    /// Which of the devices' recorded variants the simulator shows (see [`Quirks`]).
    #[serde(default)]
    pub quirks: Quirks,
    /// The hardware as it really is where it differs from the file's claims (see [`Actual`]).
    #[serde(default)]
    pub actual: Actual,
}

/// Fault injection; everything off by default.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Faults {
    #[serde(default)]
    pub seed: u64,
    /// Probability that a reply has one byte corrupted.
    #[serde(default)]
    pub garble_rate: f64,
    /// Probability that a reply is lost.
    #[serde(default)]
    pub drop_rate: f64,
    /// Extra latency added to each reply (ms).
    #[serde(default)]
    pub delay_ms: f64,
    /// Random extra latency: each reply is delayed by a further uniform draw in [0, delay_jitter_ms] (ms).
    #[serde(default)]
    pub delay_jitter_ms: f64,
    /// Probability that a move stops short with the device's own error state.
    #[serde(default)]
    pub stall_rate: f64,
    /// The port or USB device vanishes after this many seconds of instrument time...
    #[serde(default)]
    pub disconnect_after_s: Option<f64>,
    /// ...and comes back this many seconds later.
    #[serde(default)]
    pub reconnect_after_s: Option<f64>,
    /// ...and, when set, vanishes again every this many seconds after the first time (must exceed
    /// `reconnect_after_s`): a disconnect every few minutes for soak tests. Unset: one disconnect only.
    #[serde(default)]
    pub disconnect_every_s: Option<f64>,
    /// Force the detector into overload.
    #[serde(default)]
    pub saturate: bool,
}

/// What is wrong with an instrument description that parsed: the message names the table and key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidInstrument(pub String);

/// Why an instrument description was refused.
#[derive(Debug, thiserror::Error)]
pub enum InstrumentError {
    #[error("cannot read instrument file {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("instrument file {path}: {message}")]
    Parse { path: String, message: String },
    #[error("instrument file {path}: {message}")]
    Invalid { path: String, message: String },
}

/// The default simulated instrument, embedded so that the binary runs with no file at all.
pub const SIMULATED_INSTRUMENT_TOML: &str = include_str!("../../../config/instruments/simulated.toml");

impl InstrumentFile {
    /// Read and validate an instrument file.
    pub fn load(path: &Path) -> Result<InstrumentFile, InstrumentError> {
        let text = std::fs::read_to_string(path).map_err(|source| InstrumentError::Read {
            path: path.display().to_string(),
            source,
        })?;
        InstrumentFile::parse(&text, &path.display().to_string())
    }

    /// The embedded default: the simulated instrument.
    pub fn simulated() -> InstrumentFile {
        // The embedded file is validated by a unit test, so this cannot fail in a released binary.
        InstrumentFile::parse(SIMULATED_INSTRUMENT_TOML, "<embedded simulated.toml>")
            .unwrap_or_else(|e| panic!("the embedded simulated instrument is invalid: {e}"))
    }

    /// Parse and validate TOML text; `origin` names the file in messages.
    pub fn parse(text: &str, origin: &str) -> Result<InstrumentFile, InstrumentError> {
        let file: InstrumentFile = toml::from_str(text).map_err(|e| InstrumentError::Parse {
            path: origin.to_string(),
            message: e.to_string(),
        })?;
        file.instrument.validate().map_err(|e| InstrumentError::Invalid {
            path: origin.to_string(),
            message: e.0,
        })?;
        file.simulator
            .imperfections
            .validate()
            .map_err(|e| InstrumentError::Invalid {
                path: origin.to_string(),
                message: e.to_string(),
            })?;
        file.simulator
            .actual
            .validate(&file.instrument)
            .map_err(|e| InstrumentError::Invalid {
                path: origin.to_string(),
                message: e.0,
            })?;
        Ok(file)
    }
}

impl Instrument {
    pub fn axis(&self, role: AxisRole) -> Option<&Axis> {
        self.axes.iter().find(|a| a.role == role)
    }

    pub fn device(&self, name: &str) -> Option<&Device> {
        self.devices.iter().find(|d| d.name == name)
    }

    /// Bands the filter wheel offers (nm), blank excluded; or the source's single wavelength.
    pub fn bands_nm(&self) -> Vec<f64> {
        match &self.filter_wheel {
            Some(w) => w
                .positions
                .iter()
                .filter(|p| !p.blank)
                .filter_map(|p| p.band_nm)
                .collect(),
            None => self.source.wavelength_nm.into_iter().collect(),
        }
    }
}

#[cfg(test)]
mod tests;
