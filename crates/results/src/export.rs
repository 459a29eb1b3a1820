//! CSV and JSON exports of a run: every point with its units and the run's full provenance.
//!
//! CSV: `#` comment lines first (what the columns mean and their units, then the provenance: run.json flattened
//! to `# path = value` lines, the campaign and instrument files verbatim as indented blocks, and the resolved
//! configuration when the caller supplies it), then the points with the columns of points.csv. Readers that
//! skip comment lines (`pandas.read_csv(comment="#")`, R's `read.csv(comment.char="#")`, gnuplot) read the
//! table directly. JSON: one object ([`FORMAT`] version [`FORMAT_VERSION`]) with `units`, `conventions`,
//! `provenance` (run.json as written by the run), `resolved` and `points` (one object per point, missing
//! values as `null`, read-backs as an object axis -> degrees). Both also carry the short provenance every export
//! has ([`crate::provenance_summary`]): `# provenance.<key> = "<value>"` lines, a `provenance_summary` object.

use std::fmt::Write as _;

use serde_json::{Map, Value, json};

use crate::points::{self, Point};
use crate::provenance_summary::{ExportSetup, provenance_lines};
use crate::run::Run;

/// The `format` field of the JSON export.
pub const FORMAT: &str = "gonio-points";
/// Bumped when the JSON layout changes incompatibly.
pub const FORMAT_VERSION: u32 = 1;

/// What the caller adds to the run's own provenance.
#[derive(Debug, Clone, Default)]
pub struct ExportContext {
    /// The exporting program, e.g. "gonio 0.1.0".
    pub exported_by: String,
    /// The run's configuration as resolved by the campaign parser (defaults applied, presets expanded), when
    /// the caller could resolve it; kept verbatim.
    pub resolved: Option<Value>,
    /// Facts from the run's instrument and campaign files (instrument name, detector, calibration), when the
    /// caller could read them.
    pub setup: Option<ExportSetup>,
}

impl ExportContext {
    /// The short provenance every export carries ([`provenance_lines`]).
    pub fn provenance_lines(&self, run: &Run) -> Vec<(&'static str, String)> {
        provenance_lines(run, &self.exported_by, self.setup.as_ref())
    }
}

/// Unit (or meaning) of every column, in the column order of the points CSV.
pub fn column_units(run: &Run) -> Vec<(String, &'static str)> {
    points::columns(&run.axis_names, run.dry_run)
        .into_iter()
        .map(|c| {
            let unit = match c.as_str() {
                "index" => "point index in the plan (0-based)",
                "band_nm" => "nm",
                "theta_i_deg" | "phi_i_deg" | "theta_o_deg" | "phi_o_deg" => "degree",
                "signal_w" | "dark_w" | "incident_w" => "W",
                "brdf_sr" | "brdf_u_sr" => "1/sr",
                "flags" => "';'-separated reasons, empty for a valid point",
                "t_s" => "s",
                "brdf_aperture_sr" | "brdf_u_indep_sr" => "1/sr",
                "budget" => "';'-separated component[@shared-group]=standard uncertainty in 1/sr",
                c if points::TRUTH_COLUMNS.contains(&c) => "1/sr",
                // The remaining columns are the `<axis>_deg` read-backs.
                _ => "degree",
            };
            (c, unit)
        })
        .collect()
}

/// The conventions a reader needs, one sentence each.
pub const CONVENTIONS: [(&str, &str); 8] = [
    (
        "frame",
        "sample frame: z is the surface normal; theta from the normal, phi about it from +x towards +y; \
         i is the direction towards the source, o towards the detector",
    ),
    ("brdf", "BRDF values in 1/sr without the cosine factor"),
    (
        "uncertainty",
        "brdf_u_sr is the combined standard uncertainty (k = 1)",
    ),
    (
        "budget",
        "budget lists brdf_u_sr's components (k = 1, 1/sr; their root sum of squares is brdf_u_sr); a component \
         named with @group is fully correlated between the points of that group (campaign: every point; band-<nm>: \
         a band's points; range-<i>: the readings on one meter range), the others are independent from point to \
         point; brdf_u_indep_sr is the root sum of squares of the independent ones",
    ),
    (
        "readback",
        "<axis>_deg are the axes' read-back positions, physical axis angles in degrees",
    ),
    (
        "aperture",
        "brdf_sr is the BRDF at the nominal geometry: corrected, where brdf_aperture_sr is given, from that average \
         over the detector aperture (cos-weighted) with a model fitted to the campaign (budget component aperture: \
         the correction's uncertainty); a point flagged narrow-lobe keeps the average, its lobe being narrower than \
         the aperture",
    ),
    (
        "time",
        "t_s is instrument time from the start of the run, in seconds",
    ),
    (
        "truth",
        "dry-runs only: brdf_true_sr is the simulated material's point value, brdf_true_aperture_sr its average \
         over the detector aperture",
    ),
];

/// Flattens a JSON value into `# path = value` lines; arrays of scalars and small objects stay on one line.
fn flatten(out: &mut String, path: &str, v: &Value) {
    match v {
        Value::Object(map) if !map.is_empty() && map.values().any(|x| x.is_object() || x.is_array()) => {
            for (k, x) in map {
                flatten(out, &format!("{path}.{k}"), x);
            }
        }
        Value::Array(items) if items.iter().any(|x| x.is_object() || x.is_array()) => {
            for (i, x) in items.iter().enumerate() {
                flatten(out, &format!("{path}[{i}]"), x);
            }
        }
        other => {
            let _ = writeln!(out, "# {path} = {}", one_line(other));
        }
    }
}

fn one_line(v: &Value) -> String {
    serde_json::to_string(v)
        .unwrap_or_default()
        .replace(['\n', '\r'], " ")
}

/// A block of text as `#   ` comment lines.
fn block(out: &mut String, title: &str, text: &str) {
    let _ = writeln!(out, "# {title}:");
    for line in text.lines() {
        let _ = writeln!(out, "#   {}", line.trim_end_matches('\r'));
    }
}

/// The CSV export (module doc).
pub fn to_csv(run: &Run, ctx: &ExportContext) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# gonio points export of campaign {} from {}",
        one_line(&Value::String(run.name.clone())),
        one_line(&Value::String(run.origin.clone()))
    );
    let _ = writeln!(
        s,
        "# exported_by = {}",
        one_line(&Value::String(ctx.exported_by.clone()))
    );
    for (k, v) in ctx.provenance_lines(run) {
        let _ = writeln!(s, "# provenance.{k} = {}", one_line(&Value::String(v)));
    }
    s.push_str("# units:");
    let units = column_units(run);
    let _ = writeln!(
        s,
        " {}",
        units
            .iter()
            .map(|(c, u)| format!("{c} [{u}]"))
            .collect::<Vec<_>>()
            .join("; ")
    );
    for (k, v) in CONVENTIONS {
        let _ = writeln!(s, "# convention.{k}: {v}");
    }
    match run.provenance.as_ref().map(|p| p.to_value()) {
        Some(Value::Object(map)) => {
            for (key, value) in &map {
                if key == "config" {
                    continue;
                }
                flatten(&mut s, &format!("run.{key}"), value);
            }
            if let Some(Value::Object(config)) = map.get("config") {
                for (key, value) in config {
                    match value.as_str() {
                        Some(text) => block(&mut s, &format!("run.config.{key}"), text),
                        None => flatten(&mut s, &format!("run.config.{key}"), value),
                    }
                }
            }
        }
        Some(other) => flatten(&mut s, "run", &other),
        None => s.push_str("# run: no run.json: provenance unknown\n"),
    }
    if let Some(resolved) = &ctx.resolved {
        flatten(&mut s, "resolved", resolved);
    }
    s.push_str(
        &units
            .iter()
            .map(|(c, _)| c.as_str())
            .collect::<Vec<_>>()
            .join(","),
    );
    s.push('\n');
    for p in &run.points {
        points::write_row(&mut s, p, &run.axis_names, run.dry_run);
        s.push('\n');
    }
    s
}

/// One point as a JSON object.
fn point_json(p: &Point, run: &Run) -> Value {
    let mut m = Map::new();
    m.insert("index".into(), json!(p.index));
    for (k, v) in [
        ("band_nm", p.band_nm),
        ("theta_i_deg", p.theta_i_deg),
        ("phi_i_deg", p.phi_i_deg),
        ("theta_o_deg", p.theta_o_deg),
        ("phi_o_deg", p.phi_o_deg),
    ] {
        m.insert(k.into(), json!(v + 0.0));
    }
    for (k, v) in [
        ("signal_w", p.signal_w),
        ("dark_w", p.dark_w),
        ("incident_w", p.incident_w),
        ("brdf_sr", p.brdf_sr),
        ("brdf_u_sr", p.brdf_u_sr),
    ] {
        m.insert(k.into(), json!(v));
    }
    m.insert("flags".into(), json!(p.flags));
    m.insert("valid".into(), json!(p.is_valid()));
    m.insert("t_s".into(), json!(p.t_s));
    let readback: Map<String, Value> = p
        .readback_deg
        .iter()
        .map(|(a, v)| (a.clone(), json!(v)))
        .collect();
    m.insert("readback_deg".into(), Value::Object(readback));
    m.insert("brdf_aperture_sr".into(), json!(p.brdf_aperture_sr));
    if !p.budget.entries.is_empty() {
        m.insert("brdf_u_indep_sr".into(), json!(p.budget.independent_sr()));
    }
    m.insert("budget".into(), p.budget.to_json());
    if run.dry_run {
        m.insert("brdf_true_sr".into(), json!(p.truth_point_sr));
        m.insert("brdf_true_aperture_sr".into(), json!(p.truth_aperture_sr));
    }
    Value::Object(m)
}

/// The JSON export (module doc).
pub fn to_json(run: &Run, ctx: &ExportContext) -> Value {
    let units: Map<String, Value> = column_units(run)
        .into_iter()
        .map(|(c, u)| (c, json!(u)))
        .collect();
    let conventions: Map<String, Value> = CONVENTIONS
        .iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect();
    json!({
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "exported_by": ctx.exported_by,
        "source": run.origin,
        "campaign": run.name,
        "provenance_summary": ctx
            .provenance_lines(run)
            .into_iter()
            .map(|(k, v)| (k.to_string(), json!(v)))
            .collect::<Map<String, Value>>(),
        "dry_run": run.dry_run,
        "axes": run.axis_names,
        "units": units,
        "conventions": conventions,
        "provenance": run.provenance.as_ref().map(|p| p.to_value()).unwrap_or(Value::Null),
        "resolved": ctx.resolved.clone().unwrap_or(Value::Null),
        "points": run.points.iter().map(|p| point_json(p, run)).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::parse_points_csv;

    const CSV: &str = "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,\
                       brdf_sr,brdf_u_sr,flags,t_s,light_deg,brdf_true_sr,brdf_true_aperture_sr\n\
                       0,550,30,180,45,-0,1e-7,1e-10,0.0005,0.2500000000000001,0.001,,12.5,-30,0.25,0.2499\n\
                       1,450,30,180,60,0,NaN,,,,,overfilled,13,,,\n";

    fn run() -> Run {
        let table = parse_points_csv(CSV, "t/points.csv").expect("valid");
        Run::from_parts(
            "t".into(),
            "t".into(),
            table,
            Some(crate::provenance::tests::sample_record()),
        )
    }

    #[test]
    fn csv_export_keeps_every_value_and_carries_the_provenance() {
        let r = run();
        let text = to_csv(
            &r,
            &ExportContext {
                exported_by: "gonio test".into(),
                resolved: None,
                setup: None,
            },
        );
        // The table part reads back to the same points (comment lines skipped).
        let table: String = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| format!("{l}\n"))
            .collect();
        let back = parse_points_csv(&table, "export").expect("re-reads");
        assert_eq!(back.points, r.points);
        assert!(
            text.contains("# run.devices[0] = {\"identity\":\"PM100\",\"name\":\"meter\"}"),
            "{text}"
        );
        assert!(
            text.contains("# run.calibrations[0] = {\"band_nm\":550.0,\"kind\":\"direct-beam\""),
            "{text}"
        );
        assert!(
            text.contains("# run.config.campaign_toml:\n#   [campaign]\n#   id = \"t\"\n"),
            "{text}"
        );
        assert!(
            text.contains("brdf_sr [1/sr]") && text.contains("theta_i_deg [degree]"),
            "{text}"
        );
        assert!(
            text.contains("# run.software_version = \"gonio 0.1.0\""),
            "{text}"
        );
    }

    #[test]
    fn json_export_has_units_provenance_and_nulls() {
        let r = run();
        let v = to_json(
            &r,
            &ExportContext {
                exported_by: "gonio test".into(),
                resolved: Some(json!({"a": 1})),
                setup: None,
            },
        );
        assert_eq!(v["format"], FORMAT);
        assert_eq!(v["units"]["brdf_u_sr"], "1/sr");
        assert_eq!(v["units"]["light_deg"], "degree");
        assert_eq!(v["provenance"]["devices"][0]["identity"], "PM100");
        assert_eq!(v["resolved"]["a"], 1);
        let p = &v["points"];
        assert_eq!(p[0]["brdf_sr"].as_f64(), Some(0.2500000000000001));
        assert_eq!(p[0]["phi_o_deg"].as_f64(), Some(0.0));
        assert_eq!(p[0]["readback_deg"]["light"].as_f64(), Some(-30.0));
        assert_eq!(p[1]["brdf_sr"], Value::Null);
        assert_eq!(p[1]["valid"], false);
        assert_eq!(p[1]["flags"][0], "overfilled");
    }
}
