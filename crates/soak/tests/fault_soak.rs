//! CI-sized fault soak: the code path of `gonio-soak` at higher fault rates, so that every kind of fault shows up
//! within a few hundred points.

use gonio_daemon::store::{CampaignState, Store};
use gonio_soak::fault_soak::{FaultSoakConfig, run_fault_soak};

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
    // with it or carrying its reason.
    let store = Store::open(&data).expect("store");
    let campaign = store.campaigns().expect("campaigns").pop().expect("one campaign");
    assert_eq!(campaign.state, CampaignState::Completed);
    assert_eq!(campaign.total_points, 240);
    let points = store.points(campaign.id).expect("points");
    assert_eq!(points.len(), 240);
    for (i, p) in points.iter().enumerate() {
        assert_eq!(p.index, i as u64);
        match (p.brdf_sr, p.brdf_u_sr, p.truth_aperture_sr) {
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
