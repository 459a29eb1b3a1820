//! CI-sized disk soak: the store made full twice during one campaign; each time the campaign pauses with the
//! store's reason, nothing moves, nothing committed changes, and after room comes back every point is stored once.

use gonio_engine::store::{CampaignState, STORE_FILE, Store};
use gonio_soak::disk_soak::{DiskSoakConfig, run_disk_soak};
use gonio_soak::setup::SoakInstrument;
use gonio_soak::truth_check::Tolerance;

#[test]
fn a_store_full_twice_pauses_twice_and_loses_nothing() {
    store_full_twice_on(SoakInstrument::simulated());
}

/// The same on the imperfect instrument (issue 16): its errors change no guarantee.
#[test]
fn on_the_realistic_instrument_a_full_store_loses_nothing() {
    store_full_twice_on(SoakInstrument::realistic());
}

fn store_full_twice_on(instrument: SoakInstrument) {
    let tol = Tolerance::of(&instrument.file().expect("valid"));
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let cfg = DiskSoakConfig {
        points: 60,
        fills: 2,
        seed: 12,
        data_dir: data.clone(),
        hold_s: 60.0,
        instrument,
    };
    let r = run_disk_soak(&cfg).expect("the soak runs");
    for f in &r.fills {
        eprintln!("{f:?}");
    }
    assert_eq!(r.violations(), Vec::<String>::new());
    assert_eq!(r.data_lost(), 0);
    assert_eq!(r.fills.len(), 2);
    for f in &r.fills {
        assert_eq!(f.ended, CampaignState::Paused);
        let reason = f.reason.as_deref().expect("a reason");
        assert!(
            reason.contains(&format!("<data>/{STORE_FILE}")) && reason.contains("database or disk is full"),
            "{reason}"
        );
        assert!(f.record_agrees);
        assert_eq!(f.moves_while_paused, 0);
        assert_eq!(f.pose_change_deg, 0.0);
        // Held 60 s: the difference of two clock readings in seconds, exact to its last bits only.
        assert!(f.paused_s >= 60.0 - 1e-9, "{}", f.paused_s);
        assert!(f.rows_at_pause >= f.rows_at_cap && f.rows_at_pause < 60, "{f:?}");
        assert_eq!(f.changed_at_pause, None);
    }
    assert!(
        r.fills[0].rows_at_pause < r.fills[1].rows_at_cap,
        "resumed between the fills"
    );

    // The store, read back on its own: every planned point exactly once, the campaign completed.
    let store = Store::open(&data).expect("store");
    let campaign = store.campaigns().expect("campaigns").pop().expect("one campaign");
    assert_eq!(campaign.state, CampaignState::Completed);
    assert_eq!(campaign.total_points, 60);
    let points = store.points(campaign.id).expect("points");
    assert_eq!(points.len(), 60);
    for (i, p) in points.iter().enumerate() {
        assert_eq!(p.index, i as u64);
        let (f, u, t) = (
            p.brdf_sr.expect("a value"),
            p.brdf_u_sr.expect("an uncertainty"),
            p.truth_aperture_sr.expect("the ground truth"),
        );
        // On the imperfect instrument, the point's own attribution says how far the instrument's errors take it.
        let allowance = match &p.truth_effects_json {
            Some(json) if tol.imperfect => {
                let nominal = [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg];
                let (a, pose_deg) =
                    gonio_soak::truth_check::point_allowance(json, nominal, &tol, r.instrument_s)
                        .expect("a readable attribution");
                assert!(pose_deg <= tol.pose_deg, "point {i}: {pose_deg} deg off");
                a
            }
            None if tol.imperfect => panic!("point {i}: no attribution on the imperfect instrument"),
            _ => 0.0,
        };
        assert!(
            (f - t).abs() <= 5.0 * u + 1e-6 * t + allowance * t,
            "point {i}: {f} vs {t} (u {u}, allowance {allowance})"
        );
    }
}
