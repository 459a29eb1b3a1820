//! The motion layer: the instrument's axes (and the supervision of every device) without a campaign or a store.
//!
//! A campaign's run loop drives it, and so can anything else that must move the arms safely (a console for
//! manual control and alignment, a scan): [`Motion`] needs only the connected [`Rig`], the instrument's time
//! model (kinematics, speeds, the arms' safety separation), a retry count and a [`Control`] for the emergency
//! stop. Where the axes are (read back from their controllers) lives here, so every move is planned from the
//! real positions.
//!
//! Parts:
//! - `supervise`: one device operation with bounded retries, reconnection and re-homing ([`Motion::device`]);
//!   reading the axes back;
//! - `moves`: collision-safe multi-axis moves ([`Motion::move_to`]): the scheduler's pure path planning
//!   (`plan_move`, [`gonio_scheduler::separation`]) executed phase by phase, legs commanded one by one, the
//!   phase stopped as a whole when one of its axes fails, the emergency stop winning over everything;
//! - `homing`: homing an arm without sweeping it through the other, at start-up and after a fault.
//! - `sweep`: one axis swept at a set speed while the meter reads back to back, its position reports dated
//!   (a campaign's sweeps and the self-test's timing of them).
//!
//! Errors are [`MotionError`]: what a caller decides on (stop, a device's reason, something a person must do,
//! a move no plan allows). Faults that were retried are reported to the fault sink given at construction (the
//! run loop turns them into events for the operator's log).

mod homing;
mod moves;
mod supervise;
pub(crate) mod sweep;

use std::sync::Arc;

use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::timing::TimeModel;

use crate::control::Control;
use crate::rig::{InstrumentClock, Rig, RigAxis};

pub use supervise::Device;

/// Why a motion-layer operation did not complete.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// An emergency stop was requested: every axis was halted.
    #[error("emergency stop")]
    Estop,
    /// A device operation still failed after its retries and recovery: the device's reason.
    #[error("{0}")]
    Device(String),
    /// A person must act first (a device that cannot be reconnected, arms that cannot be homed safely).
    #[error("{0}")]
    NeedsOperator(String),
    /// No safe way to do it exists on this instrument (no collision-free move between the poses).
    #[error("{0}")]
    Impossible(String),
}

/// Where retried faults are reported (the message says what failed and which attempt it was).
pub type FaultSink = Arc<dyn Fn(&str) + Send + Sync>;

/// The instrument's axes and the supervision of its devices (module doc).
pub struct Motion<'r> {
    rig: &'r Rig,
    time: TimeModel,
    attempts: u32,
    control: Control,
    clock: InstrumentClock,
    faults: FaultSink,
    /// Where the axes are (physical degrees): read back, or the target for roles no axis drives.
    current: Pose,
    /// Each axis's last read-back (physical degrees), in the instrument file's axis order; empty until read.
    readback: Vec<f64>,
}

impl std::fmt::Debug for Motion<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Motion")
            .field("attempts", &self.attempts)
            .field("current", &self.current)
            .field("readback", &self.readback)
            .finish_non_exhaustive()
    }
}

impl<'r> Motion<'r> {
    /// The motion layer of `rig`, planning with `time` (the instrument's, or a campaign's with its settle
    /// time), retrying each device operation `retries` times, stopped by `control`'s emergency stop (which halts
    /// `rig`'s axes). Faults
    /// go to the log only; see [`Motion::report_faults_to`].
    pub fn new(rig: &'r Rig, time: TimeModel, retries: u32, control: Control) -> Motion<'r> {
        control.attach_rig(rig);
        Motion {
            rig,
            time,
            attempts: retries + 1,
            control,
            clock: rig.clock(),
            faults: Arc::new(|m: &str| tracing::warn!("{m}")),
            current: Pose::new(0.0, 0.0, 0.0, 0.0),
            readback: Vec::new(),
        }
    }

    /// Report retried faults to `sink` as well as the log.
    pub fn report_faults_to(mut self, sink: FaultSink) -> Motion<'r> {
        self.faults = sink;
        self
    }

    pub fn rig(&self) -> &'r Rig {
        self.rig
    }

    pub fn time_model(&self) -> &TimeModel {
        &self.time
    }

    pub fn clock(&self) -> InstrumentClock {
        self.clock
    }

    /// Where the axes are (physical degrees), as of the last read-back or completed move.
    pub fn current(&self) -> &Pose {
        &self.current
    }

    /// Each axis's last read-back (physical degrees) in the instrument file's order; empty before the first.
    pub fn readback_deg(&self) -> &[f64] {
        &self.readback
    }

    /// The read-back of the axis of `role` after a motion of its own (a sweep's arrival), the others unmoved.
    /// A read-back that is not a number leaves everything as it was.
    pub(crate) fn arrived(&mut self, role: gonio_instrument::AxisRole, deg: f64) {
        if !deg.is_finite() {
            return;
        }
        if let Some(idx) = self.rig.axes().iter().position(|a| a.config.role == role) {
            if let Some(slot) = self.readback.get_mut(idx) {
                *slot = deg;
            }
            self.current.set(role, deg);
        }
    }

    /// Reference the instrument: ask every axis whether it is referenced, home those that are not (the arms in
    /// an order that never sweeps one through the other), then read every axis back.
    pub async fn reference_all(&mut self) -> Result<(), MotionError> {
        let mut unreferenced: Vec<&RigAxis> = Vec::new();
        for a in self.rig.axes() {
            let status = self
                .device(Device::Axis(a), &format!("status of {}", a.config.name), || {
                    a.driver.status()
                })
                .await?;
            if !status.referenced {
                unreferenced.push(a);
            }
        }
        self.home_at_start_up(&unreferenced).await?;
        self.read_positions().await
    }

    fn fault(&self, message: String) {
        (self.faults)(&message);
    }

    /// Resolves when an emergency stop is requested.
    pub(crate) async fn estop_signal(&self) {
        loop {
            let n = self.control.notified();
            tokio::pin!(n);
            n.as_mut().enable();
            if self.control.estop_requested() {
                return;
            }
            n.await;
        }
    }
}
