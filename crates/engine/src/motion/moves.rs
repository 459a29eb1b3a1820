//! Multi-axis motion: collision-safe moves from where the axes really are (arm separation, legs commanded by the
//! engine, stop-the-phase on failure, emergency stop).

use std::collections::BTreeMap;

use gonio_driver::DriverError;
use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::{Pose, ROLES};
use gonio_scheduler::separation::{Parting, separating_move};

use super::{Device, Motion, MotionError};
use crate::rig::futures_join_all;

/// A multi-axis phase in which some axes failed (the rest were stopped): which, and the first reason.
struct PhaseBroken {
    failed: Vec<usize>,
    reason: String,
}

impl Motion<'_> {
    /// Move to `target` (physical pose) along a safe, backlash-aware move planned from where the axes are.
    pub async fn move_to(&mut self, target: &Pose) -> Result<(), MotionError> {
        // A phase of several axes is collision-safe only as a whole: when one of its axes fails (a stall), the
        // others are stopped and the move is planned again from where the axes really are, instead of retrying
        // the failed axis alone while the others go on (issue #8: crates/soak/tests/safety_soak.rs).
        // Each axis gets the retries a single operation gets (`acquisition.retries`); every round charges at
        // least one axis, so the loop is bounded.
        let attempts = self.attempts;
        let mut failures: BTreeMap<usize, u32> = BTreeMap::new();
        loop {
            let PhaseBroken { failed, reason } = match self.move_once(target).await {
                Ok(r) => return r,
                Err(broken) => broken,
            };
            for idx in &failed {
                *failures.entry(*idx).or_default() += 1;
            }
            // (Every broken phase names the axis that failed first; without one, nothing bounds the loop.)
            let worst = if failed.is_empty() {
                attempts
            } else {
                failures.values().copied().max().unwrap_or(0)
            };
            self.fault(format!(
                "{reason} (attempt {worst} of {attempts}); the other axes were stopped"
            ));
            if worst >= attempts {
                return Err(MotionError::Device(reason));
            }
            for idx in failed {
                if let Some(a) = self.rig.axes().get(idx) {
                    self.recover(Device::Axis(a)).await?;
                }
            }
            // Plan again from where every axis really is.
            self.read_positions().await?;
        }
    }

    /// One planned move; `Err(PhaseBroken)` when an axis of a multi-axis phase failed (the phase is stopped).
    async fn move_once(&mut self, target: &Pose) -> Result<Result<(), MotionError>, PhaseBroken> {
        let movement = match self.safe_move(target) {
            Ok(m) => m,
            Err(e) => return Ok(Err(e)),
        };
        let axes = self.rig.axes();
        // Where each axis finally goes in this move: its last leg in its last phase. Every other leg is a via
        // point (a backlash overshoot, the parted pose of a separating move), verified within the wider via-point
        // tolerance since the load lags the motor there.
        let mut last_phase: BTreeMap<usize, usize> = BTreeMap::new();
        for (p, phase) in movement.phases.iter().enumerate() {
            for m in phase {
                last_phase.insert(m.axis_index, p);
            }
        }
        let last_phase = &last_phase;
        let mut arrived = Vec::new();
        for (phase_index, phase) in movement.phases.iter().enumerate() {
            let this = &*self;
            // Set by the first axis of the phase that fails; the others then fail because they were stopped.
            let stopping = std::sync::atomic::AtomicBool::new(false);
            let stopping = &stopping;
            let moves = phase.iter().map(|m| async move {
                let a = axes.get(m.axis_index).ok_or_else(|| {
                    MotionError::Impossible(format!("the move plan names axis #{}", m.axis_index))
                })?;
                let Some(last) = m.waypoints_deg.last() else {
                    return Ok(Ok((m.axis_index, f64::NAN)));
                };
                let phys = a.config.physical_from_controller_deg(*last);
                let what = format!("move {} to {phys:.4} deg", a.config.name);
                let final_leg = last_phase.get(&m.axis_index) == Some(&phase_index);
                let arrival = |to: f64, destination: bool| {
                    if destination {
                        a.driver.wait_arrived(to)
                    } else {
                        a.driver.wait_passed_via(to)
                    }
                };
                if phase.len() < 2 {
                    // Alone in its phase: with a backlash overshoot, the driver's own approach runs the same
                    // waypoints.
                    let op = || async {
                        if m.waypoints_deg.len() > 1 {
                            a.driver.move_to(phys).await
                        } else {
                            a.driver.start_move(phys).await?;
                            arrival(phys, final_leg).await
                        }
                    };
                    let pos = this.device(Device::Axis(a), &what, op).await?;
                    return Ok::<_, MotionError>(Ok((m.axis_index, pos)));
                }
                // One attempt inside a multi-axis phase; on failure stop the phase's other axes at once. The
                // legs (overshoot, approach) are commanded here one by one rather than by the driver's own
                // approach, so that an axis told to stop never starts its next leg.
                let stopped = || stopping.load(std::sync::atomic::Ordering::SeqCst);
                let legs = async {
                    let mut pos = f64::NAN;
                    let n = m.waypoints_deg.len();
                    for (i, waypoint) in m.waypoints_deg.iter().enumerate() {
                        if stopped() || this.control.estop_requested() {
                            return Err(None::<DriverError>);
                        }
                        let to = a.config.physical_from_controller_deg(*waypoint);
                        a.driver.start_move(to).await.map_err(Some)?;
                        if stopped() {
                            // The phase's stop may have gone out just before this leg started: stop again.
                            let _ = a.driver.stop().await;
                            return Err(None);
                        }
                        pos = arrival(to, final_leg && i + 1 == n).await.map_err(Some)?;
                    }
                    Ok(pos)
                };
                let r = tokio::select! {
                    biased;
                    _ = this.estop_signal() => return Err(MotionError::Estop),
                    r = legs => r,
                };
                match r {
                    Ok(pos) => Ok(Ok((m.axis_index, pos))),
                    // Stopped short by us: not this axis's fault.
                    Err(None) => Ok(Err((None, String::new()))),
                    Err(Some(_)) if stopped() => Ok(Err((None, String::new()))),
                    Err(Some(e)) => {
                        stopping.store(true, std::sync::atomic::Ordering::SeqCst);
                        for other in phase.iter().filter(|o| o.axis_index != m.axis_index) {
                            if let Some(b) = axes.get(other.axis_index) {
                                let _ = b.driver.stop().await;
                            }
                        }
                        Ok(Err((Some(m.axis_index), format!("{what}: {e}"))))
                    }
                }
            });
            let results = futures_join_all(moves).await;
            let mut broken = PhaseBroken {
                failed: Vec::new(),
                reason: String::new(),
            };
            let mut any_failed = false;
            for r in results {
                match r {
                    Err(i) => return Ok(Err(i)),
                    Ok(Ok(done)) => arrived.push(done),
                    Ok(Err((idx, reason))) => {
                        any_failed = true;
                        broken.failed.extend(idx);
                        if broken.reason.is_empty() {
                            broken.reason = reason;
                        }
                    }
                }
            }
            if any_failed {
                // The others were stopped short of their targets too: their read-back is re-read by the caller.
                return Err(broken);
            }
            for (idx, pos) in arrived.drain(..).filter(|(_, p)| p.is_finite()) {
                if let (Some(a), Some(slot)) = (axes.get(idx), self.readback.get_mut(idx)) {
                    *slot = pos;
                    self.current.set(a.config.role, pos);
                }
            }
        }
        if !movement.phases.is_empty() {
            // A campaign's extra settling is already part of each axis's settle time in its time model (see
            // `gonio_campaign::campaign_time_model`), hence of `movement.settle_s`.
            self.clock.sleep_s(movement.settle_s).await;
        }
        // Physical targets the plan reached: nominal pose for axes that did not need to move.
        for r in ROLES {
            if self.rig.axes().iter().all(|a| a.config.role != r) {
                self.current.set(r, target.get(r));
            }
        }
        Ok(Ok(()))
    }

    /// The safe move from where the axes are to `target` (physical pose), or [`MotionError::Impossible`] when no
    /// collision-free move exists; nothing is commanded either way. [`Motion::move_to`] executes it; a console
    /// asks first, to refuse a request before anything moves.
    pub fn safe_move(&self, target: &Pose) -> Result<gonio_scheduler::timing::Move, MotionError> {
        // An axis already within its arrival tolerance of the target does not move: the read-back differs from
        // the nominal pose by up to that tolerance after every move, and re-commanding it would cost a move,
        // a status poll and a settle at every reading of a pose (each band, each repeat at one geometry) that
        // the schedule rightly predicts as free.
        let mut from = self.current;
        for a in self.rig.axes() {
            let r = a.config.role;
            if (from.get(r) - target.get(r)).abs() <= a.config.tolerance_deg {
                from.set(r, target.get(r));
            }
        }
        Ok(match self.time.plan_move(&from, target) {
            Ok(m) => m,
            Err(reason) => match self.separating_move(target) {
                Some(m) => m,
                None => {
                    return Err(MotionError::Impossible(format!(
                        "no safe move from {:?} to {:?}: {}",
                        self.current,
                        target,
                        reason.name()
                    )));
                }
            },
        })
    }

    /// The arms start closer than the safety separation: the pure planning is the scheduler's
    /// ([`gonio_scheduler::separation`]); the rig's axis limits bound the parted pose.
    fn separating_move(&self, target: &Pose) -> Option<gonio_scheduler::timing::Move> {
        let within = |role: AxisRole, v: f64| {
            self.rig
                .axes()
                .iter()
                .filter(|a| a.config.role == role)
                .all(|a| (a.config.min_deg..=a.config.max_deg).contains(&v))
        };
        let (m, how) = separating_move(&self.time, &self.current, target, within)?;
        match how {
            Parting::Simultaneous => tracing::info!(
                "arms closer than the safety separation: separating them in one simultaneous move"
            ),
            Parting::Via(parted) => tracing::info!(
                ?parted,
                "arms closer than the safety separation: parting them into the target's order first"
            ),
        }
        Some(m)
    }
}
