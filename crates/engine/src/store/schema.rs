//! Opening the store: the connection's settings, the schema and its migrations, the durability level each
//! write needs, and the mapping of SQLite errors to [`StoreError`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::LazyLock;
use std::time::Duration;

use rusqlite::{Connection, OptionalExtension};

use super::sweeps::SWEEP_TABLES;
use super::{CampaignId, Durability, SCHEMA_VERSION, STORE_FILE, Store, StoreError};

/// The points table, one column a line (name, declaration): the one definition of its schema. A new store's
/// table, the rebuild of a version-1 one, the insert and the select are all written from this list, and the
/// insert binds and the reader reads each column by its name.
const POINT_COLUMNS: &[(&str, &str)] = &[
    ("campaign_id", "INTEGER NOT NULL REFERENCES campaigns(id)"),
    ("idx", "INTEGER NOT NULL"),
    ("band_nm", "REAL NOT NULL"),
    ("theta_i_deg", "REAL NOT NULL"),
    ("phi_i_deg", "REAL NOT NULL"),
    ("theta_o_deg", "REAL NOT NULL"),
    ("phi_o_deg", "REAL NOT NULL"),
    // NULL: no reading (a failed point), stored from NaN.
    ("signal_w", "REAL"),
    ("dark_w", "REAL"),
    ("incident_w", "REAL"),
    ("brdf_sr", "REAL"),
    ("brdf_u_sr", "REAL"),
    ("flags", "TEXT NOT NULL"),
    ("t_s", "REAL NOT NULL"),
    ("readback_json", "TEXT NOT NULL"),
    ("truth_point_sr", "REAL"),
    ("truth_aperture_sr", "REAL"),
    ("truth_effects_json", "TEXT"),
    // Version 7: the uncertainty budget (the uncorrected aperture average, 1/sr; the budget's compact text,
    // gonio_results::budget). NULL for older points.
    ("brdf_aperture_sr", "REAL"),
    ("budget", "TEXT"),
];

/// How many of [`POINT_COLUMNS`] version 3 had (the rebuild of a version-1 table writes those; later versions'
/// columns are added by their own steps).
const V3_POINT_COLUMNS: usize = 18;

/// The points table's body for `CREATE TABLE points (...)`.
fn points_table_body() -> String {
    points_table_body_of(POINT_COLUMNS)
}

fn points_table_body_of(columns: &[(&str, &str)]) -> String {
    let mut lines: Vec<String> = columns
        .iter()
        .map(|(name, decl)| format!("                {name} {decl}"))
        .collect();
    lines.push("                PRIMARY KEY (campaign_id, idx)".to_string());
    format!("\n{}\n", lines.join(",\n"))
}

/// The instrument calibrations (`gonio align` files kept by the daemon), dated and never overwritten: a trigger
/// refuses every UPDATE and DELETE of a row. (`calibrations` is the campaigns' own calibration readings.)
/// `campaigns.calibration_id` names the one applied to a campaign; it is a plain INTEGER, not a foreign key, so
/// that a campaign row never depends on another table's constraint to be written.
const INSTRUMENT_CALIBRATIONS: &str = "
            CREATE TABLE instrument_calibrations (
                id INTEGER PRIMARY KEY AUTOINCREMENT,
                stored_unix_s REAL NOT NULL,
                instrument TEXT NOT NULL,
                instrument_sha256 TEXT NOT NULL,
                created_utc TEXT NOT NULL,
                software TEXT NOT NULL,
                method TEXT NOT NULL,
                source TEXT NOT NULL,
                calibration_toml TEXT NOT NULL,
                report_json TEXT
            );
            CREATE INDEX instrument_calibrations_by_sha ON instrument_calibrations (instrument_sha256, created_utc);
            CREATE TRIGGER instrument_calibrations_never_updated BEFORE UPDATE ON instrument_calibrations
                BEGIN SELECT RAISE(ABORT, 'a stored instrument calibration is never overwritten'); END;
            CREATE TRIGGER instrument_calibrations_never_deleted BEFORE DELETE ON instrument_calibrations
                BEGIN SELECT RAISE(ABORT, 'a stored instrument calibration is never deleted'); END;
";

/// `INSERT INTO points` of every column, each bound by name (`:band_nm`).
pub(super) static INSERT_POINT: LazyLock<String> = LazyLock::new(|| {
    let names: Vec<&str> = POINT_COLUMNS.iter().map(|(n, _)| *n).collect();
    let values: Vec<String> = names.iter().map(|n| format!(":{n}")).collect();
    format!(
        "INSERT INTO points ({}) VALUES ({})",
        names.join(", "),
        values.join(", ")
    )
});

/// The budgets completed once a campaign has all its points (crate::budget::complete): kept apart, so that a
/// committed point's row is never rewritten; a point's budget and `brdf_u_sr` are read from here when present.
const POINT_BUDGETS: &str = "CREATE TABLE point_budgets (
                campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
                idx INTEGER NOT NULL,
                budget TEXT NOT NULL,
                brdf_u_sr REAL NOT NULL,
                PRIMARY KEY (campaign_id, idx)
            );";

/// Version 9: the completion also keeps the value corrected to the nominal geometry (`brdf_sr`), the aperture
/// average it was corrected from and the point's flags (a narrow lobe): NULL where the committed row's stand.
const POINT_COMPLETIONS: &str = "ALTER TABLE point_budgets ADD COLUMN brdf_sr REAL;
            ALTER TABLE point_budgets ADD COLUMN brdf_aperture_sr REAL;
            ALTER TABLE point_budgets ADD COLUMN flags TEXT;";

/// The columns a completion may replace (crate::budget::complete).
const COMPLETED_COLUMNS: [&str; 5] = ["budget", "brdf_u_sr", "brdf_sr", "brdf_aperture_sr", "flags"];

/// Every column of a campaign's points from an index on (`?1` the campaign, `?2` the first index), in index
/// order, the completion's columns (the budget and its total, the corrected value, ...) in place of the
/// committed ones where there is one; read by name.
pub(super) static SELECT_POINTS_FROM: LazyLock<String> = LazyLock::new(|| select_points(true));

/// The same as committed, without the completions: what a completion starts from again.
pub(super) static SELECT_COMMITTED_POINTS_FROM: LazyLock<String> = LazyLock::new(|| select_points(false));

fn select_points(completed: bool) -> String {
    let names: Vec<String> = POINT_COLUMNS
        .iter()
        .map(|(n, _)| match *n {
            n if completed && COMPLETED_COLUMNS.contains(&n) => format!("COALESCE(b.{n}, p.{n}) AS {n}"),
            n => format!("p.{n} AS {n}"),
        })
        .collect();
    format!(
        "SELECT {} FROM points p LEFT JOIN point_budgets b ON b.campaign_id = p.campaign_id AND b.idx = p.idx \
         WHERE p.campaign_id = ?1 AND p.idx >= ?2 ORDER BY p.idx",
        names.join(", ")
    )
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

    pub(super) fn with_connection(conn: Connection, path: PathBuf) -> Store {
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
    pub(super) fn durability_for_write(&mut self, campaign: Option<CampaignId>) -> Result<(), StoreError> {
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

    /// One migration step: `sql`, then the schema version `to`, in one transaction.
    fn step(&mut self, sql: &str, to: i64) -> Result<(), StoreError> {
        let batch = format!("BEGIN; {sql} PRAGMA user_version = {to}; COMMIT;");
        self.conn
            .execute_batch(&batch)
            .map_err(|source| StoreError::Write {
                path: self.path.clone(),
                source,
            })
    }

    /// Version 1 declared the readings NOT NULL, so a failed point (NaN reading) could not be committed.
    /// SQLite cannot drop a NOT NULL constraint in place: rebuild the table, keeping every row (with no
    /// attribution: version 1 had none). This goes to version 3 (the points as they are now).
    fn migrate_v1(&mut self) -> Result<(), StoreError> {
        let body = points_table_body_of(&POINT_COLUMNS[..V3_POINT_COLUMNS]);
        let sql = format!(
            "BEGIN;
            CREATE TABLE points_v2 ({body});
            INSERT INTO points_v2 SELECT *, NULL FROM points;
            DROP TABLE points;
            ALTER TABLE points_v2 RENAME TO points;
            PRAGMA user_version = 3;
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
        // Older stores are brought forward one version at a time.
        let mut version = version;
        if version == 1 {
            self.migrate_v1()?;
            version = 3;
        }
        if version == 2 {
            // Version 3 only adds a nullable column to the points.
            self.step("ALTER TABLE points ADD COLUMN truth_effects_json TEXT;", 3)?;
            version = 3;
        }
        if version == 3 {
            // Version 4 records the time model's prediction with each campaign (absent for older campaigns).
            self.step("ALTER TABLE campaigns ADD COLUMN predicted_instrument_s REAL;", 4)?;
            version = 4;
        }
        if version == 4 {
            // Version 5 records the alignment calibration applied to a campaign (absent for older ones).
            self.step("ALTER TABLE campaigns ADD COLUMN alignment_toml TEXT;", 5)?;
            version = 5;
        }
        if version == 5 {
            // Version 6 keeps instrument calibrations, and which one a campaign was given.
            self.step(
                &format!(
                    "{INSTRUMENT_CALIBRATIONS} ALTER TABLE campaigns ADD COLUMN calibration_id INTEGER;"
                ),
                6,
            )?;
            version = 6;
        }
        if version == 6 {
            // Version 7 keeps each point's uncertainty budget and uncorrected aperture average.
            self.step(
                "ALTER TABLE points ADD COLUMN brdf_aperture_sr REAL; ALTER TABLE points ADD COLUMN budget TEXT;",
                7,
            )?;
            version = 7;
        }
        if version == 7 {
            // Version 8 keeps the budgets completed after a campaign apart from its committed rows.
            self.step(POINT_BUDGETS, 8)?;
            version = 8;
        }
        if version == 8 {
            self.step(POINT_COMPLETIONS, 9)?;
            version = 9;
        }
        if version == 9 {
            // Version 10 records when a campaign's last run ended (absent for older campaigns).
            self.step("ALTER TABLE campaigns ADD COLUMN ended_instrument_s REAL;", 10)?;
            version = 10;
        }
        if version == 10 {
            // Version 11 stores the readings of sweeps (with version 12's column).
            self.step(SWEEP_TABLES, 12)?;
            return Ok(());
        }
        if version == 11 {
            // Version 12 keeps how well each sweep's readings are placed in time.
            self.step("ALTER TABLE sweep_segments ADD COLUMN timing_u_s REAL;", 12)?;
            return Ok(());
        }
        if version != 0 {
            return Err(StoreError::SchemaVersion {
                path: self.path.clone(),
                found: version,
                expected: SCHEMA_VERSION,
            });
        }
        let points = points_table_body();
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
                operator_message TEXT,
                predicted_instrument_s REAL,
                alignment_toml TEXT,
                calibration_id INTEGER,
                ended_instrument_s REAL
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
            CREATE TABLE points ({points});
            {POINT_BUDGETS}
            {POINT_COMPLETIONS}
            {INSTRUMENT_CALIBRATIONS}
            {SWEEP_TABLES}
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

    pub(super) fn write_err(&self) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
        |source| StoreError::Write {
            path: self.path.clone(),
            source,
        }
    }

    pub(super) fn read_err(&self) -> impl Fn(rusqlite::Error) -> StoreError + '_ {
        |source| StoreError::Read {
            path: self.path.clone(),
            source,
        }
    }
}
