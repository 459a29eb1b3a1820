//! Collision-safe homing of the arms (issue #8).
//!
//! Homing drives an axis to its home switch, controller position 0 (SMC100 `OR`, Zaber `home`: the position
//! counter reads 0 there afterwards), so an arm homed from where it stands sweeps every angle between there and
//! its home: through the other arm, when the other arm stands in between. The arms must never be closer than
//! `safety.min_arm_separation_deg`, homing included. So before an arm is homed:
//!
//! - where it may be is estimated as the span between its last known position (the engine's pose, when the run
//!   has read the axes) and what its controller reads back now (after a controller reset or a power cycle the
//!   read-back may be wrong, the last known position may be stale after a stop mid-move: both are taken);
//! - its sweep is that span extended to its home;
//! - the other arm's position is read from its controller. If it keeps `clearance` from the sweep (the
//!   separation, the backlash overshoot of a move's approach, and both arms' arrival tolerances), the arm is
//!   homed at once. Otherwise, if the other arm is referenced (so can be moved), it is first parked beside the
//!   sweep, on a path that keeps the clearance from where the homing arm may be, then the arm is homed.
//!   Otherwise (the other arm lost its reference too, or no parking spot within its limits exists) the campaign
//!   pauses with the reason: a person must part the arms.
//! - An arm that does not travel (already at home within its tolerance) is homed whatever the other arm does:
//!   that is how both arms power up (at zero, together); the run's first move parts them (`separating_move`).
//!
//! During a run (the axes' positions are known), an arm homed after a fault is then brought back where the run
//! left it, and a parked arm back where it was, so the interrupted operation resumes on the plan it was made
//! for; every one of those moves retraces a path checked above. At start-up arms without reference are homed in
//! an order that needs no move of an arm without reference ([`start_up_order`]), and stay where homing left
//! them: the run plans its first move from there.
//!
//! Limits: the home is taken at controller position 0 and the homing search as a straight run to it, which is
//! what the simulated controllers do; a controller configured to search an end-of-travel switch first sweeps
//! more than this module assumes.

use gonio_driver::{DriverError, ErrorKind};
use gonio_instrument::AxisRole;

use super::{Motion, MotionError};
use crate::rig::RigAxis;

/// Extra room (fraction of the clearance) between a parked arm and the sweep of the arm being homed.
const PARK_EXTRA: f64 = 0.25;
/// Polls (0.1 s apart) waiting for the other arm to come to rest before it is measured.
const REST_POLLS: u32 = 100;

/// A closed interval of arm angles (physical degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Span {
    pub lo: f64,
    pub hi: f64,
}

impl Span {
    pub fn at(x: f64) -> Span {
        Span { lo: x, hi: x }
    }

    pub fn between(a: f64, b: f64) -> Span {
        Span {
            lo: a.min(b),
            hi: a.max(b),
        }
    }

    pub fn hull(self, x: f64) -> Span {
        Span {
            lo: self.lo.min(x),
            hi: self.hi.max(x),
        }
    }

    pub fn len(self) -> f64 {
        self.hi - self.lo
    }

    /// The smallest angular distance between a point of `self` and a point of `other`, on the circle (arms are
    /// apart by the short way round); 0 when they overlap.
    pub fn gap_deg(self, other: Span) -> f64 {
        let mut gap = f64::INFINITY;
        for turns in -2..=2 {
            let k = 360.0 * f64::from(turns);
            let (lo, hi) = (self.lo + k, self.hi + k);
            let g = if hi < other.lo {
                other.lo - hi
            } else if other.hi < lo {
                lo - other.hi
            } else {
                0.0
            };
            gap = gap.min(g);
        }
        gap
    }
}

/// The arm to home.
#[derive(Debug, Clone)]
pub(super) struct Homing {
    pub name: String,
    /// Where it may be now.
    pub may_be: Span,
    pub home_deg: f64,
    /// Travel below which homing is no motion (the arm's arrival tolerance).
    pub still_deg: f64,
}

/// The other arm.
#[derive(Debug, Clone)]
pub(super) struct Other {
    pub name: String,
    /// Where it is (a point when referenced and read back).
    pub at: Span,
    /// Referenced: it can be commanded.
    pub movable: bool,
    pub min_deg: f64,
    pub max_deg: f64,
}

/// What to do before homing.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Plan {
    /// Home at once: the sweep keeps clear of the other arm (or the arm does not travel).
    Home,
    /// Move the other arm to `park_deg` first.
    Park { park_deg: f64 },
    /// No safe way: the reason, for the operator.
    Refuse(String),
}

/// The plan for homing `arm` with `other` where it is; `clearance_deg` is the least distance kept between the
/// arms at every instant.
pub(super) fn plan(arm: &Homing, other: &Other, clearance_deg: f64) -> Plan {
    let sweep = arm.may_be.hull(arm.home_deg);
    if sweep.len() <= arm.still_deg || sweep.gap_deg(other.at) >= clearance_deg {
        return Plan::Home;
    }
    let way = format!(
        "homing the {} arm drives it from about {:.2} deg to its home at {:.2} deg, within {:.2} deg of the {} arm \
         at {:.2} deg (the arms must keep {clearance_deg:.2} deg apart)",
        arm.name,
        if (arm.may_be.lo - arm.home_deg).abs() > (arm.may_be.hi - arm.home_deg).abs() {
            arm.may_be.lo
        } else {
            arm.may_be.hi
        },
        arm.home_deg,
        sweep.gap_deg(other.at),
        other.name,
        0.5 * (other.at.lo + other.at.hi),
    );
    if !other.movable {
        return Plan::Refuse(format!(
            "{way}, and the {} arm lost its reference too, so it cannot be moved out of the way: move the arms \
             apart by hand (clear of the way home), then resume",
            other.name
        ));
    }
    let q = 0.5 * (other.at.lo + other.at.hi);
    let off = clearance_deg * (1.0 + PARK_EXTRA);
    let mut best: Option<f64> = None;
    for turns in -1..=1 {
        let k = 360.0 * f64::from(turns);
        for p in [sweep.lo + k - off, sweep.hi + k + off] {
            let ok = (other.min_deg..=other.max_deg).contains(&p)
                && Span::at(p).gap_deg(sweep) >= clearance_deg
                && Span::between(q, p).gap_deg(arm.may_be) >= clearance_deg;
            if ok && best.is_none_or(|b| (p - q).abs() < (b - q).abs()) {
                best = Some(p);
            }
        }
    }
    match best {
        Some(park_deg) => Plan::Park { park_deg },
        None => Plan::Refuse(format!(
            "{way}, and the {} arm has no place within its limits [{:.2}, {:.2}] deg clear of that way that it can \
             reach without passing the {} arm: move the arms apart by hand, then resume",
            other.name, other.min_deg, other.max_deg, arm.name
        )),
    }
}

/// Start-up with both arms unreferenced: which to home first (0 or 1), so that the first is homed without
/// moving the other (it cannot be moved before it is referenced), and the second can then be homed, parking
/// the first if needed. The refusal names the way that is blocked.
pub(super) fn start_up_order(
    arms: [&Homing; 2],
    others: [&Other; 2],
    clearance_deg: f64,
) -> Result<usize, String> {
    let mut first_refusal = None;
    for first in [0, 1] {
        let second = 1 - first;
        let (Some(arm), Some(other)) = (arms.get(first), others.get(first)) else {
            continue;
        };
        let blocked = Other {
            movable: false,
            ..(*other).clone()
        };
        match plan(arm, &blocked, clearance_deg) {
            Plan::Home => {}
            Plan::Refuse(why) => {
                first_refusal.get_or_insert(why);
                continue;
            }
            Plan::Park { .. } => continue,
        }
        // The first now rests at its home, referenced.
        let (Some(arm2), Some(other2)) = (arms.get(second), others.get(second)) else {
            continue;
        };
        let homed = Other {
            at: Span::at(arm.home_deg),
            movable: true,
            ..(*other2).clone()
        };
        match plan(arm2, &homed, clearance_deg) {
            Plan::Refuse(why) => {
                first_refusal.get_or_insert(why);
            }
            _ => return Ok(first),
        }
    }
    Err(first_refusal.unwrap_or_else(|| "no safe homing order".into()))
}

fn other_role(role: AxisRole) -> Option<AxisRole> {
    match role {
        AxisRole::LightArm => Some(AxisRole::DetectorArm),
        AxisRole::DetectorArm => Some(AxisRole::LightArm),
        _ => None,
    }
}

/// The arm's home: controller position 0, in physical degrees.
fn home_deg(a: &RigAxis) -> f64 {
    a.config.physical_from_controller_deg(0.0)
}

fn arm_name(a: &RigAxis) -> String {
    match a.config.role {
        AxisRole::LightArm => format!("light ({})", a.config.name),
        AxisRole::DetectorArm => format!("detector ({})", a.config.name),
        _ => a.config.name.clone(),
    }
}

impl Motion<'_> {
    /// Least distance kept between the arms while one is homed or parked: the separation, plus the backlash
    /// overshoot of a move's approach, plus both arms' arrival tolerances (a restored position is within them).
    fn homing_clearance_deg(&self) -> f64 {
        let tolerance: f64 = self
            .rig
            .axes()
            .iter()
            .filter(|a| other_role(a.config.role).is_some())
            .map(|a| a.config.tolerance_deg)
            .sum();
        self.time.min_arm_separation_deg + self.time.arm_overshoot_margin_deg() + tolerance
    }

    /// A device request that an emergency stop cancels.
    async fn ask<T>(
        &self,
        request: impl std::future::Future<Output = Result<T, DriverError>>,
    ) -> Result<Result<T, DriverError>, MotionError> {
        tokio::select! {
            r = request => Ok(r),
            _ = self.estop_signal() => Err(MotionError::Estop),
        }
    }

    /// Home one axis as it is: the controller's own homing, with no look at the other arm.
    pub async fn home_direct(&self, a: &RigAxis) -> Result<(), MotionError> {
        tracing::info!(axis = %a.config.name, "homing");
        self.ask(a.driver.home())
            .await?
            .map_err(|e| MotionError::NeedsOperator(format!("homing {}: {e}", a.config.name)))
    }

    /// Move an arm (referenced) to `target_deg` on a path this module checked; one more attempt after a
    /// reconnect when the move itself failed.
    async fn drive(&self, a: &RigAxis, target_deg: f64, why: &str) -> Result<(), MotionError> {
        let mut last = None;
        for attempt in 1..=2 {
            match self.ask(a.driver.move_to(target_deg)).await? {
                Ok(_) => return Ok(()),
                Err(e) => {
                    self.fault(format!(
                        "{why}: moving the {} arm to {target_deg:.3} deg: {e} (attempt {attempt} of 2)",
                        arm_name(a)
                    ));
                    // A stopped arm sits in DISABLE and refuses moves; a reply may be lost: one reconnect
                    // (which re-enables it, reference kept, or reopens the port) and one more try. An arm that
                    // lost its reference is not moved at all.
                    let retry = e.kind() != ErrorKind::NotReferenced;
                    last = Some(e);
                    if !retry {
                        break;
                    }
                    let _ = self.ask(a.driver.reconnect()).await?;
                }
            }
        }
        Err(MotionError::NeedsOperator(format!(
            "{why}: the {} arm could not be moved to {target_deg:.3} deg: {}",
            arm_name(a),
            last.map(|e| e.to_string()).unwrap_or_default()
        )))
    }

    /// Where `a` may be: its last known position (when the run has read the axes) and its read-back now.
    async fn may_be(&self, a: &RigAxis) -> Result<Option<Span>, MotionError> {
        let last = (!self.readback.is_empty()).then(|| self.current.get(a.config.role));
        let read = self.ask(a.driver.position_deg()).await?.ok();
        Ok(match (last, read) {
            (Some(l), Some(r)) => Some(Span::between(l, r)),
            (Some(x), None) | (None, Some(x)) => Some(Span::at(x)),
            (None, None) => None,
        })
    }

    /// The other arm as it is now; it is brought to rest first if it was moving (stopped mid-phase).
    async fn other_arm(&self, b: &RigAxis) -> Result<Option<Other>, MotionError> {
        let mut status = self.ask(b.driver.status()).await?;
        if matches!(&status, Ok(s) if s.moving) {
            let _ = self.ask(b.driver.stop()).await?;
            for _ in 0..REST_POLLS {
                self.clock.sleep_s(0.1).await;
                status = self.ask(b.driver.status()).await?;
                if !matches!(&status, Ok(s) if s.moving) {
                    break;
                }
            }
        }
        let last = (!self.readback.is_empty()).then(|| self.current.get(b.config.role));
        let (at, movable) = match status {
            Ok(s) if s.moving => return Ok(None),
            Ok(s) if s.referenced => (Span::at(s.position_deg), true),
            Ok(s) => (
                last.map_or(Span::at(s.position_deg), |l| Span::between(l, s.position_deg)),
                false,
            ),
            Err(e) => {
                tracing::warn!(axis = %b.config.name, "status before homing the other arm: {e}");
                match last {
                    Some(l) => (Span::at(l), false),
                    None => return Ok(None),
                }
            }
        };
        Ok(Some(Other {
            name: arm_name(b),
            at,
            movable,
            min_deg: b.config.min_deg,
            max_deg: b.config.max_deg,
        }))
    }

    /// Home `a` without sweeping it through the other arm (module doc). During a run (axes read), the arms are
    /// then put back where they were.
    pub(super) async fn home_safely(&self, a: &RigAxis) -> Result<(), MotionError> {
        let Some(b) =
            other_role(a.config.role).and_then(|r| self.rig.axes().iter().find(|x| x.config.role == r))
        else {
            return self.home_direct(a).await;
        };
        let restore = !self.readback.is_empty();
        let last_a = self.current.get(a.config.role);
        let refuse = |why: String| {
            MotionError::NeedsOperator(format!(
                "{} lost its reference and was not homed: {why}",
                arm_name(a)
            ))
        };
        let Some(may_be) = self.may_be(a).await? else {
            return Err(refuse("its position is unknown (no read-back)".into()));
        };
        let Some(other) = self.other_arm(b).await? else {
            return Err(refuse(format!(
                "the {} arm's position is unknown (no read-back)",
                arm_name(b)
            )));
        };
        let homing = Homing {
            name: arm_name(a),
            may_be,
            home_deg: home_deg(a),
            still_deg: a.config.tolerance_deg,
        };
        let q = 0.5 * (other.at.lo + other.at.hi);
        let parked = match plan(&homing, &other, self.homing_clearance_deg()) {
            Plan::Home => None,
            Plan::Refuse(why) => return Err(refuse(why)),
            Plan::Park { park_deg } => {
                self.fault(format!(
                    "{} lost its reference: parking the {} arm at {park_deg:.3} deg, clear of its way home ({:.3} \
                     to {:.3} deg), before homing it",
                    arm_name(a),
                    arm_name(b),
                    may_be.lo.min(homing.home_deg),
                    may_be.hi.max(homing.home_deg)
                ));
                self.drive(b, park_deg, "before homing").await?;
                Some(park_deg)
            }
        };
        tracing::info!(axis = %a.config.name, from_lo = may_be.lo, from_hi = may_be.hi, home_deg = homing.home_deg,
            other_deg = parked.unwrap_or(q), "homing with the way clear of the other arm");
        self.home_direct(a).await?;
        if restore {
            // Back to where the run's plan has them: the reverse of the paths checked above.
            if (last_a - homing.home_deg).abs() > a.config.tolerance_deg {
                self.drive(a, last_a, "after homing").await?;
            }
            if parked.is_some() {
                self.drive(b, q, "after homing").await?;
            }
        }
        Ok(())
    }

    /// Start-up: home the axes found without reference; the arms in an order that never sweeps one through the
    /// other ([`start_up_order`]).
    pub(super) async fn home_at_start_up(&self, unreferenced: &[&RigAxis]) -> Result<(), MotionError> {
        let (arms, rest): (Vec<&RigAxis>, Vec<&RigAxis>) = unreferenced
            .iter()
            .copied()
            .partition(|a| other_role(a.config.role).is_some());
        for a in rest {
            self.home_direct(a).await?;
        }
        let ordered = match arms.as_slice() {
            [x, y] => {
                let mut homing = Vec::new();
                let mut others = Vec::new();
                for (a, b) in [(*x, *y), (*y, *x)] {
                    let (Some(may_be), Some(other)) = (self.may_be(a).await?, self.other_arm(b).await?)
                    else {
                        return Err(MotionError::NeedsOperator(format!(
                            "the {} and {} arms lost their reference and one of their positions is unknown: move \
                             them apart by hand, then resume",
                            arm_name(x),
                            arm_name(y)
                        )));
                    };
                    homing.push(Homing {
                        name: arm_name(a),
                        may_be,
                        home_deg: home_deg(a),
                        still_deg: a.config.tolerance_deg,
                    });
                    others.push(other);
                }
                let (Some(h0), Some(h1), Some(o0), Some(o1)) =
                    (homing.first(), homing.get(1), others.first(), others.get(1))
                else {
                    return Ok(());
                };
                match start_up_order([h0, h1], [o0, o1], self.homing_clearance_deg()) {
                    Ok(0) => vec![*x, *y],
                    Ok(_) => vec![*y, *x],
                    Err(why) => {
                        return Err(MotionError::NeedsOperator(format!(
                            "both arms lost their reference and no homing order is safe: {why}"
                        )));
                    }
                }
            }
            other => other.to_vec(),
        };
        for a in ordered {
            self.home_safely(a).await?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
