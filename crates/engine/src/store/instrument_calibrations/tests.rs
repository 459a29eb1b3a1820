//! The instrument calibrations in the store: kept, found by instrument file and date, never overwritten, and the
//! migration of a version-5 store that had none.

use rusqlite::Connection;

use super::super::{CampaignId, NewCampaign, STORE_FILE};
use super::*;

fn calibration(sha: &str, created_utc: &str, text: &str) -> NewInstrumentCalibration {
    NewInstrumentCalibration {
        instrument: "simulated".into(),
        instrument_sha256: sha.into(),
        created_utc: created_utc.into(),
        software: "gonio 0.1.0".into(),
        method: "scans".into(),
        source: "test".into(),
        calibration_toml: text.into(),
        report_json: Some("{\"scans\":[]}".into()),
    }
}

fn campaign(calibration_id: Option<InstrumentCalibrationId>, alignment: Option<&str>) -> NewCampaign {
    NewCampaign {
        name: "c".into(),
        campaign_toml: String::new(),
        instrument_toml: String::new(),
        total_points: 2,
        dry_run: true,
        software_version: "0.1.0".into(),
        predicted_instrument_s: None,
        alignment_toml: alignment.map(str::to_string),
        calibration_id,
    }
}

#[test]
fn calibrations_are_kept_dated_and_the_latest_of_an_instrument_is_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    assert_eq!(store.latest_instrument_calibration("aa").expect("latest"), None);
    let old = store
        .add_instrument_calibration(&calibration("aa", "2026-01-02T03:04:05Z", "old"))
        .expect("add");
    let newest = store
        .add_instrument_calibration(&calibration("aa", "2026-03-01T00:00:00Z", "newest"))
        .expect("add");
    // Stored after, made before: not the latest.
    let late_file = store
        .add_instrument_calibration(&calibration("aa", "2026-02-01T00:00:00Z", "late file"))
        .expect("add");
    // Another instrument file's, made after all of them: never the latest of this one.
    let other = store
        .add_instrument_calibration(&calibration("bb", "2027-01-01T00:00:00Z", "other"))
        .expect("add");
    drop(store);

    let store = Store::open(dir.path()).expect("reopen");
    let all = store.instrument_calibrations().expect("list");
    assert_eq!(
        all.iter().map(|c| c.id).collect::<Vec<_>>(),
        vec![old, newest, late_file, other]
    );
    let latest = store
        .latest_instrument_calibration("aa")
        .expect("latest")
        .expect("one");
    assert_eq!((latest.id, latest.calibration_toml.as_str()), (newest, "newest"));
    assert!(latest.stored_unix_s > 1.7e9, "{}", latest.stored_unix_s);
    assert_eq!(latest.report_json.as_deref(), Some("{\"scans\":[]}"));
    assert_eq!(
        store
            .latest_instrument_calibration("bb")
            .expect("latest")
            .map(|c| c.id),
        Some(other)
    );
    assert_eq!(
        store.instrument_calibration(old).expect("fetch").calibration_toml,
        "old"
    );
    assert_eq!(
        store
            .instrument_calibration_with_text("late file")
            .expect("find")
            .map(|c| c.id),
        Some(late_file)
    );
    assert_eq!(
        store.instrument_calibration_with_text("none").expect("find"),
        None
    );
    assert!(matches!(
        store.instrument_calibration(InstrumentCalibrationId(99)),
        Err(StoreError::NoSuchCalibration(InstrumentCalibrationId(99)))
    ));
}

#[test]
fn a_stored_calibration_is_never_overwritten_nor_deleted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id = Store::open(dir.path())
        .expect("open")
        .add_instrument_calibration(&calibration("aa", "2026-01-02T03:04:05Z", "kept"))
        .expect("add");
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    let update = conn.execute(
        "UPDATE instrument_calibrations SET calibration_toml = 'changed'",
        [],
    );
    assert!(
        update
            .as_ref()
            .is_err_and(|e| e.to_string().contains("never overwritten")),
        "{update:?}"
    );
    let delete = conn.execute("DELETE FROM instrument_calibrations", []);
    assert!(
        delete
            .as_ref()
            .is_err_and(|e| e.to_string().contains("never deleted")),
        "{delete:?}"
    );
    drop(conn);
    let store = Store::open(dir.path()).expect("open");
    assert_eq!(
        store.instrument_calibration(id).expect("fetch").calibration_toml,
        "kept"
    );
}

#[test]
fn a_campaign_records_which_calibration_it_was_given() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(dir.path()).expect("open");
    let cal = store
        .add_instrument_calibration(&calibration("aa", "2026-01-02T03:04:05Z", "cal text"))
        .expect("add");
    let given = store
        .create_campaign(&campaign(Some(cal), Some("cal text")))
        .expect("create");
    let plain = store.create_campaign(&campaign(None, None)).expect("create");
    let record = store.campaign(given).expect("campaign");
    assert_eq!(
        (record.calibration_id, record.alignment_toml.as_deref()),
        (Some(cal), Some("cal text"))
    );
    assert_eq!(store.campaign(plain).expect("campaign").calibration_id, None);
}

#[test]
fn a_version_5_store_gains_the_calibrations_and_keeps_its_campaigns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let id: CampaignId = {
        let mut store = Store::open(dir.path()).expect("open");
        store
            .create_campaign(&campaign(None, Some("[calibration]\n")))
            .expect("create")
    };
    // Back to version 5: no calibrations table, no campaigns.calibration_id.
    let conn = Connection::open(dir.path().join(STORE_FILE)).expect("raw open");
    conn.execute_batch(
        "ALTER TABLE points DROP COLUMN brdf_aperture_sr; ALTER TABLE points DROP COLUMN budget; DROP TABLE instrument_calibrations; ALTER TABLE campaigns DROP COLUMN calibration_id;
         DROP TABLE point_budgets; ALTER TABLE campaigns DROP COLUMN ended_instrument_s; DROP TABLE sweep_readings; DROP TABLE sweep_segments; PRAGMA user_version = 5;",
    )
    .expect("downgrade");
    drop(conn);

    let mut store = Store::open(dir.path()).expect("migrates");
    let version: i64 = store
        .conn
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .expect("version");
    assert_eq!(version, crate::store::SCHEMA_VERSION);
    let old = store.campaign(id).expect("campaign");
    assert_eq!(
        (
            old.alignment_toml.as_deref(),
            old.calibration_id,
            old.total_points
        ),
        (Some("[calibration]\n"), None, 2)
    );
    let cal = store
        .add_instrument_calibration(&calibration("aa", "2026-01-02T03:04:05Z", "x"))
        .expect("the migrated store keeps calibrations");
    let new = store
        .create_campaign(&campaign(Some(cal), Some("x")))
        .expect("create");
    assert_eq!(store.campaign(new).expect("campaign").calibration_id, Some(cal));
    // Calibrations are never overwritten in a migrated store either.
    assert!(
        store
            .conn
            .execute("UPDATE instrument_calibrations SET source = 'y'", [])
            .is_err()
    );
    drop(store);
    // Opening it again finds version 6 and changes nothing.
    let store = Store::open(dir.path()).expect("reopen");
    assert_eq!(store.instrument_calibrations().expect("list").len(), 1);
}
