//! Unit tests of the sweep tables: a segment committed whole with its readings, never twice; the completion
//! kept beside the readings; the migration from version 10.

use gonio_results::sweeps::SweepReading;
use rusqlite::Connection;

use super::*;
use crate::store::tests::store_with_one_point;
use crate::store::{STORE_FILE, Store};

fn sweep_reading(segment: u32, k: u32) -> SweepReading {
    SweepReading {
        segment,
        k,
        band_nm: 550.0,
        t_s: 10.0 + f64::from(k) * 0.004,
        integration_s: 0.003,
        theta_i_deg: 30.0,
        phi_i_deg: 0.0,
        theta_o_deg: 0.1 / 3.0 + f64::from(k) * 0.016,
        phi_o_deg: 180.0,
        arc_from_deg: f64::from(k) * 0.016,
        arc_to_deg: f64::from(k) * 0.016 + 0.012,
        signal_w: (k % 5 != 4).then_some(1.234_567_890_123e-7),
        incident_w: Some(1e-3 + f64::from(k) * 1e-9),
        brdf_sr: (k % 5 != 4).then_some(0.1 / 3.0),
        brdf_u_sr: Some(1e-5),
        brdf_aperture_sr: None,
        flags: if k % 5 == 4 {
            vec!["failed: timeout".into()]
        } else {
            vec![]
        },
        truth_point_sr: Some(std::f64::consts::FRAC_1_PI),
    }
}

#[test]
fn sweep_segments_commit_whole_round_trip_and_are_never_stored_twice() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let mut store = Store::open(dir.path()).expect("open");
    assert_eq!(store.sweep_segments_done(id).expect("done"), 0);
    for segment in 0..2 {
        let readings: Vec<_> = (0..1000).map(|k| sweep_reading(segment, k)).collect();
        let record = SweepSegmentRecord {
            segment,
            band_nm: Some(550.0),
            started_s: 10.0,
            ended_s: 14.0,
            readings: 1000,
            timing_u_s: Some(0.002),
        };
        store
            .commit_sweep_segment(id, &record, &readings)
            .expect("commit");
    }
    assert_eq!(store.sweep_segments_done(id).expect("done"), 2);
    // A segment committed again is refused, and nothing of the second attempt is left behind.
    let again = SweepSegmentRecord {
        segment: 1,
        band_nm: Some(550.0),
        started_s: 0.0,
        ended_s: 1.0,
        readings: 1,
        timing_u_s: None,
    };
    store
        .commit_sweep_segment(id, &again, &[sweep_reading(1, 5000)])
        .expect_err("already committed");
    drop(store);
    let store = Store::open(dir.path()).expect("reopen");
    let readings = store.sweep_readings(id).expect("readings");
    assert_eq!(readings.len(), 2000);
    assert_eq!(readings[1003], sweep_reading(1, 3), "bit-exact round trip");
    assert_eq!(readings[4].signal_w, None);
    assert_eq!(store.sweep_segments(id).expect("segments").len(), 2);
    assert_eq!(store.points(id).expect("points").len(), 1, "the points are apart");
    // A completion is kept beside the readings: read back in their place, the committed value as the aperture
    // average; completing again replaces it, never compounds it.
    let mut store = store;
    for factor in [1.01, 1.02] {
        let completion = SweepCompletion {
            segment: 1,
            k: 3,
            brdf_sr: Some(0.1 / 3.0 * factor),
            brdf_u_sr: Some(2e-5),
            flags: Some(vec!["narrow-lobe".into()]),
        };
        store
            .update_sweep_completions(id, &[completion])
            .expect("complete");
        let r = &store.sweep_readings(id).expect("readings")[1003];
        assert_eq!(r.brdf_sr, Some(0.1 / 3.0 * factor));
        assert_eq!(r.brdf_aperture_sr, Some(0.1 / 3.0));
        assert_eq!(
            (r.brdf_u_sr, r.flags.clone()),
            (Some(2e-5), vec!["narrow-lobe".to_string()])
        );
    }
    assert_eq!(
        store.sweep_readings(id).expect("readings")[1002],
        sweep_reading(1, 2),
        "the others untouched"
    );
}

#[test]
fn a_version_10_store_gains_the_sweep_tables() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 10;")
        .expect("back to version 10");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    assert_eq!(store.sweep_segments_done(id).expect("done"), 0);
    let record = SweepSegmentRecord {
        segment: 0,
        band_nm: None,
        started_s: 0.0,
        ended_s: 1.0,
        readings: 1,
        timing_u_s: None,
    };
    store
        .commit_sweep_segment(id, &record, &[sweep_reading(0, 0)])
        .expect("commit");
    assert_eq!(store.sweep_readings(id).expect("readings").len(), 1);
}

#[test]
fn a_version_11_store_keeps_its_segments_and_gains_their_timing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let mut store = Store::open(dir.path()).expect("open");
    let record = |segment, timing_u_s| SweepSegmentRecord {
        segment,
        band_nm: Some(550.0),
        started_s: 0.0,
        ended_s: 1.0,
        readings: 1,
        timing_u_s,
    };
    store
        .commit_sweep_segment(id, &record(0, Some(0.003)), &[sweep_reading(0, 0)])
        .expect("commit");
    assert_eq!(
        store.sweep_segments(id).expect("segments"),
        vec![record(0, Some(0.003))]
    );
    drop(store);
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("ALTER TABLE sweep_segments DROP COLUMN timing_u_s; PRAGMA user_version = 11;")
        .expect("back to version 11");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    // The segment stored before is kept, without the timing it did not record; a new one records it.
    assert_eq!(store.sweep_segments(id).expect("segments"), vec![record(0, None)]);
    store
        .commit_sweep_segment(id, &record(1, Some(0.001)), &[sweep_reading(1, 0)])
        .expect("commit");
    assert_eq!(
        store.sweep_segments(id).expect("segments"),
        vec![record(0, None), record(1, Some(0.001))]
    );
}
