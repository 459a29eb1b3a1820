//! The store's rows after a soak: [`RowSummary`], a campaign's committed points against its plan (the verdict
//! every soak that runs a campaign ends with), and [`Snapshot`], the raw rows read with SQLite directly: every
//! column of every row as its bytes (integers and reals by their bit patterns, text and blobs as stored), so that
//! "byte-identical" means exactly that and does not depend on the store's own decoding (which, for instance, turns
//! NULL readings into NaN).

use std::path::Path;

use gonio_engine::store::PointRecord;
use rusqlite::types::ValueRef;
use rusqlite::{Connection, OpenFlags};

use crate::SoakError;
use crate::truth_check::{PointCheck, Tolerance, check_points};

/// A campaign's committed points against its plan.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RowSummary {
    /// Points the plan holds.
    pub planned: u64,
    /// Point rows in the store.
    pub rows: u64,
    /// Their indices are exactly 0..rows.
    pub indices_in_order: bool,
    /// Their values against the simulator's ground truth.
    pub points: PointCheck,
}

impl RowSummary {
    /// The summary of a campaign's `points` (as the store returns them, in index order) against `planned`, on an
    /// instrument of tolerance `tol` ([`crate::truth_check`]).
    pub fn of(planned: u64, points: &[PointRecord], tol: &Tolerance) -> RowSummary {
        RowSummary {
            planned,
            rows: points.len() as u64,
            indices_in_order: points.iter().enumerate().all(|(i, p)| p.index == i as u64),
            points: check_points(points, tol),
        }
    }

    /// Every broken rule, in words: one row per planned point with its indices in order, no silently wrong
    /// value, no point without a value or a reason. Empty when the rows are right.
    pub fn violations(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.rows != self.planned || !self.indices_in_order {
            v.push(format!(
                "{} rows for {} planned points (indices in order: {})",
                self.rows, self.planned, self.indices_in_order
            ));
        }
        for w in &self.points.wrong {
            v.push(format!("silently wrong value: {w}"));
        }
        for u in &self.points.unexplained {
            v.push(format!("point without value or reason: {u}"));
        }
        v
    }

    /// Points lost or wrong: missing rows, silently wrong values, points without value or reason.
    pub fn lost(&self) -> u64 {
        self.planned.saturating_sub(self.rows)
            + self.points.wrong.len() as u64
            + self.points.unexplained.len() as u64
    }
}

/// One row: its key and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawRow {
    /// (campaign id, index) for points; (campaign id, rowid) for calibrations.
    pub key: (i64, i64),
    pub bytes: Vec<u8>,
}

/// The rows of the tables that must never change once written.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Snapshot {
    pub points: Vec<RawRow>,
    pub calibrations: Vec<RawRow>,
}

impl Snapshot {
    /// Read the store in `data_dir` (empty when there is none yet). Opening runs SQLite's crash recovery
    /// (rolling the write-ahead log forward to its last complete transaction), as the daemon's next start would.
    pub fn read(data_dir: &Path) -> Result<Snapshot, SoakError> {
        let path = data_dir.join(gonio_engine::store::STORE_FILE);
        if !path.exists() {
            return Ok(Snapshot::default());
        }
        let conn = Connection::open_with_flags(
            &path,
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        if !has_table(&conn, "points")? {
            return Ok(Snapshot::default());
        }
        let points = dump(
            &conn,
            "SELECT campaign_id, idx, * FROM points ORDER BY campaign_id, idx",
        )?;
        let calibrations = if has_table(&conn, "calibrations")? {
            dump(
                &conn,
                "SELECT campaign_id, rowid, * FROM calibrations ORDER BY campaign_id, rowid",
            )?
        } else {
            Vec::new()
        };
        Ok(Snapshot { points, calibrations })
    }

    /// Is `self` (taken earlier) a prefix of `later`, row for row and byte for byte? The first difference, if any.
    pub fn prefix_of(&self, later: &Snapshot) -> Result<(), String> {
        for (name, a, b) in [
            ("point", &self.points, &later.points),
            ("calibration", &self.calibrations, &later.calibrations),
        ] {
            if b.len() < a.len() {
                return Err(format!("{} {name} rows before, only {} after", a.len(), b.len()));
            }
            if let Some((x, y)) = a.iter().zip(b).find(|(x, y)| x != y) {
                return Err(format!(
                    "{name} row {:?} changed (now row {:?}: {} bytes before, {} after)",
                    x.key,
                    y.key,
                    x.bytes.len(),
                    y.bytes.len()
                ));
            }
        }
        Ok(())
    }
}

fn has_table(conn: &Connection, name: &str) -> Result<bool, SoakError> {
    let n: i64 = conn.query_row(
        "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND name = ?1",
        [name],
        |r| r.get(0),
    )?;
    Ok(n > 0)
}

/// Rows of a query whose first two columns are the key.
fn dump(conn: &Connection, sql: &str) -> Result<Vec<RawRow>, SoakError> {
    let mut stmt = conn.prepare(sql)?;
    let columns = stmt.column_count();
    let mut rows = stmt.query([])?;
    let mut out = Vec::new();
    while let Some(row) = rows.next()? {
        let key = (row.get::<_, i64>(0)?, row.get::<_, i64>(1)?);
        let mut bytes = Vec::new();
        for i in 2..columns {
            encode(&mut bytes, row.get_ref(i)?);
        }
        out.push(RawRow { key, bytes });
    }
    Ok(out)
}

/// A value as tagged bytes (type tag, then the value).
fn encode(out: &mut Vec<u8>, v: ValueRef<'_>) {
    match v {
        ValueRef::Null => out.push(0),
        ValueRef::Integer(i) => {
            out.push(1);
            out.extend_from_slice(&i.to_le_bytes());
        }
        ValueRef::Real(r) => {
            out.push(2);
            out.extend_from_slice(&r.to_bits().to_le_bytes());
        }
        ValueRef::Text(t) => {
            out.push(3);
            out.extend_from_slice(&(t.len() as u64).to_le_bytes());
            out.extend_from_slice(t);
        }
        ValueRef::Blob(b) => {
            out.push(4);
            out.extend_from_slice(&(b.len() as u64).to_le_bytes());
            out.extend_from_slice(b);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_summary_names_each_kind_of_violation() {
        let mut s = RowSummary {
            planned: 3,
            rows: 3,
            indices_in_order: true,
            points: PointCheck::default(),
        };
        assert_eq!(s.violations(), Vec::<String>::new());
        assert_eq!(s.lost(), 0);
        s.rows = 2;
        assert_eq!(
            s.violations(),
            ["2 rows for 3 planned points (indices in order: true)"]
        );
        assert_eq!(s.lost(), 1);
        s.rows = 3;
        s.indices_in_order = false;
        assert_eq!(
            s.violations(),
            ["3 rows for 3 planned points (indices in order: false)"]
        );
        assert_eq!(s.lost(), 0, "rows out of order are reported, not counted as lost");
        s.indices_in_order = true;
        s.points.wrong.push("point 1".into());
        s.points.unexplained.push("point 2".into());
        assert_eq!(
            s.violations(),
            [
                "silently wrong value: point 1",
                "point without value or reason: point 2"
            ]
        );
        assert_eq!(s.lost(), 2);
    }

    #[test]
    fn a_row_summary_of_no_points_is_every_point_lost() {
        let s = RowSummary::of(5, &[], &Tolerance::ideal());
        assert_eq!((s.rows, s.indices_in_order, s.lost()), (0, true, 5));
        assert_eq!(s.violations().len(), 1);
    }

    fn row(k: i64, b: &[u8]) -> RawRow {
        RawRow {
            key: (1, k),
            bytes: b.to_vec(),
        }
    }

    #[test]
    fn prefix_means_same_rows_same_bytes() {
        let a = Snapshot {
            points: vec![row(0, b"x"), row(1, b"y")],
            calibrations: vec![],
        };
        let grown = Snapshot {
            points: vec![row(0, b"x"), row(1, b"y"), row(2, b"z")],
            calibrations: vec![row(7, b"c")],
        };
        assert_eq!(a.prefix_of(&grown), Ok(()));
        let changed = Snapshot {
            points: vec![row(0, b"x"), row(1, b"Y"), row(2, b"z")],
            calibrations: vec![],
        };
        assert!(a.prefix_of(&changed).expect_err("changed").contains("(1, 1)"));
        assert!(grown.prefix_of(&a).is_err(), "rows lost");
    }

    #[test]
    fn a_real_value_is_encoded_by_its_bits() {
        let mut a = Vec::new();
        encode(&mut a, ValueRef::Real(0.1));
        let mut b = Vec::new();
        encode(&mut b, ValueRef::Real(0.1 + 1e-18));
        let mut c = Vec::new();
        encode(&mut c, ValueRef::Real(f64::from_bits(0.1f64.to_bits() + 1)));
        assert_eq!(a, b, "the same double");
        assert_ne!(a, c, "one ulp apart");
    }
}
