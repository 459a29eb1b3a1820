//! CI-sized fault soak: the code path of `gonio-soak` at higher fault rates, so that every kind of fault shows up
//! within a few hundred points.

use gonio_engine::store::{CampaignState, Store};
use gonio_soak::fault_soak::{FaultSoakConfig, run_fault_soak};
use gonio_soak::setup::SoakInstrument;

#[test]
fn a_faulty_instrument_gives_valid_or_failed_points_never_wrong_ones() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let cfg = FaultSoakConfig::stressed(240, 21, data.clone());
    let r = run_fault_soak(&cfg).expect("the soak runs");
    eprintln!(
        "injected {:?}; points valid {} failed {:?} flagged {:?}; engine events {:?}; wall {:.1} s",
        r.injected,
        r.committed.points.valid,
        r.committed.points.failed,
        r.committed.points.flagged,
        r.events.faults,
        r.wall_s
    );
    assert_eq!(r.violations(), Vec::<String>::new());

    // Every kind of fault was injected, and the log carries each one.
    let c = r.injected;
    assert!(
        c.garbled > 0 && c.dropped > 0 && c.delayed > 0 && c.stalls > 0 && c.outages > 0,
        "{c:?}"
    );
    assert_eq!(r.log.injected.get("move will stall").copied(), Some(c.stalls));
    assert_eq!(r.log.injected.get("reply dropped").copied(), Some(c.dropped));

    // The store, read back on its own: one row per planned point, each valid against the ground truth stored
    // with it (at the geometry its value stands for) or carrying its reason.
    let store = Store::open(&data).expect("store");
    let campaign = store.campaigns().expect("campaigns").pop().expect("one campaign");
    assert_eq!(campaign.state, CampaignState::Completed);
    assert_eq!(campaign.total_points, 240);
    let points = store.points(campaign.id).expect("points");
    assert_eq!(points.len(), 240);
    for (i, p) in points.iter().enumerate() {
        assert_eq!(p.index, i as u64);
        // A value the completion took from the aperture's average to the nominal geometry is held to the BRDF
        // there; one it left alone, to the aperture's average.
        let truth = if p.brdf_aperture_sr.is_some() {
            p.truth_point_sr
        } else {
            p.truth_aperture_sr
        };
        match (p.brdf_sr, p.brdf_u_sr, truth) {
            (Some(f), Some(u), Some(t)) => {
                assert!(p.flags.is_empty(), "point {i}: {:?}", p.flags);
                assert!(
                    (f - t).abs() <= 5.0 * u + 1e-6 * t,
                    "point {i}: {f} vs truth {t} (u {u})"
                );
            }
            (None, _, _) => assert!(
                p.flags.iter().any(|f| !f.is_empty()),
                "point {i} has no value and no reason"
            ),
            other => panic!("point {i}: {other:?}"),
        }
    }
}

/// The same faults on the imperfect instrument (issue 16): nothing lost, nothing stored twice, the campaign
/// completed, and no value further from its truth than its noise and the imperfections' attribution explain
/// (`gonio_soak::truth_check`).
#[test]
fn on_the_realistic_instrument_faults_lose_nothing_and_values_stay_within_the_attribution() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let mut cfg = FaultSoakConfig::stressed(240, 21, data.clone());
    cfg.instrument = SoakInstrument::realistic();
    let r = run_fault_soak(&cfg).expect("the soak runs");
    let p = &r.committed.points;
    eprintln!(
        "injected {:?}; points valid {} failed {:?} flagged {:?}; largest error {:.2} % ({:.1} u), allowance median \
         {:.2} % max {:.2} %, largest pose error {:.3} deg",
        r.injected,
        p.valid,
        p.failed,
        p.flagged,
        p.max_error_rel * 100.0,
        p.max_error_in_u,
        p.allowance_median_rel * 100.0,
        p.allowance_max_rel * 100.0,
        p.max_pose_deg
    );
    assert_eq!(r.violations(), Vec::<String>::new());
    let c = r.injected;
    assert!(
        c.garbled > 0 && c.dropped > 0 && c.stalls > 0 && c.outages > 0,
        "{c:?}"
    );
    // The imperfections were on: the points carry their attribution, and the values really are off their truth
    // by more than the noise somewhere (else this test would not exercise the allowance).
    assert!(p.valid > 200, "{}", p.valid);
    assert!(p.max_error_in_noise > 5.0, "{}", p.max_error_in_noise);
    assert!(p.max_pose_deg > 0.0 && p.allowance_median_rel > 0.0);

    let store = Store::open(&data).expect("store");
    let campaign = store.campaigns().expect("campaigns").pop().expect("one campaign");
    assert_eq!(campaign.state, CampaignState::Completed);
    let points = store.points(campaign.id).expect("points");
    assert_eq!(points.len(), 240);
    for (i, p) in points.iter().enumerate() {
        assert_eq!(p.index, i as u64);
        assert!(p.brdf_sr.is_some() || !p.flags.is_empty(), "point {i}");
        if p.brdf_sr.is_some() {
            assert!(p.truth_effects_json.is_some(), "point {i}: no attribution");
        }
    }
}
