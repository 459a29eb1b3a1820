//! The connected instrument: one driver per axis, the detector, the filter wheel, and for dry-runs the
//! in-process simulator with a sample that can be changed per campaign.
//!
//! Every device of the instrument file is opened: `port = "sim"` (or no port) means the embedded simulator,
//! `port = "sim-pty"` the embedded simulator with its serial devices served on pseudo-terminals and opened by
//! path like real ports (the power meter stays in process; needs a runtime on the real clock), anything else a
//! real serial port or pseudo-terminal, and for the power meter USB by vendor/product id, or
//! `port = "usb-socket:PATH"` for a meter served on a Unix socket (a separate `gonio sim --link-dir`). Axes keep
//! the instrument file's order, which is also the order of the read-back columns.
//!
//! What lies in the simulated sample holder is the rig's to switch: [`Rig::mount_sample`] builds and mounts a
//! campaign's sample; [`Rig::build_optics`] and [`Rig::show_optics`] let the engine swap in another sample (the
//! relative method's reference) and back, as the operator would, each with its own optics on the same source.

mod dry_run;
mod hidden;
pub mod sim_link;

pub use dry_run::{Held, InstrumentClock, SampleHolder};
pub use hidden::simulator_truth;

use std::sync::{Arc, RwLock};

use gonio_driver::fw102c::Fw102c;
use gonio_driver::pm100::{PipeOpener, Pm100};
use gonio_driver::smc100::{Smc100Axis, Smc100Chain};
use gonio_driver::transport::{LinePort, PortOpener, SerialSettings};
use gonio_driver::zaber::{ZaberAxis, ZaberChain};
use gonio_driver::{Axis, Detector, FilterWheel};
use gonio_instrument::{InstrumentFile, Protocol};
use gonio_simulator::SimInstrument;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::pty::PtyDevice;
use gonio_simulator::scene::{Band, Pose, Scene};

use crate::error::EngineError;

/// Simulated seconds per real second for dry-runs on a normal (unpaused) runtime: motion takes little wall time.
/// `gonio run` instead runs dry-runs on a paused tokio clock at scale 1 (no wall time at all).
pub const DEFAULT_DRY_RUN_TIME_SCALE: f64 = 200.0;

/// One axis: its configuration and its driver.
#[derive(Debug, Clone)]
pub struct RigAxis {
    pub config: gonio_instrument::Axis,
    pub driver: Arc<dyn Axis>,
}

/// A controller chain that can be stopped as a whole.
#[derive(Debug, Clone)]
enum Chain {
    Smc100 {
        chain: Arc<Smc100Chain>,
        addresses: Vec<u8>,
    },
    Zaber(Arc<ZaberChain>),
}

/// The connected instrument. Cheap to clone (shared).
#[derive(Debug, Clone)]
pub struct Rig {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    file: InstrumentFile,
    axes: Vec<RigAxis>,
    detector: Arc<dyn Detector>,
    wheel: Option<Arc<dyn FilterWheel>>,
    wheel_identity: Option<Arc<Fw102c>>,
    chains: Vec<Chain>,
    /// The simulator, when any device is simulated.
    sim: Option<SimInstrument>,
    scene: Arc<SwitchScene>,
    /// True when every device is simulated: a dry-run, with ground truth.
    all_simulated: bool,
    /// The pseudo-terminals of `port = "sim-pty"` devices: alive as long as the rig.
    ptys: Vec<PtyDevice>,
}

/// The simulator's scene, replaceable per campaign (each dry-run campaign mounts its own material).
#[derive(Debug)]
pub struct SwitchScene {
    optics: RwLock<Option<Arc<Optics>>>,
}

impl Scene for SwitchScene {
    fn detector_power_w(&self, pose: &Pose, band: &Band, t_s: f64) -> f64 {
        match self.optics.read().unwrap_or_else(|e| e.into_inner()).as_ref() {
            Some(o) => o.detector_power_w(pose, band, t_s),
            // No sample and no optics: darkness.
            None => 0.0,
        }
    }

    fn detector_power_series_w(&self, pose: &Pose, band: &Band, times_s: &[f64], out: &mut Vec<f64>) {
        match self.optics.read().unwrap_or_else(|e| e.into_inner()).as_ref() {
            // The optics compute the geometry once for all the instants.
            Some(o) => o.detector_power_series_w(pose, band, times_s, out),
            None => {
                out.clear();
                out.resize(times_s.len(), 0.0);
            }
        }
    }
}

impl Rig {
    /// Connect every device of `file`; simulated devices run at [`DEFAULT_DRY_RUN_TIME_SCALE`].
    pub async fn connect(
        file: &InstrumentFile,
        dry_run_sample: Option<SampleSpec>,
    ) -> Result<Rig, EngineError> {
        Rig::connect_with_time_scale(file, dry_run_sample, DEFAULT_DRY_RUN_TIME_SCALE).await
    }

    /// Connect with simulated devices at `time_scale` simulated seconds per (tokio) second.
    pub async fn connect_with_time_scale(
        file: &InstrumentFile,
        dry_run_sample: Option<SampleSpec>,
        time_scale: f64,
    ) -> Result<Rig, EngineError> {
        let inst = &file.instrument;
        inst.validate().map_err(|e| EngineError::Instrument(e.0))?;
        let scene = Arc::new(SwitchScene {
            optics: RwLock::new(None),
        });
        let any_sim = inst.devices.iter().any(|d| d.is_simulated());
        let all_simulated = inst.devices.iter().all(|d| d.is_simulated());
        let sim = if any_sim {
            let s = SimInstrument::new(file, scene.clone(), time_scale)
                .map_err(|e| EngineError::Instrument(format!("simulated instrument: {e}")))?;
            Some(s)
        } else {
            None
        };

        let mut ports = std::collections::BTreeMap::new();
        let mut ptys = Vec::new();
        for dev in &inst.devices {
            if dev.protocol == Protocol::Pm100 {
                continue;
            }
            let opener = if dev.is_sim_pty() {
                // The simulated device on a real pseudo-terminal, opened by path like a real port.
                let sim = sim
                    .as_ref()
                    .ok_or_else(|| EngineError::Instrument("no simulator".into()))?;
                let pty = PtyDevice::serve(sim, &dev.name).map_err(|e| {
                    EngineError::Device(format!(
                        "device {:?}: cannot serve it on a pseudo-terminal: {e}",
                        dev.name
                    ))
                })?;
                let mut on_pty = dev.clone();
                on_pty.port = Some(pty.path().display().to_string());
                let settings = SerialSettings::for_device(&on_pty).ok_or_else(|| {
                    EngineError::Instrument(format!("device {:?}: not a serial device", dev.name))
                })?;
                ptys.push(pty);
                PortOpener::Serial(settings)
            } else if dev.is_simulated() {
                let sim = sim
                    .clone()
                    .ok_or_else(|| EngineError::Instrument("no simulator".into()))?;
                sim_link::serial_opener(sim, &dev.name)
            } else {
                let settings = SerialSettings::for_device(dev).ok_or_else(|| {
                    EngineError::Instrument(format!("device {:?}: no serial port given", dev.name))
                })?;
                PortOpener::Serial(settings)
            };
            let port = LinePort::open(dev.name.as_str(), opener).map_err(|e| {
                EngineError::Device(format!(
                    "device {:?} ({}): cannot open its port: {e}",
                    dev.name,
                    dev.protocol.name()
                ))
            })?;
            ports.insert(dev.name.clone(), (dev.protocol, Arc::new(port)));
        }

        let mut chains = Vec::new();
        let mut smc: std::collections::BTreeMap<String, Arc<Smc100Chain>> = Default::default();
        let mut zab: std::collections::BTreeMap<String, Arc<ZaberChain>> = Default::default();
        let mut axes = Vec::new();
        for axis in &inst.axes {
            let Some((protocol, port)) = ports.get(&axis.device) else {
                return Err(EngineError::Instrument(format!(
                    "axis {:?}: device {:?} is not a serial controller",
                    axis.name, axis.device
                )));
            };
            let driver: Arc<dyn Axis> = match protocol {
                Protocol::Smc100 => {
                    let chain = smc
                        .entry(axis.device.clone())
                        .or_insert_with(|| {
                            // A simulated controller keeps its pause after a set command in simulated time.
                            let simulated = inst
                                .devices
                                .iter()
                                .any(|d| d.name == axis.device && d.is_simulated());
                            let gap = if simulated {
                                gonio_driver::smc100::SET_GAP.div_f64(time_scale.max(1.0))
                            } else {
                                gonio_driver::smc100::SET_GAP
                            };
                            Smc100Chain::with_set_gap(axis.device.as_str(), Arc::clone(port), gap)
                        })
                        .clone();
                    Arc::new(Smc100Axis::new(chain, axis.clone()))
                }
                Protocol::ZaberAscii => {
                    let chain = zab
                        .entry(axis.device.clone())
                        .or_insert_with(|| ZaberChain::new(axis.device.as_str(), Arc::clone(port)))
                        .clone();
                    Arc::new(
                        ZaberAxis::new(chain, axis.clone())
                            .map_err(|e| EngineError::Device(e.to_string()))?,
                    )
                }
                other => {
                    return Err(EngineError::Instrument(format!(
                        "axis {:?}: device {:?} speaks {}, not a motion protocol",
                        axis.name,
                        axis.device,
                        other.name()
                    )));
                }
            };
            axes.push(RigAxis {
                config: axis.clone(),
                driver,
            });
        }
        for (name, chain) in &smc {
            let addresses = inst
                .axes
                .iter()
                .filter(|a| &a.device == name)
                .map(|a| a.address)
                .collect();
            chains.push(Chain::Smc100 {
                chain: Arc::clone(chain),
                addresses,
            });
        }
        for chain in zab.values() {
            chains.push(Chain::Zaber(Arc::clone(chain)));
        }

        let (wheel, wheel_identity) = match &inst.filter_wheel {
            Some(w) => {
                let Some((Protocol::Fw102c, port)) = ports.get(&w.device) else {
                    return Err(EngineError::Instrument(format!(
                        "filter wheel: device {:?} is not an fw102c device",
                        w.device
                    )));
                };
                let fw = Arc::new(
                    Fw102c::new(w.device.as_str(), Arc::clone(port), w.seconds_per_position)
                        .with_speed(w.speed),
                );
                (Some(fw.clone() as Arc<dyn FilterWheel>), Some(fw))
            }
            None => (None, None),
        };

        let det_dev = inst.device(&inst.detector.device).ok_or_else(|| {
            EngineError::Instrument(format!("detector: no device named {:?}", inst.detector.device))
        })?;
        let detector: Arc<dyn Detector> = if det_dev.is_simulated() {
            let sim = sim
                .clone()
                .ok_or_else(|| EngineError::Instrument("no simulator".into()))?;
            let name = det_dev.name.clone();
            let pipe = sim_link::open_pipe(&sim, &name)
                .map_err(|e| EngineError::Device(format!("detector {name:?}: {e}")))?;
            let opener: PipeOpener = sim_link::pipe_opener(sim.clone(), name.clone());
            Arc::new(Pm100::new(name, pipe, Some(opener)))
        } else if let Some(socket) = det_dev
            .port
            .as_deref()
            .and_then(|p| p.strip_prefix(gonio_driver::transport::usb_socket::PORT_PREFIX))
        {
            Arc::new(
                Pm100::open_socket(det_dev.name.clone(), socket.into())
                    .await
                    .map_err(|e| EngineError::Device(e.to_string()))?,
            )
        } else {
            let (Some(vid), Some(pid)) = (det_dev.usb_vendor_id, det_dev.usb_product_id) else {
                return Err(EngineError::Instrument(format!(
                    "detector device {:?}: usb_vendor_id and usb_product_id are required for a real power meter",
                    det_dev.name
                )));
            };
            Arc::new(
                Pm100::open_usb(det_dev.name.clone(), vid, pid, det_dev.usb_serial.clone())
                    .await
                    .map_err(|e| EngineError::Device(e.to_string()))?,
            )
        };

        let rig = Rig {
            inner: Arc::new(Inner {
                file: file.clone(),
                axes,
                detector,
                wheel,
                wheel_identity,
                chains,
                sim,
                scene,
                all_simulated,
                ptys,
            }),
        };
        if let Some(sample) = dry_run_sample {
            rig.mount_sample(sample, file.simulator.seed)?;
        }
        Ok(rig)
    }

    /// The instrument file the rig was built from.
    pub fn file(&self) -> &InstrumentFile {
        &self.inner.file
    }

    /// Axes in instrument file order.
    pub fn axes(&self) -> &[RigAxis] {
        &self.inner.axes
    }

    pub fn detector(&self) -> &Arc<dyn Detector> {
        &self.inner.detector
    }

    pub fn wheel(&self) -> Option<&Arc<dyn FilterWheel>> {
        self.inner.wheel.as_ref()
    }

    /// The simulator, when any device is simulated.
    pub fn sim(&self) -> Option<&SimInstrument> {
        self.inner.sim.as_ref()
    }

    /// Paths of the pseudo-terminals serving `port = "sim-pty"` devices: (device name, path).
    pub fn sim_ptys(&self) -> Vec<(String, std::path::PathBuf)> {
        self.inner
            .ptys
            .iter()
            .map(|p| (p.device().to_string(), p.path().to_path_buf()))
            .collect()
    }

    /// True when every device is simulated: campaigns are dry-runs with ground truth.
    pub fn is_dry_run(&self) -> bool {
        self.inner.all_simulated
    }

    /// The simulated optics currently mounted (dry-runs).
    pub fn optics(&self) -> Option<Arc<Optics>> {
        self.inner
            .scene
            .optics
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Mount a simulated sample (dry-runs): builds its optics on this instrument.
    pub fn mount_sample(&self, sample: SampleSpec, seed: u64) -> Result<Arc<Optics>, EngineError> {
        let optics = self.build_optics(sample, seed)?;
        self.show_optics(Arc::clone(&optics));
        Ok(optics)
    }

    /// Build the optics of a simulated sample on this instrument without mounting it. With the instrument's
    /// `seed`, its source is the very source of every other sample's optics (same drift, same noise at the same
    /// instant): swapping samples changes the sample, not the lamp.
    pub fn build_optics(&self, sample: SampleSpec, seed: u64) -> Result<Arc<Optics>, EngineError> {
        self.unshared_optics(sample, seed).map(Arc::new)
    }

    /// [`Rig::build_optics`] before it is shared (to be made into an alignment mirror).
    pub(crate) fn unshared_optics(&self, sample: SampleSpec, seed: u64) -> Result<Optics, EngineError> {
        if self.inner.sim.is_none() {
            return Err(EngineError::Instrument(
                "a simulated sample needs the simulated instrument (no device is simulated)".into(),
            ));
        }
        let hidden = self.inner.sim.as_ref().and_then(|s| s.hidden_truth());
        // The source as it really is (its hidden relative noise, `[simulator.actual.source]`).
        let real = gonio_simulator::imperfections::HiddenTruth::real_instrument(&self.inner.file, hidden);
        Ok(Optics::new(&real, sample, seed)
            .map_err(|e| EngineError::Instrument(format!("simulated optics: {e}")))?
            // The instrument's hidden imperfections stay inside the simulator's optics.
            .with_hidden_truth(hidden))
    }

    /// Put already built optics in the simulated sample holder (the simulated operator's swap).
    pub fn show_optics(&self, optics: Arc<Optics>) {
        *self.inner.scene.optics.write().unwrap_or_else(|e| e.into_inner()) = Some(optics);
    }

    /// Identity strings of the devices, for the store and run.json: (device name, identity).
    pub async fn identities(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let inst = &self.inner.file.instrument;
        for dev in &inst.devices {
            let place = if dev.is_sim_pty() && dev.protocol != Protocol::Pm100 {
                "simulated, pseudo-terminal".to_string()
            } else if dev.is_simulated() {
                "simulated".to_string()
            } else {
                dev.port.clone().unwrap_or_else(|| "usb".into())
            };
            let id = match dev.protocol {
                Protocol::Pm100 if dev.name == inst.detector.device => {
                    match self.inner.detector.identify().await {
                        Ok(s) => s.trim().to_string(),
                        Err(e) => format!("unidentified ({e})"),
                    }
                }
                Protocol::Fw102c => match &self.inner.wheel_identity {
                    Some(w) => match w.identify().await {
                        Ok(s) => s.trim().to_string(),
                        Err(e) => format!("unidentified ({e})"),
                    },
                    None => "unused".into(),
                },
                p => p.name().to_string(),
            };
            out.push((
                dev.name.clone(),
                format!("{id} [{} on {place}]", dev.protocol.name()),
            ));
        }
        out
    }

    /// Emergency stop: every axis, now. Chains get one stop-all on the priority path, and every axis its own
    /// stop as well; in dry-runs the simulator halts its axes too. Errors are logged: there is nothing more to do.
    pub async fn estop(&self) {
        tracing::warn!("emergency stop: halting every axis");
        if let Some(sim) = &self.inner.sim {
            sim.estop();
        }
        let chain_stops = self.inner.chains.iter().map(|c| async move {
            let r = match c {
                Chain::Smc100 { chain, addresses } => chain.stop_all(addresses).await,
                Chain::Zaber(chain) => chain.stop_all().await,
            };
            if let Err(e) = r {
                tracing::error!("emergency stop: {e}");
            }
        });
        futures_join_all(chain_stops).await;
        let axis_stops = self.inner.axes.iter().map(|a| async move {
            if let Err(e) = a.driver.stop().await {
                tracing::error!("emergency stop of {}: {e}", a.config.name);
            }
        });
        futures_join_all(axis_stops).await;
    }
}

/// Run futures concurrently and wait for all (no extra dependency for this one use).
pub(crate) async fn futures_join_all<F: std::future::Future>(
    futs: impl IntoIterator<Item = F>,
) -> Vec<F::Output> {
    let mut set: Vec<std::pin::Pin<Box<F>>> = futs.into_iter().map(Box::pin).collect();
    let mut out: Vec<Option<F::Output>> = (0..set.len()).map(|_| None).collect();
    std::future::poll_fn(|cx| {
        let mut pending = false;
        for (i, f) in set.iter_mut().enumerate() {
            if out.get(i).is_some_and(|o| o.is_none()) {
                match f.as_mut().poll(cx) {
                    std::task::Poll::Ready(v) => {
                        if let Some(slot) = out.get_mut(i) {
                            *slot = Some(v);
                        }
                    }
                    std::task::Poll::Pending => pending = true,
                }
            }
        }
        if pending {
            std::task::Poll::Pending
        } else {
            std::task::Poll::Ready(())
        }
    })
    .await;
    out.into_iter().flatten().collect()
}
