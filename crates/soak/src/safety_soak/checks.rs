//! The checks of a case: arm separation on the recorded physical trajectories, limits, stops within their
//! deadline, and every point committed once.

use super::*;

/// The separation rule on the arms' physical trajectories, with the scheduler's own tolerance: `Err` names the
/// first stretch where they were too close; `Ok` is the smallest separation seen once apart.
pub fn check_separation(l: &[Piece], d: &[Piece], constraints: &Constraints) -> Result<f64, String> {
    check_arm_separation(l, d, constraints.min_arm_separation_deg, |s| {
        constraints.separation_ok(s)
    })
    .map_err(|e| e.0)
}

/// What one case measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseResult {
    pub index: u32,
    pub faults: bool,
    /// Pause, abort and emergency-stop requests made.
    pub acts: [u64; 3],
    pub final_state: Option<CampaignState>,
    pub planned_points: u64,
    pub points: u64,
    /// Sweep segments planned, and those with readings in the store; sweep readings committed.
    pub planned_segments: u64,
    pub segments: u64,
    pub sweep_readings: u64,
    /// Move and home commands received by the devices.
    pub move_commands: u64,
    /// Closest approach of the arms once apart (deg): motors, loads.
    pub closest_motor_deg: f64,
    pub closest_load_deg: f64,
    /// Smallest distance of any commanded target, and of any trajectory, to its axis limit (deg; < 0: beyond).
    pub command_margin_deg: f64,
    pub trajectory_margin_deg: f64,
    /// (axis, extreme physical target commanded, the limit on that side).
    pub extreme_command: Option<(String, f64, f64)>,
    /// Time from each emergency-stop request to the stop at each axis (simulated seconds).
    pub estop_latencies_s: Vec<f64>,
    /// Of the emergency stops requested while a sweep's arm cruised: the time to the stop at the last axis (s).
    pub estops_in_sweeps_s: Vec<f64>,
    /// Broken invariants, in words.
    pub violations: Vec<String>,
    /// Which rules they broke.
    pub broken: Vec<Rule>,
}

/// The rules a case is checked against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// Arm separation at every instant (and only growing before the arms are first apart).
    Separation,
    /// Commanded targets and trajectories within the axis limits.
    Limits,
    /// Emergency stop at every axis within the deadline, no move before the resume.
    Estop,
    /// Measured points' read-back poses allowed by the scheduler's constraints.
    MeasuredPose,
    /// The case could not run, or ended in a state it should not.
    Other,
}

/// Check what happened in case `index` against every rule; the verdict and the margins measured.
pub fn check(index: u32, case: &Case, o: &Outcome) -> CaseResult {
    let inst = &o.file.instrument;
    let constraints = Constraints::new(inst, Some(SAMPLE_RADIUS_MM));
    let role = |r: AxisRole| o.records.iter().find(|(a, _)| a.role == r);
    let mut v = Vec::new();
    let mut broken = Vec::new();
    let mut fail = |rule: Rule, message: String| {
        if !broken.contains(&rule) {
            broken.push(rule);
        }
        v.push(message);
    };
    let mut command_margin = f64::INFINITY;
    let mut trajectory_margin = f64::INFINITY;
    let mut extreme: Option<(String, f64, f64)> = None;
    let mut moves = 0u64;

    // Limits: every commanded target and every trajectory.
    for (axis, record) in &o.records {
        if record.truncated {
            fail(Rule::Other, format!("record of {} truncated", axis.name));
        }
        for c in &record.commands {
            match c.command {
                MotionCommand::MoveTo { target_deg } => {
                    moves += 1;
                    let phys = axis.physical_from_controller_deg(target_deg);
                    let (margin, limit) = if phys - axis.min_deg < axis.max_deg - phys {
                        (phys - axis.min_deg, axis.min_deg)
                    } else {
                        (axis.max_deg - phys, axis.max_deg)
                    };
                    if margin < command_margin {
                        command_margin = margin;
                        extreme = Some((axis.name.clone(), phys, limit));
                    }
                    if margin < -EPS_DEG {
                        fail(
                            Rule::Limits,
                            format!(
                                "{} commanded to {phys} deg at t = {} s, limits [{}, {}]",
                                axis.name, c.t_s, axis.min_deg, axis.max_deg
                            ),
                        );
                    }
                }
                MotionCommand::Home => moves += 1,
                _ => {}
            }
        }
        for p in physical_pieces(axis, record.motor_pieces(o.end_s)) {
            let mut values = vec![p.position_at(p.t0_s), p.position_at(p.t1_s)];
            if p.a_deg_s2 != 0.0 {
                let tv = p.t0_s - p.v0_deg_s / p.a_deg_s2;
                if tv > p.t0_s && tv < p.t1_s {
                    values.push(p.position_at(tv));
                }
            }
            for x in values {
                let margin = (x - axis.min_deg).min(axis.max_deg - x);
                trajectory_margin = trajectory_margin.min(margin);
                if margin < -EPS_DEG {
                    fail(
                        Rule::Limits,
                        format!(
                            "{} at {x} deg around t = {} s, limits [{}, {}]",
                            axis.name, p.t0_s, axis.min_deg, axis.max_deg
                        ),
                    );
                }
            }
        }
    }

    // Arm separation at every instant, for the motors and for the loads (what really swings).
    let (mut closest_motor, mut closest_load) = (f64::NAN, f64::NAN);
    match (role(AxisRole::LightArm), role(AxisRole::DetectorArm)) {
        (Some((la, lr)), Some((da, dr))) => {
            match check_separation(
                &physical_pieces(la, lr.motor_pieces(o.end_s)),
                &physical_pieces(da, dr.motor_pieces(o.end_s)),
                &constraints,
            ) {
                Ok(m) => closest_motor = m,
                Err(e) => fail(Rule::Separation, format!("motors: {e}")),
            }
            match check_separation(
                &physical_pieces(la, lr.load_pieces(la.backlash_deg, o.end_s)),
                &physical_pieces(da, dr.load_pieces(da.backlash_deg, o.end_s)),
                &constraints,
            ) {
                Ok(m) => closest_load = m,
                Err(e) => fail(Rule::Separation, format!("loads: {e}")),
            }
        }
        _ => fail(Rule::Other, "no arm axes in the record".into()),
    }

    // Emergency stops: a stop on the wire at every axis within the deadline, then no move until resumed.
    let mut latencies = Vec::new();
    let mut in_sweeps = Vec::new();
    let speeds = sweep_speeds(case);
    for &(requested, resumed) in &o.estops {
        let first = latencies.len();
        for (axis, record) in &o.records {
            let stop_at = record.commands.iter().position(|c| {
                matches!(c.command, MotionCommand::Stop { .. })
                    && c.t_s >= requested - EPS_DEG
                    && c.t_s <= resumed
            });
            let Some(stop_at) = stop_at else {
                let next = record
                    .commands
                    .iter()
                    .find(|c| c.t_s >= requested - EPS_DEG)
                    .map(|c| format!("{:?} at {} s", c.command, c.t_s));
                fail(
                    Rule::Estop,
                    format!(
                        "emergency stop at t = {requested} s: no stop reached {} before the resume at {resumed} s \
                         (next command: {next:?})",
                        axis.name
                    ),
                );
                continue;
            };
            let stop = &record.commands[stop_at];
            let latency = (stop.t_s - requested).max(0.0);
            latencies.push(latency);
            if latency > ESTOP_DEADLINE_S {
                fail(
                    Rule::Estop,
                    format!(
                        "emergency stop at t = {requested} s reached {} after {:.1} ms (deadline {} ms)",
                        axis.name,
                        latency * 1e3,
                        ESTOP_DEADLINE_S * 1e3
                    ),
                );
            }
            // After the stop on the wire (the record keeps the wire's order: a move sent at the same simulated
            // instant just before the stop is overridden by it, one sent just after it is a violation).
            let moved = record.commands[stop_at..].iter().find(|c| {
                matches!(c.command, MotionCommand::MoveTo { .. } | MotionCommand::Home) && c.t_s < resumed
            });
            if let Some(m) = moved {
                fail(
                    Rule::Estop,
                    format!(
                        "{} commanded {:?} at {} s, after the emergency stop at {requested} s and before the resume \
                     at {resumed} s",
                        axis.name, m.command, m.t_s
                    ),
                );
            }
        }
        if sweeping_at(o, &speeds, requested) {
            in_sweeps.push(latencies[first..].iter().copied().fold(0.0, f64::max));
        }
    }

    // Every measured point, by the scheduler's own rules: read-back within limits, arms apart, and the
    // geometry it measured allowed.
    let kinematics = Kinematics::new(inst);
    for p in o
        .points
        .iter()
        .filter(|p| p.flags.iter().all(|f| !f.starts_with("failed")))
    {
        let mut pose = Pose::new(0.0, 0.0, 0.0, 0.0);
        for (name, value) in &p.readback_deg {
            match inst.axes.iter().find(|a| &a.name == name) {
                None => fail(
                    Rule::MeasuredPose,
                    format!("point {}: read-back of unknown axis {name}", p.index),
                ),
                Some(axis) => {
                    if !(axis.min_deg..=axis.max_deg).contains(value) {
                        fail(
                            Rule::MeasuredPose,
                            format!("point {}: {name} read back at {value}", p.index),
                        );
                    }
                    pose.set(axis.role, *value);
                }
            }
        }
        if !constraints.separation_ok(pose.arm_separation_deg()) {
            fail(
                Rule::MeasuredPose,
                format!(
                    "point {} measured with the arms {} deg apart",
                    p.index,
                    pose.arm_separation_deg()
                ),
            );
        }
        let (wi, wo) = kinematics.forward(&pose);
        // Positioning tolerance can push a point sitting exactly on a limit a hair over it: only a clear
        // violation counts (the arm-separation rule is checked exactly above).
        if let Err(reason) = constraints.check_directions(&wi, &wo) {
            let nominal = gonio_brdf::geometry::Direction::from_spherical_deg(p.theta_i_deg, p.phi_i_deg);
            let nominal_o = gonio_brdf::geometry::Direction::from_spherical_deg(p.theta_o_deg, p.phi_o_deg);
            if constraints.check_directions(&nominal, &nominal_o).is_err() {
                fail(
                    Rule::MeasuredPose,
                    format!(
                        "point {} ({}, {}, {}, {}) violates {reason}",
                        p.index, p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg
                    ),
                );
            }
        }
    }
    // Every sweep reading, by the same direction rules (its geometry: the middle of the arc it covered).
    for r in o
        .sweep_readings
        .iter()
        .filter(|r| r.flags.iter().all(|f| !f.starts_with("failed")))
    {
        let wi = gonio_brdf::geometry::Direction::from_spherical_deg(r.theta_i_deg, r.phi_i_deg);
        let wo = gonio_brdf::geometry::Direction::from_spherical_deg(r.theta_o_deg, r.phi_o_deg);
        if let Err(reason) = constraints.check_directions(&wi, &wo) {
            fail(
                Rule::MeasuredPose,
                format!(
                    "sweep reading {}/{} ({}, {}, {}, {}) violates {reason}",
                    r.segment, r.k, r.theta_i_deg, r.phi_i_deg, r.theta_o_deg, r.phi_o_deg
                ),
            );
        }
    }
    let segments: std::collections::BTreeSet<u32> = o.sweep_readings.iter().map(|r| r.segment).collect();
    if !(matches!(o.final_state, CampaignState::Completed | CampaignState::Aborted) || case.faults.any()) {
        fail(Rule::Other, format!("the campaign ended {}", o.final_state));
    }
    CaseResult {
        index,
        faults: case.faults.any(),
        acts: o.acts,
        final_state: Some(o.final_state),
        planned_points: o.planned_points,
        points: o.points.len() as u64,
        planned_segments: o.planned_segments,
        segments: segments.len() as u64,
        sweep_readings: o.sweep_readings.len() as u64,
        move_commands: moves,
        closest_motor_deg: closest_motor,
        closest_load_deg: closest_load,
        command_margin_deg: command_margin,
        trajectory_margin_deg: trajectory_margin,
        extreme_command: extreme,
        estop_latencies_s: latencies,
        estops_in_sweeps_s: in_sweeps,
        violations: v,
        broken,
    }
}

/// The cruise speeds of a case's sweeps (deg/s), from its campaign text.
pub fn sweep_speeds(case: &Case) -> Vec<f64> {
    gonio_campaign::CampaignFile::parse(&case.campaign)
        .map(|f| f.plan.sweeps.iter().map(|s| s.speed_deg_s).collect())
        .unwrap_or_default()
}

/// Was an arm cruising at one of `speeds_deg_s` (a sweep's) at `t_s` (simulated)? Point moves run at the axis's
/// top speed (above every sweep's), or accelerate and brake without a cruise.
pub fn sweeping_at(o: &Outcome, speeds_deg_s: &[f64], t_s: f64) -> bool {
    o.records
        .iter()
        .filter(|(a, _)| matches!(a.role, AxisRole::LightArm | AxisRole::DetectorArm))
        .any(|(axis, record)| {
            physical_pieces(axis, record.motor_pieces(o.end_s))
                .iter()
                .any(|p| {
                    // A stop at the very instant of the request ends the cruise there: the end counts.
                    p.t0_s < t_s
                        && t_s <= p.t1_s
                        && p.a_deg_s2 == 0.0
                        && speeds_deg_s
                            .iter()
                            .any(|v| (p.v0_deg_s.abs() - v).abs() <= 1e-6 * v.max(1.0))
                })
        })
}
