//! What every axis driver shares, whatever its protocol: the axis's configuration and motion settings
//! ([`AxisCore`]), and the [`Axis`] trait built once over the few operations a protocol supplies
//! ([`AxisDriver`]): limits checked before anything is sent, moves with the backlash approach, speeds checked,
//! remembered for deadlines and not written again while the device is known to hold them, the re-verification
//! after a reconnect.

use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::error::DriverError;
use crate::motion::{
    approach_waypoints, check_speed, move_deadline, trapezoid_time_s, via_point_tolerance_deg,
};
use crate::traits::{Axis, AxisLimits, AxisStatus, PositionReport};
use crate::transport::{BoxFuture, LinePort};

/// How long a move is expected to take and may take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovePlan {
    /// Controller units to travel: from the recorded start, or the whole travel when the start is unknown.
    pub distance: f64,
    /// The move's deadline ([`move_deadline`]).
    pub timeout: Duration,
    /// When the move is predicted to end, from now.
    pub predicted: Duration,
}

/// An axis's configuration, the speed and acceleration in use, and where its last move started.
#[derive(Debug)]
pub struct AxisCore {
    cfg: gonio_instrument::Axis,
    /// Speed and acceleration in use (controller units per s, per s^2), for deadlines.
    motion: Mutex<(f64, f64)>,
    /// Controller position where the last move started (`None`: unknown, the wait assumes the whole travel).
    start: Mutex<Option<f64>>,
    /// Controller position the axis came to rest at, read back (verified) when its last move was seen over;
    /// `None` once anything else may have moved it (a move commanded, a stop, a homing, a reconnect, any error).
    /// The next move starts from it without reading it again: two position reads fewer before each SMC100
    /// `PA` (with the controller's ~10 ms a query, about 25 ms a leg on the line) and one `get pos` before each
    /// Zaber `move abs`, exchanges that held up the motion.
    at_rest: Mutex<Option<f64>>,
    /// The speed and acceleration this driver last wrote to the device and saw taken (`None`: not known, as
    /// after a reconnect or a homing). A value the device already holds is not written again: each write is a
    /// set command with its pause (65 ms on an SMC100), and a sweep that follows the BRDF sets its speed once a
    /// piece with the same acceleration every time.
    written: Mutex<(Option<f64>, Option<f64>)>,
}

impl AxisCore {
    pub fn new(cfg: gonio_instrument::Axis) -> AxisCore {
        let motion = Mutex::new((cfg.max_speed_deg_s, cfg.accel_deg_s2));
        AxisCore {
            cfg,
            motion,
            start: Mutex::new(None),
            at_rest: Mutex::new(None),
            written: Mutex::new((None, None)),
        }
    }

    /// Where the axis is at rest (module doc of [`AxisCore::at_rest`]), forgotten as it is taken: whoever takes
    /// it is about to move the axis.
    fn take_at_rest(&self) -> Option<f64> {
        self.at_rest.lock().ok().and_then(|mut g| g.take())
    }

    /// Record where the axis came to rest (controller units), or forget it (`None`).
    fn set_at_rest(&self, at_c: Option<f64>) {
        if let Ok(mut g) = self.at_rest.lock() {
            *g = at_c.filter(|c| c.is_finite());
        }
    }

    /// Of a speed and an acceleration, those the device is not known to hold already.
    fn to_write(&self, speed: f64, accel: f64) -> (Option<f64>, Option<f64>) {
        let held = self.written.lock().map(|g| *g).unwrap_or((None, None));
        (
            (held.0 != Some(speed)).then_some(speed),
            (held.1 != Some(accel)).then_some(accel),
        )
    }

    /// What the device holds after a write (`None`s: not known).
    fn set_written(&self, held: (Option<f64>, Option<f64>)) {
        if let Ok(mut g) = self.written.lock() {
            *g = held;
        }
    }

    pub fn cfg(&self) -> &gonio_instrument::Axis {
        &self.cfg
    }

    /// Speed and acceleration in use.
    pub fn speed_accel(&self) -> (f64, f64) {
        self.motion
            .lock()
            .map(|g| *g)
            .unwrap_or((self.cfg.max_speed_deg_s, self.cfg.accel_deg_s2))
    }

    fn set_speed_accel(&self, speed: f64, accel: f64) {
        if let Ok(mut g) = self.motion.lock() {
            *g = (speed, accel);
        }
    }

    /// Refuse a target outside the configured travel (or not a number) before anything is sent.
    pub fn check_limits(&self, device: &str, target_deg: f64) -> Result<(), DriverError> {
        let c = &self.cfg;
        if !(target_deg.is_finite() && target_deg >= c.min_deg && target_deg <= c.max_deg) {
            return Err(DriverError::OutOfRange {
                device: device.into(),
                what: "target (deg)".into(),
                value: target_deg,
                min: c.min_deg,
                max: c.max_deg,
            });
        }
        Ok(())
    }

    /// Record where the move being started starts from (controller units), `None` when it is not known.
    pub fn set_start(&self, start_c: Option<f64>) {
        if let Ok(mut g) = self.start.lock() {
            *g = start_c;
        }
    }

    /// The plan of the move to `target_deg` that was last started, `under_way` after it was commanded.
    pub fn plan(&self, target_deg: f64, under_way: Duration) -> MovePlan {
        let (v, a) = self.speed_accel();
        let target_c = self.cfg.controller_from_physical_deg(target_deg);
        let distance = match self.start.lock().ok().and_then(|g| *g) {
            Some(s) => (target_c - s).abs(),
            None => self.cfg.max_deg - self.cfg.min_deg,
        };
        let predicted = trapezoid_time_s(distance, v, a) - under_way.as_secs_f64();
        MovePlan {
            distance,
            timeout: move_deadline(distance, v, a),
            predicted: Duration::from_secs_f64(if predicted.is_finite() {
                predicted.clamp(0.0, 600.0)
            } else {
                0.0
            }),
        }
    }
}

/// Reopen `port` after a disconnect; a port that cannot be opened makes the device unavailable.
async fn reopen(port: &LinePort, device: String) -> Result<(), DriverError> {
    port.reconnect().await.map_err(|e| DriverError::Unavailable {
        device,
        detail: e.to_string(),
    })
}

/// The operations one protocol supplies; [`Axis`] is implemented over them for every such driver. Names differ
/// from [`Axis`]'s so that both traits can be in scope.
pub trait AxisDriver: Send + Sync + std::fmt::Debug {
    fn core(&self) -> &AxisCore;
    /// The axis in messages: name, chain and address.
    fn device(&self) -> String;
    /// The port of the axis's chain.
    fn line_port(&self) -> &Arc<LinePort>;
    /// Home and wait, with a deadline, until the axis is referenced.
    fn home_axis(&self) -> impl Future<Output = Result<(), DriverError>> + Send;
    /// Command an absolute move (limits already checked), recording its start in [`AxisCore::set_start`]:
    /// `start_c` when the caller knows it (controller units, read back where the axis came to rest), else read
    /// from the device before the move.
    fn command_move(
        &self,
        target_deg: f64,
        start_c: Option<f64>,
    ) -> impl Future<Output = Result<(), DriverError>> + Send;
    /// Wait for the move to end; arrived when the read-back is within `tolerance_deg`. Returns the read-back.
    fn wait_within(
        &self,
        target_deg: f64,
        tolerance_deg: f64,
    ) -> impl Future<Output = Result<f64, DriverError>> + Send;
    /// The position (controller units), trustworthy enough to decide on (see each driver).
    fn controller_position(&self) -> impl Future<Output = Result<f64, DriverError>> + Send;
    /// One position read (controller units) in a single exchange, and the bytes of its request and reply.
    fn position_exchange(&self) -> impl Future<Output = Result<(f64, usize, usize), DriverError>> + Send;
    fn axis_status(&self) -> impl Future<Output = Result<AxisStatus, DriverError>> + Send;
    /// Stop now on the priority path.
    fn stop_axis(&self) -> impl Future<Output = Result<(), DriverError>> + Send;
    /// Send a speed, an acceleration or both (already checked) to the device; `None`: leave it as it is.
    fn write_speed(
        &self,
        speed_deg_s: Option<f64>,
        accel_deg_s2: Option<f64>,
    ) -> impl Future<Output = Result<(), DriverError>> + Send;
    /// Make a reopened device ready to be commanded again (e.g. leave a fault state that refuses moves).
    fn re_enable(&self) -> impl Future<Output = Result<(), DriverError>> + Send;
}

async fn move_to<D: AxisDriver>(d: &D, target_deg: f64) -> Result<f64, DriverError> {
    let core = d.core();
    core.check_limits(&d.device(), target_deg)?;
    // Where the axis is decides whether the approach needs the backlash overshoot: where it came to rest, or a
    // verified read.
    let mut at_c = match core.take_at_rest() {
        Some(c) => c,
        None => d.controller_position().await?,
    };
    let mut read = f64::NAN;
    for (step_deg, tolerance) in approach_waypoints(core.cfg(), at_c, target_deg) {
        core.check_limits(&d.device(), step_deg)?;
        d.command_move(step_deg, Some(at_c)).await?;
        read = d.wait_within(step_deg, tolerance).await?;
        at_c = core.cfg().controller_from_physical_deg(read);
    }
    core.set_at_rest(Some(at_c));
    Ok(read)
}

/// Wait for the move to `to_deg` within `tolerance_deg`; seen over, where the axis came to rest is recorded.
async fn wait_and_remember<D: AxisDriver>(
    d: &D,
    to_deg: f64,
    tolerance_deg: f64,
) -> Result<f64, DriverError> {
    let read = d.wait_within(to_deg, tolerance_deg).await?;
    d.core()
        .set_at_rest(Some(d.core().cfg().controller_from_physical_deg(read)));
    Ok(read)
}

async fn set_speed<D: AxisDriver>(d: &D, speed_deg_s: f64, accel_deg_s2: f64) -> Result<(), DriverError> {
    check_speed(d.device(), speed_deg_s, accel_deg_s2)?;
    let core = d.core();
    let (speed, accel) = core.to_write(speed_deg_s, accel_deg_s2);
    if speed.is_some() || accel.is_some() {
        // Until the device has taken both, what it holds is not known.
        core.set_written((None, None));
        d.write_speed(speed, accel).await?;
        core.set_written((Some(speed_deg_s), Some(accel_deg_s2)));
    }
    core.set_speed_accel(speed_deg_s, accel_deg_s2);
    Ok(())
}

async fn reconnect<D: AxisDriver>(d: &D) -> Result<AxisStatus, DriverError> {
    // A device that went away may have been power-cycled back to its stored speed, and moved.
    d.core().set_written((None, None));
    d.core().set_at_rest(None);
    reopen(d.line_port(), d.device()).await?;
    d.re_enable().await?;
    let status = d.axis_status().await?;
    if !status.referenced {
        return Err(DriverError::NotReferenced {
            device: d.device(),
            state: status.raw,
        });
    }
    tracing::info!(axis = %d.device(), position_deg = status.position_deg, "re-verified after reconnect");
    Ok(status)
}

impl<D: AxisDriver> Axis for D {
    fn name(&self) -> &str {
        &self.core().cfg().name
    }
    fn limits(&self) -> AxisLimits {
        let c = self.core().cfg();
        AxisLimits {
            min_deg: c.min_deg,
            max_deg: c.max_deg,
            max_speed_deg_s: c.max_speed_deg_s,
            accel_deg_s2: c.accel_deg_s2,
        }
    }
    fn home(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        // Homing is where a power-cycled controller is met again: its speed is what it stored.
        self.core().set_written((None, None));
        self.core().set_at_rest(None);
        Box::pin(self.home_axis())
    }
    fn move_to(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(move_to(self, target_deg))
    }
    fn start_move(&self, target_deg: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move {
            self.core().check_limits(&self.device(), target_deg)?;
            let start_c = self.core().take_at_rest();
            self.command_move(target_deg, start_c).await
        })
    }
    fn wait_arrived(&self, target_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(wait_and_remember(
            self,
            target_deg,
            self.core().cfg().tolerance_deg,
        ))
    }
    fn wait_passed_via(&self, via_deg: f64) -> BoxFuture<'_, Result<f64, DriverError>> {
        Box::pin(wait_and_remember(
            self,
            via_deg,
            via_point_tolerance_deg(self.core().cfg()),
        ))
    }
    fn position_deg(&self) -> BoxFuture<'_, Result<f64, DriverError>> {
        // The engine plans moves (and their collision safety) from this: a verified read.
        Box::pin(async move {
            let c = self.controller_position().await?;
            Ok(self.core().cfg().physical_from_controller_deg(c))
        })
    }
    fn position_report(&self) -> BoxFuture<'_, Result<PositionReport, DriverError>> {
        Box::pin(async move {
            let (c, request_bytes, reply_bytes) = self.position_exchange().await?;
            Ok(PositionReport {
                position_deg: self.core().cfg().physical_from_controller_deg(c),
                request_bytes,
                reply_bytes,
            })
        })
    }
    fn status(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(self.axis_status())
    }
    fn stop(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        self.core().set_at_rest(None);
        Box::pin(self.stop_axis())
    }
    fn set_speed(&self, speed_deg_s: f64, accel_deg_s2: f64) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(set_speed(self, speed_deg_s, accel_deg_s2))
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<AxisStatus, DriverError>> {
        Box::pin(reconnect(self))
    }
}
