//! The console: a person's hands on the instrument (state, safe moves, homing, the wheel, the meter), through
//! the same motion layer as a campaign.
//!
//! Every motion goes through [`Motion`]: a target is checked first ([`request`]: each axis within its travel,
//! the arms' separation at the target, a geometry's static rules), then moved along the motion layer's safe path
//! (the separation kept along the way, a failed axis stopping the move, the emergency stop winning). A request
//! that breaks a rule is refused with the rule's key and nothing moves. Moves need every axis referenced: a jog
//! never starts a homing by surprise (home first).
//!
//! Who may use it, and when, is the service's business (one owner at a time, `gonio-daemon`); the console
//! itself needs only a [`Motion`] on the connected rig.

mod request;
mod state;

pub use request::{
    BAND_MATCH_NM, ConsoleError, FilterChoice, axis_named, filter_position, geometry_poses, geometry_text,
    parse_filter_choice, target_pose,
};
pub use state::{
    AxisPosition, AxisState, ConsoleReading, DeviceHealth, FilterSlot, InstrumentState, WheelState,
};

use std::time::UNIX_EPOCH;

use gonio_driver::{DetectorConfig, PowerRange};
use gonio_scheduler::kinematics::{Geometry, Pose};

use crate::align::correction::PoseCorrection;
use crate::motion::{Device, Motion, MotionError};

/// The meter's correction wavelength when no band filter is in the beam (nm): mid-visible.
pub const UNFILTERED_NM: f64 = 550.0;
/// Samples the meter averages per console reading: a quick reading for a person watching a trace.
pub const CONSOLE_AVERAGING: u32 = 10;

impl From<MotionError> for ConsoleError {
    fn from(e: MotionError) -> ConsoleError {
        ConsoleError::Motion(e.to_string())
    }
}

/// A person's hands on the instrument (module doc).
#[derive(Debug)]
pub struct Console<'r> {
    motion: Motion<'r>,
    /// The wavelength the meter was last configured for by this console (nm).
    configured_nm: Option<f64>,
    /// The alignment calibration moves by geometry go through (crate::align::correction); None: nominal.
    correction: Option<PoseCorrection>,
}

impl<'r> Console<'r> {
    pub fn new(motion: Motion<'r>) -> Console<'r> {
        Console {
            motion,
            configured_nm: None,
            correction: None,
        }
    }

    /// Moves by geometry go through `correction` (the alignment applied to campaigns) when there is one.
    pub fn with_correction(mut self, correction: Option<PoseCorrection>) -> Console<'r> {
        self.correction = correction;
        self
    }

    /// Every device asked once, without retries (a state must come back quickly and say what is wrong).
    pub async fn state(&mut self) -> InstrumentState {
        let rig = self.motion.rig();
        let file = rig.file();
        let mut axes = Vec::new();
        for a in rig.axes() {
            let status = a.driver.status().await;
            axes.push(match status {
                Ok(s) => AxisState {
                    name: a.config.name.clone(),
                    role: a.config.role,
                    position_deg: Some(s.position_deg),
                    referenced: Some(s.referenced),
                    moving: Some(s.moving),
                    fault: s.fault,
                    min_deg: a.config.min_deg,
                    max_deg: a.config.max_deg,
                },
                Err(e) => AxisState {
                    name: a.config.name.clone(),
                    role: a.config.role,
                    position_deg: None,
                    referenced: None,
                    moving: None,
                    fault: Some(format!("no status: {e}")),
                    min_deg: a.config.min_deg,
                    max_deg: a.config.max_deg,
                },
            });
        }
        let filters: Vec<FilterSlot> = file
            .instrument
            .filter_wheel
            .iter()
            .flat_map(|w| &w.positions)
            .map(|f| FilterSlot {
                position: f.position,
                band_nm: f.band_nm,
            })
            .collect();
        let wheel = match rig.wheel() {
            None => None,
            Some(w) => Some(match w.position().await {
                Ok(p) => WheelState {
                    position: Some(p),
                    band_nm: self.band_at(p),
                    fault: None,
                    filters,
                },
                Err(e) => WheelState {
                    position: None,
                    band_nm: None,
                    fault: Some(format!("no position: {e}")),
                    filters,
                },
            }),
        };
        let meter = self.read_once(wheel.as_ref().and_then(|w| w.position)).await;
        let mut devices = Vec::new();
        for (name, identity) in rig.identities().await {
            let axes_ok = file
                .instrument
                .axes
                .iter()
                .zip(&axes)
                .filter(|(cfg, _)| cfg.device == name)
                .all(|(_, s)| s.position_deg.is_some());
            let is_meter = name == file.instrument.detector.device;
            let is_wheel = file
                .instrument
                .filter_wheel
                .as_ref()
                .is_some_and(|w| w.device == name);
            let meter_ok = !is_meter || meter.is_ok();
            let wheel_ok = !is_wheel || wheel.as_ref().is_none_or(|w| w.fault.is_none());
            let ok = axes_ok && meter_ok && wheel_ok && !identity.starts_with("unidentified");
            let identity = match (&meter, name == file.instrument.detector.device) {
                (Err(e), true) => format!("{identity}; no reading: {e}"),
                _ => identity,
            };
            devices.push(DeviceHealth { name, identity, ok });
        }
        InstrumentState {
            instrument: file.instrument.name.clone(),
            dry_run: rig.is_dry_run(),
            axes,
            wheel,
            meter: meter.ok(),
            devices,
        }
    }

    /// Move the named axes (physical degrees) in one safe move; the others hold.
    pub async fn move_axes(&mut self, targets: &[(String, f64)]) -> Result<Vec<AxisPosition>, ConsoleError> {
        self.motion.read_positions().await?;
        let target = target_pose(self.motion.rig().file(), self.motion.current(), targets)?;
        self.move_to(&target).await
    }

    /// Move by `delta_deg` on one axis.
    pub async fn jog(&mut self, axis: &str, delta_deg: f64) -> Result<Vec<AxisPosition>, ConsoleError> {
        if !delta_deg.is_finite() {
            return Err(ConsoleError::Invalid(format!("jog by {delta_deg}: not an angle")));
        }
        self.motion.read_positions().await?;
        let role = axis_named(self.motion.rig().file(), axis)?.role;
        let to = self.motion.current().get(role) + delta_deg;
        let target = target_pose(
            self.motion.rig().file(),
            self.motion.current(),
            &[(axis.to_string(), to)],
        )?;
        self.move_to(&target).await
    }

    /// Move to the pose that measures `geometry` (degrees; the instrument's kinematics with the instrument
    /// file's `zero_offset_deg` of each axis, then the alignment calibration when the console has one): the
    /// nearest such pose a safe path reaches.
    pub async fn move_geometry(&mut self, geometry: &Geometry) -> Result<Vec<AxisPosition>, ConsoleError> {
        self.motion.read_positions().await?;
        let mut poses = geometry_poses(
            &self.motion.rig().file().instrument,
            self.motion.current(),
            geometry,
        )?;
        if let Some(c) = &self.correction {
            for p in &mut poses {
                *p = c.correct(p);
            }
        }
        match poses.iter().find(|p| self.motion.safe_move(p).is_ok()) {
            Some(target) => self.move_to(target).await,
            None => Err(ConsoleError::Refused {
                rule: "safety.min_arm_separation_deg".into(),
                message: format!(
                    "no path from where the arms are keeps them apart on the way to any pose that measures {}",
                    geometry_text(geometry)
                ),
            }),
        }
    }

    /// Home one axis (by name) or every axis, never sweeping an arm through the other.
    pub async fn home(&mut self, axis: Option<&str>) -> Result<(), ConsoleError> {
        let rig = self.motion.rig();
        let chosen: Vec<_> = match axis {
            Some(name) => {
                axis_named(rig.file(), name)?;
                rig.axes().iter().filter(|a| a.config.name == name).collect()
            }
            None => rig.axes().iter().collect(),
        };
        for a in chosen {
            tracing::info!(axis = %a.config.name, "console: homing");
            self.motion.home(a).await?;
        }
        self.motion.read_positions().await?;
        Ok(())
    }

    /// Turn the wheel to a filter.
    pub async fn filter(&mut self, choice: FilterChoice) -> Result<u8, ConsoleError> {
        let rig = self.motion.rig();
        let position = filter_position(&rig.file().instrument, choice)?;
        let Some(wheel) = rig.wheel() else {
            return Err(ConsoleError::Invalid(
                "this instrument has no filter wheel".into(),
            ));
        };
        self.motion
            .device(Device::Wheel, &format!("turn the wheel to {position}"), || {
                wheel.go_to(position)
            })
            .await?;
        Ok(position)
    }

    /// `count` readings of the meter at the filter in the beam, each with its time, pose, band and range.
    pub async fn read(&mut self, count: usize) -> Result<Vec<ConsoleReading>, ConsoleError> {
        let position = match self.motion.rig().wheel() {
            Some(w) => Some(
                self.motion
                    .device(Device::Wheel, "wheel position", || w.position())
                    .await?,
            ),
            None => None,
        };
        self.motion.read_positions().await?;
        let mut out = Vec::with_capacity(count);
        for _ in 0..count {
            out.push(self.read_once(position).await?);
        }
        Ok(out)
    }

    /// One reading at the filter at `position`, the meter configured for its band when it is not yet.
    async fn read_once(&mut self, position: Option<u8>) -> Result<ConsoleReading, ConsoleError> {
        let band_nm = position.and_then(|p| self.band_at(p));
        let nm = band_nm.unwrap_or(UNFILTERED_NM);
        let det = self.motion.rig().detector();
        let config = DetectorConfig {
            wavelength_nm: nm,
            averaging: CONSOLE_AVERAGING,
            range: PowerRange::Auto,
        };
        if self.configured_nm != Some(nm) {
            self.motion
                .device(Device::Detector, "configure the detector", || {
                    det.configure(config)
                })
                .await?;
            self.configured_nm = Some(nm);
        }
        let r = self
            .motion
            .device(Device::Detector, "read the detector", || det.read_power())
            .await?;
        let axes = self.positions();
        Ok(ConsoleReading {
            t_s: self.motion.clock().now_s(),
            unix_s: r
                .timestamp
                .duration_since(UNIX_EPOCH)
                .map(|d| d.as_secs_f64())
                .unwrap_or(0.0),
            power_w: r.power_w,
            range_w: r.range_w,
            overload: r.overload,
            wavelength_nm: nm,
            band_nm,
            filter_position: position,
            axes,
        })
    }

    /// The band of the filter at wheel position `position` (None for the blank or an unlisted position).
    fn band_at(&self, position: u8) -> Option<f64> {
        let wheel = self.motion.rig().file().instrument.filter_wheel.as_ref()?;
        wheel.positions.iter().find(|f| f.position == position)?.band_nm
    }

    /// Check every axis is referenced, then move along the motion layer's safe path.
    async fn move_to(&mut self, target: &Pose) -> Result<Vec<AxisPosition>, ConsoleError> {
        for a in self.motion.rig().axes() {
            let s = self
                .motion
                .device(Device::Axis(a), &format!("status of {}", a.config.name), || {
                    a.driver.status()
                })
                .await?;
            if !s.referenced {
                return Err(ConsoleError::Refused {
                    rule: "referenced".into(),
                    message: format!(
                        "{} is not referenced: home it first (gonio ctl home {})",
                        a.config.name, a.config.name
                    ),
                });
            }
        }
        // Planned before anything is commanded: a target no safe path reaches is refused with nothing moved.
        if let Err(MotionError::Impossible(why)) = self.motion.safe_move(target) {
            return Err(ConsoleError::Refused {
                rule: "safety.min_arm_separation_deg".into(),
                message: format!("no path keeps the arms apart: {why}"),
            });
        }
        tracing::info!(?target, "console: move");
        self.motion.move_to(target).await?;
        self.motion.read_positions().await?;
        Ok(self.positions())
    }

    /// Each axis's last read-back, in the instrument file's order.
    fn positions(&self) -> Vec<AxisPosition> {
        self.motion
            .rig()
            .axes()
            .iter()
            .zip(self.motion.readback_deg())
            .map(|(a, p)| AxisPosition {
                name: a.config.name.clone(),
                position_deg: *p,
            })
            .collect()
    }
}
