//! One Zaber rotary axis: verified positions, status, homing, moves with the backlash approach.
//! [`Axis`](crate::Axis) comes from [`AxisDriver`], shared with the other axis drivers.

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use super::chain::ZaberChain;
use super::protocol::{Flag, Reply, describe_warning, encode_command, is_warning, parse_int};
use super::{ACCEL_UNIT, ATTEMPTS, POLL_MAX, POLL_MIN, REPLY_TIMEOUT, SPEED_UNIT};
use crate::axis_driver::{AxisCore, AxisDriver};
use crate::error::DriverError;
use crate::motion::move_deadline;
use crate::poll::Poll;
use crate::traits::AxisStatus;
use crate::transport::LinePort;

/// The data of a `warnings` reply: a count, then that many flags. Never panics.
fn parse_warnings(data: &str) -> Option<Vec<String>> {
    let mut it = data.split(' ').filter(|t| !t.is_empty());
    let count = it
        .next()
        .and_then(parse_int)
        .and_then(|c| usize::try_from(c).ok())?;
    let flags: Vec<String> = it.filter(|f| is_warning(f)).map(str::to_string).collect();
    (flags.len() == count).then_some(flags)
}

/// One Zaber rotary axis.
#[derive(Debug)]
pub struct ZaberAxis {
    chain: Arc<ZaberChain>,
    device: u8,
    axis: u8,
    microstep_deg: f64,
    core: AxisCore,
}

impl ZaberAxis {
    /// `cfg.microstep_deg` is required (the instrument file validation guarantees it for Zaber axes).
    pub fn new(chain: Arc<ZaberChain>, cfg: gonio_instrument::Axis) -> Result<ZaberAxis, DriverError> {
        let microstep_deg = cfg
            .microstep_deg
            .filter(|m| m.is_finite() && *m > 0.0)
            .ok_or_else(|| DriverError::OutOfRange {
                device: cfg.name.clone(),
                what: "microstep_deg".into(),
                value: cfg.microstep_deg.unwrap_or(f64::NAN),
                min: 0.0,
                max: f64::INFINITY,
            })?;
        Ok(ZaberAxis {
            device: cfg.address,
            axis: cfg.zaber_axis,
            chain,
            microstep_deg,
            core: AxisCore::new(cfg),
        })
    }

    fn dev(&self) -> String {
        format!(
            "{} ({}/{}.{})",
            self.core.cfg().name,
            self.chain.name,
            self.device,
            self.axis
        )
    }

    fn steps_from_deg(&self, physical_deg: f64) -> i64 {
        (self.core.cfg().controller_from_physical_deg(physical_deg) / self.microstep_deg).round() as i64
    }

    fn deg_from_steps(&self, steps: i64) -> f64 {
        self.core
            .cfg()
            .physical_from_controller_deg(steps as f64 * self.microstep_deg)
    }

    async fn ok(&self, command: &str, idempotent: bool) -> Result<Reply, DriverError> {
        let r = self
            .chain
            .request(self.device, self.axis, command, idempotent)
            .await?;
        if r.flag == Flag::Rejected {
            // The reply shows only the first flag in priority order (a fault hides WR): a refused movement
            // asks for the whole list before calling it anything but a refusal.
            let unreferenced = matches!(r.warning.as_deref(), Some("WR") | Some("WH"))
                || (command.starts_with("move")
                    && r.data == "BADDATA"
                    && r.warning.is_some()
                    && self
                        .chain
                        .request(self.device, self.axis, "warnings", true)
                        .await
                        .ok()
                        .and_then(|w| parse_warnings(&w.data))
                        .is_some_and(|w| w.iter().any(|f| f == "WR" || f == "WH")));
            if unreferenced {
                return Err(DriverError::NotReferenced {
                    device: self.dev(),
                    state: format!(
                        "{command:?} rejected ({}), {}",
                        r.data,
                        describe_warning(r.warning.as_deref().unwrap_or(""))
                    ),
                });
            }
            return Err(DriverError::Rejected {
                device: self.dev(),
                request: command.into(),
                reason: r.data,
            });
        }
        Ok(r)
    }

    /// `get pos`: (microsteps, busy, warning). The position of an idle axis decides things (arrival, where a
    /// move starts, where the engine plans from), and a digit garbled inside the number parses like a good one:
    /// it is taken from a checksummed reply, or else confirmed by a second read that agrees within the encoder
    /// resolution. (A busy axis's position decides nothing; only its busy flag and warning do, which a single
    /// garbled byte cannot turn into another valid value.) Bounded; a typed Protocol error otherwise.
    async fn get_pos(&self) -> Result<(i64, bool, Option<String>), DriverError> {
        let tolerance_steps = (self.core.cfg().encoder_resolution_deg / self.microstep_deg)
            .round()
            .clamp(0.0, 1e9) as i64;
        let mut seen = Vec::new();
        let mut unconfirmed: Vec<i64> = Vec::new();
        for _ in 0..ATTEMPTS {
            let r = self.ok("get pos", true).await?;
            let Some(steps) = parse_int(&r.data) else {
                seen.push(r.data);
                continue;
            };
            if r.checksummed || r.busy {
                return Ok((steps, r.busy, r.warning));
            }
            // Confirmed by any earlier read: one garbled read among good ones is outvoted.
            if unconfirmed.iter().any(|p| (p - steps).abs() <= tolerance_steps) {
                return Ok((steps, r.busy, r.warning));
            }
            tracing::debug!(axis = %self.dev(), steps, "position without checksum; reading it again");
            unconfirmed.push(steps);
            seen.push(r.data);
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: "get pos".into(),
            detail: format!("no trustworthy position: {seen:?}"),
        })
    }

    /// All active warning flags (`warnings` answers a count then the flags).
    pub async fn warnings(&self) -> Result<Vec<String>, DriverError> {
        let r = self.ok("warnings", true).await?;
        parse_warnings(&r.data).ok_or_else(|| DriverError::Protocol {
            device: self.dev(),
            request: "warnings".into(),
            detail: format!("{:?}", r.data),
        })
    }

    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let (steps, busy, warning) = self.get_pos().await?;
        let flags = self.warnings().await?;
        let referenced = !flags.iter().any(|f| f == "WR" || f == "WH");
        let faults: Vec<String> = flags
            .iter()
            .filter(|f| f.starts_with('F'))
            .map(|f| describe_warning(f))
            .collect();
        Ok(AxisStatus {
            position_deg: self.deg_from_steps(steps),
            moving: busy,
            referenced,
            fault: if faults.is_empty() {
                None
            } else {
                Some(faults.join(", "))
            },
            raw: format!(
                "pos {steps}, {}, warning {}",
                if busy { "BUSY" } else { "IDLE" },
                warning.as_deref().unwrap_or("--")
            ),
        })
    }

    /// The fault flags when any is set, in words; cleared afterwards so that the next move is not refused.
    async fn clear_faults(&self, seen: Option<&str>) -> Option<String> {
        let flags = self
            .warnings()
            .await
            .unwrap_or_else(|_| seen.map(str::to_string).into_iter().collect());
        let _ = self.ok("warnings clear", true).await;
        (!flags.is_empty()).then(|| {
            flags
                .iter()
                .map(|f| describe_warning(f))
                .collect::<Vec<_>>()
                .join(", ")
        })
    }

    /// Stop this axis now on the priority path.
    pub async fn stop_now(&self) -> Result<(), DriverError> {
        let line = encode_command(self.device, self.axis, None, "stop");
        self.chain
            .port
            .send_priority(line.as_bytes(), Instant::now() + REPLY_TIMEOUT)
            .await
            .map_err(|e| self.chain.transport_error(self.device, self.axis, "stop", e))
    }
}

impl AxisDriver for ZaberAxis {
    fn core(&self) -> &AxisCore {
        &self.core
    }

    fn device(&self) -> String {
        self.dev()
    }

    fn line_port(&self) -> &Arc<LinePort> {
        &self.chain.port
    }

    async fn home_axis(&self) -> Result<(), DriverError> {
        tracing::info!(axis = %self.dev(), "homing");
        // Sent once: a lost reply is resolved by polling, not by homing again.
        match self.ok("home", false).await {
            Ok(_) | Err(DriverError::Timeout { .. }) => {}
            Err(e) => return Err(e),
        }
        let (v, a) = self.core.speed_accel();
        let span = self.core.cfg().max_deg - self.core.cfg().min_deg;
        let timeout = move_deadline(span, v, a) + Duration::from_secs(5);
        let mut poll = Poll::new(self.dev(), "home", timeout, Duration::ZERO, POLL_MIN, POLL_MAX);
        while self.get_pos().await?.1 {
            poll.pause(|| self.ok("stop", true)).await?;
        }
        let flags = self.warnings().await?;
        if let Some(f) = flags.iter().find(|f| f.starts_with('F')) {
            return Err(DriverError::MotionFault {
                device: self.dev(),
                target_deg: f64::NAN,
                reason: format!("homing ended with {}", describe_warning(f)),
            });
        }
        if flags.iter().any(|f| f == "WR" || f == "WH") {
            return Err(DriverError::NotReferenced {
                device: self.dev(),
                state: format!("after homing: {}", flags.join(" ")),
            });
        }
        tracing::info!(axis = %self.dev(), "homed");
        Ok(())
    }

    async fn command_move(&self, target_deg: f64, start_c: Option<f64>) -> Result<(), DriverError> {
        // The start sets the deadline and when to ask whether the move is over: where the axis came to rest,
        // or read now.
        let start_c = match start_c {
            Some(c) => c,
            None => self.get_pos().await?.0 as f64 * self.microstep_deg,
        };
        self.core.set_start(Some(start_c));
        let steps = self.steps_from_deg(target_deg);
        tracing::info!(axis = %self.dev(), target_deg, steps, "move abs");
        let r = self.ok(&format!("move abs {steps}"), true).await?;
        if let Some(w) = r.warning.as_deref().filter(|w| w.starts_with('F')) {
            // A fault flag set before the move: the move may not happen. Report it rather than wait in vain.
            tracing::warn!(axis = %self.dev(), warning = %describe_warning(w), "fault flag active at move start");
        }
        Ok(())
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    async fn wait_within(&self, target_deg: f64, tolerance_deg: f64) -> Result<f64, DriverError> {
        let plan = self.core.plan(target_deg, Duration::ZERO);
        // The first question at once (the reply to `get pos` says busy or idle and where, in one exchange).
        let mut poll = Poll::new(
            self.dev(),
            format!("move to {target_deg} deg"),
            plan.timeout,
            plan.predicted,
            POLL_MIN,
            POLL_MAX,
        );
        let (steps, warning) = loop {
            let (steps, busy, warning) = self.get_pos().await?;
            if let Some(f) = warning.as_deref().filter(|w| w.starts_with('F')) {
                let why = self
                    .clear_faults(Some(f))
                    .await
                    .unwrap_or_else(|| describe_warning(f));
                return Err(DriverError::MotionFault {
                    device: self.dev(),
                    target_deg,
                    reason: format!("{why}; stopped at {} deg", self.deg_from_steps(steps)),
                });
            }
            if !busy {
                break (steps, warning);
            }
            poll.pause(|| self.ok("stop", true)).await?;
        };
        let read = self.deg_from_steps(steps);
        if (read - target_deg).abs() <= tolerance_deg.max(self.microstep_deg) {
            tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
            return Ok(read);
        }
        let why = self.clear_faults(None).await.unwrap_or_else(|| {
            warning
                .map(|w| describe_warning(&w))
                .unwrap_or_else(|| "no warning flag".into())
        });
        Err(DriverError::MotionFault {
            device: self.dev(),
            target_deg,
            reason: format!(
                "idle at {read} deg, {} deg from the target: {why}",
                read - target_deg
            ),
        })
    }

    async fn controller_position(&self) -> Result<f64, DriverError> {
        Ok(self.get_pos().await?.0 as f64 * self.microstep_deg)
    }

    /// One `get pos`, as the chain sends it (with a message id and a checksum).
    async fn position_exchange(&self) -> Result<(f64, usize, usize), DriverError> {
        let r = self.ok("get pos", true).await?;
        let steps = parse_int(&r.data).ok_or_else(|| DriverError::Protocol {
            device: self.dev(),
            request: "get pos".into(),
            detail: format!("not a position: {:?}", r.data),
        })?;
        let request = encode_command(self.device, self.axis, Some(0), "get pos").len();
        Ok((steps as f64 * self.microstep_deg, request, r.line_len()))
    }

    fn axis_status(&self) -> impl Future<Output = Result<AxisStatus, DriverError>> + Send {
        self.read_status()
    }

    fn stop_axis(&self) -> impl Future<Output = Result<(), DriverError>> + Send {
        self.stop_now()
    }

    async fn write_speed(
        &self,
        speed_deg_s: Option<f64>,
        accel_deg_s2: Option<f64>,
    ) -> Result<(), DriverError> {
        if let Some(v) = speed_deg_s {
            let speed = (v / self.microstep_deg * SPEED_UNIT).round().max(1.0) as i64;
            self.ok(&format!("set maxspeed {speed}"), true).await?;
        }
        if let Some(a) = accel_deg_s2 {
            let accel = (a / self.microstep_deg * ACCEL_UNIT).round().max(1.0) as i64;
            self.ok(&format!("set accel {accel}"), true).await?;
        }
        Ok(())
    }

    /// Nothing to leave: a Zaber device takes moves again once its fault flags are cleared, which the wait
    /// that saw them did.
    async fn re_enable(&self) -> Result<(), DriverError> {
        Ok(())
    }
}
