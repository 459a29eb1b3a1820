//! The points CSV of a run: the one column definition, its writer (`gonio run`'s points.csv, the daemon's
//! `/api/campaigns/{id}/points.csv`, the table of `gonio export --format csv`) and its reader.
//!
//! Columns: `index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,
//! brdf_u_sr,flags,t_s` ([`FIXED_COLUMNS`]), then one `<axis>_deg` read-back column per axis (instrument file
//! order), then the uncertainty budget's `brdf_aperture_sr,brdf_u_indep_sr,budget` ([`BUDGET_COLUMNS`]), then in
//! dry-runs `brdf_true_sr,brdf_true_aperture_sr` ([`TRUTH_COLUMNS`]). The writer puts numbers in
//! shortest round-trip form (`Display`), so the CSV holds exactly what the store holds, and a missing value
//! (including a failed reading) as an empty field.
//!
//! The reader goes by the header, not by position: the geometry, `brdf_sr`, `brdf_u_sr` and `flags` columns are
//! required, the others optional, unknown columns are ignored. An empty field is a missing value; `NaN` (what
//! older versions wrote for a failed reading) is read as missing too. Quoted fields (RFC 4180, on one line) are
//! accepted although gonio never writes them, so that a CSV that went through a spreadsheet still reads. Every
//! error names the file, the line and the column.

use std::fmt::Write as _;

use crate::budget::Budget;
use crate::error::ResultsError;

/// One measured point, as stored. Angles in degrees (the CSV's nominal sample-frame geometry), BRDF in 1/sr.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub index: u64,
    pub band_nm: f64,
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    pub signal_w: Option<f64>,
    pub dark_w: Option<f64>,
    pub incident_w: Option<f64>,
    pub brdf_sr: Option<f64>,
    /// Standard uncertainty (k = 1) of `brdf_sr`.
    pub brdf_u_sr: Option<f64>,
    /// Empty for a valid point, else the reasons (saturated, overfilled, failed: ...).
    pub flags: Vec<String>,
    /// Instrument time of the reading, s from the start of the run.
    pub t_s: Option<f64>,
    /// Read-back axis positions, degrees, in the CSV's column order.
    pub readback_deg: Vec<(String, Option<f64>)>,
    /// The aperture average the value was corrected from (1/sr): `brdf_sr` is the BRDF at the nominal
    /// geometry, this is what the detector's aperture saw ([`crate::budget`]'s `aperture` component is the
    /// correction's own uncertainty). `None`: no correction was made (older runs, or none was possible).
    pub brdf_aperture_sr: Option<f64>,
    /// The point's uncertainty budget; `brdf_u_sr` is its total. Empty for older runs.
    pub budget: Budget,
    /// Dry-runs: the simulator's point value and aperture-averaged value, 1/sr.
    pub truth_point_sr: Option<f64>,
    pub truth_aperture_sr: Option<f64>,
}

impl Point {
    /// A valid point of value `f` (1/sr) at a geometry (degrees) in a band, nothing else known: what the tests
    /// of this crate build on.
    #[cfg(test)]
    pub(crate) fn at(band_nm: f64, geometry_deg: [f64; 4], f: f64) -> Point {
        let [theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg] = geometry_deg;
        Point {
            index: 0,
            band_nm,
            theta_i_deg,
            phi_i_deg,
            theta_o_deg,
            phi_o_deg,
            signal_w: None,
            dark_w: None,
            incident_w: None,
            brdf_sr: Some(f),
            brdf_u_sr: None,
            flags: Vec::new(),
            t_s: None,
            readback_deg: Vec::new(),
            brdf_aperture_sr: None,
            budget: Budget::default(),
            truth_point_sr: None,
            truth_aperture_sr: None,
        }
    }
    /// True when the point carries a usable BRDF value: no flag, a finite value.
    pub fn is_valid(&self) -> bool {
        self.flags.is_empty() && self.brdf_sr.is_some_and(f64::is_finite)
    }

    /// The BRDF value of a valid point.
    pub fn value(&self) -> Option<f64> {
        if self.is_valid() { self.brdf_sr } else { None }
    }

    /// The independent part of the point's standard uncertainty (1/sr): the budget's when it has one, else the
    /// whole `brdf_u_sr` (a run without a budget cannot tell its parts apart).
    pub fn u_independent_sr(&self) -> Option<f64> {
        if self.budget.entries.is_empty() {
            self.brdf_u_sr
        } else {
            Some(self.budget.independent_sr())
        }
    }
}

/// A parsed points CSV: the points and what the header said about the run.
#[derive(Debug, Clone, PartialEq)]
pub struct PointsTable {
    pub points: Vec<Point>,
    /// The `<axis>_deg` read-back columns, axis names without the suffix.
    pub axis_names: Vec<String>,
    /// True when the CSV has the dry-run truth columns.
    pub dry_run: bool,
}

/// The fixed leading columns, in the order they are written.
pub const FIXED_COLUMNS: [&str; 13] = [
    "index",
    "band_nm",
    "theta_i_deg",
    "phi_i_deg",
    "theta_o_deg",
    "phi_o_deg",
    "signal_w",
    "dark_w",
    "incident_w",
    "brdf_sr",
    "brdf_u_sr",
    "flags",
    "t_s",
];

const REQUIRED: [&str; 9] = [
    "index",
    "band_nm",
    "theta_i_deg",
    "phi_i_deg",
    "theta_o_deg",
    "phi_o_deg",
    "brdf_sr",
    "brdf_u_sr",
    "flags",
];

/// The uncertainty budget's columns, after the fixed ones and the read-back axes: the uncorrected aperture
/// average (1/sr), the independent part of `brdf_u_sr` (1/sr), and the budget in its compact form
/// ([`crate::budget`]).
pub const BUDGET_COLUMNS: [&str; 3] = ["brdf_aperture_sr", "brdf_u_indep_sr", "budget"];

/// The dry-run columns, last: the simulator's point value and its aperture average.
pub const TRUTH_COLUMNS: [&str; 2] = ["brdf_true_sr", "brdf_true_aperture_sr"];

/// Every column name of a points CSV with these read-back axes, in order.
pub fn columns(axis_names: &[String], dry_run: bool) -> Vec<String> {
    let mut c: Vec<String> = FIXED_COLUMNS.iter().map(|c| c.to_string()).collect();
    c.extend(axis_names.iter().map(|a| format!("{a}_deg")));
    c.extend(BUDGET_COLUMNS.iter().map(|c| c.to_string()));
    if dry_run {
        c.extend(TRUTH_COLUMNS.iter().map(|c| c.to_string()));
    }
    c
}

fn num(s: &mut String, v: f64) {
    // `+ 0.0` turns -0 into 0; Display is the shortest representation that round-trips.
    let _ = write!(s, "{}", v + 0.0);
}

fn opt(s: &mut String, v: Option<f64>) {
    if let Some(v) = v.filter(|v| v.is_finite()) {
        num(s, v);
    }
}

/// Appends one row (no newline) in the column order of [`columns`] for these axes.
pub fn write_row(s: &mut String, p: &Point, axis_names: &[String], dry_run: bool) {
    let _ = write!(s, "{}", p.index);
    for v in [p.band_nm, p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg] {
        s.push(',');
        num(s, v);
    }
    for v in [p.signal_w, p.dark_w, p.incident_w, p.brdf_sr, p.brdf_u_sr] {
        s.push(',');
        opt(s, v);
    }
    s.push(',');
    // Flags are our own words and never hold these, but a row must stay one unquoted CSV record.
    s.push_str(&p.flags.join(";").replace([',', '"', '\n', '\r'], " "));
    s.push(',');
    opt(s, p.t_s);
    for axis in axis_names {
        s.push(',');
        opt(
            s,
            p.readback_deg
                .iter()
                .find(|(a, _)| a == axis)
                .and_then(|(_, v)| *v),
        );
    }
    s.push(',');
    opt(s, p.brdf_aperture_sr);
    s.push(',');
    if !p.budget.entries.is_empty() {
        num(s, p.budget.independent_sr());
    }
    s.push(',');
    s.push_str(&p.budget.to_compact());
    if dry_run {
        s.push(',');
        opt(s, p.truth_point_sr);
        s.push(',');
        opt(s, p.truth_aperture_sr);
    }
}

/// The whole points CSV, header included: what [`parse_points_csv`] reads back to the same table.
pub fn write_points_csv(table: &PointsTable) -> String {
    let mut s = columns(&table.axis_names, table.dry_run).join(",");
    s.push('\n');
    for p in &table.points {
        write_row(&mut s, p, &table.axis_names, table.dry_run);
        s.push('\n');
    }
    s
}

/// Splits one CSV line into fields. Quoted fields may hold commas and doubled quotes; a quote must close on
/// the same line.
pub(crate) fn split_record(line: &str) -> Result<Vec<String>, String> {
    let mut fields = Vec::new();
    let mut field = String::new();
    let mut chars = line.chars().peekable();
    let mut at_start = true;
    loop {
        if at_start && chars.peek() == Some(&'"') {
            chars.next();
            loop {
                match chars.next() {
                    None => {
                        return Err(format!(
                            "field {} opens a quote that is never closed",
                            fields.len() + 1
                        ));
                    }
                    Some('"') if chars.peek() == Some(&'"') => {
                        chars.next();
                        field.push('"');
                    }
                    Some('"') => break,
                    Some(c) => field.push(c),
                }
            }
            match chars.next() {
                None => {
                    fields.push(std::mem::take(&mut field));
                    return Ok(fields);
                }
                Some(',') => {
                    fields.push(std::mem::take(&mut field));
                    at_start = true;
                    continue;
                }
                Some(c) => {
                    return Err(format!(
                        "field {} has {c:?} after its closing quote (expected a comma)",
                        fields.len() + 1
                    ));
                }
            }
        }
        at_start = false;
        match chars.next() {
            None => {
                fields.push(field);
                return Ok(fields);
            }
            Some(',') => {
                fields.push(std::mem::take(&mut field));
                at_start = true;
            }
            Some(c) => field.push(c),
        }
    }
}

/// Where each known column is in the header.
struct Layout {
    index: usize,
    band_nm: usize,
    theta_i: usize,
    phi_i: usize,
    theta_o: usize,
    phi_o: usize,
    signal: Option<usize>,
    dark: Option<usize>,
    incident: Option<usize>,
    brdf: usize,
    brdf_u: usize,
    flags: usize,
    t_s: Option<usize>,
    axes: Vec<(String, usize)>,
    aperture: Option<usize>,
    budget: Option<usize>,
    truth_point: Option<usize>,
    truth_aperture: Option<usize>,
    columns: usize,
}

impl Layout {
    fn from_header(header: &[String], origin: &str) -> Result<Layout, ResultsError> {
        let bad = |message: String| ResultsError::Csv {
            origin: origin.to_string(),
            line: 1,
            message,
        };
        for (i, name) in header.iter().enumerate() {
            if header[..i].contains(name) {
                return Err(bad(format!("the header names column `{name}` twice")));
            }
        }
        let find = |name: &str| header.iter().position(|h| h == name);
        let missing: Vec<&str> = REQUIRED.iter().copied().filter(|c| find(c).is_none()).collect();
        if !missing.is_empty() {
            return Err(bad(format!(
                "the header lacks the column(s) {}; a gonio points CSV starts with `{}`",
                missing.join(", "),
                FIXED_COLUMNS.join(",")
            )));
        }
        let need = |name: &str| find(name).unwrap_or(0);
        let axes = header
            .iter()
            .enumerate()
            .filter(|(_, h)| h.ends_with("_deg") && !FIXED_COLUMNS.contains(&h.as_str()) && h.len() > 4)
            .map(|(i, h)| (h[..h.len() - 4].to_string(), i))
            .collect();
        Ok(Layout {
            index: need("index"),
            band_nm: need("band_nm"),
            theta_i: need("theta_i_deg"),
            phi_i: need("phi_i_deg"),
            theta_o: need("theta_o_deg"),
            phi_o: need("phi_o_deg"),
            signal: find("signal_w"),
            dark: find("dark_w"),
            incident: find("incident_w"),
            brdf: need("brdf_sr"),
            brdf_u: need("brdf_u_sr"),
            flags: need("flags"),
            t_s: find("t_s"),
            axes,
            aperture: find(BUDGET_COLUMNS[0]),
            budget: find(BUDGET_COLUMNS[2]),
            truth_point: find(TRUTH_COLUMNS[0]),
            truth_aperture: find(TRUTH_COLUMNS[1]),
            columns: header.len(),
        })
    }
}

/// Reads the text of a points CSV; `origin` names it in errors (a path, or "store ... campaign ...").
pub fn parse_points_csv(text: &str, origin: &str) -> Result<PointsTable, ResultsError> {
    let mut lines = text.lines().enumerate();
    let Some((_, header_line)) = lines.next() else {
        return Err(ResultsError::Csv {
            origin: origin.to_string(),
            line: 0,
            message: "the file is empty (expected a header line)".into(),
        });
    };
    let header = split_record(header_line.trim_end_matches('\r')).map_err(|message| ResultsError::Csv {
        origin: origin.to_string(),
        line: 1,
        message,
    })?;
    let header: Vec<String> = header.into_iter().map(|h| h.trim().to_string()).collect();
    let layout = Layout::from_header(&header, origin)?;
    let mut points = Vec::new();
    for (i, raw) in lines {
        let line_no = i + 1;
        let line = raw.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        let err = |message: String| ResultsError::Csv {
            origin: origin.to_string(),
            line: line_no,
            message,
        };
        let fields = split_record(line).map_err(err)?;
        if fields.len() != layout.columns {
            return Err(err(format!(
                "{} fields, but the header has {} columns",
                fields.len(),
                layout.columns
            )));
        }
        points.push(parse_row(&fields, &layout, &header).map_err(err)?);
    }
    Ok(PointsTable {
        points,
        axis_names: layout.axes.iter().map(|(n, _)| n.clone()).collect(),
        dry_run: layout.truth_point.is_some() || layout.truth_aperture.is_some(),
    })
}

fn parse_row(fields: &[String], layout: &Layout, header: &[String]) -> Result<Point, String> {
    let text = |i: usize| fields.get(i).map(|s| s.trim()).unwrap_or("");
    let name = |i: usize| header.get(i).map(String::as_str).unwrap_or("?");
    // A required number: present and finite.
    let number = |i: usize| -> Result<f64, String> {
        let t = text(i);
        match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(format!("column `{}`: {t:?} is not a finite number", name(i))),
            Err(_) if t.is_empty() => Err(format!("column `{}` is empty (a number is required)", name(i))),
            Err(_) => Err(format!("column `{}`: {t:?} is not a number", name(i))),
        }
    };
    // An optional number: empty or NaN is missing; anything else must parse.
    let optional = |i: Option<usize>| -> Result<Option<f64>, String> {
        let Some(i) = i else { return Ok(None) };
        let t = text(i);
        if t.is_empty() {
            return Ok(None);
        }
        match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(Some(v)),
            Ok(v) if v.is_nan() => Ok(None),
            Ok(_) => Err(format!("column `{}`: {t:?} is not a finite number", name(i))),
            Err(_) => Err(format!("column `{}`: {t:?} is not a number", name(i))),
        }
    };
    let index_text = text(layout.index);
    let index = index_text.parse::<u64>().map_err(|_| {
        format!("column `index`: {index_text:?} is not a point index (a non-negative integer)")
    })?;
    let band_nm = number(layout.band_nm)?;
    if band_nm <= 0.0 {
        return Err(format!(
            "column `band_nm`: {band_nm} is not a positive wavelength"
        ));
    }
    let flags_text = text(layout.flags);
    let flags = if flags_text.is_empty() {
        Vec::new()
    } else {
        flags_text
            .split(';')
            .map(|f| f.trim().to_string())
            .filter(|f| !f.is_empty())
            .collect()
    };
    let brdf_u_sr = optional(Some(layout.brdf_u))?;
    if let Some(u) = brdf_u_sr
        && u < 0.0
    {
        return Err(format!(
            "column `brdf_u_sr`: {u} is negative (an uncertainty is >= 0)"
        ));
    }
    // `brdf_u_indep_sr` is the budget's independent part, recomputed from the budget: not read.
    let budget = match layout.budget.map(text) {
        Some(t) => Budget::parse_compact(t).map_err(|e| format!("column `budget`: {}", e.reason))?,
        None => Budget::default(),
    };
    let mut readback_deg = Vec::with_capacity(layout.axes.len());
    for (axis, i) in &layout.axes {
        readback_deg.push((axis.clone(), optional(Some(*i))?));
    }
    Ok(Point {
        index,
        band_nm,
        theta_i_deg: number(layout.theta_i)?,
        phi_i_deg: number(layout.phi_i)?,
        theta_o_deg: number(layout.theta_o)?,
        phi_o_deg: number(layout.phi_o)?,
        signal_w: optional(layout.signal)?,
        dark_w: optional(layout.dark)?,
        incident_w: optional(layout.incident)?,
        brdf_sr: optional(Some(layout.brdf))?,
        brdf_u_sr,
        flags,
        t_s: optional(layout.t_s)?,
        readback_deg,
        brdf_aperture_sr: optional(layout.aperture)?,
        budget,
        truth_point_sr: optional(layout.truth_point)?,
        truth_aperture_sr: optional(layout.truth_aperture)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const HEADER: &str = "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,\
                          brdf_sr,brdf_u_sr,flags,t_s,light_deg,detector_deg,brdf_true_sr,brdf_true_aperture_sr";
    /// What this version writes: the budget columns after the axes.
    const BUDGET_HEADER: &str = "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,\
                                 incident_w,brdf_sr,brdf_u_sr,flags,t_s,light_deg,detector_deg,brdf_aperture_sr,\
                                 brdf_u_indep_sr,budget,brdf_true_sr,brdf_true_aperture_sr";

    #[test]
    fn reads_the_gonio_run_layout() {
        let text = format!(
            "{HEADER}\n0,550,30,180,45,0,1e-7,1e-10,5e-4,0.25,0.001,,12.5,-30,45,0.2501,0.2502\n\
             1,550,30,180,60,0,NaN,,,,,failed: meter timeout;saturated,13,,,0.1,\n"
        );
        let t = parse_points_csv(&text, "x.csv").expect("parses");
        assert!(t.dry_run);
        assert_eq!(t.axis_names, vec!["light".to_string(), "detector".to_string()]);
        assert_eq!(t.points.len(), 2);
        let p = &t.points[0];
        assert_eq!((p.index, p.band_nm, p.theta_o_deg), (0, 550.0, 45.0));
        assert_eq!(p.brdf_sr, Some(0.25));
        assert_eq!(p.readback_deg[1], ("detector".to_string(), Some(45.0)));
        assert!(p.is_valid());
        let q = &t.points[1];
        assert_eq!(
            q.flags,
            vec!["failed: meter timeout".to_string(), "saturated".to_string()]
        );
        assert_eq!(q.signal_w, None);
        assert!(!q.is_valid());
        assert_eq!(q.truth_aperture_sr, None);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let text = format!("{HEADER}\n0,550,30,180,45,0,1e-7,1e-10,5e-4,abc,0.001,,12.5,-30,45,0.25,0.25\n");
        let e = parse_points_csv(&text, "run/points.csv")
            .expect_err("bad number")
            .to_string();
        assert!(
            e.contains("run/points.csv, line 2") && e.contains("brdf_sr") && e.contains("\"abc\""),
            "{e}"
        );
        let e = parse_points_csv("index,band_nm\n0,550\n", "p.csv")
            .expect_err("missing columns")
            .to_string();
        assert!(e.contains("p.csv, line 1") && e.contains("theta_i_deg"), "{e}");
        let e = parse_points_csv(&format!("{HEADER}\n0,550\n"), "p.csv")
            .expect_err("short row")
            .to_string();
        assert!(
            e.contains("line 2") && e.contains("2 fields") && e.contains("17 columns"),
            "{e}"
        );
        let e = parse_points_csv("", "empty.csv").expect_err("empty").to_string();
        assert!(e.contains("empty.csv") && e.contains("empty"), "{e}");
    }

    #[test]
    fn the_writer_writes_what_the_reader_reads() {
        let text = format!(
            "{BUDGET_HEADER}\n0,550,30,180,45,0,0.0000001,0.0000000001,0.0005,0.2500000000000001,0.001,,12.5,-30,45,0.2502,0.0009,signal-noise=0.0009;solid-angle@campaign=0.0004,0.2501,0.2502\n\
             1,550,30,180,60,0,,,,,,failed: meter timeout;saturated,13,,,,,,0.1,\n"
        );
        let table = parse_points_csv(&text, "x.csv").expect("parses");
        assert_eq!(
            write_points_csv(&table),
            text,
            "the canonical text comes back byte for byte"
        );
        // What older versions wrote for a failed reading (NaN) reads as missing and is written as such.
        let old = text.replacen("1,550,30,180,60,0,,", "1,550,30,180,60,0,NaN,", 1);
        assert_ne!(old, text);
        let table = parse_points_csv(&old, "old.csv").expect("parses");
        assert_eq!(write_points_csv(&table), text);
        // -0 is written as 0.
        let mut table = table;
        table.points[0].phi_o_deg = -0.0;
        assert!(write_points_csv(&table).contains("\n0,550,30,180,45,0,"));
    }

    #[test]
    fn quoted_fields_hold_commas() {
        assert_eq!(
            split_record(r#"a,"b,c","d""e",,"#).expect("valid"),
            vec!["a", "b,c", "d\"e", "", ""]
        );
        assert!(split_record(r#"a,"b"#).is_err());
        assert!(split_record(r#""a"x,b"#).is_err());
    }

    proptest! {
        // The reader never panics, whatever the bytes after a valid header.
        #[test]
        fn never_panics_on_arbitrary_rows(body in "[0-9a-zA-Z,.;:\"\\-+ \\n\\r]{0,400}") {
            let _ = parse_points_csv(&format!("{HEADER}\n{body}"), "fuzz.csv");
        }

        #[test]
        fn never_panics_on_arbitrary_text(text in any::<String>()) {
            let _ = parse_points_csv(&text, "fuzz.csv");
        }

        // Well-formed rows round-trip their numbers exactly (the writer uses shortest round-trip formatting).
        #[test]
        fn numbers_round_trip(f in 0.0f64..1e3, u in 0.0f64..1.0, t in 0.0f64..90.0) {
            let text = format!("{HEADER}\n7,650,{t},0,{t},180,1,0,1,{f},{u},,1,0,0,{f},{f}\n");
            let table = parse_points_csv(&text, "rt.csv").expect("valid row");
            prop_assert_eq!(table.points[0].brdf_sr, Some(f));
            prop_assert_eq!(table.points[0].brdf_u_sr, Some(u));
            prop_assert_eq!(table.points[0].theta_i_deg, t);
        }
    }
}
