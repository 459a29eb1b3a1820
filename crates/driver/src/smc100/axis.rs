//! One SMC100 axis: verified positions, status, homing, moves with the backlash approach and a verified
//! arrival.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::chain::Smc100Chain;
use super::protocol::{State, Ts, describe_error_bits, parse_number, parse_ts, wire_number};
use super::wait::Wait;
use super::{ATTEMPTS, MOVING_READ_WINDOW_S, POLL_MIN};
use crate::error::{DriverError, ErrorKind};
use crate::motion::{approach_waypoints, check_speed, move_deadline, trapezoid_time_s};
use crate::traits::{Axis, AxisLimits, AxisStatus};
use crate::transport::BoxFuture;

/// One SMC100 axis.
#[derive(Debug)]
pub struct Smc100Axis {
    pub(super) chain: Arc<Smc100Chain>,
    pub(super) addr: u8,
    pub(super) cfg: gonio_instrument::Axis,
    /// Speed and acceleration in use (controller units per s, per s^2), for deadlines.
    motion: Mutex<(f64, f64)>,
    /// Controller position where the last move started.
    last_start: Mutex<Option<f64>>,
    /// When the last `PA` went out: the wait that follows counts the move's predicted time from there (the
    /// pause after the set command is already part of the move).
    pa_sent: Mutex<Option<tokio::time::Instant>>,
    /// The last move was already over at its first status question (a move that was tiny, or a controller much
    /// faster than its configured motion, like the simulator at a large time scale): the first question of the
    /// next move then asks for the read-back at once, saving an exchange.
    pub(super) early_finish: AtomicBool,
}

impl Smc100Axis {
    pub fn new(chain: Arc<Smc100Chain>, cfg: gonio_instrument::Axis) -> Smc100Axis {
        let motion = Mutex::new((cfg.max_speed_deg_s, cfg.accel_deg_s2));
        Smc100Axis {
            chain,
            addr: cfg.address,
            cfg,
            motion,
            last_start: Mutex::new(None),
            pa_sent: Mutex::new(None),
            early_finish: AtomicBool::new(false),
        }
    }

    pub fn address(&self) -> u8 {
        self.addr
    }

    pub(super) fn dev(&self) -> String {
        format!("{} ({}/{})", self.cfg.name, self.chain.name, self.addr)
    }

    pub(super) fn speed_accel(&self) -> (f64, f64) {
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

    /// Whether two position reads (controller units) agree: within the encoder resolution for an axis at rest;
    /// for a moving axis, within what it travels at full speed between the two reads.
    pub(super) fn reads_agree(&self, a: f64, b: f64, moving: bool) -> bool {
        let mut tolerance = self.cfg.encoder_resolution_deg.max(1e-6) + 1e-9;
        if moving {
            let (v, _) = self.speed_accel();
            tolerance += v.abs() * MOVING_READ_WINDOW_S;
        }
        (a - b).abs() <= tolerance
    }

    /// The controller position (controller units), read for a decision: where a move starts from, where it
    /// ended, where the engine plans from. Why two reads: a reply garbled inside a well-formed number
    /// (`1TP12.345` with one digit changed) parses like a good one, and this protocol has no checksum. Two reads
    /// in one exchange must agree within the encoder resolution (one corrupted byte cannot make both wrong
    /// alike); a moving axis is allowed its travel between them. Retried, boundedly; a typed Protocol error
    /// when the reads never agree.
    pub async fn verified_position(&self) -> Result<f64, DriverError> {
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = self.chain.queries(self.addr, &[("TP", ""), ("TP", "")]).await?;
            let (a, b) = (number_at(&r, 0), number_at(&r, 1));
            if let (Some(a), Some(b)) = (a, b) {
                if self.reads_agree(a, b, false) {
                    return Ok(b);
                }
                // Reads of a moving axis differ by its travel: that is motion, not garbage.
                if let Ok(ts) = self.chain.ts(self.addr).await
                    && is_moving(ts.state)
                    && self.reads_agree(a, b, true)
                {
                    return Ok(b);
                }
            }
            tracing::warn!(axis = %self.dev(), attempt, replies = ?r, "two position reads disagree; reading again");
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: format!("{}TP (read twice)", self.addr),
            detail: format!(
                "the two reads never agreed within the encoder resolution ({} deg): {}",
                self.cfg.encoder_resolution_deg,
                seen.join(", ")
            ),
        })
    }

    /// A TS reading that would end a wait or report a fault (DISABLE, NOT REFERENCED, CONFIGURATION, and error
    /// bits when `errors_matter`) is confirmed by a second TS before anything acts on it: one garbled byte turns
    /// READY (33) into DISABLE (3C). Returns the latest reading (the second when a confirmation was asked).
    pub(super) async fn confirmed(&self, ts: Ts, errors_matter: bool) -> Result<Ts, DriverError> {
        let alarming = (errors_matter && ts.errors != 0)
            || matches!(
                ts.state,
                State::Disable(_) | State::NotReferenced(_) | State::Configuration | State::Unknown(_)
            );
        if !alarming {
            return Ok(ts);
        }
        let again = self.chain.ts(self.addr).await?;
        if again != ts {
            tracing::warn!(axis = %self.dev(), first = %ts_reason(&ts), second = %ts_reason(&again), "status changed on a second look");
        }
        Ok(again)
    }

    /// Status with the position converted to physical degrees: TS and two TP reads in one exchange.
    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = self
                .chain
                .queries(self.addr, &[("TS", ""), ("TP", ""), ("TP", "")])
                .await?;
            let ts = r.first().and_then(|v| v.as_deref()).and_then(parse_ts);
            if let (Some(ts), Some(a), Some(b)) = (ts, number_at(&r, 1), number_at(&r, 2))
                && self.reads_agree(a, b, is_moving(ts.state))
            {
                let ts = self.confirmed(ts, true).await?;
                let fault = match ts.state {
                    State::Disable(_) | State::Unknown(_) => Some(ts_reason(&ts)),
                    _ if ts.errors != 0 => Some(ts_reason(&ts)),
                    _ => None,
                };
                return Ok(AxisStatus {
                    position_deg: self.cfg.physical_from_controller_deg(b),
                    moving: is_moving(ts.state),
                    referenced: !matches!(ts.state, State::NotReferenced(_) | State::Configuration),
                    fault,
                    raw: format!("TS errors {:04X}, {}", ts.errors, ts.state.describe()),
                });
            }
            tracing::warn!(axis = %self.dev(), attempt, replies = ?r, "status replies malformed or disagreeing; reading again");
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: self.dev(),
            request: format!("{0}TS {0}TP {0}TP", self.addr),
            detail: format!("no consistent status: {}", seen.join(", ")),
        })
    }

    /// Home: NOT REFERENCED -> `OR` and wait for READY; DISABLE -> `MM1` back to READY (reference kept);
    /// READY -> nothing to do. `OR` is sent once, never retried blindly.
    pub async fn do_home(&self) -> Result<(), DriverError> {
        let ts = self.chain.ts(self.addr).await?;
        match ts.state {
            State::Ready(_) => {
                tracing::info!(axis = %self.dev(), "already referenced");
                Ok(())
            }
            State::Disable(_) => {
                tracing::info!(axis = %self.dev(), state = %ts.state.describe(), "leaving DISABLE (MM1)");
                self.chain.command(self.addr, "MM", "1", true).await?;
                self.wait_state(
                    |s| matches!(s, State::Ready(_)),
                    Wait::plain(Duration::from_secs(5), Duration::ZERO),
                    None,
                )
                .await
                .map(|_| ())
            }
            State::NotReferenced(_) => {
                tracing::info!(axis = %self.dev(), "homing (OR)");
                if let Err(e) = self.chain.command(self.addr, "OR", "", false).await {
                    // OR is not resent blindly, but a lost or garbled TE reply says nothing about whether homing
                    // started: the controller's state does.
                    if !matches!(e.kind(), ErrorKind::Timeout | ErrorKind::Protocol) {
                        return Err(e);
                    }
                    match self.chain.ts(self.addr).await?.state {
                        State::Homing(_) | State::Ready(_) => {
                            tracing::warn!(axis = %self.dev(), error = %e, "no clear reply to OR, but homing is under way")
                        }
                        State::NotReferenced(_) => {
                            tracing::warn!(axis = %self.dev(), error = %e, "OR not taken; sending it again");
                            self.chain.command(self.addr, "OR", "", false).await?;
                        }
                        _ => return Err(e),
                    }
                }
                // Homing searches at reduced speed across at most the whole travel.
                let (v, a) = self.speed_accel();
                let span = self.cfg.max_deg - self.cfg.min_deg;
                let deadline = move_deadline(span, v * 0.25, a) + Duration::from_secs(10);
                self.wait_state(
                    |s| matches!(s, State::Ready(_)),
                    Wait::plain(deadline, Duration::ZERO),
                    None,
                )
                .await
                .map(|_| ())
            }
            other => Err(DriverError::Rejected {
                device: self.dev(),
                request: format!("{}OR", self.addr),
                reason: format!("cannot home in state {}", other.describe()),
            }),
        }
    }

    /// Send `PA` for a physical target (idempotent, retried when its TE is lost).
    pub async fn do_start_move(&self, target_deg: f64) -> Result<(), DriverError> {
        self.check_limits(target_deg)?;
        let controller = self.cfg.controller_from_physical_deg(target_deg);
        if let Ok(mut g) = self.last_start.lock() {
            *g = None;
        }
        if let Ok(mut g) = self.pa_sent.lock() {
            *g = Some(tokio::time::Instant::now());
        }
        tracing::info!(axis = %self.dev(), target_deg, controller, "move absolute");
        // The position the move starts from (read twice, see `verified_position`) goes out in the same exchange
        // as PA: the distance sets the deadline and when to ask whether the move is over. When the two reads do
        // not agree the start stays unknown and the wait assumes the whole travel (a longer deadline, no harm).
        match self
            .chain
            .command_after(
                self.addr,
                &[("TP", ""), ("TP", "")],
                "PA",
                &wire_number(controller),
                true,
            )
            .await
        {
            Ok(start) => {
                let start = match (number_at(&start, 0), number_at(&start, 1)) {
                    (Some(a), Some(b)) if self.reads_agree(a, b, false) => Some(b),
                    _ => None,
                };
                if let Ok(mut g) = self.last_start.lock() {
                    *g = start;
                }
                Ok(())
            }
            // A retried PA whose first copy got through (only its TE reply was lost) meets the axis already
            // MOVING: that is success if the controller's set-point is our target. During a move the set-point
            // (TH) is the profile generator's position, which reaches the target only at the end of the move:
            // when it does not match at once, wait (bounded) for the move in progress to end and look again.
            Err(e @ DriverError::Rejected { .. }) if e.to_string().contains("error M:") => {
                let on_target =
                    |th: f64| (th - controller).abs() <= self.cfg.encoder_resolution_deg.max(1e-6);
                if let Ok(th) = self.chain.number(self.addr, "TH", "").await
                    && on_target(th)
                {
                    tracing::info!(axis = %self.dev(), target_deg, "already moving to this target");
                    return Ok(());
                }
                let (v, a) = self.speed_accel();
                let timeout = move_deadline(self.cfg.max_deg - self.cfg.min_deg, v, a);
                match self
                    .wait_state(
                        |s| matches!(s, State::Ready(_)),
                        Wait::plain(timeout, Duration::ZERO),
                        Some(target_deg),
                    )
                    .await
                {
                    Ok(_) => {}
                    // The move in progress ended in a fault (a stall leaves DISABLE): that is the error to report.
                    Err(stalled) if stalled.kind() == ErrorKind::MotionFault => return Err(stalled),
                    Err(_) => return Err(e),
                }
                match self.chain.number(self.addr, "TH", "").await {
                    Ok(th) if on_target(th) => {
                        tracing::info!(axis = %self.dev(), target_deg, "the retried move had already run to this target");
                        Ok(())
                    }
                    _ => Err(e),
                }
            }
            // DISABLE is where a stall or a stop leaves the controller: a motion fault, which the caller recovers
            // from (reconnecting re-enables the axis), not a refusal to give up on.
            Err(DriverError::Rejected { reason, .. }) if reason.starts_with("error J:") => {
                Err(DriverError::MotionFault {
                    device: self.dev(),
                    target_deg,
                    reason: format!(
                        "the controller is in DISABLE after a fault and refused the move ({reason})"
                    ),
                })
            }
            Err(other) => Err(other),
        }
    }

    /// Wait for the move to end and verify the read-back against the target.
    pub async fn do_wait_arrived(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.wait_arrived_within(target_deg, self.cfg.tolerance_deg).await
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    pub(super) async fn wait_arrived_within(
        &self,
        target_deg: f64,
        tolerance_deg: f64,
    ) -> Result<f64, DriverError> {
        let controller_target = self.cfg.controller_from_physical_deg(target_deg);
        let (v, a) = self.speed_accel();
        let start = self.last_start.lock().ok().and_then(|g| *g);
        let distance = match start {
            Some(s) => (controller_target - s).abs(),
            None => self.cfg.max_deg - self.cfg.min_deg,
        };
        // Already under way since the PA went out (and the pause after it): what is left of the predicted time.
        let under_way_s = self
            .pa_sent
            .lock()
            .ok()
            .and_then(|g| *g)
            .map_or(0.0, |t| t.elapsed().as_secs_f64());
        let predicted = trapezoid_time_s(distance, v, a) - under_way_s;
        let wait = Wait {
            timeout: move_deadline(distance, v, a),
            predicted: Duration::from_secs_f64(if predicted.is_finite() {
                predicted.clamp(0.0, 600.0)
            } else {
                0.0
            }),
            pt_distance: Some(distance),
            readback: true,
        };
        let (ts, read_c) = self
            .wait_state(|s| matches!(s, State::Ready(_)), wait, Some(target_deg))
            .await?;
        // READY: verify the read-back. The position decides whether the move arrived and becomes the point's
        // recorded position, hence two agreeing reads (see `verified_position`), never one.
        let mut read_c = match read_c {
            Some(p) => p,
            None => self.verified_position().await?,
        };
        let mut read = f64::NAN;
        for attempt in 1..=ATTEMPTS {
            read = self.cfg.physical_from_controller_deg(read_c);
            if (read - target_deg).abs() <= tolerance_deg {
                tracing::info!(axis = %self.dev(), target_deg, read_back_deg = read, "arrived");
                return Ok(read);
            }
            if attempt == ATTEMPTS {
                break;
            }
            // A servo may still settle into its deadband just after READY: look again, a little later.
            tokio::time::sleep(POLL_MIN).await;
            read_c = self.verified_position().await?;
        }
        Err(DriverError::MotionFault {
            device: self.dev(),
            target_deg,
            reason: format!(
                "stopped at {read} deg ({}), tolerance {} deg; {}",
                read - target_deg,
                tolerance_deg,
                ts_reason(&ts)
            ),
        })
    }

    /// Move with the backlash approach and verified arrival.
    pub async fn do_move_to(&self, target_deg: f64) -> Result<f64, DriverError> {
        self.check_limits(target_deg)?;
        // Where the axis is decides whether the approach needs the backlash overshoot: a verified read.
        let current = self.verified_position().await?;
        let mut read = f64::NAN;
        for (step_deg, tolerance) in approach_waypoints(&self.cfg, current, target_deg) {
            self.do_start_move(step_deg).await?;
            read = self.wait_arrived_within(step_deg, tolerance).await?;
        }
        Ok(read)
    }

    pub async fn do_set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
        check_speed(self.dev(), speed_deg_s, accel_deg_s2)?;
        self.chain
            .command(self.addr, "VA", &wire_number(speed_deg_s), true)
            .await?;
        self.chain
            .command(self.addr, "AC", &wire_number(accel_deg_s2), true)
            .await?;
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
        // A stall (following error) or a stop leaves the controller in DISABLE, where it refuses every move
        // (error J). Reconnecting means "ready to be commanded again": leave DISABLE with MM1, which keeps the
        // reference, so that the caller's retry of an absolute move is not refused.
        let ts = self.chain.ts(self.addr).await?;
        if let State::Disable(_) = ts.state {
            tracing::warn!(axis = %self.dev(), reason = %ts_reason(&ts), "controller in DISABLE after a fault; re-enabling");
            self.do_home().await?;
        }
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

    /// Expected duration of a move of `distance_deg` at the current settings (for planning).
    pub fn move_time_s(&self, distance_deg: f64) -> f64 {
        let (v, a) = self.speed_accel();
        trapezoid_time_s(distance_deg, v, a)
    }
}

/// The number in reply `i` of an exchange, if it came and parses.
pub(super) fn number_at(replies: &[Option<String>], i: usize) -> Option<f64> {
    replies.get(i)?.as_deref().and_then(parse_number)
}

/// States in which the axis moves by itself.
pub(super) fn is_moving(state: State) -> bool {
    matches!(state, State::Moving | State::Homing(_) | State::Jogging(_))
}

pub(super) fn ts_reason(ts: &Ts) -> String {
    let bits = describe_error_bits(ts.errors);
    if bits.is_empty() {
        ts.state.describe()
    } else {
        format!(
            "{}; positioner errors {:04X}: {}",
            ts.state.describe(),
            ts.errors,
            bits.join(", ")
        )
    }
}

impl Axis for Smc100Axis {
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
        // The engine plans moves (and their collision safety) from this: a verified read.
        Box::pin(async move {
            let pos = self.verified_position().await?;
            Ok(self.cfg.physical_from_controller_deg(pos))
        })
    }
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.read_status())
    }
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.chain.stop_all(std::slice::from_ref(&self.addr)))
    }
    fn set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_set_speed(speed_deg_s, accel_deg_s2))
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.do_reconnect())
    }
}
