//! [`World`]: the physical state every simulated device shares (clock, axes, filter wheel, optics).
//!
//! Its own module, beneath both the instrument that builds it and the devices that read it (the power meter
//! integrates the scene over the world's pose and band), so that neither has to reach into the other.

use std::sync::{Arc, Mutex};

use gonio_instrument::{Axis, AxisRole};

use crate::clock::SimClock;
use crate::fw102c::Fw102c;
use crate::motion::AxisMotion;
use crate::scene::{Band, Pose, Scene};

/// The physical state every device shares: the clock, the axes, what is in the beam, and the optics.
#[derive(Debug)]
pub(crate) struct World {
    pub clock: SimClock,
    pub scene: Arc<dyn Scene>,
    /// Each axis of the instrument file with its motion, in file order.
    pub axes: Vec<(Axis, Arc<Mutex<AxisMotion>>)>,
    /// The filter wheel that sets the band, if the instrument has one.
    pub wheel: Option<Arc<Mutex<Fw102c>>>,
    /// The band when there is no filter wheel.
    pub fixed_band: Band,
}

impl World {
    pub fn pose(&self, t_s: f64) -> Pose {
        self.pose_by(|m| m.optical_deg(t_s))
    }

    /// The pose at `t_s` without advancing any axis's state (`AxisMotion::optical_deg_ahead`): for a meter's
    /// samples over a window still ahead of the present.
    pub fn pose_ahead(&self, t_s: f64) -> Pose {
        self.pose_by(|m| m.optical_deg_ahead(t_s))
    }

    /// The pose from each axis's controller angle as `controller_deg` reads it from the axis's motion.
    fn pose_by(&self, controller_deg: impl Fn(&mut AxisMotion) -> f64) -> Pose {
        let mut pose = Pose::default();
        for (axis, motion) in &self.axes {
            let c = controller_deg(&mut motion.lock().unwrap_or_else(|e| e.into_inner()));
            let physical = axis.physical_from_controller_deg(c);
            match axis.role {
                AxisRole::LightArm => pose.light_deg = physical,
                AxisRole::DetectorArm => pose.detector_deg = physical,
                AxisRole::SampleTilt => pose.tilt_deg = physical,
                AxisRole::SampleRotation => pose.rotation_deg = physical,
            }
        }
        pose
    }

    pub fn band(&self, t_s: f64) -> Band {
        match &self.wheel {
            Some(w) => w.lock().unwrap_or_else(|e| e.into_inner()).band_at(t_s),
            None => self.fixed_band,
        }
    }

    /// Stray photocurrent at the detector at `t_s` that no optics explain (A): the filter wheel's lit position
    /// sensors.
    pub fn stray_a(&self, t_s: f64) -> f64 {
        match &self.wheel {
            Some(w) => w.lock().unwrap_or_else(|e| e.into_inner()).stray_a(t_s),
            None => 0.0,
        }
    }
}
