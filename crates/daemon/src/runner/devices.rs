//! Device supervision: bounded retries of a device operation, reconnection, re-homing, reading the axes back.

use super::*;

impl<'a> Run<'a> {
    /// Run a device operation with bounded retries and recovery; an emergency stop cancels it at once.
    pub(super) async fn device<T, F, Fut>(&self, dev: Dev<'_>, what: &str, mut op: F) -> Result<T, Interrupt>
    where
        F: FnMut() -> Fut,
        Fut: Future<Output = Result<T, DriverError>>,
    {
        let attempts = self.c.campaign.acquisition.retries + 1;
        let mut last = String::new();
        for attempt in 1..=attempts {
            // Biased, the stop first: an emergency stop requested at the same instant must win before the
            // operation sends anything (an unbiased select polls in random order; crates/soak/tests/safety_soak.rs).
            let r = tokio::select! {
                biased;
                _ = self.estop_signal() => return Err(Interrupt::Estop),
                r = op() => r,
            };
            let e = match r {
                Ok(v) => return Ok(v),
                Err(e) => e,
            };
            if self.control.estop_requested() {
                return Err(Interrupt::Estop);
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
                    if let Dev::Axis(a) = dev {
                        self.home(a).await?;
                    }
                }
                // An absolute move that stopped short is safe to command again once.
                ErrorKind::MotionFault if matches!(dev, Dev::Axis(_)) => {
                    self.recover(dev).await?;
                }
                _ => break,
            }
        }
        // Out of attempts: the device's own reason, for a failed point (or a pause, during calibration).
        Err(Interrupt::Fatal(EngineError::Device(last)))
    }

    /// Reconnect a device, with a few spaced attempts; re-home an axis that lost its reference.
    pub(super) async fn recover(&self, dev: Dev<'_>) -> Result<(), Interrupt> {
        let mut last = String::new();
        for wait_s in [0.0, 0.5, 2.0, 5.0, 10.0] {
            self.clock.sleep_s(wait_s).await;
            if self.control.estop_requested() {
                return Err(Interrupt::Estop);
            }
            let r = match dev {
                Dev::Axis(a) => match a.driver.reconnect().await {
                    Ok(_) => Ok(()),
                    Err(e) if e.kind() == ErrorKind::NotReferenced => return self.home(a).await,
                    Err(e) => Err(e),
                },
                Dev::Detector => self.rig.detector().reconnect().await,
                Dev::Wheel => match self.rig.wheel() {
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
        Err(Interrupt::Pause(format!(
            "a device cannot be reconnected: {last}"
        )))
    }

    /// Home an axis that lost its reference, never sweeping an arm through the other ([`rehome`]).
    pub(super) async fn home(&self, a: &RigAxis) -> Result<(), Interrupt> {
        self.home_safely(a).await
    }

    pub(super) async fn read_positions(&mut self) -> Result<(), Interrupt> {
        let mut readback = Vec::new();
        for a in self.rig.axes() {
            let p = self
                .device(Dev::Axis(a), &format!("position of {}", a.config.name), || {
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
