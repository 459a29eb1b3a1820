//! Parting arms that start closer than the safety separation (both at zero after power-up, say): the moves
//! [`crate::timing::TimeModel::plan_move`] refuses to plan from there. Pure planning beside the time model; the
//! engine executes the phases (leg by leg, stopping the phase on any failure).
//!
//! Moving both arms at once is safe when each moves away from the other (or stays), so that their separation
//! only grows. When the target has each arm on its side of the other, that is the whole move (every axis at
//! once, [`simultaneous_phases`]). Otherwise the arms are first parted about their midpoint into the target's
//! order (each moving away from the other), and the time model's planner takes it from there.

use gonio_instrument::AxisRole;

use crate::kinematics::{Pose, ROLES};
use crate::timing::{AxisMotion, Move, TimeModel};

/// How [`separating_move`] parts the arms.
#[derive(Debug, Clone, PartialEq)]
pub enum Parting {
    /// One simultaneous move to the target: each arm already moves away from the other.
    Simultaneous,
    /// First to this pose (the arms parted about their midpoint into the target's order), then a planned move.
    Via(Pose),
}

/// The move from `from` to `to` when the arms start closer than the separation, and how it parts them. None when
/// the arms are already apart, or neither way is possible (the target itself too close, the parted pose beyond
/// a limit: `within(role, physical_deg)` says whether an arm may go there).
pub fn separating_move(
    time: &TimeModel,
    from: &Pose,
    to: &Pose,
    within: impl Fn(AxisRole, f64) -> bool,
) -> Option<(Move, Parting)> {
    let min_sep = time.min_arm_separation_deg;
    let (l0, d0) = (from.light_deg, from.detector_deg);
    let (l1, d1) = (to.light_deg, to.detector_deg);
    if (l0 - d0).abs() >= min_sep {
        return None;
    }
    // Which side each arm ends on decides "away"; both must move apart (or not at all).
    let side = (l1 - d1).signum();
    if side == 0.0 || (l1 - d1).abs() < min_sep {
        return None;
    }
    let away = |a: f64, b: f64, sign: f64| (b - a) * sign >= 0.0;
    if away(l0, l1, side) && away(d0, d1, -side) {
        let (phases, settle_s) = simultaneous_phases(time, from, to);
        return Some((
            Move {
                phases,
                motion_s: 0.0,
                settle_s,
            },
            Parting::Simultaneous,
        ));
    }
    // Part them: a quarter more than the separation (room for a backlash overshoot), about their midpoint.
    let half = 0.5 * 1.25 * min_sep;
    let mid = 0.5 * (l0 + d0);
    let mut parted = *from;
    parted.light_deg = mid + side * half;
    parted.detector_deg = mid - side * half;
    if !(within(AxisRole::LightArm, parted.light_deg) && within(AxisRole::DetectorArm, parted.detector_deg)) {
        return None;
    }
    let rest = time.plan_move(&parted, to).ok()?;
    let (mut phases, settle_s) = simultaneous_phases(time, from, &parted);
    phases.extend(rest.phases);
    Some((
        Move {
            phases,
            motion_s: rest.motion_s,
            settle_s: settle_s.max(rest.settle_s),
        },
        Parting::Via(parted),
    ))
}

/// Every axis moved from `from` to `to` at once, as phases that each take every moving axis one leg further
/// (first every backlash overshoot point, then the approaches), and the longest settle time of the axes that
/// move. The overshoot point lies beyond the target in the direction of travel, so while the arms are parted
/// each only moves away from the other until both reach it: their separation only grows before they are
/// apart. (A single phase would let one arm come back from its overshoot while the other, stalled early, is
/// still close: caught by crates/soak/tests/safety_soak.rs.)
pub fn simultaneous_phases(time: &TimeModel, from: &Pose, to: &Pose) -> (Vec<Vec<AxisMotion>>, f64) {
    let mut phases: Vec<Vec<AxisMotion>> = Vec::new();
    let mut settle = 0.0f64;
    for (i, role) in ROLES.iter().enumerate() {
        let Some(model) = time.axes.get(i).and_then(|m| m.as_ref()) else {
            continue;
        };
        let mut at = model.controller_deg(from.get(*role));
        let end = model.controller_deg(to.get(*role));
        let waypoints = model.waypoints(at, end);
        if waypoints.is_empty() {
            continue;
        }
        settle = settle.max(model.settle_s);
        for (leg, waypoint) in waypoints.into_iter().enumerate() {
            if phases.len() <= leg {
                phases.push(Vec::new());
            }
            phases[leg].push(AxisMotion {
                role: *role,
                axis_index: model.axis_index,
                duration_s: model.driven_time_s(at, &[waypoint]),
                waypoints_deg: vec![waypoint],
            });
            at = waypoint;
        }
    }
    (phases, settle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    fn time() -> TimeModel {
        TimeModel::new(&InstrumentFile::simulated().instrument)
    }

    #[test]
    fn arms_apart_need_no_parting() {
        let t = time();
        let from = Pose::new(-40.0, 40.0, 0.0, 0.0);
        assert!(separating_move(&t, &from, &Pose::new(-30.0, 50.0, 0.0, 0.0), |_, _| true).is_none());
    }

    #[test]
    fn arms_together_part_in_one_move_when_each_moves_away_else_via_a_parted_pose() {
        let t = time();
        let zero = Pose::new(0.0, 0.0, 0.0, 0.0);
        // Light to the negative side, detector to the positive: each moves away from the other.
        let (m, how) =
            separating_move(&t, &zero, &Pose::new(-30.0, 40.0, 0.0, 0.0), |_, _| true).expect("move");
        assert_eq!(how, Parting::Simultaneous);
        assert!(!m.phases.is_empty());
        // The first phase (every overshoot point) takes each arm away from the other: the separation grows
        // until both are there.
        for a in &m.phases[0] {
            let model = t
                .axes
                .iter()
                .flatten()
                .find(|x| x.axis_index == a.axis_index)
                .expect("axis");
            let physical = model.physical_deg(*a.waypoints_deg.last().expect("waypoint"));
            match a.role {
                AxisRole::LightArm => assert!(physical < 0.0, "light towards the detector: {physical}"),
                AxisRole::DetectorArm => assert!(physical > 0.0, "detector towards the light: {physical}"),
                _ => {}
            }
        }
        // Both arms to the same side: parted first about their midpoint, into the target's order.
        let (_, how) =
            separating_move(&t, &zero, &Pose::new(20.0, 60.0, 0.0, 0.0), |_, _| true).expect("move");
        let Parting::Via(p) = how else {
            panic!("expected a parted pose, got {how:?}")
        };
        assert!(
            (p.detector_deg - p.light_deg - 1.25 * t.min_arm_separation_deg).abs() < 1e-9,
            "{p:?}"
        );
        // A parted pose beyond a limit: no move.
        assert!(
            separating_move(&t, &zero, &Pose::new(20.0, 60.0, 0.0, 0.0), |role, v| role
                != AxisRole::LightArm
                || v >= 0.0)
            .is_none()
        );
    }
}
