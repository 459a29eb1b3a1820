//! One SMC100 axis: verified positions, status, homing, moves with the backlash approach and a verified
//! arrival. [`Axis`](crate::Axis) comes from [`AxisDriver`], shared with the other axis drivers.

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::chain::Smc100Chain;
use super::controller::Controller;
use super::protocol::{State, is_moving, number_at, parse_number, parse_ts, ts_reason, wire_number};
use super::wait::{Wait, wait_state};
use super::{ATTEMPTS, MOVING_READ_WINDOW_S, POLL_MIN};
use crate::axis_driver::{AxisCore, AxisDriver};
use crate::error::{DriverError, ErrorKind};
use crate::motion::move_deadline;
use crate::traits::AxisStatus;
use crate::transport::LinePort;

/// One SMC100 axis.
#[derive(Debug)]
pub struct Smc100Axis {
    ctl: Controller,
    core: AxisCore,
    /// When the last `PA` went out (the write of the PA line itself, not the start of the exchange carrying it):
    /// the wait that follows counts the move's predicted time from there (the pause after the set command is
    /// already part of the move), so that its first question after the predicted end finds the move over.
    pa_sent: Mutex<Option<tokio::time::Instant>>,
    /// Whether the last move was over at its first status question (see [`wait_state`]).
    early_finish: AtomicBool,
}

impl Smc100Axis {
    pub fn new(chain: Arc<Smc100Chain>, cfg: gonio_instrument::Axis) -> Smc100Axis {
        Smc100Axis {
            ctl: Controller::new(chain, &cfg),
            core: AxisCore::new(cfg),
            pa_sent: Mutex::new(None),
            early_finish: AtomicBool::new(false),
        }
    }

    pub fn address(&self) -> u8 {
        self.ctl.addr
    }

    /// Whether two position reads (controller units) agree: within the encoder resolution for an axis at rest;
    /// for a moving axis, within what it travels at full speed between the two reads.
    fn reads_agree(&self, a: f64, b: f64, moving: bool) -> bool {
        let travel = if moving {
            self.core.speed_accel().0 * MOVING_READ_WINDOW_S
        } else {
            0.0
        };
        self.ctl.reads_agree(a, b, travel)
    }

    fn wait(
        &self,
        done: impl Fn(State) -> bool,
        wait: Wait,
        target_deg: Option<f64>,
    ) -> impl Future<Output = Result<(super::protocol::Ts, Option<f64>), DriverError>> {
        wait_state(&self.ctl, &self.early_finish, done, wait, target_deg)
    }

    /// Wait (bounded by `timeout`) until the controller is READY.
    async fn wait_ready(&self, timeout: Duration, target_deg: Option<f64>) -> Result<(), DriverError> {
        self.wait(
            |s| matches!(s, State::Ready(_)),
            Wait::plain(timeout, Duration::ZERO),
            target_deg,
        )
        .await
        .map(|_| ())
    }

    /// The controller position (controller units), read for a decision: where a move starts from, where it
    /// ended, where the engine plans from. Why two reads: a reply garbled inside a well-formed number
    /// (`1TP12.345` with one digit changed) parses like a good one, and this protocol has no checksum. Two reads
    /// in one exchange must agree within the encoder resolution (one corrupted byte cannot make both wrong
    /// alike); a moving axis is allowed its travel between them. Retried, boundedly; a typed Protocol error
    /// when the reads never agree.
    pub async fn verified_position(&self) -> Result<f64, DriverError> {
        let ctl = &self.ctl;
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = ctl.chain.queries(ctl.addr, &[("TP", ""), ("TP", "")]).await?;
            if let (Some(a), Some(b)) = (number_at(&r, 0), number_at(&r, 1)) {
                if self.reads_agree(a, b, false) {
                    return Ok(b);
                }
                // Reads of a moving axis differ by its travel: that is motion, not garbage.
                if let Ok(ts) = ctl.chain.ts(ctl.addr).await
                    && is_moving(ts.state)
                    && self.reads_agree(a, b, true)
                {
                    return Ok(b);
                }
            }
            tracing::warn!(axis = %ctl.device, attempt, replies = ?r, "two position reads disagree; reading again");
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: ctl.device.clone(),
            request: format!("{}TP (read twice)", ctl.addr),
            detail: format!(
                "the two reads never agreed within the encoder resolution ({} deg): {}",
                self.core.cfg().encoder_resolution_deg,
                seen.join(", ")
            ),
        })
    }

    /// Status with the position converted to physical degrees: TS and two TP reads in one exchange.
    pub async fn read_status(&self) -> Result<AxisStatus, DriverError> {
        let ctl = &self.ctl;
        let mut seen = Vec::new();
        for attempt in 1..=ATTEMPTS {
            let r = ctl
                .chain
                .queries(ctl.addr, &[("TS", ""), ("TP", ""), ("TP", "")])
                .await?;
            let ts = r.first().and_then(|v| v.as_deref()).and_then(parse_ts);
            if let (Some(ts), Some(a), Some(b)) = (ts, number_at(&r, 1), number_at(&r, 2))
                && self.reads_agree(a, b, is_moving(ts.state))
            {
                let ts = ctl.confirmed(ts, true).await?;
                let fault = match ts.state {
                    State::Disable(_) | State::Unknown(_) => Some(ts_reason(&ts)),
                    _ if ts.errors != 0 => Some(ts_reason(&ts)),
                    _ => None,
                };
                return Ok(AxisStatus {
                    position_deg: self.core.cfg().physical_from_controller_deg(b),
                    moving: is_moving(ts.state),
                    referenced: !matches!(ts.state, State::NotReferenced(_) | State::Configuration),
                    fault,
                    raw: format!("TS errors {:04X}, {}", ts.errors, ts.state.describe()),
                });
            }
            if ts.is_none() && ctl.chain.lost_first_ts(ctl.addr) {
                tracing::debug!(axis = %ctl.device, attempt, replies = ?r, "first TS unanswered, as recorded for real SMC100s; reading again");
            } else {
                tracing::warn!(axis = %ctl.device, attempt, replies = ?r, "status replies malformed or disagreeing; reading again");
            }
            seen.push(format!("{r:?}"));
        }
        Err(DriverError::Protocol {
            device: ctl.device.clone(),
            request: format!("{0}TS {0}TP {0}TP", ctl.addr),
            detail: format!("no consistent status: {}", seen.join(", ")),
        })
    }

    /// The retried `PA` met the axis MOVING (error M): success if the controller's set-point is our target.
    /// During a move the set-point (TH) is the profile generator's position, which reaches the target only at
    /// the end of the move: when it does not match at once, wait (bounded) for the move in progress to end and
    /// look again. `refused` is the error to report when it is not.
    async fn resolve_moving(
        &self,
        target_deg: f64,
        controller: f64,
        refused: DriverError,
    ) -> Result<(), DriverError> {
        let ctl = &self.ctl;
        let resolution = self.core.cfg().encoder_resolution_deg.max(1e-6);
        let on_target = |th: f64| (th - controller).abs() <= resolution;
        if let Ok(th) = ctl.chain.number(ctl.addr, "TH", "").await
            && on_target(th)
        {
            tracing::info!(axis = %ctl.device, target_deg, "already moving to this target");
            return Ok(());
        }
        let (v, a) = self.core.speed_accel();
        let span = self.core.cfg().max_deg - self.core.cfg().min_deg;
        match self.wait_ready(move_deadline(span, v, a), Some(target_deg)).await {
            Ok(()) => {}
            // The move in progress ended in a fault (a stall leaves DISABLE): that is the error to report.
            Err(stalled) if stalled.kind() == ErrorKind::MotionFault => return Err(stalled),
            Err(_) => return Err(refused),
        }
        match ctl.chain.number(ctl.addr, "TH", "").await {
            Ok(th) if on_target(th) => {
                tracing::info!(axis = %ctl.device, target_deg, "the retried move had already run to this target");
                Ok(())
            }
            _ => Err(refused),
        }
    }

    /// Home: NOT REFERENCED -> `OR` and wait for READY; DISABLE -> `MM1` back to READY (reference kept);
    /// READY -> nothing to do. `OR` is sent once, never retried blindly.
    async fn home_from_state(&self) -> Result<(), DriverError> {
        let ctl = &self.ctl;
        let ts = ctl.chain.ts(ctl.addr).await?;
        match ts.state {
            State::Ready(_) => {
                tracing::info!(axis = %ctl.device, "already referenced");
                Ok(())
            }
            State::Disable(_) => {
                tracing::info!(axis = %ctl.device, state = %ts.state.describe(), "leaving DISABLE (MM1)");
                ctl.chain.command(ctl.addr, "MM", "1", true).await?;
                self.wait_ready(Duration::from_secs(5), None).await
            }
            State::NotReferenced(_) => {
                tracing::info!(axis = %ctl.device, "homing (OR)");
                if let Err(e) = ctl.chain.command(ctl.addr, "OR", "", false).await {
                    // OR is not resent blindly, but a lost or garbled TE reply says nothing about whether homing
                    // started: the controller's state does.
                    if !matches!(e.kind(), ErrorKind::Timeout | ErrorKind::Protocol) {
                        return Err(e);
                    }
                    match ctl.chain.ts(ctl.addr).await?.state {
                        State::Homing(_) | State::Ready(_) => {
                            tracing::warn!(axis = %ctl.device, error = %e, "no clear reply to OR, but homing is under way")
                        }
                        State::NotReferenced(_) => {
                            tracing::warn!(axis = %ctl.device, error = %e, "OR not taken; sending it again");
                            ctl.chain.command(ctl.addr, "OR", "", false).await?;
                        }
                        _ => return Err(e),
                    }
                }
                // Homing searches at reduced speed across at most the whole travel.
                let (v, a) = self.core.speed_accel();
                let span = self.core.cfg().max_deg - self.core.cfg().min_deg;
                let deadline = move_deadline(span, v * 0.25, a) + Duration::from_secs(10);
                self.wait_ready(deadline, None).await
            }
            other => Err(DriverError::Rejected {
                device: ctl.device.clone(),
                request: format!("{}OR", ctl.addr),
                reason: format!("cannot home in state {}", other.describe()),
            }),
        }
    }
}

impl AxisDriver for Smc100Axis {
    fn core(&self) -> &AxisCore {
        &self.core
    }

    fn device(&self) -> String {
        self.ctl.device.clone()
    }

    fn line_port(&self) -> &Arc<LinePort> {
        &self.ctl.chain.port
    }

    /// Home (see `home_from_state`), then report at info the first TSs the controller left unanswered on the way, as real
    /// controllers are recorded to (after power-up, after homing): expected, so counted rather than warned.
    async fn home_axis(&self) -> Result<(), DriverError> {
        let homed = self.home_from_state().await;
        self.ctl.chain.report_first_ts(self.ctl.addr);
        homed
    }

    /// Send `PA` for a physical target (idempotent, retried when its TE is lost).
    async fn command_move(&self, target_deg: f64, start_c: Option<f64>) -> Result<(), DriverError> {
        let ctl = &self.ctl;
        let controller = self.core.cfg().controller_from_physical_deg(target_deg);
        self.core.set_start(None);
        if let Ok(mut g) = self.pa_sent.lock() {
            *g = Some(tokio::time::Instant::now());
        }
        tracing::info!(axis = %ctl.device, target_deg, controller, "move absolute");
        // The position the move starts from sets the deadline and when to ask whether the move is over. Known
        // (where the axis came to rest), PA goes out alone; otherwise it is read twice (see `verified_position`)
        // in the same exchange as PA. When the two reads do not agree the start stays unknown and the wait
        // assumes the whole travel (a longer deadline, no harm).
        let reads: &[(&str, &str)] = if start_c.is_some() {
            &[]
        } else {
            &[("TP", ""), ("TP", "")]
        };
        let start = ctl
            .chain
            .command_after(ctl.addr, reads, "PA", &wire_number(controller), true)
            .await;
        match start {
            Ok(start) => {
                // The move is under way since the PA itself went out, after any reads before it.
                if let (Ok(mut g), Some(sent)) = (self.pa_sent.lock(), ctl.chain.last_set_sent(ctl.addr)) {
                    *g = Some(sent);
                }
                self.core.set_start(
                    start_c.or_else(|| match (number_at(&start, 0), number_at(&start, 1)) {
                        (Some(a), Some(b)) if self.reads_agree(a, b, false) => Some(b),
                        _ => None,
                    }),
                );
                Ok(())
            }
            // A retried PA whose first copy got through (only its TE reply was lost) meets the axis already
            // MOVING.
            Err(e @ DriverError::Rejected { .. }) if e.to_string().contains("error M:") => {
                self.resolve_moving(target_deg, controller, e).await
            }
            // DISABLE is where a stall or a stop leaves the controller: a motion fault, which the caller recovers
            // from (reconnecting re-enables the axis), not a refusal to give up on.
            Err(DriverError::Rejected { reason, .. }) if reason.starts_with("error J:") => {
                Err(DriverError::MotionFault {
                    device: ctl.device.clone(),
                    target_deg,
                    reason: format!(
                        "the controller is in DISABLE after a fault and refused the move ({reason})"
                    ),
                })
            }
            Err(other) => Err(other),
        }
    }

    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg` of the target.
    async fn wait_within(&self, target_deg: f64, tolerance_deg: f64) -> Result<f64, DriverError> {
        let ctl = &self.ctl;
        // Already under way since the PA went out (and the pause after it): what is left of the predicted time.
        let under_way = self
            .pa_sent
            .lock()
            .ok()
            .and_then(|g| *g)
            .map_or(Duration::ZERO, |t| t.elapsed());
        let plan = self.core.plan(target_deg, under_way);
        let wait = Wait {
            timeout: plan.timeout,
            predicted: plan.predicted,
            pt_distance: Some(plan.distance),
            readback: true,
        };
        let (ts, read_c) = self
            .wait(|s| matches!(s, State::Ready(_)), wait, Some(target_deg))
            .await?;
        // READY: verify the read-back. The position decides whether the move arrived and becomes the point's
        // recorded position, hence two agreeing reads (see `verified_position`), never one.
        let mut read_c = match read_c {
            Some(p) => p,
            None => self.verified_position().await?,
        };
        let mut read = f64::NAN;
        for attempt in 1..=ATTEMPTS {
            read = self.core.cfg().physical_from_controller_deg(read_c);
            if (read - target_deg).abs() <= tolerance_deg {
                tracing::info!(axis = %ctl.device, target_deg, read_back_deg = read, "arrived");
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
            device: ctl.device.clone(),
            target_deg,
            reason: format!(
                "stopped at {read} deg ({}), tolerance {} deg; {}",
                read - target_deg,
                tolerance_deg,
                ts_reason(&ts)
            ),
        })
    }

    fn controller_position(&self) -> impl Future<Output = Result<f64, DriverError>> + Send {
        self.verified_position()
    }

    /// One `TP`: `1TP\r\n` out, `1TP12.3456\r\n` back.
    async fn position_exchange(&self) -> Result<(f64, usize, usize), DriverError> {
        let ctl = &self.ctl;
        let value = ctl.chain.query(ctl.addr, "TP", "").await?;
        let position = parse_number(&value).ok_or_else(|| DriverError::Protocol {
            device: ctl.device.clone(),
            request: format!("{}TP", ctl.addr),
            detail: format!("not a position: {value:?}"),
        })?;
        let head = format!("{}TP", ctl.addr).len();
        Ok((position, head + 2, head + value.len() + 2))
    }

    fn axis_status(&self) -> impl Future<Output = Result<AxisStatus, DriverError>> + Send {
        self.read_status()
    }

    fn stop_axis(&self) -> impl Future<Output = Result<(), DriverError>> + Send {
        self.ctl.chain.stop_all(std::slice::from_ref(&self.ctl.addr))
    }

    async fn write_speed(
        &self,
        speed_deg_s: Option<f64>,
        accel_deg_s2: Option<f64>,
    ) -> Result<(), DriverError> {
        let ctl = &self.ctl;
        if let Some(v) = speed_deg_s {
            ctl.chain.command(ctl.addr, "VA", &wire_number(v), true).await?;
        }
        if let Some(a) = accel_deg_s2 {
            ctl.chain.command(ctl.addr, "AC", &wire_number(a), true).await?;
        }
        Ok(())
    }

    /// A stall (following error) or a stop leaves the controller in DISABLE, where it refuses every move (error
    /// J). Reconnecting means "ready to be commanded again": leave DISABLE with MM1, which keeps the reference,
    /// so that the caller's retry of an absolute move is not refused.
    async fn re_enable(&self) -> Result<(), DriverError> {
        // The port was just opened again: a first TS may go unanswered as after power-up.
        self.ctl.chain.port_reopened();
        let ts = self.ctl.chain.ts(self.ctl.addr).await?;
        if let State::Disable(_) = ts.state {
            tracing::warn!(axis = %self.ctl.device, reason = %ts_reason(&ts), "controller in DISABLE after a fault; re-enabling");
            self.home_axis().await?;
        }
        Ok(())
    }
}
