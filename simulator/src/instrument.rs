//! [`SimInstrument`]: the whole simulated instrument, built from an instrument file, and its in-process API.
//!
//! It owns the physical state (where every axis really is, which filter is in the beam), the device emulators
//! that speak the real protocols over it, the fault injector and the simulated clock. Hosts reach the serial
//! devices through [`SimInstrument::serial_port`] (a duplex byte stream, exactly what a port would carry) and
//! the power meter through [`SimInstrument::usb_device`] (bulk and control transfers, as libusb would give).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use gonio_instrument::{Axis, InstrumentFile, Protocol};

use crate::clock::SimClock;
use crate::faults::{FaultCounts, FaultInjector};
use crate::fw102c::Fw102c;
use crate::motion::{AxisMotion, AxisParams, Settling};
use crate::pm100::{Pm100, SimUsbDevice};
use crate::recording::MotionRecord;
use crate::scene::{Band, Pose, Scene};
use crate::session::{self, SerialStream, SharedEmulator};
use crate::smc100::Smc100Chain;
use crate::world::World;
use crate::zaber::ZaberChain;

/// Why the simulated instrument could not be built or a device not reached.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("simulated instrument: {0}")]
    Invalid(String),
    #[error("simulated instrument: {0}")]
    Imperfections(#[from] gonio_instrument::ImperfectionsError),
    #[error("simulated instrument has no device named {device:?}")]
    UnknownDevice { device: String },
    #[error("device {device:?} speaks {protocol}, which is not a {wanted} device")]
    WrongKind {
        device: String,
        protocol: &'static str,
        wanted: &'static str,
    },
    #[error("device {device:?} is disconnected (simulated fault)")]
    Disconnected { device: String },
    #[error("the simulated device {device:?} must be opened inside a tokio runtime")]
    NoRuntime { device: String },
    #[error("simulated device {device:?}: pseudo-terminal: {message}")]
    Pty { device: String, message: String },
    #[error("simulated device {device:?}: FunctionFS gadget: {message}")]
    Gadget { device: String, message: String },
}

/// The simulated instrument. Cheap to clone: every clone shares the same devices and clock.
#[derive(Debug, Clone)]
pub struct SimInstrument {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    file: InstrumentFile,
    world: Arc<World>,
    faults: Arc<FaultInjector>,
    serial: BTreeMap<String, (Protocol, SharedEmulator)>,
    meters: BTreeMap<String, Arc<Pm100>>,
    /// The hidden imperfections drawn from the file's magnitudes and seed; `None` on the ideal instrument.
    hidden: Option<crate::imperfections::HiddenTruth>,
}

impl SimInstrument {
    /// Build the instrument. `time_scale` is simulated seconds per real (tokio) second, finite and > 0.
    pub fn new(
        file: &InstrumentFile,
        scene: Arc<dyn Scene>,
        time_scale: f64,
    ) -> Result<SimInstrument, SimError> {
        if !(time_scale.is_finite() && time_scale > 0.0) {
            return Err(SimError::Invalid(format!(
                "time scale must be finite and > 0, got {time_scale}"
            )));
        }
        file.instrument.validate().map_err(|e| SimError::Invalid(e.0))?;
        FaultInjector::validate(&file.simulator.faults).map_err(|e| SimError::Invalid(e.0))?;
        file.simulator.imperfections.validate()?;
        let hidden = crate::imperfections::HiddenTruth::draw(file);
        // The devices are the hardware as it really is (hidden timing, `[simulator.actual]`); the engine plans
        // with the file.
        let actual = crate::imperfections::HiddenTruth::real_instrument(file, hidden.as_ref());
        let inst = &actual;
        let clock = SimClock::new(time_scale);
        let faults = Arc::new(FaultInjector::new(file.simulator.faults.clone()));

        let mut axes = Vec::new();
        for axis in &inst.axes {
            let a = axis.controller_from_physical_deg(axis.min_deg);
            let b = axis.controller_from_physical_deg(axis.max_deg);
            let params = AxisParams {
                hw_min_deg: a.min(b),
                hw_max_deg: a.max(b),
                backlash_deg: axis.backlash_deg,
                encoder_resolution_deg: axis.encoder_resolution_deg,
            };
            // Power-up position: the counter's zero, or the nearest end of travel if zero is outside it.
            let start = 0.0f64.clamp(params.hw_min_deg, params.hw_max_deg);
            // The load rings after each move (crate::motion::settling) on an instrument whose settle times are
            // drawn or stated as the hardware's; the ideal instrument's loads stop dead, as before.
            let rings = file.simulator.imperfections.timing.settle_sd > 0.0
                || file
                    .simulator
                    .actual
                    .axes
                    .get(&axis.name)
                    .is_some_and(|a| a.settle_s.is_some());
            let motion = AxisMotion::new(params, start)
                .with_mechanical_limits(axis.max_speed_deg_s, axis.accel_deg_s2)
                .with_settling(
                    rings
                        .then(|| Settling::new(axis.settle_s, axis.tolerance_deg))
                        .flatten(),
                );
            axes.push((axis.clone(), Arc::new(Mutex::new(motion))));
        }

        let mut serial: BTreeMap<String, (Protocol, SharedEmulator)> = BTreeMap::new();
        let mut wheel = None;
        for dev in &inst.devices {
            let dev_axes: Vec<(Axis, Arc<Mutex<AxisMotion>>)> = axes
                .iter()
                .filter(|(a, _)| a.device == dev.name)
                .cloned()
                .collect();
            let dev_faults = faults.for_device(&dev.name);
            match dev.protocol {
                Protocol::Smc100 => {
                    let emu: SharedEmulator = Arc::new(Mutex::new(
                        Smc100Chain::new(&dev.name, dev_axes, dev_faults).with_quirks(&file.simulator.quirks),
                    ));
                    serial.insert(dev.name.clone(), (dev.protocol, emu));
                }
                Protocol::ZaberAscii => {
                    let emu: SharedEmulator = Arc::new(Mutex::new(
                        ZaberChain::new(&dev.name, dev_axes, dev_faults, clock)
                            .with_bad_checksum(file.simulator.quirks.zaber_bad_checksum),
                    ));
                    serial.insert(dev.name.clone(), (dev.protocol, emu));
                }
                Protocol::Fw102c => {
                    let config = inst.filter_wheel.as_ref().filter(|w| w.device == dev.name);
                    let w = Arc::new(Mutex::new(
                        Fw102c::new(&dev.name, config)
                            .with_noise_at_open(file.simulator.quirks.fw102c_noise_at_open),
                    ));
                    if config.is_some() {
                        wheel = Some(Arc::clone(&w));
                    }
                    let emu: SharedEmulator = w;
                    serial.insert(dev.name.clone(), (dev.protocol, emu));
                }
                Protocol::Pm100 => {}
            }
        }
        let fixed_band = Band {
            band_nm: inst.source.wavelength_nm,
            transmission: 1.0,
        };
        let world = Arc::new(World {
            clock,
            scene,
            axes,
            wheel,
            fixed_band,
        });

        let mut meters = BTreeMap::new();
        for dev in inst.devices.iter().filter(|d| d.protocol == Protocol::Pm100) {
            let meter = Pm100::new(
                dev,
                inst,
                &file.simulator,
                Arc::clone(&world),
                faults.for_device(&dev.name),
                hidden.as_ref().and_then(|h| h.detector.clone()),
            )
            .map_err(SimError::Invalid)?;
            meters.insert(dev.name.clone(), Arc::new(meter));
        }
        Ok(SimInstrument {
            inner: Arc::new(Inner {
                file: file.clone(),
                world,
                faults,
                serial,
                meters,
                hidden,
            }),
        })
    }

    /// The instrument file this simulation was built from.
    pub fn file(&self) -> &InstrumentFile {
        &self.inner.file
    }

    /// The instrument's hidden imperfections (`None`: the ideal instrument). The simulator's optics compute with
    /// them; the devices report what the controllers believe. For tests and a dry-run's run.json only: the rig
    /// passes them to the optics it builds and never to the engine.
    pub fn hidden_truth(&self) -> Option<&crate::imperfections::HiddenTruth> {
        self.inner.hidden.as_ref()
    }

    /// Open the named serial device: returns the host end of a byte stream to its emulator (whose task is
    /// spawned on the current tokio runtime). Fails while the device is disconnected by a fault.
    pub fn serial_port(&self, device: &str) -> Result<SerialStream, SimError> {
        let (protocol, emu) = self.serial_emulator(device)?;
        let handle = tokio::runtime::Handle::try_current().map_err(|_| SimError::NoRuntime {
            device: device.to_string(),
        })?;
        let now = self.inner.world.clock.now_s();
        if !self.inner.faults.link_up(now) {
            self.inner.faults.note_refused_open(device, now);
            return Err(SimError::Disconnected {
                device: device.to_string(),
            });
        }
        let (host, dev) = session::link(self.inner.world.clock, 64 * 1024);
        tracing::debug!(device, protocol = protocol.name(), "simulated serial port opened");
        let baud = self
            .inner
            .file
            .instrument
            .device(device)
            .map_or_else(|| protocol.default_baud(), gonio_instrument::Device::line_baud);
        // The hardware's own time to answer, and when it takes what it reports: the file's, or
        // `[simulator.actual.devices]`'s.
        let actual = self.inner.file.actual_instrument();
        let actual_device = actual.device(device);
        let latency_ms = actual_device.and_then(|d| d.reply_latency_ms).unwrap_or(0.0);
        let act_after_ms = actual_device.and_then(|d| d.position_sampled_ms).unwrap_or(0.0);
        handle.spawn(session::serve(
            dev,
            emu,
            self.inner.faults.for_device(device),
            self.inner.world.clock,
            device.to_string(),
            session::LineRate::from_baud(baud)
                .with_latency_s(latency_ms / 1000.0)
                .with_act_after_s(act_after_ms / 1000.0),
        ));
        Ok(host)
    }

    pub(crate) fn serial_emulator(&self, device: &str) -> Result<(Protocol, SharedEmulator), SimError> {
        if let Some((p, emu)) = self.inner.serial.get(device) {
            return Ok((*p, Arc::clone(emu)));
        }
        match self.inner.file.instrument.device(device) {
            Some(d) => Err(SimError::WrongKind {
                device: device.into(),
                protocol: d.protocol.name(),
                wanted: "serial",
            }),
            None => Err(SimError::UnknownDevice {
                device: device.into(),
            }),
        }
    }

    /// Open the named USB power meter. Fails while the device is disconnected by a fault.
    pub fn usb_device(&self, device: &str) -> Result<SimUsbDevice, SimError> {
        let Some(meter) = self.inner.meters.get(device) else {
            return match self.inner.file.instrument.device(device) {
                Some(d) => Err(SimError::WrongKind {
                    device: device.into(),
                    protocol: d.protocol.name(),
                    wanted: "USB",
                }),
                None => Err(SimError::UnknownDevice {
                    device: device.into(),
                }),
            };
        };
        let now = self.inner.world.clock.now_s();
        if !self.inner.faults.link_up(now) {
            self.inner.faults.note_refused_open(device, now);
            return Err(SimError::Disconnected {
                device: device.to_string(),
            });
        }
        Ok(SimUsbDevice::open(Arc::clone(meter), now))
    }

    /// Names and protocols of the serial devices (what `gonio sim` puts on pseudo-terminals).
    pub fn serial_devices(&self) -> Vec<(String, Protocol)> {
        self.inner
            .serial
            .iter()
            .map(|(name, (p, _))| (name.clone(), *p))
            .collect()
    }

    /// What the imperfections did to the named meter's last reading (hidden truth, for a dry-run's record and
    /// tests); `None` on the ideal instrument, before any reading, or for an unknown device.
    pub fn last_meter_effects(&self, device: &str) -> Option<crate::imperfections::MeterEffects> {
        self.inner.meters.get(device).and_then(|m| m.last_effects())
    }

    /// Names of the USB devices (power meters).
    pub fn usb_devices(&self) -> Vec<String> {
        self.inner.meters.keys().cloned().collect()
    }

    /// Where the controllers' positions put the axes by the instrument file's calibration (degrees, after zero
    /// offset and direction): the pose the optics are given. On an imperfect instrument the optics turn it into
    /// the true geometry (`Optics::true_geometry`).
    pub fn pose(&self) -> Pose {
        self.inner.world.pose(self.now_s())
    }

    /// What the filter wheel puts in the beam now (the blank while the wheel turns between positions).
    pub fn band(&self) -> Band {
        self.inner.world.band(self.now_s())
    }

    /// Simulated seconds since the instrument was built.
    pub fn now_s(&self) -> f64 {
        self.inner.world.clock.now_s()
    }

    /// The simulated clock (for sleeping in simulated time).
    pub fn clock(&self) -> SimClock {
        self.inner.world.clock
    }

    /// The optical power on the detector now (watts), straight from the scene: ground truth for tests.
    pub fn detector_power_w(&self) -> f64 {
        let t = self.now_s();
        self.inner
            .world
            .scene
            .detector_power_w(&self.inner.world.pose(t), &self.inner.world.band(t), t)
    }

    /// How many faults of each kind were injected so far.
    pub fn fault_counts(&self) -> FaultCounts {
        self.inner.faults.counts()
    }

    /// Command lines the serial devices lost so far because they came while the device could not take them
    /// (`[simulator.quirks] smc100_min_command_gap_ms`): always zero on the ideal instrument, which takes every
    /// line as the manual describes; under the recorded pacing (config/instruments/realistic.toml), zero for a
    /// host that paces its commands as it should.
    pub fn lost_input_lines(&self) -> u64 {
        self.lost_input_by_command().values().sum()
    }

    /// [`SimInstrument::lost_input_lines`] by command code (`ST`, `TE`, ...), over every serial device.
    pub fn lost_input_by_command(&self) -> BTreeMap<String, u64> {
        let mut all = BTreeMap::new();
        for (_, emu) in self.inner.serial.values() {
            for (code, n) in emu.lock().unwrap_or_else(|e| e.into_inner()).lost_input() {
                *all.entry(code).or_default() += n;
            }
        }
        all
    }

    /// Start recording, on every axis, the motion commands the emulators receive and every change of the
    /// motor's profile (see [`crate::recording`]); an earlier record is discarded.
    pub fn start_motion_recording(&self) {
        let now = self.now_s();
        for (_, motion) in &self.inner.world.axes {
            motion
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .start_recording(now);
        }
    }

    /// The records so far (recording goes on), per axis in instrument-file order; empty records when recording
    /// was never started.
    pub fn motion_records(&self) -> Vec<(Axis, MotionRecord)> {
        self.inner
            .world
            .axes
            .iter()
            .map(|(axis, motion)| {
                let m = motion.lock().unwrap_or_else(|e| e.into_inner());
                (axis.clone(), m.record().cloned().unwrap_or_default())
            })
            .collect()
    }

    /// Stop every axis now, as each controller's own stop does (the controllers' states say so).
    pub fn estop(&self) {
        let now = self.now_s();
        tracing::warn!(t_s = now, "simulated instrument: emergency stop of all axes");
        for (_, emu) in self.inner.serial.values() {
            emu.lock().unwrap_or_else(|e| e.into_inner()).estop(now);
        }
    }
}
