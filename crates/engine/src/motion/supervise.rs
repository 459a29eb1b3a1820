//! Device supervision: bounded retries of a device operation, reconnection, re-homing, reading the axes back.

use std::future::Future;

use gonio_driver::{DriverError, ErrorKind};

use super::{Motion, MotionError};
use crate::rig::RigAxis;

/// Which device an operation talks to (for recovery).
#[derive(Debug, Clone, Copy)]
pub enum Device<'a> {
    Axis(&'a RigAxis),
    Detector,
    Wheel,
}

impl Motion<'_> {
    /// Run a device operation with bounded retries and recovery; an emergency stop cancels it at once.
    pub async fn device<T, F, Fut>(&self, dev: Device<'_>, what: &str, mut op: F) -> Result<T, MotionError>
    where
        F: FnMut() -> Fut,
        Fut: Future<Output = Result<T, DriverError>>,
    {
        let attempts = self.attempts;
        let mut last = String::new();
        for attempt in 1..=attempts {
            // Biased, the stop first: an emergency stop requested at the same instant must win before the
            // operation sends anything (an unbiased select polls in random order; crates/soak/tests/safety_soak.rs).
            let r = tokio::select! {
                biased;
                _ = self.estop_signal() => return Err(MotionError::Estop),
                r = op() => r,
            };
            let e = match r {
                Ok(v) => return Ok(v),
                Err(e) => e,
            };
            if self.control.estop_requested() {
                return Err(MotionError::Estop);
            }
            last = e.to_string();
            self.fault(format!("{what}: {e} (attempt {attempt} of {attempts})"));
            match e.kind() {
                ErrorKind::Timeout
                | ErrorKind::Protocol
                | ErrorKind::Disconnected
                | ErrorKind::Unavailable => {
                    if matches!(e.kind(), ErrorKind::Disconnected | ErrorKind::Unavailable) || attempt > 1 {
                        self.recover(dev).await?;
                    }
                }
                ErrorKind::NotReferenced => {
                    if let Device::Axis(a) = dev {
                        self.home(a).await?;
                    }
                }
                // An absolute move that stopped short is safe to command again once.
                ErrorKind::MotionFault if matches!(dev, Device::Axis(_)) => {
                    self.recover(dev).await?;
                }
                _ => break,
            }
        }
        // Out of attempts: the device's own reason, for a failed point (or a pause, during calibration).
        Err(MotionError::Device(last))
    }

    /// Reconnect a device, with a few spaced attempts; re-home an axis that lost its reference.
    pub async fn recover(&self, dev: Device<'_>) -> Result<(), MotionError> {
        let mut last = String::new();
        for wait_s in [0.0, 0.5, 2.0, 5.0, 10.0] {
            self.clock.sleep_s(wait_s).await;
            if self.control.estop_requested() {
                return Err(MotionError::Estop);
            }
            let r = match dev {
                Device::Axis(a) => match a.driver.reconnect().await {
                    Ok(_) => Ok(()),
                    Err(e) if e.kind() == ErrorKind::NotReferenced => return self.home(a).await,
                    Err(e) => Err(e),
                },
                Device::Detector => self.rig.detector().reconnect().await,
                Device::Wheel => match self.rig.wheel() {
                    Some(w) => w.reconnect().await,
                    None => Ok(()),
                },
            };
            match r {
                Ok(()) => {
                    tracing::info!("device reconnected");
                    return Ok(());
                }
                Err(e) => {
                    last = e.to_string();
                    self.fault(format!("reconnect: {e}"));
                }
            }
        }
        Err(MotionError::NeedsOperator(format!(
            "a device cannot be reconnected: {last}"
        )))
    }

    /// Home an axis that lost its reference, never sweeping an arm through the other (`homing`).
    pub async fn home(&self, a: &RigAxis) -> Result<(), MotionError> {
        self.home_safely(a).await
    }

    /// Read every axis back (bounded retries): the pose moves are planned from.
    pub async fn read_positions(&mut self) -> Result<(), MotionError> {
        let mut readback = Vec::new();
        for a in self.rig.axes() {
            let p = self
                .device(Device::Axis(a), &format!("position of {}", a.config.name), || {
                    a.driver.position_deg()
                })
                .await?;
            self.current.set(a.config.role, p);
            readback.push(p);
        }
        self.readback = readback;
        Ok(())
    }
}
