//! One Zaber rotary axis: verified positions, status, homing, moves with the backlash approach.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use super::chain::ZaberChain;
use super::protocol::{Flag, Reply, describe_warning, encode_command, is_warning, parse_int};
use super::{ACCEL_UNIT, ATTEMPTS, POLL_MAX, POLL_MIN, REPLY_TIMEOUT, SPEED_UNIT};
use crate::error::DriverError;
use crate::motion::{PollSchedule, approach_waypoints, check_speed, move_deadline, trapezoid_time_s};
use crate::traits::{Axis, AxisLimits, AxisStatus};
use crate::transport::BoxFuture;

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
    cfg: gonio_instrument::Axis,
    motion: Mutex<(f64, f64)>,
    last_start: Mutex<Option<f64>>,
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
        let motion = Mutex::new((cfg.max_speed_deg_s, cfg.accel_deg_s2));
        Ok(ZaberAxis {
            device: cfg.address,
            axis: cfg.zaber_axis,
            chain,
            microstep_deg,
            cfg,
            motion,
            last_start: Mutex::new(None),
        })
    }

    fn dev(&self) -> String {
        format!(
            "{} ({}/{}.{})",
            self.cfg.name, self.chain.name, self.device, self.axis
        )
    }

    fn steps_from_deg(&self, physical_deg: f64) -> i64 {
        (self.cfg.controller_from_physical_deg(physical_deg) / self.microstep_deg).round() as i64
    }

    fn deg_from_steps(&self, steps: i64) -> f64 {
        self.cfg
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
        let tolerance_steps = (self.cfg.encoder_resolution_deg / self.microstep_deg)
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

    pub async fn do_home(&self) -> Result<(), DriverError> {
        tracing::info!(axis = %self.dev(), "homing");
        // Sent once: a lost reply is resolved by polling, not by homing again.
        match self.ok("home", false).await {
            Ok(_) | Err(DriverError::Timeout { .. }) => {}
            Err(e) => return Err(e),
        }
        let (v, a) = self.speed_accel();
        let span = self.cfg.max_deg - self.cfg.min_deg;
        let deadline = Instant::now() + move_deadline(span, v, a) + Duration::from_secs(5);
        let mut schedule = PollSchedule::new(Instant::now(), POLL_MIN, POLL_MAX);
        loop {
            let (_, busy, _) = self.get_pos().await?;
            if !busy {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                let _ = self.ok("stop", true).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: "home".into(),
                    timeout: move_deadline(span, v, a),
                });
            }
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
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

    fn speed_accel(&self) -> (f64, f64) {
        self.motion
            .lock()
            .map(|g| *g)
            .unwrap_or((self.cfg.max_speed_deg_s, self.cfg.accel_deg_s2))
    }

    fn check_limits(&self, target_deg: f64) -> Result<(), DriverError> {
        if !(target_deg.is_finite() && target_deg >= self.cfg.min_deg && target_deg <= self.cfg.max_deg) {
            return Err(DriverError::OutOfRange {
                device: self.dev(),
                what: "target (deg)".into(),
                value: target_deg,
                min: self.cfg.min_deg,
                max: self.cfg.max_deg,
            });
        }
        Ok(())
    }

    pub async fn do_start_move(&self, target_deg: f64) -> Result<(), DriverError> {
        self.check_limits(target_deg)?;
        let (start, _, _) = self.get_pos().await?;
        if let Ok(mut g) = self.last_start.lock() {
            *g = Some(self.deg_from_steps(start));
        }
        let steps = self.steps_from_deg(target_deg);
        tracing::info!(axis = %self.dev(), target_deg, steps, "move abs");
        let r = self.ok(&format!("move abs {steps}"), true).await?;
        if let Some(w) = r.warning.as_deref().filter(|w| w.starts_with('F')) {
            // A fault flag set before the move: the move may not happen. Report it rather than wait in vain.
            tracing::warn!(axis = %self.dev(), warning = %describe_warning(w), "fault flag active at move start");
        }
        Ok(())
    }

    pub async fn do_wait_arrived(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.wait_arrived_within(target_deg, self.cfg.tolerance_deg).await
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    async fn wait_arrived_within(&self, target_deg: f64, tolerance_deg: f64) -> Result<f64, DriverError> {
        let (v, a) = self.speed_accel();
        let start = self.last_start.lock().ok().and_then(|g| *g);
        let distance = start
            .map(|s| (target_deg - s).abs())
            .unwrap_or(self.cfg.max_deg - self.cfg.min_deg);
        let timeout = move_deadline(distance, v, a);
        let predicted = trapezoid_time_s(distance, v, a);
        let now = Instant::now();
        let deadline = now + timeout;
        // The first question at once (the reply to `get pos` says busy or idle and where, in one exchange).
        let mut schedule = PollSchedule::new(
            now + Duration::from_secs_f64(if predicted.is_finite() {
                predicted.clamp(0.0, 600.0)
            } else {
                0.0
            }),
            POLL_MIN,
            POLL_MAX,
        );
        let (mut steps, mut warning);
        loop {
            let (s, busy, w) = self.get_pos().await?;
            steps = s;
            warning = w;
            if let Some(f) = warning.as_deref().filter(|w| w.starts_with('F')) {
                let flags = self.warnings().await.unwrap_or_else(|_| vec![f.to_string()]);
                let _ = self.ok("warnings clear", true).await;
                return Err(DriverError::MotionFault {
                    device: self.dev(),
                    target_deg,
                    reason: format!(
                        "{}; stopped at {} deg",
                        flags
                            .iter()
                            .map(|f| describe_warning(f))
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.deg_from_steps(steps)
                    ),
                });
            }
            if !busy {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                tracing::warn!(axis = %self.dev(), "deadline passed while moving; stopping the axis");
                let _ = self.ok("stop", true).await;
                return Err(DriverError::Timeout {
                    device: self.dev(),
                    request: format!("move to {target_deg} deg"),
                    timeout,
                });
            }
            tokio::time::sleep(schedule.next_pause(now).min(deadline - now)).await;
        }
        let read = self.deg_from_steps(steps);
        if (read - target_deg).abs() <= tolerance_deg.max(self.microstep_deg) {
            tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
            return Ok(read);
        }
        let flags = self.warnings().await.unwrap_or_default();
        let why = if flags.is_empty() {
            warning
                .map(|w| describe_warning(&w))
                .unwrap_or_else(|| "no warning flag".into())
        } else {
            flags
                .iter()
                .map(|f| describe_warning(f))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = self.ok("warnings clear", true).await;
        Err(DriverError::MotionFault {
            device: self.dev(),
            target_deg,
            reason: format!(
                "idle at {read} deg, {} deg from the target: {why}",
                read - target_deg
            ),
        })
    }

    pub async fn do_move_to(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.check_limits(target_deg)?;
        let (steps, _, _) = self.get_pos().await?;
        let current_c = steps as f64 * self.microstep_deg;
        let mut read = f64::NAN;
        for (step_deg, tolerance) in approach_waypoints(&self.cfg, current_c, target_deg) {
            self.do_start_move(step_deg).await?;
            read = self.wait_arrived_within(step_deg, tolerance).await?;
        }
        Ok(read)
    }

    pub async fn do_set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
        check_speed(self.dev(), speed_deg_s, accel_deg_s2)?;
        let speed = (speed_deg_s / self.microstep_deg * SPEED_UNIT).round().max(1.0) as i64;
        let accel = (accel_deg_s2 / self.microstep_deg * ACCEL_UNIT).round().max(1.0) as i64;
        self.ok(&format!("set maxspeed {speed}"), true).await?;
        self.ok(&format!("set accel {accel}"), true).await?;
        if let Ok(mut g) = self.motion.lock() {
            *g = (speed_deg_s, accel_deg_s2);
        }
        Ok(())
    }

    pub async fn do_reconnect(&self) -> Result<AxisStatus, DriverError> {
        self.chain
            .port
            .reconnect()
            .await
            .map_err(|e| DriverError::Unavailable {
                device: self.dev(),
                detail: e.to_string(),
            })?;
        let status = self.read_status().await?;
        if !status.referenced {
            return Err(DriverError::NotReferenced {
                device: self.dev(),
                state: status.raw,
            });
        }
        tracing::info!(axis = %self.dev(), position_deg = status.position_deg, "re-verified after reconnect");
        Ok(status)
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

impl Axis for ZaberAxis {
    fn name(&self) -> &str {
        &self.cfg.name
    }
    fn limits(&self) -> AxisLimits {
        AxisLimits {
            min_deg: self.cfg.min_deg,
            max_deg: self.cfg.max_deg,
            max_speed_deg_s: self.cfg.max_speed_deg_s,
            accel_deg_s2: self.cfg.accel_deg_s2,
        }
    }
    fn home(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_home())
    }
    fn move_to(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.do_move_to(target_deg))
    }
    fn start_move(&self, target_deg: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_start_move(target_deg))
    }
    fn wait_arrived(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.do_wait_arrived(target_deg))
    }
    fn wait_passed_via(&self, via_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(self.wait_arrived_within(via_deg, crate::motion::via_point_tolerance_deg(&self.cfg)))
    }
    fn position_deg(&self) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(async move { self.get_pos().await.map(|(s, _, _)| self.deg_from_steps(s)) })
    }
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.read_status())
    }
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.stop_now())
    }
    fn set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_set_speed(speed_deg_s, accel_deg_s2))
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.do_reconnect())
    }
}
