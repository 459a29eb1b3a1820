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

use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;

use rusqlite::{Connection, OptionalExtension, params};
use serde::{Deserialize, Serialize};

/// File name of the store inside the data directory.
pub const STORE_FILE: &str = "gonio.sqlite";

/// Bumped when the schema changes; a store with another version is refused rather than misread.
/// Version 2: `signal_w`, `dark_w` and `incident_w` may be NULL (a failed point has no reading; SQLite cannot
/// store NaN and turns it into NULL).
const SCHEMA_VERSION: i64 = 2;

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

/// Campaign identifier: a positive integer assigned by the store.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(transparent)]
pub struct CampaignId(pub i64);

impl fmt::Display for CampaignId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Lifecycle of a campaign.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CampaignState {
    Queued,
    Running,
    Pausing,
    Paused,
    WaitingOperator,
    Completed,
    Aborted,
    Failed,
}

impl CampaignState {
    pub const ALL: [CampaignState; 8] = [
        CampaignState::Queued,
        CampaignState::Running,
        CampaignState::Pausing,
        CampaignState::Paused,
        CampaignState::WaitingOperator,
        CampaignState::Completed,
        CampaignState::Aborted,
        CampaignState::Failed,
    ];

    pub fn as_str(&self) -> &'static str {
        match self {
            CampaignState::Queued => "queued",
            CampaignState::Running => "running",
            CampaignState::Pausing => "pausing",
            CampaignState::Paused => "paused",
            CampaignState::WaitingOperator => "waiting-operator",
            CampaignState::Completed => "completed",
            CampaignState::Aborted => "aborted",
            CampaignState::Failed => "failed",
        }
    }

    /// A finished campaign never runs again.
    pub fn is_final(&self) -> bool {
        matches!(
            self,
            CampaignState::Completed | CampaignState::Aborted | CampaignState::Failed
        )
    }

    /// States that mean "was in the middle of running" when found after a restart.
    pub fn was_interrupted(&self) -> bool {
        matches!(
            self,
            CampaignState::Running | CampaignState::Pausing | CampaignState::WaitingOperator
        )
    }
}

impl fmt::Display for CampaignState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for CampaignState {
    type Err = StoreError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        CampaignState::ALL
            .iter()
            .copied()
            .find(|st| st.as_str() == s)
            .ok_or_else(|| StoreError::Corrupt(format!("unknown campaign state {s:?}")))
    }
}

/// What is stored when a campaign is submitted: enough to reproduce the run.
#[derive(Debug, Clone, PartialEq)]
pub struct NewCampaign {
    pub name: String,
    /// The campaign file as submitted (TOML text).
    pub campaign_toml: String,
    /// The instrument file in force (TOML text).
    pub instrument_toml: String,
    /// Number of planned points.
    pub total_points: u64,
    /// True when the instrument is the simulator.
    pub dry_run: bool,
    pub software_version: String,
}

/// A campaign as stored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CampaignRecord {
    pub id: CampaignId,
    pub name: String,
    pub state: CampaignState,
    pub campaign_toml: String,
    pub instrument_toml: String,
    pub total_points: u64,
    pub points_done: u64,
    pub dry_run: bool,
    pub software_version: String,
    pub created_unix_s: f64,
    pub last_error: Option<String>,
    /// Message shown while waiting for the operator.
    pub operator_message: Option<String>,
}

/// One measured (or failed) point with everything needed to recompute it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointRecord {
    pub index: u64,
    pub band_nm: f64,
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    /// Raw detector reading (W).
    pub signal_w: f64,
    /// Dark reading subtracted from it (W).
    pub dark_w: f64,
    /// Incident power from the direct-beam calibration, interpolated in time (W); or the reference signal
    /// for the relative method.
    pub incident_w: f64,
    /// The BRDF (1/sr); `None` for a failed or flagged point that has no valid value.
    pub brdf_sr: Option<f64>,
    /// Standard uncertainty of the BRDF (1/sr).
    pub brdf_u_sr: Option<f64>,
    /// Empty for a valid point, else reasons (saturated, overfilled, failed: ...).
    pub flags: Vec<String>,
    /// Seconds since the campaign started (instrument time).
    pub t_s: f64,
    /// Read-back positions per axis, in the instrument file's axis order (name, physical degrees).
    pub readback_deg: Vec<(String, f64)>,
    /// Dry-runs only: the simulator's ground truth at the nominal geometry and averaged over the aperture.
    pub truth_point_sr: Option<f64>,
    pub truth_aperture_sr: Option<f64>,
}

/// A calibration reading (direct beam, reference sample, dark) taken during a campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// "direct-beam", "reference" or "dark".
    pub kind: String,
    pub band_nm: Option<f64>,
    pub t_s: f64,
    pub value_w: f64,
    pub u_w: f64,
}

/// How far a commit survives (module doc): the store picks it from the campaign written to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// `synchronous = FULL`: survives a crash of the process or the operating system and a power cut (campaigns
    /// on the real instrument, and writes that belong to no campaign).
    PowerLoss,
    /// `synchronous = NORMAL` (WAL): survives a crash or `kill -9` of the process, not of the operating system
    /// (dry-runs).
    ProcessCrash,
}

impl Durability {
    /// The level a campaign's writes get.
    pub fn for_campaign(dry_run: bool) -> Durability {
        if dry_run {
            Durability::ProcessCrash
        } else {
            Durability::PowerLoss
        }
    }

    fn pragma(self) -> &'static str {
        match self {
            Durability::PowerLoss => "PRAGMA synchronous = FULL",
            Durability::ProcessCrash => "PRAGMA synchronous = NORMAL",
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

impl Store {
    /// Open (creating if needed) the store in a data directory.
    pub fn open(dir: &Path) -> Result<Store, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::CreateDir {
            path: dir.to_path_buf(),
            source,
        })?;
        let path = dir.join(STORE_FILE);
        let conn = Connection::open(&path).map_err(|source| StoreError::Open {
            path: path.clone(),
            source,
        })?;
        let mut store = Store::with_connection(conn, path);
        store.configure()?;
        store.migrate()?;
        Ok(store)
    }

    fn with_connection(conn: Connection, path: PathBuf) -> Store {
        Store {
            conn,
            path,
            unrecorded: HashMap::new(),
            durability: Durability::PowerLoss,
            dry_runs: HashMap::new(),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Call `hook` inside every commit, after the transaction's writes and before SQLite makes them durable
    /// (SQLite's commit hook; `true` from it turns the commit into a rollback). For crash tests, which kill the
    /// process there: a kill in the middle of a commit, placed exactly.
    pub fn on_commit<F: FnMut() -> bool + Send + 'static>(&mut self, hook: F) -> Result<(), StoreError> {
        self.conn
            .commit_hook(Some(hook))
            .map_err(|source| StoreError::Write {
                path: self.path.clone(),
                source,
            })
    }

    /// The durability the connection is set to now (the level of the last write).
    pub fn durability(&self) -> Durability {
        self.durability
    }

    /// Before a write: set the level the written campaign needs (`None`: no campaign, FULL).
    fn durability_for_write(&mut self, campaign: Option<CampaignId>) -> Result<(), StoreError> {
        let wanted = match campaign {
            None => Durability::PowerLoss,
            Some(id) => match self.dry_runs.get(&id) {
                Some(dry) => Durability::for_campaign(*dry),
                None => {
                    let dry: Option<bool> = self
                        .conn
                        .prepare_cached("SELECT dry_run FROM campaigns WHERE id = ?1")
                        .and_then(|mut st| st.query_row([id.0], |r| r.get(0)).optional())
                        .map_err(self.read_err())?;
                    match dry {
                        Some(d) => {
                            self.dry_runs.insert(id, d);
                            Durability::for_campaign(d)
                        }
                        // Not (yet) a campaign: the write fails on its own; keep the strict level meanwhile.
                        None => Durability::PowerLoss,
                    }
                }
            },
        };
        if wanted != self.durability {
            self.conn
                .execute_batch(wanted.pragma())
                .map_err(self.write_err())?;
            self.durability = wanted;
        }
        Ok(())
    }

    fn configure(&mut self) -> Result<(), StoreError> {
        let open_err = |source| StoreError::Open {
            path: self.path.clone(),
            source,
        };
        // A busy timeout rather than immediate failure when a reader (e.g. an export) holds a lock.
        self.conn.busy_timeout(Duration::from_secs(5)).map_err(open_err)?;
        self.conn
            .execute_batch("PRAGMA journal_mode = WAL; PRAGMA synchronous = FULL; PRAGMA foreign_keys = ON;")
            .map_err(|source| StoreError::Open {
                path: self.path.clone(),
                source,
            })
    }

    /// Version 1 declared the readings NOT NULL, so a failed point (NaN reading) could not be committed.
    /// SQLite cannot drop a NOT NULL constraint in place: rebuild the table, keeping every row.
    fn migrate_v1_to_v2(&mut self) -> Result<(), StoreError> {
        let sql = format!(
            "BEGIN;
            CREATE TABLE points_v2 (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                idx INTEGER NOT NULL,
                band_nm REAL NOT NULL,
                theta_i_deg REAL NOT NULL,
                phi_i_deg REAL NOT NULL,
                theta_o_deg REAL NOT NULL,
                phi_o_deg REAL NOT NULL,
                signal_w REAL,
                dark_w REAL,
                incident_w REAL,
                brdf_sr REAL,
                brdf_u_sr REAL,
                flags TEXT NOT NULL,
                t_s REAL NOT NULL,
                readback_json TEXT NOT NULL,
                truth_point_sr REAL,
                truth_aperture_sr REAL,
                PRIMARY KEY (campaign_id, idx)
            );
            INSERT INTO points_v2 SELECT * FROM points;
            DROP TABLE points;
            ALTER TABLE points_v2 RENAME TO points;
            PRAGMA user_version = {SCHEMA_VERSION};
            COMMIT;"
        );
        self.conn.execute_batch(&sql).map_err(|source| StoreError::Write {
            path: self.path.clone(),
            source,
        })
    }

    fn migrate(&mut self) -> Result<(), StoreError> {
        let version: i64 = self
            .conn
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(|source| StoreError::Read {
                path: self.path.clone(),
                source,
            })?;
        if version == SCHEMA_VERSION {
            return Ok(());
        }
        if version == 1 {
            return self.migrate_v1_to_v2();
        }
        if version != 0 {
            return Err(StoreError::SchemaVersion {
                path: self.path.clone(),
                found: version,
                expected: SCHEMA_VERSION,
            });
        }
        let schema = format!(
            "BEGIN;
            CREATE TABLE campaigns (
                id INTEGER PRIMARY KEY AUTOINCREMENT,
                name TEXT NOT NULL,
                state TEXT NOT NULL,
                campaign_toml TEXT NOT NULL,
                instrument_toml TEXT NOT NULL,
                total_points INTEGER NOT NULL,
                dry_run INTEGER NOT NULL,
                software_version TEXT NOT NULL,
                created_unix_s REAL NOT NULL,
                last_error TEXT,
                operator_message TEXT
            );
            CREATE TABLE devices (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                name TEXT NOT NULL,
                identity TEXT NOT NULL,
                PRIMARY KEY (campaign_id, name)
            );
            CREATE TABLE calibrations (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                seq INTEGER NOT NULL,
                kind TEXT NOT NULL,
                band_nm REAL,
                t_s REAL NOT NULL,
                value_w REAL NOT NULL,
                u_w REAL NOT NULL,
                PRIMARY KEY (campaign_id, seq)
            );
            CREATE TABLE points (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                idx INTEGER NOT NULL,
                band_nm REAL NOT NULL,
                theta_i_deg REAL NOT NULL,
                phi_i_deg REAL NOT NULL,
                theta_o_deg REAL NOT NULL,
                phi_o_deg REAL NOT NULL,
                signal_w REAL,
                dark_w REAL,
                incident_w REAL,
                brdf_sr REAL,
                brdf_u_sr REAL,
                flags TEXT NOT NULL,
                t_s REAL NOT NULL,
                readback_json TEXT NOT NULL,
                truth_point_sr REAL,
                truth_aperture_sr REAL,
                PRIMARY KEY (campaign_id, idx)
            );
            PRAGMA user_version = {SCHEMA_VERSION};
            COMMIT;"
        );
        self.conn
            .execute_batch(&schema)
            .map_err(|source| StoreError::Write {
                path: self.path.clone(),
                source,
            })
    }

    fn write_err(&self) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
        |source| StoreError::Write {
            path: self.path.clone(),
            source,
        }
    }

    fn read_err(&self) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
        |source| StoreError::Read {
            path: self.path.clone(),
            source,
        }
    }

    /// Store a new campaign in the `queued` state.
    pub fn create_campaign(&mut self, new: &NewCampaign) -> Result<CampaignId, StoreError> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0);
        self.durability_for_write(None)?;
        self.conn
            .execute(
                "INSERT INTO campaigns (name, state, campaign_toml, instrument_toml, total_points, dry_run,
                 software_version, created_unix_s) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![
                    new.name,
                    CampaignState::Queued.as_str(),
                    new.campaign_toml,
                    new.instrument_toml,
                    to_i64(new.total_points),
                    new.dry_run,
                    new.software_version,
                    now
                ],
            )
            .map_err(self.write_err())?;
        let id = CampaignId(self.conn.last_insert_rowid());
        self.dry_runs.insert(id, new.dry_run);
        Ok(id)
    }

    pub fn campaign(&self, id: CampaignId) -> Result<CampaignRecord, StoreError> {
        let record = self
            .conn
            .query_row(
                &format!("{CAMPAIGN_SELECT} WHERE c.id = ?1"),
                [id.0],
                campaign_from_row,
            )
            .optional()
            .map_err(self.read_err())?
            .ok_or(StoreError::NoSuchCampaign(id))??;
        Ok(self.overlay(record))
    }

    /// A campaign's state (cheaper than [`Store::campaign`]: no configuration texts).
    pub fn state(&self, id: CampaignId) -> Result<CampaignState, StoreError> {
        if let Some((state, _)) = self.unrecorded.get(&id) {
            return Ok(*state);
        }
        let state: String = self
            .conn
            .prepare_cached("SELECT state FROM campaigns WHERE id = ?1")
            .and_then(|mut st| st.query_row([id.0], |r| r.get(0)).optional())
            .map_err(self.read_err())?
            .ok_or(StoreError::NoSuchCampaign(id))?;
        state.parse()
    }

    /// A record with the state that could not be written, if any.
    fn overlay(&self, mut record: CampaignRecord) -> CampaignRecord {
        if let Some((state, message)) = self.unrecorded.get(&record.id) {
            record.state = *state;
            if *state == CampaignState::Completed {
                record.last_error = None;
            } else if message.is_some() {
                record.last_error.clone_from(message);
            }
        }
        record
    }

    /// All campaigns, oldest first.
    pub fn campaigns(&self) -> Result<Vec<CampaignRecord>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(&format!("{CAMPAIGN_SELECT} ORDER BY c.id"))
            .map_err(self.read_err())?;
        let rows = stmt.query_map([], campaign_from_row).map_err(self.read_err())?;
        let mut out = Vec::new();
        for row in rows {
            out.push(self.overlay(row.map_err(self.read_err())??));
        }
        Ok(out)
    }

    pub fn set_state(
        &mut self,
        id: CampaignId,
        state: CampaignState,
        last_error: Option<&str>,
    ) -> Result<(), StoreError> {
        let result = self.durability_for_write(Some(id)).and_then(|()| {
            self.conn
                .prepare_cached(
                    // A completed campaign has no error left to show: a pause's reason from before its
                    // resume is cleared (it stays in the log and the events).
                    "UPDATE campaigns SET state = ?2, last_error = CASE WHEN ?2 = 'completed' THEN NULL \
                         ELSE COALESCE(?3, last_error) END WHERE id = ?1",
                )
                .and_then(|mut st| st.execute(params![id.0, state.as_str(), last_error]))
                .map_err(self.write_err())
        });
        match result {
            Ok(0) => Err(StoreError::NoSuchCampaign(id)),
            Ok(_) => {
                self.unrecorded.remove(&id);
                Ok(())
            }
            Err(e) => {
                if e.is_write_failure() {
                    // Shown from memory until a later write succeeds (module doc).
                    let message = last_error
                        .map(str::to_string)
                        .or_else(|| self.unrecorded.get(&id).and_then(|u| u.1.clone()));
                    self.unrecorded.insert(id, (state, message));
                }
                Err(e)
            }
        }
    }

    /// Set the points a campaign measures in all: an adaptive campaign that reached its target error before its
    /// budget ends with fewer points than it was submitted with.
    pub fn set_total_points(&mut self, id: CampaignId, total: u64) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        let n = self
            .conn
            .execute(
                "UPDATE campaigns SET total_points = ?2 WHERE id = ?1",
                params![id.0, to_i64(total)],
            )
            .map_err(self.write_err())?;
        if n == 0 {
            return Err(StoreError::NoSuchCampaign(id));
        }
        Ok(())
    }

    /// Cap the store file at `pages` pages (None: SQLite's own maximum); returns the cap in force. Writes that
    /// would grow the file beyond it fail as a full disk would (SQLITE_FULL). The cap lasts while this `Store`
    /// is open.
    pub fn set_max_pages(&mut self, pages: Option<u64>) -> Result<u64, StoreError> {
        // SQLite's largest page count; asking for more keeps that.
        let n = to_i64(pages.unwrap_or(u64::from(u32::MAX - 1)));
        let cap: i64 = self
            .conn
            .query_row(&format!("PRAGMA max_page_count = {n}"), [], |r| r.get(0))
            .map_err(self.write_err())?;
        Ok(from_i64(cap))
    }

    /// Pages the store file holds now.
    pub fn page_count(&self) -> Result<u64, StoreError> {
        let n: i64 = self
            .conn
            .query_row("PRAGMA page_count", [], |r| r.get(0))
            .map_err(self.read_err())?;
        Ok(from_i64(n))
    }

    pub fn set_operator_message(&mut self, id: CampaignId, message: Option<&str>) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .execute(
                "UPDATE campaigns SET operator_message = ?2 WHERE id = ?1",
                params![id.0, message],
            )
            .map_err(self.write_err())?;
        Ok(())
    }

    /// Record the identity string a device reported (e.g. `*IDN?`), replacing an earlier one.
    pub fn record_device(&mut self, id: CampaignId, name: &str, identity: &str) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .execute(
                "INSERT OR REPLACE INTO devices (campaign_id, name, identity) VALUES (?1, ?2, ?3)",
                params![id.0, name, identity],
            )
            .map_err(self.write_err())?;
        Ok(())
    }

    pub fn devices(&self, id: CampaignId) -> Result<Vec<(String, String)>, StoreError> {
        let mut stmt = self
            .conn
            .prepare("SELECT name, identity FROM devices WHERE campaign_id = ?1 ORDER BY name")
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map([id.0], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(self.read_err())?;
        rows.collect::<Result<_, _>>().map_err(self.read_err())
    }

    pub fn record_calibration(&mut self, id: CampaignId, cal: &CalibrationRecord) -> Result<(), StoreError> {
        self.durability_for_write(Some(id))?;
        self.conn
            .prepare_cached(
                "INSERT INTO calibrations (campaign_id, seq, kind, band_nm, t_s, value_w, u_w)
                 VALUES (?1, (SELECT COALESCE(MAX(seq), 0) + 1 FROM calibrations WHERE campaign_id = ?1),
                         ?2, ?3, ?4, ?5, ?6)",
            )
            .and_then(|mut st| {
                st.execute(params![
                    id.0,
                    cal.kind,
                    cal.band_nm,
                    cal.t_s,
                    cal.value_w,
                    cal.u_w
                ])
            })
            .map_err(self.write_err())?;
        Ok(())
    }

    pub fn calibrations(&self, id: CampaignId) -> Result<Vec<CalibrationRecord>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT kind, band_nm, t_s, value_w, u_w FROM calibrations WHERE campaign_id = ?1 ORDER BY seq",
            )
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map([id.0], |r| {
                Ok(CalibrationRecord {
                    kind: r.get(0)?,
                    band_nm: r.get(1)?,
                    t_s: r.get(2)?,
                    value_w: r.get(3)?,
                    u_w: r.get(4)?,
                })
            })
            .map_err(self.read_err())?;
        rows.collect::<Result<_, _>>().map_err(self.read_err())
    }

    /// Commit one point in its own transaction, as durably as its campaign asks ([`Durability`]). A point
    /// already committed is refused, never overwritten.
    pub fn commit_point(&mut self, id: CampaignId, p: &PointRecord) -> Result<(), StoreError> {
        let readback = serde_json::to_string(&p.readback_deg)
            .map_err(|e| StoreError::Corrupt(format!("cannot encode read-back positions: {e}")))?;
        let flags = p.flags.join(";");
        self.durability_for_write(Some(id))?;
        // Prepared once per connection (SQLite's parse and plan cost as much as the insert itself).
        let result = self.conn.prepare_cached(
            "INSERT INTO points (campaign_id, idx, band_nm, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg,
             signal_w, dark_w, incident_w, brdf_sr, brdf_u_sr, flags, t_s, readback_json, truth_point_sr,
             truth_aperture_sr) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17)",
        );
        let result = result.and_then(|mut st| {
            st.execute(params![
                id.0,
                to_i64(p.index),
                p.band_nm,
                p.theta_i_deg,
                p.phi_i_deg,
                p.theta_o_deg,
                p.phi_o_deg,
                p.signal_w,
                p.dark_w,
                p.incident_w,
                p.brdf_sr,
                p.brdf_u_sr,
                flags,
                p.t_s,
                readback,
                p.truth_point_sr,
                p.truth_aperture_sr
            ])
        });
        match result {
            Ok(_) => Ok(()),
            // Only the primary key means "already committed"; any other constraint is a bug, not a duplicate.
            Err(rusqlite::Error::SqliteFailure(e, _))
                if e.extended_code == rusqlite::ffi::SQLITE_CONSTRAINT_PRIMARYKEY =>
            {
                Err(StoreError::DuplicatePoint {
                    campaign: id,
                    index: p.index,
                })
            }
            Err(source) => Err(StoreError::Write {
                path: self.path.clone(),
                source,
            }),
        }
    }

    /// The first point index not yet committed: where a resumed campaign continues.
    pub fn next_index(&self, id: CampaignId) -> Result<u64, StoreError> {
        // Points are committed in index order, so the count of rows is the next index; check that the rows
        // really are 0..count so that a hole (which would mean a bug) is reported rather than skipped.
        let (count, max): (i64, Option<i64>) = self
            .conn
            .prepare_cached("SELECT COUNT(*), MAX(idx) FROM points WHERE campaign_id = ?1")
            .and_then(|mut st| st.query_row([id.0], |r| Ok((r.get(0)?, r.get(1)?))))
            .map_err(self.read_err())?;
        match max {
            None => Ok(0),
            Some(m) if m + 1 == count => Ok(from_i64(count)),
            Some(m) => Err(StoreError::Corrupt(format!(
                "campaign {id} has {count} points but the highest index is {m}: points are missing"
            ))),
        }
    }

    /// All committed points of a campaign in index order.
    pub fn points(&self, id: CampaignId) -> Result<Vec<PointRecord>, StoreError> {
        self.points_from(id, 0)
    }

    /// Committed points with index >= `from`, in index order.
    pub fn points_from(&self, id: CampaignId, from: u64) -> Result<Vec<PointRecord>, StoreError> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT idx, band_nm, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg, signal_w, dark_w,
                 incident_w, brdf_sr, brdf_u_sr, flags, t_s, readback_json, truth_point_sr, truth_aperture_sr
                 FROM points WHERE campaign_id = ?1 AND idx >= ?2 ORDER BY idx",
            )
            .map_err(self.read_err())?;
        let rows = stmt
            .query_map(params![id.0, to_i64(from)], point_from_row)
            .map_err(self.read_err())?;
        let mut out = Vec::new();
        for row in rows {
            out.push(row.map_err(self.read_err())??);
        }
        Ok(out)
    }

    /// Campaigns that were running when the daemon last stopped, oldest first.
    pub fn interrupted_campaigns(&self) -> Result<Vec<CampaignId>, StoreError> {
        Ok(self
            .campaigns()?
            .into_iter()
            .filter(|c| c.state.was_interrupted())
            .map(|c| c.id)
            .collect())
    }
}

const CAMPAIGN_SELECT: &str = "SELECT c.id, c.name, c.state, c.campaign_toml, c.instrument_toml, c.total_points,
    (SELECT COUNT(*) FROM points p WHERE p.campaign_id = c.id), c.dry_run, c.software_version, c.created_unix_s,
    c.last_error, c.operator_message FROM campaigns c";

fn campaign_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<Result<CampaignRecord, StoreError>> {
    let state: String = r.get(2)?;
    let total: i64 = r.get(5)?;
    let done: i64 = r.get(6)?;
    let record = |state| CampaignRecord {
        id: CampaignId(0),
        name: String::new(),
        state,
        campaign_toml: String::new(),
        instrument_toml: String::new(),
        total_points: from_i64(total),
        points_done: from_i64(done),
        dry_run: false,
        software_version: String::new(),
        created_unix_s: 0.0,
        last_error: None,
        operator_message: None,
    };
    let state = match state.parse::<CampaignState>() {
        Ok(s) => s,
        Err(e) => return Ok(Err(e)),
    };
    Ok(Ok(CampaignRecord {
        id: CampaignId(r.get(0)?),
        name: r.get(1)?,
        campaign_toml: r.get(3)?,
        instrument_toml: r.get(4)?,
        dry_run: r.get(7)?,
        software_version: r.get(8)?,
        created_unix_s: r.get(9)?,
        last_error: r.get(10)?,
        operator_message: r.get(11)?,
        ..record(state)
    }))
}

fn point_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<Result<PointRecord, StoreError>> {
    let flags: String = r.get(11)?;
    let readback: String = r.get(13)?;
    let readback_deg = match serde_json::from_str(&readback) {
        Ok(v) => v,
        Err(e) => {
            return Ok(Err(StoreError::Corrupt(format!(
                "read-back positions {readback:?}: {e}"
            ))));
        }
    };
    Ok(Ok(PointRecord {
        index: from_i64(r.get(0)?),
        band_nm: r.get(1)?,
        theta_i_deg: r.get(2)?,
        phi_i_deg: r.get(3)?,
        theta_o_deg: r.get(4)?,
        phi_o_deg: r.get(5)?,
        // NULL: no reading (a failed point), stored from NaN.
        signal_w: r.get::<_, Option<f64>>(6)?.unwrap_or(f64::NAN),
        dark_w: r.get::<_, Option<f64>>(7)?.unwrap_or(f64::NAN),
        incident_w: r.get::<_, Option<f64>>(8)?.unwrap_or(f64::NAN),
        brdf_sr: r.get(9)?,
        brdf_u_sr: r.get(10)?,
        flags: if flags.is_empty() {
            Vec::new()
        } else {
            flags.split(';').map(str::to_string).collect()
        },
        t_s: r.get(12)?,
        readback_deg,
        truth_point_sr: r.get(14)?,
        truth_aperture_sr: r.get(15)?,
    }))
}

/// Counts in the store are SQLite INTEGERs (i64); ours are u64 and far below 2^63.
fn to_i64(v: u64) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

fn from_i64(v: i64) -> u64 {
    u64::try_from(v).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn new_campaign(total: u64) -> NewCampaign {
        NewCampaign {
            name: "gold test".into(),
            campaign_toml: "[campaign]\nid = \"x\"\n".into(),
            instrument_toml: "[instrument]\n".into(),
            total_points: total,
            dry_run: true,
            software_version: "0.1.0".into(),
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

    #[test]
    fn a_version_1_store_is_migrated_keeping_its_points() {
        let dir = tempfile::tempdir().expect("tempdir");
        let id = {
            let mut store = Store::open(dir.path()).expect("open");
            let id = store.create_campaign(&new_campaign(3)).expect("create");
            store.commit_point(id, &point(0)).expect("commit");
            id
        };
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
            .replace("CREATE TABLE points", "CREATE TABLE points_v1");
        assert!(v1_table.contains("signal_w REAL NOT NULL"), "{v1_table}");
        conn.execute_batch(&format!(
            "{v1_table}; INSERT INTO points_v1 SELECT * FROM points; DROP TABLE points;
             ALTER TABLE points_v1 RENAME TO points; PRAGMA user_version = 1;"
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
}
