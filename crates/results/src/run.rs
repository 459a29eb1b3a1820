//! A run: its points and its provenance, loaded from a run directory (`gonio run --out DIR` writes
//! `DIR/points.csv` and `DIR/run.json`) or assembled by the caller from another source (the daemon's store).

use std::path::Path;

use crate::error::ResultsError;
use crate::points::{Point, PointsTable, parse_points_csv};
use crate::provenance::RunRecord;

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
    /// The run's provenance, the content of run.json. `None` when only the CSV is known.
    pub provenance: Option<RunRecord>,
}

impl Run {
    /// From parsed points and an optional provenance document.
    pub fn from_parts(
        origin: String,
        name: String,
        table: PointsTable,
        provenance: Option<RunRecord>,
    ) -> Run {
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
            Some(RunRecord::parse(
                &read_text(&json_path)?,
                &json_path.display().to_string(),
            )?)
        } else {
            None
        };
        let name = provenance
            .as_ref()
            .map(|p| p.campaign.name.clone())
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

    /// The configuration texts the run used (campaign, instrument), when its provenance is known.
    pub fn config(&self) -> Option<&crate::provenance::RunConfig> {
        self.provenance.as_ref().map(|p| &p.config)
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
