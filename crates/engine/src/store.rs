//! The durable store: one SQLite file (bundled build) holding campaigns, their resolved configuration, device
//! identities, calibration readings and every measured point.
//!
//! Durability: WAL journal and one transaction per point, so that after a crash a point is either entirely in
//! the store or not at all. The primary key (campaign, index) makes it impossible to store a point twice; resuming
//! means continuing from [`Store::next_index`], the first index not committed. How far a commit survives depends
//! on the campaign ([`Durability`]):
//! - a campaign on the real instrument: `synchronous = FULL`, every commit is fsync'd before it returns: a
//!   committed point survives a crash of the process (`kill -9` at any moment), of the operating system, and a
//!   power cut;
//! - a dry-run (every device simulated, [`NewCampaign::dry_run`]): `synchronous = NORMAL` in WAL mode, commits are
//!   not fsync'd (only checkpoints are): a committed point survives a crash or `kill -9` of the process (the
//!   write-ahead log is in the operating system's cache, which the next opening reads), but the last commits may
//!   be lost when the operating system crashes or the power fails. Either way the store stays consistent (a
//!   commit is whole or absent) and resuming continues from the first point not committed. Nothing of value is at
//!   stake: a simulated point is measured again in microseconds, and the fsync per point cost a dry-run most of
//!   its time.
//!
//! Every write sets the level its campaign needs (writes that belong to no campaign use FULL), so a real campaign
//! never commits at the dry-run's level, whatever ran before on the same connection. A FULL commit fsyncs the whole
//! log, earlier NORMAL commits with it.
//!
//! Values are stored as SQLite REALs, which are IEEE-754 doubles: what is read back is bit-identical to what was
//! written.
//!
//! Disk trouble: a write that fails with a condition a person can fix (SQLite FULL, READONLY, IOERR, CANTOPEN,
//! BUSY/LOCKED beyond the busy timeout) is a [`StoreError::Write`] with [`StoreError::is_write_failure`]; the
//! failed statement leaves nothing behind. A campaign state that cannot be written is kept in memory and shown
//! by [`Store::campaign`], [`Store::campaigns`] and [`Store::state`] until a later write of that campaign's state
//! succeeds (the file keeps the last state it could record). [`Store::set_max_pages`] caps the file's size
//! (a quota; the tests use it to fill the store for real).

//!
//! Parts: `records` holds the types read and written; `schema` opens the file, sets the connection up, creates
//! and migrates the schema and picks each write's durability; `queries` reads and writes campaigns, devices,
//! calibrations and points; `sweeps` the readings of sweeps, a segment per transaction; `instrument_calibrations` keeps the instrument's calibrations (`gonio align` files)
//! and finds the latest one made for an instrument file. [`Store`] and [`StoreError`] are here.

mod instrument_calibrations;
mod queries;
mod records;
mod schema;
mod sweeps;

pub use records::{
    CalibrationRecord, CampaignId, CampaignRecord, CampaignState, Durability, InstrumentCalibration,
    InstrumentCalibrationId, NewCampaign, NewInstrumentCalibration, PointCompletion, PointRecord, PointValue,
};
pub use sweeps::{SweepCompletion, SweepSegmentRecord};

use std::collections::HashMap;
use std::path::PathBuf;

use rusqlite::Connection;

/// File name of the store inside the data directory.
pub const STORE_FILE: &str = "gonio.sqlite";

/// Bumped when the schema changes; a store with another version is refused rather than misread.
/// Version 2: `signal_w`, `dark_w` and `incident_w` may be NULL (a failed point has no reading; SQLite cannot
/// store NaN and turns it into NULL).
/// Version 3: `truth_effects_json` (a dry-run's per-point attribution of its imperfections).
/// Version 4: `predicted_instrument_s`; version 5: `alignment_toml` (the alignment applied to a campaign).
/// Version 6: `instrument_calibrations` (the daemon's calibrations, dated, never overwritten) and
/// `campaigns.calibration_id` (which one a campaign was given). Version 7: each point's `budget` and
/// `brdf_aperture_sr`; version 8: `point_budgets` (budgets completed after a campaign, its rows untouched);
/// version 9: `point_budgets` also keeps the value corrected to the nominal geometry, the aperture average it came
/// from and the flags (crate::budget::complete). Version 10: `campaigns.ended_instrument_s`. Version 11:
/// `sweep_segments` and `sweep_readings` (a campaign's sweeps, a segment per transaction: `sweeps`).
const SCHEMA_VERSION: i64 = 12;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("cannot open the store {path}: {source}")]
    Open { path: PathBuf, source: rusqlite::Error },
    #[error("cannot create the data directory {path}: {source}")]
    CreateDir { path: PathBuf, source: std::io::Error },
    #[error("the store {path} has schema version {found}, this gonio understands version {expected}")]
    SchemaVersion {
        path: PathBuf,
        found: i64,
        expected: i64,
    },
    /// Writing failed: disk full, read-only directory, I/O error. Nothing partial was committed.
    #[error("cannot write to the store {path}: {source}")]
    Write { path: PathBuf, source: rusqlite::Error },
    #[error("cannot read from the store {path}: {source}")]
    Read { path: PathBuf, source: rusqlite::Error },
    #[error("campaign {0} is not in the store")]
    NoSuchCampaign(CampaignId),
    #[error("instrument calibration {0} is not in the store")]
    NoSuchCalibration(InstrumentCalibrationId),
    #[error("point {index} of campaign {campaign} is already committed")]
    DuplicatePoint { campaign: CampaignId, index: u64 },
    #[error("the store holds a value it cannot interpret: {0}")]
    Corrupt(String),
}

impl StoreError {
    /// True for write errors a person can fix without losing data (disk or quota full, read-only file or
    /// directory, I/O error, file cannot be opened, lock held by another process too long): the campaign should
    /// pause, not fail. Other write errors (a constraint, a misuse) are bugs.
    pub fn is_write_failure(&self) -> bool {
        use rusqlite::ErrorCode as C;
        match self {
            StoreError::Write {
                source: rusqlite::Error::SqliteFailure(e, _),
                ..
            } => matches!(
                e.code,
                C::DiskFull
                    | C::ReadOnly
                    | C::SystemIoFailure
                    | C::CannotOpen
                    | C::DatabaseBusy
                    | C::DatabaseLocked
            ),
            _ => false,
        }
    }
}

/// The store. One connection; callers serialise access (the daemon owns it on one task).
#[derive(Debug)]
pub struct Store {
    conn: Connection,
    path: PathBuf,
    /// Campaign states that could not be written (disk trouble): (state, message), shown until written.
    unrecorded: HashMap<CampaignId, (CampaignState, Option<String>)>,
    /// The connection's `synchronous` level now.
    durability: Durability,
    /// Campaigns' dry-run flags as stored (they never change): which level their writes get.
    dry_runs: HashMap<CampaignId, bool>,
}

#[cfg(test)]
mod tests;
