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
    /// Sweep segments, keyed (campaign id, segment).
    pub sweep_segments: Vec<RawRow>,
    /// Sweep readings as committed, keyed (campaign id, segment << 32 | reading): every column but the
    /// completion kept beside them (`completed_*`, written again when the campaign completes).
    pub sweep_readings: Vec<RawRow>,
}

/// The committed columns of a sweep reading (the store's `sweep_readings` less its `completed_*` columns).
const SWEEP_READING_COLUMNS: &str = "campaign_id, segment, k, band_nm, t_s, integration_s, theta_i_deg, \
    phi_i_deg, theta_o_deg, phi_o_deg, arc_from_deg, arc_to_deg, signal_w, incident_w, brdf_sr, brdf_u_sr, flags, \
    truth_point_sr";

/// A campaign's committed sweep segments against its plan: each planned segment once, in order, each with
/// exactly the readings its row counts, numbered from 0 without a gap.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SweepSummary {
    pub planned: u64,
    /// Segment rows in the store.
    pub segments: u64,
    /// Their indices are exactly 0..segments.
    pub in_order: bool,
    /// Readings stored, all segments.
    pub readings: u64,
    /// Segments whose readings are not exactly 0..n for the n their row states.
    pub incomplete: Vec<String>,
}

impl SweepSummary {
    /// Every broken rule, in words. Empty when the sweeps are right.
    pub fn violations(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.segments != self.planned || !self.in_order {
            v.push(format!(
                "{} sweep segments for {} planned (indices in order: {})",
                self.segments, self.planned, self.in_order
            ));
        }
        v.extend(
            self.incomplete
                .iter()
                .map(|m| format!("sweep segment incomplete: {m}")),
        );
        v
    }

    /// Segments lost or incomplete.
    pub fn lost(&self) -> u64 {
        self.planned.saturating_sub(self.segments) + self.incomplete.len() as u64
    }

    /// The sweeps of the store in `data_dir` (one campaign) against `planned` segments, read with SQLite directly.
    pub fn read(data_dir: &Path, planned: u64) -> Result<SweepSummary, SoakError> {
        let mut s = SweepSummary {
            planned,
            in_order: true,
            ..SweepSummary::default()
        };
        let path = data_dir.join(gonio_engine::store::STORE_FILE);
        let conn = Connection::open_with_flags(&path, OpenFlags::SQLITE_OPEN_READ_ONLY)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        if !has_table(&conn, "sweep_segments")? {
            return Ok(s);
        }
        let mut st =
            conn.prepare("SELECT segment, readings FROM sweep_segments ORDER BY campaign_id, segment")?;
        let segments: Vec<(i64, i64)> = st
            .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?
            .collect::<Result<_, _>>()?;
        s.segments = segments.len() as u64;
        s.in_order = segments.iter().enumerate().all(|(i, (seg, _))| *seg == i as i64);
        let mut st = conn.prepare(
            "SELECT COUNT(*), COALESCE(MIN(k), 0), COALESCE(MAX(k), -1) FROM sweep_readings WHERE segment = ?1",
        )?;
        for (segment, stated) in segments {
            let (n, lo, hi): (i64, i64, i64) =
                st.query_row([segment], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?;
            s.readings += u64::try_from(n).unwrap_or(0);
            if n != stated || lo != 0 || hi != stated - 1 {
                s.incomplete.push(format!(
                    "segment {segment}: {n} readings (k {lo}..={hi}) where its row states {stated}"
                ));
            }
        }
        Ok(s)
    }
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
        let (sweep_segments, sweep_readings) = if has_table(&conn, "sweep_segments")? {
            (
                dump(
                    &conn,
                    "SELECT campaign_id, segment, * FROM sweep_segments ORDER BY campaign_id, segment",
                )?,
                dump(
                    &conn,
                    &format!(
                        "SELECT campaign_id, (segment << 32) | k, {SWEEP_READING_COLUMNS} FROM sweep_readings \
                         ORDER BY campaign_id, segment, k"
                    ),
                )?,
            )
        } else {
            (Vec::new(), Vec::new())
        };
        Ok(Snapshot {
            points,
            calibrations,
            sweep_segments,
            sweep_readings,
        })
    }

    /// Is `self` (taken earlier) a prefix of `later`, row for row and byte for byte? The first difference, if any.
    pub fn prefix_of(&self, later: &Snapshot) -> Result<(), String> {
        for (name, a, b) in [
            ("point", &self.points, &later.points),
            ("calibration", &self.calibrations, &later.calibrations),
            ("sweep segment", &self.sweep_segments, &later.sweep_segments),
            ("sweep reading", &self.sweep_readings, &later.sweep_readings),
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
            sweep_readings: vec![row(3, b"r")],
            ..Snapshot::default()
        };
        let grown = Snapshot {
            points: vec![row(0, b"x"), row(1, b"y"), row(2, b"z")],
            calibrations: vec![row(7, b"c")],
            sweep_segments: vec![row(0, b"s")],
            sweep_readings: vec![row(3, b"r"), row(4, b"q")],
        };
        assert_eq!(a.prefix_of(&grown), Ok(()));
        let changed = Snapshot {
            points: vec![row(0, b"x"), row(1, b"Y"), row(2, b"z")],
            sweep_readings: vec![row(3, b"r")],
            ..Snapshot::default()
        };
        assert!(a.prefix_of(&changed).expect_err("changed").contains("(1, 1)"));
        assert!(grown.prefix_of(&a).is_err(), "rows lost");
        let reading_changed = Snapshot {
            sweep_readings: vec![row(3, b"R")],
            ..grown.clone()
        };
        assert!(
            a.prefix_of(&reading_changed)
                .expect_err("changed")
                .starts_with("sweep reading row")
        );
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
