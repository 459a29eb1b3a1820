//! A run: its points and its provenance, loaded from a run directory (`gonio run --out DIR` writes
//! `DIR/points.csv` and `DIR/run.json`) or assembled by the caller from another source (the daemon's store).

use std::path::Path;

use serde_json::Value;

use crate::error::ResultsError;
use crate::points::{Point, PointsTable, parse_points_csv};

/// Two bands closer than this (nm) are the same filter.
pub const BAND_TOLERANCE_NM: f64 = 0.5;

/// A measured run.
#[derive(Debug, Clone)]
pub struct Run {
    /// What the data came from, for messages: a path, or "store DIR/gonio.sqlite, campaign 3".
    pub origin: String,
    /// The campaign (sample) id.
    pub name: String,
    pub points: Vec<Point>,
    /// The read-back axes, in column order.
    pub axis_names: Vec<String>,
    /// True for a dry-run against the simulator (the points carry the simulator's truth).
    pub dry_run: bool,
    /// The run's provenance, the content of run.json: `campaign` (id, name, state, counts), `software_version`,
    /// `config` (`campaign_toml`, `instrument_toml`: the configuration the run used), `devices`
    /// (name, identity), `calibrations`, `timing`, `truth`. `None` when only the CSV is known.
    pub provenance: Option<Value>,
}

impl Run {
    /// From parsed points and an optional provenance document.
    pub fn from_parts(origin: String, name: String, table: PointsTable, provenance: Option<Value>) -> Run {
        Run {
            origin,
            name,
            points: table.points,
            axis_names: table.axis_names,
            dry_run: table.dry_run,
            provenance,
        }
    }

    /// Loads a run directory (points.csv, and run.json when present), or a points CSV file (with the run.json
    /// beside it, when present).
    pub fn load(path: &Path) -> Result<Run, ResultsError> {
        let meta = std::fs::metadata(path).map_err(|source| ResultsError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let (csv_path, dir) = if meta.is_dir() {
            (path.join("points.csv"), path.to_path_buf())
        } else {
            (
                path.to_path_buf(),
                path.parent().map(Path::to_path_buf).unwrap_or_default(),
            )
        };
        if meta.is_dir() && !csv_path.is_file() {
            return Err(ResultsError::NoData {
                origin: path.display().to_string(),
                message:
                    "no points.csv here: a run directory (written by `gonio run --out DIR`) holds points.csv \
                          and run.json"
                        .into(),
            });
        }
        let text = read_text(&csv_path)?;
        let table = parse_points_csv(&text, &csv_path.display().to_string())?;
        let json_path = dir.join("run.json");
        let provenance = if json_path.is_file() {
            Some(parse_run_json(
                &read_text(&json_path)?,
                &json_path.display().to_string(),
            )?)
        } else {
            None
        };
        let name = provenance
            .as_ref()
            .and_then(|p| p.pointer("/campaign/name"))
            .and_then(Value::as_str)
            .map(str::to_string)
            .or_else(|| dir.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "run".to_string());
        let origin = if meta.is_dir() {
            path.display().to_string()
        } else {
            csv_path.display().to_string()
        };
        Ok(Run::from_parts(origin, name, table, provenance))
    }

    /// The points with a usable value.
    pub fn valid_points(&self) -> impl Iterator<Item = &Point> {
        self.points.iter().filter(|p| p.is_valid())
    }

    /// The distinct bands of the valid points, nm, ascending (bands within [`BAND_TOLERANCE_NM`] merged).
    pub fn bands_nm(&self) -> Vec<f64> {
        let mut bands: Vec<f64> = Vec::new();
        let mut all: Vec<f64> = self.valid_points().map(|p| p.band_nm).collect();
        all.sort_by(f64::total_cmp);
        for b in all {
            if bands.last().is_none_or(|last| b - last > BAND_TOLERANCE_NM) {
                bands.push(b);
            }
        }
        bands
    }

    /// The band among [`Run::bands_nm`] within [`BAND_TOLERANCE_NM`] of `nm`, or an error listing the bands.
    pub fn band(&self, nm: f64) -> Result<f64, ResultsError> {
        let bands = self.bands_nm();
        bands
            .iter()
            .copied()
            .find(|b| (b - nm).abs() <= BAND_TOLERANCE_NM)
            .ok_or_else(|| ResultsError::NoData {
                origin: self.origin.clone(),
                message: format!(
                    "no valid points at {nm} nm; the run's bands are: {}",
                    list_nm(&bands)
                ),
            })
    }

    /// A string from the provenance at a JSON pointer (e.g. "/software_version").
    pub fn provenance_str(&self, pointer: &str) -> Option<&str> {
        self.provenance.as_ref()?.pointer(pointer)?.as_str()
    }
}

/// "450, 550, 650 nm" (or "none").
pub fn list_nm(bands: &[f64]) -> String {
    if bands.is_empty() {
        "none".into()
    } else {
        format!(
            "{} nm",
            bands
                .iter()
                .map(|b| format!("{b}"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

fn read_text(path: &Path) -> Result<String, ResultsError> {
    std::fs::read_to_string(path).map_err(|source| ResultsError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// Parses a run.json: a JSON object. Its known parts are checked for their type so that a damaged file is
/// reported here rather than half-used.
pub fn parse_run_json(text: &str, origin: &str) -> Result<Value, ResultsError> {
    let value: Value = serde_json::from_str(text).map_err(|e| ResultsError::Json {
        origin: origin.to_string(),
        message: format!("not valid JSON: {e}"),
    })?;
    let Some(object) = value.as_object() else {
        return Err(ResultsError::Json {
            origin: origin.to_string(),
            message: "expected a JSON object (the run's provenance), found another value".into(),
        });
    };
    let expect = |key: &str, ok: fn(&Value) -> bool, what: &str| -> Result<(), ResultsError> {
        match object.get(key) {
            Some(v) if !ok(v) && !v.is_null() => Err(ResultsError::Json {
                origin: origin.to_string(),
                message: format!("key `{key}` must be {what}"),
            }),
            _ => Ok(()),
        }
    };
    expect("campaign", Value::is_object, "an object")?;
    expect("software_version", Value::is_string, "a string")?;
    expect("config", Value::is_object, "an object")?;
    expect("devices", Value::is_array, "an array")?;
    expect("calibrations", Value::is_array, "an array")?;
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn run_json_must_be_an_object_with_typed_parts() {
        assert!(parse_run_json("{\"software_version\": \"gonio 0.1.0\"}", "r.json").is_ok());
        let e = parse_run_json("[1, 2]", "r.json").expect_err("array").to_string();
        assert!(e.starts_with("r.json: expected a JSON object"), "{e}");
        let e = parse_run_json("{\"devices\": 3}", "r.json")
            .expect_err("bad type")
            .to_string();
        assert!(e.contains("`devices` must be an array"), "{e}");
        let e = parse_run_json("{\"campaign\": ", "dir/run.json")
            .expect_err("truncated")
            .to_string();
        assert!(e.starts_with("dir/run.json: not valid JSON"), "{e}");
    }

    #[test]
    fn missing_points_csv_is_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let e = Run::load(dir.path()).expect_err("empty dir").to_string();
        assert!(e.contains("no points.csv"), "{e}");
        let e = Run::load(&dir.path().join("nope"))
            .expect_err("no such path")
            .to_string();
        assert!(e.contains("nope"), "{e}");
    }

    proptest! {
        #[test]
        fn run_json_reader_never_panics(text in any::<String>()) {
            let _ = parse_run_json(&text, "fuzz.json");
        }

        #[test]
        fn run_json_reader_never_panics_on_jsonish(text in "[{}\\[\\]\":,0-9a-z_ ]{0,200}") {
            let _ = parse_run_json(&text, "fuzz.json");
        }
    }
}
