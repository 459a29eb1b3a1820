//! Kinematics round trips, constraint checks and the move planner, against independent expectations.

use crate::common;

use common::*;
use gonio_brdf::geometry::Direction;
use gonio_instrument::{AxisRole, GeometryKind};
use gonio_scheduler::constraints::{Constraints, Reason};
use gonio_scheduler::kinematics::{Geometry, Kinematics, KinematicsError, Pose};
use gonio_scheduler::timing::{TimeModel, trapezoid_time_s};
use proptest::prelude::*;

fn angle_deg(a: &Direction, b: &Direction) -> f64 {
    a.angle_to(b).to_degrees()
}

#[test]
fn forward_matches_the_documented_convention_by_hand() {
    let kin = Kinematics::new(&simulated());
    // Zero tilt and rotation: the arms' plane is the sample's x-z plane; arms at +-30 are a specular pair.
    let g = kin.forward_geometry(&Pose::new(30.0, -30.0, 0.0, 0.0));
    assert!(
        (g.theta_i_deg - 30.0).abs() < 1e-12 && g.phi_i_deg.abs() < 1e-12,
        "{g:?}"
    );
    assert!(
        (g.theta_o_deg - 30.0).abs() < 1e-12 && (g.phi_o_deg.abs() - 180.0).abs() < 1e-12,
        "{g:?}"
    );
    // Tilt 30, light arm along lab X: n = (cos30, 0, sin30), sample y = (-sin30, 0, cos30), sample x = lab Y.
    // wi = lab X -> (0, -sin30, cos30): theta 30, phi -90.
    let g = kin.forward_geometry(&Pose::new(0.0, 90.0, 30.0, 0.0));
    assert!(
        (g.theta_i_deg - 30.0).abs() < 1e-12 && (g.phi_i_deg + 90.0).abs() < 1e-12,
        "{g:?}"
    );
    // Detector along lab Y = sample x at zero rotation: theta 90, phi 0.
    assert!(
        (g.theta_o_deg - 90.0).abs() < 1e-12 && g.phi_o_deg.abs() < 1e-12,
        "{g:?}"
    );
    // Rotation r turns sample azimuths by -r.
    let g0 = kin.forward_geometry(&Pose::new(40.0, -20.0, 10.0, 0.0));
    let g1 = kin.forward_geometry(&Pose::new(40.0, -20.0, 10.0, 25.0));
    assert!(
        (g1.phi_i_deg - (g0.phi_i_deg - 25.0)).abs() < 1e-9,
        "{g0:?} {g1:?}"
    );
    assert!((g1.theta_i_deg - g0.theta_i_deg).abs() < 1e-12);
}

#[test]
fn in_plane_instrument_rejects_out_of_plane_requests() {
    let mut inst = simulated();
    inst.geometry = GeometryKind::InPlane;
    inst.axes.retain(|a| a.role != AxisRole::SampleTilt);
    let kin = Kinematics::new(&inst);
    let hint = Pose::new(0.0, 0.0, 0.0, 0.0);
    let (wi, wo) = Geometry::new(30.0, 0.0, 40.0, 90.0).directions();
    match kin.solutions(&wi, &wo, &hint) {
        Err(KinematicsError::OutOfPlane { deviation_deg }) => assert!(deviation_deg > 1.0),
        other => panic!("expected out-of-plane, got {other:?}"),
    }
    let (wi, wo) = Geometry::new(30.0, 40.0, 50.0, 220.0).directions();
    let sols = kin.solutions(&wi, &wo, &hint).expect("in-plane request");
    for p in sols {
        assert_eq!(p.tilt_deg, 0.0);
        let (a, b) = kin.forward(&p);
        assert!(angle_deg(&a, &wi) < 1e-9 && angle_deg(&b, &wo) < 1e-9);
    }
}

#[test]
fn trapezoid_times_by_hand() {
    // v^2/a = 5: 100 deg cruises (100/20 + 20/80), 1 deg does not (2 sqrt(1/80)).
    assert!((trapezoid_time_s(100.0, 20.0, 80.0) - 5.25).abs() < 1e-12);
    assert!((trapezoid_time_s(1.0, 20.0, 80.0) - 2.0 * (1.0f64 / 80.0).sqrt()).abs() < 1e-12);
    assert!((trapezoid_time_s(5.0, 20.0, 80.0) - 0.5).abs() < 1e-12);
    assert_eq!(trapezoid_time_s(0.0, 20.0, 80.0), 0.0);
}

#[test]
fn a_move_lasts_as_long_as_its_slowest_axis_plus_settle_and_backlash() {
    let inst = simulated();
    let tm = TimeModel::new(&inst);
    // Upwards: no backlash approach. Light 0 -> 40 (2.25 s), detector 60 -> 70 (0.75 s), tilt 0 -> 10.
    let m = tm
        .plan_move(&Pose::new(0.0, 60.0, 0.0, 0.0), &Pose::new(40.0, 70.0, 10.0, 0.0))
        .expect("move");
    // Plus the SMC100 driver's exchanges (2 ms each at 57600 baud): none before the PA (the driver knows where
    // the axis came to rest), the status and two reads just after (1 ms) the predicted end.
    assert_eq!(m.phases.len(), 1);
    assert!((m.motion_s - (2.25 + 0.007)).abs() < 1e-12, "{m:?}");
    // The detector, second on the arms' chain, starts with the light arm: 0.75 s of motion.
    let detector = m.phases[0]
        .iter()
        .find(|a| a.role == AxisRole::DetectorArm)
        .expect("detector");
    assert!(
        (detector.duration_s - (0.75 + 0.007)).abs() < 1e-12,
        "{detector:?}"
    );
    // The tilt on its Zaber chain (3 ms exchanges at 115200 baud): move abs, then get pos at the end.
    let tilt = m.phases[0]
        .iter()
        .find(|a| a.role == AxisRole::SampleTilt)
        .expect("tilt");
    let tilt_motion = trapezoid_time_s(10.0, 30.0, 120.0);
    assert!(
        (tilt.duration_s - (tilt_motion + 0.007)).abs() < 1e-12,
        "{tilt:?}"
    );
    assert!((m.settle_s - 0.05).abs() < 1e-12, "{m:?}");
    // Downwards with 0.01 deg backlash: overshoot by 0.02 and come back up.
    let m = tm
        .plan_move(&Pose::new(40.0, 70.0, 0.0, 0.0), &Pose::new(0.0, 70.0, 0.0, 0.0))
        .expect("move");
    let light = &m.phases[0][0];
    assert_eq!(light.waypoints_deg, vec![-0.02, 0.0]);
    // Alone, the light arm's driver plans the approach from where the axis came to rest (no read), then two
    // legs. The 32 ms overshoot leg is seen no sooner than the 65 ms pause after its PA and five exchanges.
    let overshoot = trapezoid_time_s(0.02, 20.0, 80.0);
    assert!(overshoot < 0.04);
    let expected = (trapezoid_time_s(40.02, 20.0, 80.0) + 0.007) + (0.065 + 0.010);
    assert!((m.motion_s - expected).abs() < 1e-12, "{m:?}");
}

#[test]
fn a_move_that_would_cross_mid_way_is_split_into_two_safe_phases() {
    let mut inst = simulated();
    // A slow light arm and a fast detector: light 20 -> 50 and detector 0 -> 30 keep 20 degrees apart at both
    // ends, but moved together the detector overtakes the light arm.
    for a in inst.axes.iter_mut() {
        match a.role {
            AxisRole::LightArm => a.max_speed_deg_s = 2.0,
            AxisRole::DetectorArm => a.max_speed_deg_s = 50.0,
            _ => {}
        }
        a.backlash_deg = 0.0;
    }
    let tm = TimeModel::new(&inst);
    let (from, to) = (Pose::new(20.0, 0.0, 0.0, 0.0), Pose::new(50.0, 30.0, 0.0, 0.0));
    let m = tm.plan_move(&from, &to).expect("a safe move exists");
    assert_eq!(m.phases.len(), 2, "{m:?}");
    assert_eq!(
        m.phases[0][0].role,
        AxisRole::LightArm,
        "the light arm must get out of the way first"
    );
    assert!(min_separation_during(&inst, &from, &m, 1e-3) >= 10.0 - 1e-6);
    // Arms that would have to pass each other: no safe move.
    assert_eq!(
        tm.plan_move(&Pose::new(20.0, 0.0, 0.0, 0.0), &Pose::new(0.0, 20.0, 0.0, 0.0)),
        Err(Reason::ArmSeparation)
    );
}

#[test]
fn arms_that_only_move_apart_from_the_closest_pose_allowed_move_together() {
    let inst = simulated();
    let tm = TimeModel::new(&inst);
    // A sweep ended with the detector just beyond the separation from the light arm (10 deg on the simulated
    // instrument); the next stretch has the light arm on the other side and the detector far up: each arm only
    // moves away from the other (the light's backlash approach of 0.02 deg included), so no stall of one can
    // bring the other closer than they start. One phase, as long as its slowest axis.
    let from = Pose::new(30.0, 40.02, 0.0, 0.0);
    let to = Pose::new(-30.0, 80.0, 0.0, -180.0);
    let m = tm.plan_move(&from, &to).expect("a safe move");
    assert_eq!(m.phases.len(), 1, "{m:?}");
    let rotation = trapezoid_time_s(180.0, 30.0, 120.0);
    assert!(m.motion_s < rotation + 0.1, "{m:?}");
    assert!(min_separation_during(&inst, &from, &m, 1e-3) >= 10.0 - 1e-6);
    // Arms whose swept ranges overlap still keep the stopping margin: the detector following the light arm
    // 12.5 deg behind is two phases (crates/soak/tests/safety_soak.rs has the case the safety soak caught).
    let m = tm
        .plan_move(
            &Pose::new(-6.25, 6.25, 0.0, 0.0),
            &Pose::new(-60.0, -20.0, 0.0, 0.0),
        )
        .expect("a safe move");
    assert_eq!(m.phases.len(), 2, "{m:?}");
}

fn geometry_strategy() -> impl Strategy<Value = Geometry> {
    prop_oneof![
        8 => (0.0..89.0f64, -180.0..180.0f64, 0.0..89.0f64, -180.0..180.0f64)
            .prop_map(|(a, b, c, d)| Geometry::new(a, b, c, d)),
        // Singular: normal incidence or exitance, the specular plane, retro-reflection.
        1 => (0.0..89.0f64, -180.0..180.0f64).prop_map(|(c, d)| Geometry::new(0.0, 0.0, c, d)),
        1 => (0.0..89.0f64, -180.0..180.0f64).prop_map(|(c, d)| Geometry::new(c, d, 0.0, 0.0)),
        1 => (0.0..89.0f64, -180.0..180.0f64).prop_map(|(c, d)| Geometry::new(c, d, c, d)),
        1 => (0.0..89.0f64, -180.0..180.0f64, 0.0..89.0f64).prop_map(|(a, b, c)| Geometry::new(a, b, c, b + 180.0)),
    ]
}

fn hint_strategy() -> impl Strategy<Value = Pose> {
    (-60.0..60.0f64, -60.0..60.0f64, -20.0..20.0f64, -150.0..150.0f64)
        .prop_map(|(a, b, c, d)| Pose::new(a, b, c, d))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// forward(inverse(g)) == g for every solution returned, within the limits, on random instruments.
    #[test]
    fn kinematics_round_trip(ri in random_instrument(), g in geometry_strategy(), hint in hint_strategy()) {
        let inst = ri.build();
        let kin = Kinematics::new(&inst);
        let (wi, wo) = g.directions();
        match kin.solutions(&wi, &wo, &hint) {
            Ok(sols) => {
                prop_assert!(!sols.is_empty());
                for p in &sols {
                    let (a, b) = kin.forward(p);
                    prop_assert!(angle_deg(&a, &wi) < 1e-9, "wi off by {} for {:?} at {:?}", angle_deg(&a, &wi), g, p);
                    prop_assert!(angle_deg(&b, &wo) < 1e-9, "wo off by {} for {:?} at {:?}", angle_deg(&b, &wo), g, p);
                    for axis in &inst.axes {
                        let v = p.get(axis.role);
                        prop_assert!(v >= axis.min_deg - 1e-9 && v <= axis.max_deg + 1e-9, "{} = {v} outside limits", axis.name);
                        let c = axis.controller_from_physical_deg(v);
                        prop_assert!((axis.physical_from_controller_deg(c) - v).abs() < 1e-9);
                    }
                    // phi is compared where it is defined.
                    let back = kin.forward_geometry(p);
                    if g.theta_i_deg > 1e-6 {
                        let d = (back.phi_i_deg - g.phi_i_deg).rem_euclid(360.0);
                        prop_assert!(d.min(360.0 - d) < 1e-7, "phi_i {:?} -> {:?}", g, back);
                    }
                }
            }
            Err(KinematicsError::OutOfPlane { .. }) => {
                prop_assert!(ri.in_plane);
                // Independent check: wi, wo and the normal are not coplanar.
                let triple = wi.cross(&wo)[2];
                prop_assert!(triple.abs() > 1e-10, "rejected an in-plane request {:?}", g);
            }
            Err(KinematicsError::AxisLimits { .. }) => {
                // Independent check: with unlimited axes, no solution falls in the real limits modulo 360.
                let mut wide = inst.clone();
                for a in wide.axes.iter_mut() { a.min_deg = -540.0; a.max_deg = 540.0; }
                let all = Kinematics::new(&wide).solutions(&wi, &wo, &hint).expect("unlimited axes reach it");
                for p in all {
                    let fits = inst.axes.iter().all(|a| {
                        let v = p.get(a.role);
                        (-2..=2).any(|k| { let x = v + 360.0 * f64::from(k); x >= a.min_deg - 1e-6 && x <= a.max_deg + 1e-6 })
                    });
                    prop_assert!(!fits, "solution {:?} fits the limits but was refused", p);
                }
            }
        }
    }

    /// Each static rule agrees with a brute-force evaluation from its definition.
    #[test]
    fn constraint_checks_agree_with_brute_force(ri in random_instrument(), g in geometry_strategy(),
                                               radius in 2.0..20.0f64, field in 2.0..20.0f64, beam in 0.5..4.0f64) {
        let mut inst = ri.build();
        inst.detector.field_radius_mm = field;
        inst.source.beam_radius_mm = beam;
        let c = Constraints::new(&inst, Some(radius));
        let (wi, wo) = g.directions();
        let verdict = c.check_directions(&wi, &wo);
        // Brute force: walk the footprint's boundary and test each point against sample disc and field.
        let (ct, st) = (wi.cos_theta(), wi.sin_theta());
        let (ux, uy) = if st > 0.0 { (wi.x() / st, wi.y() / st) } else { (1.0, 0.0) };
        let (mut max_r, mut max_field) = (0.0f64, 0.0f64);
        for k in 0..2000 {
            let s = k as f64 / 2000.0 * std::f64::consts::TAU;
            let (a, b) = (beam / ct * s.cos(), beam * s.sin());
            let (px, py) = (a * ux - b * uy, a * uy + b * ux);
            max_r = max_r.max(px.hypot(py));
            let along = px * wo.x() + py * wo.y();
            max_field = max_field.max((px * px + py * py - along * along).sqrt());
        }
        let sep = angle_deg(&wi, &wo);
        let theta_max = wi.theta().to_degrees().max(wo.theta().to_degrees());
        let margin = |x: f64, limit: f64| (x - limit).abs() > 1e-3 * limit;
        if theta_max > ri.grazing + 1e-6 {
            prop_assert_eq!(verdict, Err(Reason::GrazingLimit));
        } else if theta_max < ri.grazing - 1e-6 && margin(max_r, radius) && margin(max_field, field) {
            let expected = if max_r > radius {
                Err(Reason::SampleOverfill)
            } else if max_field > field {
                Err(Reason::FieldOfViewOverfill)
            } else if sep < ri.retro - 1e-6 {
                Err(Reason::RetroBlock)
            } else if sep < ri.min_sep - 1e-6 {
                Err(Reason::ArmSeparation)
            } else if sep > ri.min_sep.max(ri.retro) + 1e-6 {
                Ok(())
            } else {
                verdict
            };
            prop_assert_eq!(verdict, expected, "{:?} r {} f {}", g, max_r, max_field);
        }
    }

    /// Every planned move keeps the arms apart at every instant (independent dense simulation of the profiles),
    /// and its duration is at least the provable lower bound.
    #[test]
    fn planned_moves_keep_the_arms_apart(ri in random_instrument(),
                                         l0 in -60.0..60.0f64, gap0 in 0.0..100.0f64,
                                         l1 in -60.0..60.0f64, gap1 in 0.0..100.0f64,
                                         t0 in -20.0..20.0f64, t1 in -20.0..20.0f64) {
        let inst = ri.build();
        let tm = TimeModel::new(&inst);
        let sep = ri.min_sep;
        // Same side (detector above the light arm), both ends valid.
        let from = Pose::new(l0, l0 + sep + gap0, if ri.in_plane { 0.0 } else { t0 }, 0.0);
        let to = Pose::new(l1, l1 + sep + gap1, if ri.in_plane { 0.0 } else { t1 }, 10.0);
        match tm.plan_move(&from, &to) {
            Ok(m) => {
                let seen = min_separation_during(&inst, &from, &m, 5e-4);
                prop_assert!(seen >= sep - 1e-6, "separation {seen} < {sep} during {:?}", m);
                prop_assert!(m.total_s() + 1e-12 >= tm.lower_bound_s(&from, &to));
                prop_assert!((tm.fast_cost_s(&from, &to) - m.total_s()).abs() < 1e-9);
            }
            // Only backlash overshoots can make both orders fail, and only with a hair's margin.
            Err(_) => prop_assert!(gap0.min(gap1) <= 2.0 * overshoot(&inst) + 1e-9, "refused a move with gaps {gap0} {gap1}"),
        }
    }
}
