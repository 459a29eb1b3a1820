//! Plans (parsing, reductions, skip accounting), schedules (constraints on every emitted point and move),
//! ordering against raster order and against a brute-force optimum, and the lower bound.

use crate::common;

use std::collections::HashSet;

use common::*;
use gonio_instrument::Instrument;
use gonio_scheduler::constraints::{Constraints, Reason};
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_scheduler::order;
use gonio_scheduler::plan::{self, BuildContext, Plan, PlanSpec, SampleTraits};
use gonio_scheduler::schedule::{self, BandMode, Schedule, StepKind};
use gonio_scheduler::timing::{EXCHANGE_S, TimeModel};
use proptest::prelude::*;

pub(crate) const ISO: SampleTraits = SampleTraits {
    isotropic: true,
    spectrally_flat: false,
};
const ANISO: SampleTraits = SampleTraits {
    isotropic: false,
    spectrally_flat: false,
};

pub(crate) fn build(text: &str, inst: &Instrument, traits: SampleTraits) -> Result<Plan, String> {
    let spec = PlanSpec::from_toml(text, "test.toml").map_err(|e| e.to_string())?;
    let ctx = BuildContext {
        instrument: inst,
        traits,
        sample_radius_mm: None,
        start: None,
    };
    plan::build(&spec, &ctx).map_err(|e| e.to_string())
}

fn err(text: &str) -> String {
    build(text, &simulated(), ISO).expect_err("must be refused")
}

#[test]
fn plan_errors_name_the_key() {
    let base = "[plan]\n[plan.grid]\nkind = \"isotropic\"\ntheta_i_deg = [0.0]\ntheta_o_deg = [30.0]\ndelta_phi_deg = [180.0]\n";
    assert!(build(base, &simulated(), ISO).is_ok());
    let m = err(&base.replace("[0.0]", "{ from = 0.0, to = 60.0, step = 0.0 }"));
    assert!(m.contains("theta_i_deg") && m.contains("step"), "{m}");
    let m = err(&format!("{base}bogus = 1\n"));
    assert!(m.contains("bogus"), "{m}");
    let m = err(&base.replace("[plan]\n", "[plan]\nbands_nm = [451.0]\n"));
    assert!(m.contains("bands_nm") && m.contains("451"), "{m}");
    let m = err(&base.replace("delta_phi_deg = [180.0]\n", ""));
    assert!(m.contains("delta_phi_deg") && m.contains("isotropic"), "{m}");
    let m = err(&format!("{base}phi_i_deg = [0.0]\n"));
    assert!(m.contains("phi_i_deg") && m.contains("not used"), "{m}");
    let m = err(&base.replace("[plan]\n", "[plan]\nrepeats = 0\n"));
    assert!(m.contains("repeats"), "{m}");
    let m = err(&format!(
        "{base}[plan.calibration]\nreference_every_points = 10\nreference_pose_deg = {{ light = -120.0, detector = 90.0 }}\n"
    ));
    assert!(m.contains("reference_pose_deg") && m.contains("light"), "{m}");
    let m = err(&format!("{base}[plan.calibration]\ndark_every_points = 0\n"));
    assert!(m.contains("dark_every_points"), "{m}");
    let m = err("[plan]\n[plan.grid]\nkind = \"spiral\"\n");
    assert!(m.contains("kind") || m.contains("spiral"), "{m}");
}

/// Isotropic 3-D grid text.
pub(crate) fn iso_grid(step_t: f64, step_p: f64, max_t: f64) -> String {
    format!(
        "[plan]\nbands_nm = [450.0, 550.0, 650.0]\n[plan.grid]\nkind = \"isotropic\"\n\
         theta_i_deg = {{ from = 0.0, to = {max_t}, step = {step_t} }}\ntheta_o_deg = {{ from = 0.0, to = {max_t}, step = {step_t} }}\n\
         delta_phi_deg = {{ from = 0.0, to = 180.0, step = {step_p} }}\n"
    )
}

#[test]
fn isotropic_samples_are_never_swept_in_absolute_phi() {
    let inst = simulated();
    let full = "[plan]\nbands_nm = [550.0]\nreciprocity = false\n[plan.grid]\nkind = \"full\"\ntheta_i_deg = [30.0]\n\
                phi_i_deg = [0.0, 90.0, 180.0]\ntheta_o_deg = [45.0]\nphi_o_deg = [90.0, 180.0, 270.0]\n";
    let p = build(full, &inst, ISO).expect("plan");
    // 9 requests, delta_phi in {90, 180, 90, 90, 0, 90, 180, 90, 0} -> {0, 90, 180}: 3 kept, 6 isotropic.
    assert_eq!(p.geometries.len(), 3);
    assert_eq!(p.skipped.get(&Reason::Isotropic), Some(&6));
    for g in &p.geometries {
        for (pose, _) in &g.candidates {
            assert_eq!(pose.rotation_deg, 0.0, "the rotation axis is held");
        }
    }
    let p = build(full, &inst, ANISO).expect("plan");
    assert_eq!(p.geometries.len(), 9);
}

#[test]
fn reciprocity_halves_a_symmetric_grid_and_keeps_a_mirror_map() {
    let inst = simulated();
    let text = iso_grid(15.0, 45.0, 60.0);
    let with = build(&text, &inst, ISO).expect("plan");
    let without = build(
        &text.replace("[plan]\n", "[plan]\nreciprocity = false\n"),
        &inst,
        ISO,
    )
    .expect("plan");
    let kept: HashSet<(i64, i64, i64)> = with
        .geometries
        .iter()
        .map(|g| {
            let r = g.requested;
            (
                (r.theta_i_deg * 1e6) as i64,
                (r.theta_o_deg * 1e6) as i64,
                (r.delta_phi_deg() * 1e6) as i64,
            )
        })
        .collect();
    for (a, b, c) in &kept {
        if a != b {
            assert!(
                !kept.contains(&(*b, *a, *c)),
                "both ({a},{b},{c}) and its reciprocal are measured"
            );
        }
    }
    // Every reciprocity skip is served by a kept geometry that is its mirror image.
    let mut n = 0;
    for s in &with.served {
        if s.reason == Reason::Reciprocity {
            n += 1;
            let by = with.geometries[s.by].requested;
            assert!(s.reciprocal);
            assert!((by.theta_i_deg - s.requested.theta_o_deg).abs() < 1e-9);
            assert!((by.theta_o_deg - s.requested.theta_i_deg).abs() < 1e-9);
        }
    }
    assert_eq!(
        with.skipped.get(&Reason::Reciprocity).copied().unwrap_or(0),
        n * 3
    );
    // Exactly one measurement per unordered pair {(i, o), (o, i)} that has a measurable member.
    let classes: HashSet<(i64, i64, i64)> = without
        .geometries
        .iter()
        .map(|g| {
            let r = g.requested;
            let (a, b) = ((r.theta_i_deg * 1e6) as i64, (r.theta_o_deg * 1e6) as i64);
            (a.min(b), a.max(b), (r.delta_phi_deg() * 1e6) as i64)
        })
        .collect();
    assert_eq!(with.geometries.len(), classes.len());
    assert!(with.geometries.len() < without.geometries.len());
    assert_eq!(with.kept() + with.skipped_total(), with.requested);
}

#[test]
fn flat_materials_are_measured_at_one_band() {
    let inst = simulated();
    let text = iso_grid(20.0, 60.0, 60.0);
    let p = build(
        &text,
        &inst,
        SampleTraits {
            isotropic: true,
            spectrally_flat: true,
        },
    )
    .expect("plan");
    assert_eq!(p.bands_nm, vec![450.0]);
    assert_eq!(
        p.skipped.get(&Reason::SpectrallyFlat),
        Some(&(p.geometries.len() * 2))
    );
    assert_eq!(p.kept() + p.skipped_total(), p.requested);
}

#[test]
fn in_plane_grid_signs_and_constraint_reasons() {
    let inst = simulated();
    let text = "[plan]\nbands_nm = [550.0]\nreciprocity = false\n[plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = [30.0]\n\
                theta_o_deg = [-88.0, -32.0, -30.0, 0.0, 30.0, 60.0, 88.0]\n";
    let p = build(text, &inst, ANISO).expect("plan");
    // -88 and 88: grazing; -30 (retro) and -32 (2 degrees from the source: retro block is 5).
    assert_eq!(p.skipped.get(&Reason::GrazingLimit), Some(&2));
    assert_eq!(p.skipped.get(&Reason::RetroBlock), Some(&2));
    assert_eq!(p.geometries.len(), 3);
    let spec = p
        .geometries
        .iter()
        .find(|g| g.requested.theta_o_deg == 30.0)
        .expect("specular point");
    assert_eq!(spec.requested.phi_o_deg, 180.0);
}

fn check_schedule(inst: &Instrument, plan: &Plan, sched: &Schedule) -> Result<(), TestCaseError> {
    let kin = Kinematics::new(inst);
    let constraints = Constraints::new(inst, None);
    let tm = TimeModel::new(inst);
    let mut prev: Option<Pose> = None;
    let mut t = 0.0;
    let mut measured = 0;
    for step in &sched.steps {
        prop_assert!((step.start_s - t).abs() < 1e-6 * (1.0 + t), "start times add up");
        t += step.movement.total_s() + step.wheel_s + step.reading_s;
        for axis in &inst.axes {
            let v = step.pose.get(axis.role);
            prop_assert!(
                v >= axis.min_deg - 1e-9 && v <= axis.max_deg + 1e-9,
                "{} at {v}",
                axis.name
            );
        }
        prop_assert!(step.pose.arm_separation_deg() >= inst.safety.min_arm_separation_deg - 1e-9);
        if let Some(p) = prev
            && tm.lower_bound_s(&p, &step.pose) > 0.0
        {
            // A step at another pose than the one before it carries the move there (its time is predicted).
            prop_assert!(
                step.movement.total_s() >= tm.lower_bound_s(&p, &step.pose) - 1e-9,
                "{} step at {:?} after {p:?} predicts no move",
                step.kind.name(),
                step.pose
            );
        }
        if let Some(p) = prev {
            let seen = min_separation_during(inst, &p, &step.movement, 1e-3);
            prop_assert!(
                seen >= inst.safety.min_arm_separation_deg - 1e-6,
                "separation {seen} during the move"
            );
        }
        if step.kind == StepKind::Measure {
            measured += 1;
            let g = step.geometry.expect("geometry");
            let (wi, wo) = g.directions();
            prop_assert_eq!(constraints.check_directions(&wi, &wo), Ok(()));
            let (a, b) = kin.forward(&step.pose);
            prop_assert!(
                a.angle_to(&wi).to_degrees() < 1e-9 && b.angle_to(&wo).to_degrees() < 1e-9,
                "pose measures its geometry"
            );
            let c = tm.controller_deg(&step.pose);
            for (k, axis) in inst.axes.iter().enumerate() {
                prop_assert!(
                    (c[k] - axis.controller_from_physical_deg(step.pose.get(axis.role))).abs() < 1e-12
                );
            }
        }
        prev = Some(step.pose);
    }
    // The plan keeps room for backlash overshoots, so every transition has a safe move: nothing is dropped.
    prop_assert_eq!(sched.dropped, 0);
    prop_assert_eq!(measured, plan.kept() * plan.repeats as usize);
    // The run ends with the beam closed: a last turn of the wheel to its blank, in the breakdown but no step.
    let b = &sched.breakdown;
    let blank = tm.wheel.as_ref().and_then(|w| w.blank);
    match (&tm.wheel, blank) {
        // At most half a turn of the wheel, and its exchanges.
        (Some(w), Some(_)) => prop_assert!(
            b.closing_s >= 0.0
                && b.closing_s <= f64::from(w.slots / 2) * w.seconds_per_position + 5.0 * EXCHANGE_S + 1e-9,
            "closing turn {} s",
            b.closing_s
        ),
        _ => prop_assert_eq!(b.closing_s, 0.0),
    }
    prop_assert!(
        (b.total_s() - t - b.closing_s).abs() < 1e-6 * (1.0 + t),
        "breakdown adds up to the step times and the closing turn of the wheel"
    );
    prop_assert!(
        b.total_s() <= sched.raster.total_s() + 1e-9,
        "ordered {} > raster {}",
        b.total_s(),
        sched.raster.total_s()
    );
    prop_assert!(
        sched.lower_bound_s <= b.total_s() + 1e-9,
        "lower bound {} > ordered {}",
        sched.lower_bound_s,
        b.total_s()
    );
    Ok(())
}

#[test]
fn a_calibration_between_two_bands_of_one_geometry_is_followed_by_the_move_back() {
    // A fast wheel measures every band at each geometry; references every 4 points fall between the bands of one
    // geometry, which must then be reached again from the direct-beam pose (the walk once predicted no move).
    let mut inst = simulated();
    if let Some(w) = inst.filter_wheel.as_mut() {
        w.seconds_per_position = 0.01;
    }
    let text = format!(
        "{}[plan.calibration]\nreference_every_points = 4\ndark_every_points = 5\n",
        iso_grid(20.0, 60.0, 60.0)
    );
    let plan = build(&text, &inst, ISO).expect("plan");
    let sched = schedule::schedule(&plan, &TimeModel::new(&inst), None);
    assert_eq!(sched.mode, BandMode::PerGeometry);
    let between_bands = sched.steps.windows(3).filter(|w| {
        w[0].kind == StepKind::Measure
            && w[1].kind == StepKind::Reference
            && w.iter().filter(|s| s.kind == StepKind::Measure).count() == 1
    });
    let mut seen = 0;
    for (k, step) in sched.steps.iter().enumerate().skip(1) {
        let before = &sched.steps[k - 1];
        if step.kind == StepKind::Measure
            && before.kind == StepKind::Reference
            && sched.steps[..k]
                .iter()
                .rev()
                .find(|s| s.kind == StepKind::Measure)
                .is_some_and(|m| m.geometry_index == step.geometry_index)
        {
            seen += 1;
            let back = TimeModel::new(&inst).move_cost_s(&before.pose, &step.pose);
            assert!(
                (step.movement.total_s() - back).abs() < 1e-9,
                "step {k}: {} s predicted, the move back takes {back} s",
                step.movement.total_s()
            );
        }
    }
    assert!(
        seen > 0 && between_bands.count() > 0,
        "no calibration fell between two bands of one geometry"
    );
    check_schedule(&inst, &plan, &sched).expect("a valid schedule");
}

fn grid_strategy() -> impl Strategy<Value = String> {
    let list = || prop::collection::vec(0.0..90.0f64, 1..5).prop_map(|v| format!("{v:?}"));
    prop_oneof![
        (list(), list(), prop::collection::vec(0.0..180.0f64, 1..4).prop_map(|v| format!("{v:?}")))
            .prop_map(|(a, b, c)| format!("kind = \"isotropic\"\ntheta_i_deg = {a}\ntheta_o_deg = {b}\ndelta_phi_deg = {c}\n")),
        (list(), prop::collection::vec(-180.0..180.0f64, 1..3), list(), prop::collection::vec(-180.0..180.0f64, 1..3))
            .prop_map(|(a, b, c, d)| format!("kind = \"full\"\ntheta_i_deg = {a}\nphi_i_deg = {b:?}\ntheta_o_deg = {c}\nphi_o_deg = {d:?}\n")),
        (list(), prop::collection::vec(-90.0..90.0f64, 1..8))
            .prop_map(|(a, b)| format!("kind = \"in-plane\"\ntheta_i_deg = {a}\ntheta_o_deg = {b:?}\n")),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Random plans on random instruments: kept + skipped = requested; no emitted point or move violates a
    /// constraint; ordered <= raster; lower bound <= ordered.
    #[test]
    fn random_plans_are_safe_and_accounted(ri in random_instrument(), grid in grid_strategy(),
                                            iso in any::<bool>(), flat in any::<bool>(), reciprocity in any::<bool>(),
                                            darks in prop::option::of(1u32..20), repeats in 1u32..3) {
        let inst = ri.build();
        let mut text = format!("[plan]\nreciprocity = {reciprocity}\nrepeats = {repeats}\n[plan.grid]\n{grid}");
        if let Some(n) = darks {
            text.push_str(&format!("[plan.calibration]\ndark_every_points = {n}\n"));
        }
        let traits = SampleTraits { isotropic: iso, spectrally_flat: flat };
        let plan = build(&text, &inst, traits).map_err(TestCaseError::fail)?;
        prop_assert_eq!(plan.kept() + plan.skipped_total(), plan.requested);
        let sched = schedule::schedule(&plan, &TimeModel::new(&inst), None);
        check_schedule(&inst, &plan, &sched)?;
    }

    /// The heuristic never loses to raster order, and the lower bound never exceeds the true optimum
    /// (brute force over every order of a few poses).
    #[test]
    fn ordering_against_raster_and_brute_force(ri in random_instrument(),
                                               raw in prop::collection::vec((-50.0..-5.0f64, 5.0..60.0f64, -15.0..15.0f64, -90.0..90.0f64), 2..7)) {
        let inst = ri.build();
        let tm = TimeModel::new(&inst);
        let poses: Vec<Pose> = raw.iter().map(|(l, d, t, r)| Pose::new(*l, d + ri.min_sep, if ri.in_plane { 0.0 } else { *t }, *r)).collect();
        let tour = order::order(&poses, None, &tm);
        let mut sorted = tour.clone();
        sorted.sort_unstable();
        prop_assert_eq!(sorted, (0..poses.len()).collect::<Vec<_>>());
        let raster: Vec<usize> = (0..poses.len()).collect();
        let c = order::path_cost(&tour, &poses, None, &tm);
        prop_assert!(c <= order::path_cost(&raster, &poses, None, &tm) + 1e-9);
        // Brute force optimum.
        let mut best = f64::INFINITY;
        let mut perm = raster.clone();
        permute(&mut perm, 0, &mut |p| best = best.min(order::path_cost(p, &poses, None, &tm)));
        let nodes: Vec<Vec<Pose>> = poses.iter().map(|p| vec![*p]).collect();
        let lb = order::lower_bound_s(&nodes, None, None, &tm);
        prop_assert!(lb <= best + 1e-9, "lower bound {lb} > optimum {best}");
        prop_assert!(best <= c + 1e-9);
    }
}

pub(crate) fn permute(v: &mut Vec<usize>, k: usize, f: &mut dyn FnMut(&[usize])) {
    if k == v.len() {
        f(v);
        return;
    }
    for i in k..v.len() {
        v.swap(k, i);
        permute(v, k + 1, f);
        v.swap(k, i);
    }
}

#[test]
fn realistic_grid_orders_well_below_raster() {
    let inst = simulated();
    let text = format!(
        "{}[plan.calibration]\ndark_every_points = 150\nreference_every_s = 900.0\n",
        iso_grid(10.0, 30.0, 80.0)
    );
    let plan = build(&text, &inst, ISO).expect("plan");
    let sched = schedule::schedule(&plan, &TimeModel::new(&inst), None);
    let (o, r) = (&sched.breakdown, &sched.raster);
    // With the vendor's wheel timing (1 s a position) one tour per band is quicker than changing the wheel at
    // every geometry: the arms then walk the ordered tour once per band, where raster visits each geometry
    // once. The ordering is judged per tour.
    let tours = match sched.mode {
        BandMode::PerBand => plan.bands_nm.len() as f64,
        _ => 1.0,
    };
    let motion_ratio = (o.motion_s + o.settle_s) / tours / (r.motion_s + r.settle_s);
    let total_ratio = o.total_s() / r.total_s();
    println!(
        "{} points: ordered {:.0} s, raster {:.0} s, lower bound {:.0} s; motion+settle ratio per tour {motion_ratio:.3}, total ratio {total_ratio:.3}, mode {:?}",
        plan.kept(),
        o.total_s(),
        r.total_s(),
        sched.lower_bound_s,
        sched.mode
    );
    assert!(
        motion_ratio <= 0.6,
        "ordered/raster motion per tour {motion_ratio}"
    );
    assert!(total_ratio <= 0.6, "ordered/raster total {total_ratio}");
    assert!(sched.lower_bound_s <= o.total_s());
    check_schedule(&inst, &plan, &sched).expect("valid schedule");
}

#[test]
fn explicit_points_keep_their_geometry_on_an_anisotropic_sample() {
    let inst = simulated();
    let text = "[plan]\nbands_nm = [550.0]\n[plan.grid]\nkind = \"points\"\npoints = [[30.0, 10.0, 45.0, 100.0], [45.0, 100.0, 30.0, 10.0], [0.0, 0.0, 0.0, 0.0]]\n";
    let p = build(text, &inst, ANISO).expect("plan");
    // The second is the reciprocal of the first; the third is retro-reflection at the pole.
    assert_eq!(p.geometries.len(), 1);
    assert_eq!(p.skipped.get(&Reason::Reciprocity), Some(&1));
    assert_eq!(p.skipped.get(&Reason::RetroBlock), Some(&1));
    let g = p.geometries[0].requested;
    assert_eq!(g, Geometry::new(30.0, 10.0, 45.0, 100.0));
    let sched = schedule::schedule(&p, &TimeModel::new(&inst), None);
    let step = sched.measure_steps().next().expect("one step");
    let got = step.geometry.expect("geometry");
    assert!(got.max_direction_angle_deg(&g) < 1e-9);
}

/// A campaign with no calibration cadence still opens with darks and the normalisation readings (the engine
/// takes them on every start) and closes with darks (the values are net of the dark interpolated between the
/// darks around them): both are steps of the schedule, so their time is predicted. Without a blank on the wheel
/// there is no dark to take, at either end.
#[test]
fn a_schedule_without_a_cadence_opens_with_darks_and_normalisation_and_closes_with_darks() {
    let inst = simulated();
    let plan = build(&iso_grid(30.0, 60.0, 60.0), &inst, ISO).expect("plan");
    assert!(!plan.calibration.darks() && !plan.calibration.references());
    let sched = schedule::schedule(&plan, &TimeModel::new(&inst), None);
    let kinds: Vec<StepKind> = sched.steps.iter().map(|s| s.kind).collect();
    let first_measure = kinds
        .iter()
        .position(|k| *k == StepKind::Measure)
        .expect("measure steps");
    let last_measure = kinds
        .iter()
        .rposition(|k| *k == StepKind::Measure)
        .expect("measure steps");
    assert_eq!(kinds[0], StepKind::Dark, "{kinds:?}");
    assert!(
        kinds[1..first_measure].iter().all(|k| *k == StepKind::Reference),
        "{kinds:?}"
    );
    assert_eq!(first_measure, 1 + plan.bands_nm.len(), "{kinds:?}");
    assert_eq!(&kinds[last_measure + 1..], &[StepKind::Dark], "{kinds:?}");
    assert!(sched.breakdown.calibration_s > 0.0);
    // The same instrument without a blank: the normalisation readings only.
    let mut no_blank = inst.clone();
    if let Some(w) = no_blank.filter_wheel.as_mut() {
        w.positions.retain(|p| !p.blank);
    }
    let plan = build(&iso_grid(30.0, 60.0, 60.0), &no_blank, ISO).expect("plan");
    let sched = schedule::schedule(&plan, &TimeModel::new(&no_blank), None);
    assert!(sched.steps.iter().all(|s| s.kind != StepKind::Dark));
    assert_eq!(sched.steps[0].kind, StepKind::Reference);
}
