//! Unit tests of the store: schema and migration, durability levels, campaigns, points, calibrations, and disk trouble.

use super::*;

fn new_campaign(total: u64) -> NewCampaign {
    NewCampaign {
        name: "gold test".into(),
        campaign_toml: "[campaign]\nid = \"x\"\n".into(),
        instrument_toml: "[instrument]\n".into(),
        total_points: total,
        dry_run: true,
        software_version: "0.1.0".into(),
        predicted_instrument_s: Some(12.5),
        alignment_toml: None,
        calibration_id: None,
    }
}

fn point(index: u64) -> PointRecord {
    PointRecord {
        index,
        band_nm: 550.0,
        theta_i_deg: 30.0,
        phi_i_deg: 0.0,
        theta_o_deg: 30.0 + index as f64 * 0.1,
        phi_o_deg: 180.0,
        signal_w: 1.234_567_890_123e-7 * (index as f64 + 1.0),
        dark_w: 1e-11,
        incident_w: 1e-3,
        brdf_sr: Some(0.1 / 3.0),
        brdf_u_sr: Some(1e-5),
        flags: if index % 2 == 0 {
            vec![]
        } else {
            vec!["saturated".into(), "overfilled".into()]
        },
        t_s: index as f64 * 0.5,
        readback_deg: vec![("light".into(), 30.000_123), ("detector".into(), -0.1 / 3.0)],
        truth_point_sr: Some(std::f64::consts::FRAC_1_PI),
        truth_aperture_sr: None,
        truth_effects_json: None,
        brdf_aperture_sr: None,
        budget: Default::default(),
    }
}

#[test]
fn points_round_trip_bit_exactly_and_resume_index_follows() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(5)).expect("create");
    assert_eq!(store.next_index(id).expect("next"), 0);
    for i in 0..3 {
        store.commit_point(id, &point(i)).expect("commit");
    }
    assert_eq!(store.next_index(id).expect("next"), 3);
    drop(store);

    let store = Store::open(dir.path()).expect("reopen");
    let points = store.points(id).expect("points");
    assert_eq!(points, (0..3).map(point).collect::<Vec<_>>());
    let c = store.campaign(id).expect("campaign");
    assert_eq!(
        (c.points_done, c.total_points, c.state),
        (3, 5, CampaignState::Queued)
    );
}

#[test]
fn point_values_are_the_committed_geometries_and_brdfs_of_a_range() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(6)).expect("create");
    for i in 0..4 {
        store.commit_point(id, &point(i)).expect("commit");
    }
    store.commit_point(id, &failed_point(4)).expect("commit");
    let values = store.point_values(id, 1, 5).expect("values");
    let full = store.points_from(id, 1).expect("points");
    assert_eq!(values.len(), 4);
    for (v, p) in values.iter().zip(&full) {
        assert_eq!(v.index, p.index);
        assert_eq!(
            (v.theta_i_deg, v.phi_i_deg, v.theta_o_deg, v.phi_o_deg, v.brdf_sr),
            (p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg, p.brdf_sr)
        );
    }
    assert_eq!(values.last().map(|v| v.brdf_sr), Some(None));
    assert!(store.point_values(id, 5, 9).expect("none yet").is_empty());
}

fn failed_point(index: u64) -> PointRecord {
    PointRecord {
        signal_w: f64::NAN,
        brdf_sr: None,
        brdf_u_sr: None,
        flags: vec!["failed: arms/1: motion fault: DISABLE from MOVING".into()],
        ..point(index)
    }
}

#[test]
fn a_failed_point_without_a_reading_is_committed_and_read_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(2)).expect("create");
    store
        .commit_point(id, &failed_point(0))
        .expect("a failed point commits");
    let back = store.points(id).expect("points");
    assert_eq!(back.len(), 1);
    assert!(back[0].signal_w.is_nan());
    assert_eq!(back[0].flags, failed_point(0).flags);
    assert_eq!(back[0].brdf_sr, None);
    assert_eq!(store.next_index(id).expect("next"), 1);
}

/// A store in `dir` with one campaign of 3 points and its point 0 committed (closed again).
pub(super) fn store_with_one_point(dir: &std::path::Path) -> CampaignId {
    let mut store = Store::open(dir).expect("open");
    let id = store.create_campaign(&new_campaign(3)).expect("create");
    store.commit_point(id, &point(0)).expect("commit");
    id
}

#[test]
fn a_version_1_store_is_migrated_keeping_its_points() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    // Turn the file back into version 1 (readings NOT NULL), as stores written before the change are.
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    let v1_table = conn
        .query_row("SELECT sql FROM sqlite_master WHERE name = 'points'", [], |r| {
            r.get::<_, String>(0)
        })
        .expect("schema")
        .replace("signal_w REAL,", "signal_w REAL NOT NULL,")
        .replace("dark_w REAL,", "dark_w REAL NOT NULL,")
        .replace("incident_w REAL,", "incident_w REAL NOT NULL,")
        .replace("truth_effects_json TEXT,", "")
        .replace("brdf_aperture_sr REAL,", "")
        .replace("budget TEXT,", "")
        .replace("CREATE TABLE points", "CREATE TABLE points_v1");
    assert!(v1_table.contains("signal_w REAL NOT NULL"), "{v1_table}");
    assert!(!v1_table.contains("truth_effects_json"), "{v1_table}");
    conn.execute_batch(&format!(
        "{v1_table}; INSERT INTO points_v1 SELECT campaign_id, idx, band_nm, theta_i_deg, phi_i_deg, theta_o_deg,
             phi_o_deg, signal_w, dark_w, incident_w, brdf_sr, brdf_u_sr, flags, t_s, readback_json,
             truth_point_sr, truth_aperture_sr FROM points; DROP TABLE points;
             ALTER TABLE points_v1 RENAME TO points;
             ALTER TABLE campaigns DROP COLUMN predicted_instrument_s; ALTER TABLE campaigns DROP COLUMN alignment_toml; ALTER TABLE campaigns DROP COLUMN calibration_id; DROP TABLE instrument_calibrations; DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 1;"
    ))
    .expect("downgrade");
    drop(conn);

    let mut store = Store::open(dir.path()).expect("migrates");
    assert_eq!(store.points(id).expect("points"), vec![point(0)]);
    store
        .commit_point(id, &failed_point(1))
        .expect("a failed point commits after migration");
    assert_eq!(store.next_index(id).expect("next"), 2);
}

#[test]
fn a_version_2_store_gains_the_attribution_column() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    // Version 2: no truth_effects_json column.
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch(
        "ALTER TABLE points DROP COLUMN truth_effects_json; ALTER TABLE points DROP COLUMN brdf_aperture_sr; ALTER TABLE points DROP COLUMN budget; 
         ALTER TABLE campaigns DROP COLUMN predicted_instrument_s; ALTER TABLE campaigns DROP COLUMN alignment_toml; ALTER TABLE campaigns DROP COLUMN calibration_id; DROP TABLE instrument_calibrations; DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 2;",
    )
    .expect("downgrade");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    assert_eq!(store.points(id).expect("points"), vec![point(0)]);
    let mut attributed = point(1);
    attributed.truth_effects_json = Some("{\"relative\":{\"meter\":0.001}}".into());
    store.commit_point(id, &attributed).expect("commit");
    assert_eq!(store.points(id).expect("points")[1], attributed);
}

#[test]
fn a_version_3_store_gains_the_prediction_and_keeps_its_campaigns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    assert_eq!(
        Store::open(dir.path())
            .expect("open")
            .campaign(id)
            .expect("campaign")
            .predicted_instrument_s,
        Some(12.5),
        "the prediction is stored with the campaign"
    );
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("ALTER TABLE points DROP COLUMN brdf_aperture_sr; ALTER TABLE points DROP COLUMN budget; ALTER TABLE campaigns DROP COLUMN predicted_instrument_s; ALTER TABLE campaigns DROP COLUMN alignment_toml; ALTER TABLE campaigns DROP COLUMN calibration_id; DROP TABLE instrument_calibrations; DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 3;")
        .expect("downgrade");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    let old = store.campaign(id).expect("campaign");
    assert_eq!(
        (old.predicted_instrument_s, old.points_done),
        (None, 1),
        "an older campaign has no prediction"
    );
    let new = store.create_campaign(&new_campaign(2)).expect("create");
    assert_eq!(
        store.campaign(new).expect("campaign").predicted_instrument_s,
        Some(12.5)
    );
}

#[test]
fn a_version_4_store_gains_the_alignment_column_and_keeps_its_campaigns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = {
        let mut store = Store::open(dir.path()).expect("open");
        let mut aligned = new_campaign(2);
        aligned.alignment_toml = Some("[calibration]\n".into());
        let a = store.create_campaign(&aligned).expect("create");
        assert_eq!(
            store.campaign(a).expect("campaign").alignment_toml.as_deref(),
            Some("[calibration]\n"),
            "the alignment is stored with the campaign"
        );
        store.create_campaign(&new_campaign(2)).expect("create")
    };
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("ALTER TABLE points DROP COLUMN brdf_aperture_sr; ALTER TABLE points DROP COLUMN budget; ALTER TABLE campaigns DROP COLUMN alignment_toml; ALTER TABLE campaigns DROP COLUMN calibration_id; DROP TABLE instrument_calibrations; DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 4;")
        .expect("downgrade");
    drop(conn);
    let store = Store::open(dir.path()).expect("migrates");
    let old = store.campaign(id).expect("campaign");
    assert_eq!((old.alignment_toml, old.total_points), (None, 2));
}

#[test]
fn a_version_6_store_gains_the_budget_columns_and_a_budget_round_trips() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("ALTER TABLE points DROP COLUMN brdf_aperture_sr; ALTER TABLE points DROP COLUMN budget; DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 6;")
        .expect("downgrade");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    assert_eq!(store.points(id).expect("points"), vec![point(0)]);
    let mut budgeted = point(1);
    budgeted.brdf_aperture_sr = Some(0.2995);
    budgeted.budget = gonio_results::budget::Budget::parse_compact(
        "signal-noise=0.00001;solid-angle@campaign=0.0003;range@range-2=0.00002",
    )
    .expect("budget");
    store.commit_point(id, &budgeted).expect("commit");
    assert_eq!(store.points(id).expect("points")[1], budgeted);
}

#[test]
fn completed_budgets_are_read_in_place_of_the_committed_ones_whose_rows_never_change() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let mut store = Store::open(dir.path()).expect("open");
    store.commit_point(id, &point(1)).expect("commit");
    let budget = gonio_results::budget::Budget::parse_compact("signal-noise=0.0003;band@band-550=0.0004")
        .expect("budget");
    // Index 7 is not stored: nothing happens to it, and nothing fails.
    let completion = |index: u64| crate::store::PointCompletion {
        index,
        budget: budget.clone(),
        brdf_sr: None,
        brdf_aperture_sr: None,
        flags: None,
    };
    store
        .update_completions(id, &[completion(1), completion(7)])
        .expect("update");
    let points = store.points(id).expect("points");
    assert_eq!(points.len(), 2);
    assert_eq!(points[0], point(0), "the other point is untouched");
    let mut expected = point(1);
    expected.budget = budget;
    expected.brdf_u_sr = Some(0.0005);
    assert_eq!(points[1].budget, expected.budget);
    assert!((points[1].brdf_u_sr.expect("u") - 0.0005).abs() < 1e-15);
    assert_eq!(points[1].brdf_sr, expected.brdf_sr, "the value is never touched");
    // The committed row itself is as it was committed.
    drop(store);
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    let (budget, u): (Option<String>, Option<f64>) = conn
        .query_row("SELECT budget, brdf_u_sr FROM points WHERE idx = 1", [], |r| {
            Ok((r.get(0)?, r.get(1)?))
        })
        .expect("the row");
    assert_eq!((budget, u), (None, point(1).brdf_u_sr));
}

#[test]
fn a_completion_corrects_values_and_flags_in_place_and_a_later_one_replaces_it_whole() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let mut store = Store::open(dir.path()).expect("open");
    store.commit_point(id, &point(1)).expect("commit");
    let budget =
        gonio_results::budget::Budget::parse_compact("signal-noise=0.0003;aperture=0.0001").expect("budget");
    let corrected = crate::store::PointCompletion {
        index: 0,
        budget: budget.clone(),
        brdf_sr: Some(0.034),
        brdf_aperture_sr: point(0).brdf_sr,
        flags: None,
    };
    let narrow = crate::store::PointCompletion {
        index: 1,
        budget: budget.clone(),
        brdf_sr: None,
        brdf_aperture_sr: point(1).brdf_sr,
        flags: Some(vec![
            "saturated".into(),
            "overfilled".into(),
            "narrow-lobe".into(),
        ]),
    };
    store
        .update_completions(id, &[corrected, narrow.clone()])
        .expect("complete");
    let points = store.points(id).expect("points");
    assert_eq!(points[0].brdf_sr, Some(0.034));
    assert_eq!(points[0].brdf_aperture_sr, point(0).brdf_sr);
    assert_eq!(points[0].flags, point(0).flags, "flags not completed stand");
    assert_eq!(
        points[1].brdf_sr,
        point(1).brdf_sr,
        "a value not completed stands"
    );
    assert_eq!(points[1].flags.last().map(String::as_str), Some("narrow-lobe"));
    assert_eq!(
        store.committed_points(id).expect("committed"),
        vec![point(0), point(1)]
    );
    // A second completion replaces the first whole: point 0's correction is gone with it.
    store.update_completions(id, &[narrow]).expect("again");
    let points = store.points(id).expect("points");
    assert_eq!(points[0], point(0));
    assert_eq!(points[1].flags.len(), 3);
}

#[test]
fn a_version_8_store_gains_the_completion_columns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch(
        "ALTER TABLE point_budgets DROP COLUMN brdf_sr; ALTER TABLE point_budgets DROP COLUMN brdf_aperture_sr; \
         ALTER TABLE point_budgets DROP COLUMN flags; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 8;",
    )
    .expect("downgrade");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    assert_eq!(store.points(id).expect("points"), vec![point(0)]);
    let completion = crate::store::PointCompletion {
        index: 0,
        budget: Default::default(),
        brdf_sr: Some(0.5),
        brdf_aperture_sr: Some(0.49),
        flags: None,
    };
    store.update_completions(id, &[completion]).expect("complete");
    assert_eq!(store.points(id).expect("points")[0].brdf_sr, Some(0.5));
}

#[test]
fn a_point_is_never_stored_twice() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(2)).expect("create");
    store.commit_point(id, &point(0)).expect("commit");
    let mut changed = point(0);
    changed.signal_w = 99.0;
    let err = store.commit_point(id, &changed).expect_err("duplicate");
    assert!(
        matches!(err, StoreError::DuplicatePoint { index: 0, .. }),
        "{err}"
    );
    assert_eq!(store.points(id).expect("points")[0], point(0));
}

#[test]
fn interrupted_campaigns_are_found_after_reopen() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let a = store.create_campaign(&new_campaign(1)).expect("a");
    let b = store.create_campaign(&new_campaign(1)).expect("b");
    let c = store.create_campaign(&new_campaign(1)).expect("c");
    store.set_state(a, CampaignState::Running, None).expect("state");
    store.set_state(b, CampaignState::Completed, None).expect("state");
    store
        .set_state(c, CampaignState::WaitingOperator, Some("swap in the reference"))
        .expect("state");
    drop(store);
    let store = Store::open(dir.path()).expect("reopen");
    assert_eq!(store.interrupted_campaigns().expect("list"), vec![a, c]);
    assert_eq!(
        store.campaign(c).expect("c").last_error.as_deref(),
        Some("swap in the reference")
    );
}

#[test]
fn calibrations_and_devices_are_kept_in_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(1)).expect("create");
    let cal = |t_s, value_w| CalibrationRecord {
        kind: "direct-beam".into(),
        band_nm: Some(550.0),
        t_s,
        value_w,
        u_w: 1e-7,
    };
    store.record_calibration(id, &cal(0.0, 1e-3)).expect("cal");
    store.record_calibration(id, &cal(60.0, 1.001e-3)).expect("cal");
    assert_eq!(
        store.calibrations(id).expect("cals"),
        vec![cal(0.0, 1e-3), cal(60.0, 1.001e-3)]
    );
    store
        .record_device(id, "meter", "Thorlabs,PM100USB,P200,1.0")
        .expect("dev");
    store
        .record_device(id, "meter", "Thorlabs,PM100USB,P201,1.0")
        .expect("dev");
    assert_eq!(
        store.devices(id).expect("devs"),
        vec![("meter".into(), "Thorlabs,PM100USB,P201,1.0".into())]
    );
}

/// SQLite's own word on the connection's level: 1 NORMAL, 2 FULL.
fn synchronous(store: &Store) -> i64 {
    store
        .conn
        .query_row("PRAGMA synchronous", [], |r| r.get(0))
        .expect("pragma")
}

#[test]
fn dry_runs_commit_at_normal_and_real_campaigns_at_full_whatever_ran_before() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    assert_eq!(synchronous(&store), 2);
    let dry = store.create_campaign(&new_campaign(3)).expect("dry");
    let real = store
        .create_campaign(&NewCampaign {
            dry_run: false,
            ..new_campaign(3)
        })
        .expect("real");
    // Creating a campaign belongs to no campaign yet: FULL.
    assert_eq!(synchronous(&store), 2);

    store.commit_point(dry, &point(0)).expect("commit");
    assert_eq!(
        (synchronous(&store), store.durability()),
        (1, Durability::ProcessCrash)
    );
    // Right after a dry-run's commit, every kind of write of the real campaign is back at FULL.
    store.commit_point(real, &point(0)).expect("commit");
    assert_eq!(
        (synchronous(&store), store.durability()),
        (2, Durability::PowerLoss)
    );
    store.commit_point(dry, &point(1)).expect("commit");
    store
        .set_state(real, CampaignState::Running, None)
        .expect("state");
    assert_eq!(synchronous(&store), 2);
    store.commit_point(dry, &point(2)).expect("commit");
    let cal = CalibrationRecord {
        kind: "dark".into(),
        band_nm: Some(550.0),
        t_s: 1.0,
        value_w: 1e-11,
        u_w: 1e-13,
    };
    store.record_calibration(real, &cal).expect("cal");
    assert_eq!(synchronous(&store), 2);
    store.record_calibration(dry, &cal).expect("cal");
    assert_eq!(synchronous(&store), 1);
    store.record_device(real, "meter", "x").expect("dev");
    assert_eq!(synchronous(&store), 2);
    store.set_operator_message(dry, Some("m")).expect("msg");
    assert_eq!(synchronous(&store), 1);
    store.set_operator_message(real, Some("m")).expect("msg");
    assert_eq!(synchronous(&store), 2);

    // A reopened store learns each campaign's level from the file.
    drop(store);
    let mut store = Store::open(dir.path()).expect("reopen");
    store.set_state(dry, CampaignState::Running, None).expect("state");
    assert_eq!(synchronous(&store), 1);
    store.commit_point(real, &point(1)).expect("commit");
    assert_eq!(synchronous(&store), 2);
    assert_eq!(
        store.points(dry).expect("points"),
        (0..3).map(point).collect::<Vec<_>>()
    );
}

#[test]
fn unknown_campaign_is_a_typed_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store = Store::open(dir.path()).expect("open");
    assert!(matches!(
        store.campaign(CampaignId(42)),
        Err(StoreError::NoSuchCampaign(CampaignId(42)))
    ));
}

#[test]
fn a_read_only_store_reports_a_write_failure_and_keeps_committed_points() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(3)).expect("create");
    store.commit_point(id, &point(0)).expect("commit");
    // Open a second, read-only connection to the same file: writes through it must fail cleanly.
    let ro = Connection::open_with_flags(store.path(), rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
        .expect("read-only open");
    let mut ro_store = Store::with_connection(ro, store.path().to_path_buf());
    let err = ro_store.commit_point(id, &point(1)).expect_err("read-only");
    assert!(err.is_write_failure(), "{err}");
    assert_eq!(store.points(id).expect("points"), vec![point(0)]);
    assert_eq!(store.next_index(id).expect("next"), 1);
}

#[test]
fn a_full_store_is_a_write_failure_and_a_state_it_cannot_write_is_still_shown() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let id = store.create_campaign(&new_campaign(500)).expect("create");
    store.set_state(id, CampaignState::Running, None).expect("state");
    let pages = store.page_count().expect("pages");
    store.set_max_pages(Some(pages)).expect("cap");
    let mut full = None;
    for i in 0..500 {
        if let Err(e) = store.commit_point(id, &point(i)) {
            full = Some((i, e));
            break;
        }
    }
    let (first_missing, err) = full.expect("the capped store fills up");
    assert!(err.is_write_failure(), "{err}");
    assert!(err.to_string().contains("database or disk is full"), "{err}");
    assert_eq!(store.next_index(id).expect("next"), first_missing);

    // A state that cannot be written (read-only connection) is shown from memory until written.
    let ro = Connection::open_with_flags(store.path(), rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
        .expect("read-only open");
    let mut ro_store = Store::with_connection(ro, store.path().to_path_buf());
    let e = ro_store
        .set_state(id, CampaignState::Paused, Some("disk trouble"))
        .expect_err("read-only");
    assert!(e.is_write_failure(), "{e}");
    let c = ro_store.campaign(id).expect("campaign");
    assert_eq!(
        (c.state, c.last_error.as_deref()),
        (CampaignState::Paused, Some("disk trouble"))
    );
    assert_eq!(ro_store.state(id).expect("state"), CampaignState::Paused);
    assert_eq!(
        ro_store.campaigns().expect("list")[0].state,
        CampaignState::Paused
    );
    // The file itself still says running (what a restart resumes).
    assert_eq!(store.state(id).expect("state"), CampaignState::Running);
    // Once a write of the state succeeds, the file is the truth again.
    store.set_max_pages(None).expect("lift");
    store
        .set_state(id, CampaignState::Paused, Some("disk trouble"))
        .expect("state");
    assert_eq!(store.campaign(id).expect("c").state, CampaignState::Paused);
}

#[test]
fn a_constraint_violation_is_not_disk_trouble() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    // No campaign 7: the foreign key refuses the row. A bug, not something to pause for.
    let e = store
        .record_device(CampaignId(7), "meter", "x")
        .expect_err("foreign key");
    assert!(
        matches!(e, StoreError::Write { .. }) && !e.is_write_failure(),
        "{e}"
    );
}

#[test]
fn a_version_9_store_gains_the_end_of_the_run_and_it_round_trips() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = store_with_one_point(dir.path());
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch("ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 9;")
        .expect("back to version 9");
    drop(conn);
    let mut store = Store::open(dir.path()).expect("migrates");
    let before = store.campaign(id).expect("campaign");
    assert_eq!(
        before.ended_instrument_s, None,
        "not recorded by a version 9 store"
    );
    assert_eq!(before.points_done, 1, "the point survives");
    store.set_ended_instrument_s(id, 123.25).expect("records the end");
    assert_eq!(
        store.campaign(id).expect("campaign").ended_instrument_s,
        Some(123.25)
    );
}
