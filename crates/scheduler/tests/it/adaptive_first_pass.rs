//! `first_pass_theta_i_deg` of `[plan.adaptive]`: a hostile list is refused at once with a clear message, and
//! repeated incidences or reciprocal geometries give no repeated point (checked by brute force here).

use crate::common;

use common::simulated;
use gonio_instrument::Instrument;
use gonio_scheduler::adaptive::{Adaptive, MAX_FIRST_PASS_INCIDENCES, Measured};
use gonio_scheduler::kinematics::Geometry;
use gonio_scheduler::plan::AdaptiveSpec;
use gonio_scheduler::plan::{BuildContext, PlanError, SampleTraits};

fn ctx(inst: &Instrument) -> BuildContext<'_> {
    BuildContext {
        instrument: inst,
        traits: SampleTraits {
            isotropic: true,
            spectrally_flat: false,
        },
        sample_radius_mm: None,
        start: None,
    }
}

/// A large budget, so that the first pass is not thinned to a quarter of it.
fn spec(incidences: Option<toml::Value>) -> AdaptiveSpec {
    AdaptiveSpec {
        budget_points: 100_000,
        budget_s: None,
        batch_points: 20,
        target_error: 0.0,
        first_pass_step_deg: 10.0,
        first_pass_theta_i_deg: incidences,
        resolution_deg: 10.0,
        first_pass_sweeps: None,
    }
}

fn list(angles: &[f64]) -> toml::Value {
    toml::Value::Array(angles.iter().map(|a| toml::Value::Float(*a)).collect())
}

fn build(incidences: Option<toml::Value>) -> Result<Adaptive, PlanError> {
    let inst = simulated();
    Adaptive::new(&spec(incidences), &ctx(&inst))
}

fn message(r: Result<Adaptive, PlanError>) -> String {
    match r {
        Ok(_) => panic!("accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_huge_incidence_list_is_refused_with_its_size() {
    let huge = list(&vec![30.0; 1_000_000]);
    let m = message(build(Some(huge)));
    assert!(
        m.contains("first_pass_theta_i_deg") && m.contains("1000000 incidences") && m.contains("at most 181"),
        "{m}"
    );
    // One past the limit is refused too; the limit itself is accepted.
    let over: Vec<f64> = (0..=MAX_FIRST_PASS_INCIDENCES).map(|k| k as f64 * 0.25).collect();
    assert!(message(build(Some(list(&over)))).contains("at most 181"));
    let at: Vec<f64> = (0..MAX_FIRST_PASS_INCIDENCES).map(|k| k as f64 * 0.5).collect();
    let a = build(Some(list(&at))).expect("181 incidences, 0 to 90 deg");
    assert!(!a.first_pass().is_empty());
}

#[test]
fn a_range_with_too_many_incidences_is_refused() {
    let range: toml::Value = toml::from_str::<toml::Table>("r = { from = 0.0, to = 90.0, step = 0.1 }")
        .expect("toml")
        .remove("r")
        .expect("r");
    let m = message(build(Some(range)));
    assert!(
        m.contains("range gives 901 incidences") && m.contains("at most 181"),
        "{m}"
    );
}

#[test]
fn a_non_finite_incidence_is_refused() {
    for bad in [f64::NAN, f64::INFINITY] {
        let m = message(build(Some(list(&[30.0, bad]))));
        assert!(m.contains("finite"), "{m}");
    }
}

/// The canonical form of an isotropic geometry (reciprocity: theta_i and theta_o in either order), to the
/// nanodegree: two geometries with the same key are one measurement.
fn key(g: &Geometry) -> (i64, i64, i64) {
    let (a, b) = (g.theta_i_deg.min(g.theta_o_deg), g.theta_i_deg.max(g.theta_o_deg));
    let dp = (g.phi_o_deg - g.phi_i_deg).rem_euclid(360.0);
    let q = |x: f64| (x * 1e9).round() as i64;
    (q(a), q(b), q(dp))
}

#[test]
fn repeated_incidences_and_reciprocal_geometries_give_no_repeated_point() {
    let plain = build(Some(list(&[30.0, 0.0, 60.0]))).expect("valid").first_pass();
    // The same angles repeated, one of them off by rounding (0.1 + 0.2 - 0.3 is not 0 in floating point).
    let repeated = build(Some(list(&[30.0, 0.0, 30.0, 60.0, 0.0, 0.1 + 0.2 - 0.3, 60.0])))
        .expect("valid")
        .first_pass();
    assert_eq!(repeated, plain, "repeats change nothing, order kept");
    // Brute force: no two points are the same measurement.
    for (i, a) in plain.iter().enumerate() {
        for b in &plain[i + 1..] {
            assert_ne!(key(a), key(b), "{a:?} and {b:?}");
        }
    }
    // Reciprocity merged the sweeps: (30 -> 60) and (60 -> 30) in the plane are measured once, at its first
    // occurrence (the 30-degree sweep comes first).
    let in_plane = |ti: f64, to: f64| Geometry::new(ti, 0.0, to, 180.0);
    assert!(plain.iter().any(|g| key(g) == key(&in_plane(30.0, 60.0))));
    assert!(plain.contains(&in_plane(30.0, 60.0)));
    assert!(!plain.contains(&in_plane(60.0, 30.0)));
    // And the order of the incidences is the order given.
    let first_ti = |p: &[Geometry]| p.first().map(|g| g.theta_i_deg);
    assert_eq!(first_ti(&plain), Some(30.0));
    let reordered = build(Some(list(&[0.0, 30.0, 60.0]))).expect("valid").first_pass();
    assert_eq!(first_ti(&reordered), Some(0.0));
    assert_eq!(reordered.len(), plain.len());
}

#[test]
fn a_first_pass_of_sweeps_is_one_detector_sweep_per_incidence_from_grazing_to_grazing() {
    use gonio_scheduler::plan::{FirstPassSweeps, SweptArm};
    let inst = simulated();
    let points = Adaptive::new(&spec(Some(list(&[0.0, 45.0]))), &ctx(&inst)).expect("planner");
    assert!(
        points.first_pass_sweeps().is_none(),
        "a first pass of points by default"
    );
    let swept = AdaptiveSpec {
        first_pass_sweeps: Some(FirstPassSweeps {
            speed_deg_s: 5.0,
            averaging: 3,
        }),
        ..spec(Some(list(&[0.0, 45.0])))
    };
    let planner = Adaptive::new(&swept, &ctx(&inst)).expect("planner");
    let sweeps = planner.first_pass_sweeps().expect("sweeps");
    assert_eq!(sweeps.len(), 1);
    let s = &sweeps[0];
    assert_eq!(s.arm, SweptArm::Detector);
    assert_eq!(s.theta_i_deg, list(&[0.0, 45.0]));
    let grazing = inst.safety.grazing_limit_deg;
    let arc = s.theta_o_deg.as_table().expect("an arc");
    assert_eq!(arc["from"].as_float(), Some(-grazing));
    assert_eq!(arc["to"].as_float(), Some(grazing));
    assert_eq!((s.speed_deg_s, s.averaging), (5.0, 3));
    // A bad speed or averaging is named where the campaign asked for it.
    for (speed, averaging) in [(0.0, 1), (f64::NAN, 1), (5.0, 0)] {
        let bad = AdaptiveSpec {
            first_pass_sweeps: Some(FirstPassSweeps {
                speed_deg_s: speed,
                averaging,
            }),
            ..spec(None)
        };
        match Adaptive::new(&bad, &ctx(&inst)) {
            Err(PlanError::Invalid { key, .. }) => assert_eq!(key, "first_pass_sweeps"),
            other => panic!("{speed} deg/s, averaging {averaging}: {other:?}"),
        }
    }
}

#[test]
fn sweep_readings_count_in_bins_and_not_against_the_budget() {
    let inst = simulated();
    let s = AdaptiveSpec {
        budget_points: 30,
        ..spec(Some(list(&[30.0])))
    };
    let planner = Adaptive::new(&s, &ctx(&inst)).expect("planner");
    // Bins half the candidate grid's step wide (10 deg here), in the canonical frame (theta_i <= theta_o).
    assert_eq!(planner.sweep_bin_deg(), 5.0);
    let b = planner.sweep_bin(&Geometry::new(30.0, 90.0, 12.3, 270.0));
    assert_eq!(
        (b.theta_i_deg, b.phi_i_deg, b.theta_o_deg, b.phi_o_deg),
        (10.0, 0.0, 30.0, 180.0)
    );
    // A line of swept values along the arc, one a bin: with no point measured, the batch is full, and none of it
    // lies on the swept arc.
    let swept: Vec<Measured> = (-16..=16)
        .map(|k| {
            let g = planner.sweep_bin(&Geometry::new(
                30.0,
                0.0,
                f64::from(k).abs() * 5.0,
                if k < 0 { 0.0 } else { 180.0 },
            ));
            Measured {
                geometry: g,
                value: 0.1 + (-(f64::from(k) * 5.0 - 30.0).powi(2) / 50.0).exp(),
            }
        })
        .collect();
    let batch = planner.next_batch_counting(&swept, 0, 0.0);
    assert_eq!(batch.done, None);
    assert_eq!(batch.geometries.len(), 20);
    let on_arc = |g: &Geometry| {
        let dphi = g.delta_phi_deg().rem_euclid(360.0);
        (dphi < 1e-6 || (dphi - 180.0).abs() < 1e-6) && (g.theta_i_deg == 30.0 || g.theta_o_deg == 30.0)
    };
    assert!(!batch.geometries.iter().any(on_arc), "{:?}", batch.geometries);
    // Counted as points, the same values exhaust the budget.
    assert_eq!(
        planner.next_batch(&swept, 0.0).done,
        Some(gonio_scheduler::adaptive::StopReason::PointBudget)
    );
    // Ten points measured: the batch takes what is left of the budget up to its size.
    assert_eq!(planner.next_batch_counting(&swept, 10, 0.0).geometries.len(), 20);
    assert_eq!(planner.next_batch_counting(&swept, 25, 0.0).geometries.len(), 5);
}
