//! One band of a run as a BSDF Data Interchange file (Radiant Imaging's text format, read by Zemax OpticStudio's
//! tabular BSDF scatter model, LightTools and libbsdf): BRDF values on a grid of scatter azimuth and radial
//! angles about the specular direction, one block per angle of incidence, each with its TIS.
//!
//! Layout (from the format's specification, "BSDF Data Interchange File Format Specification", R. Rykowski):
//! `#` comment lines anywhere before the data; `Source Measured`, `Symmetry PlaneSymmetrical`,
//! `SpectralContent Monochrome`, `ScatterType BRDF`; `SampleRotation` with its count and then its values (one,
//! 0: an isotropic run), likewise `AngleOfIncidence`, `ScatterAzimuth` (0 to 180 degrees: plane symmetry about
//! the plane of incidence) and `ScatterRadial`; an empty line; `Monochrome`; `DataBegin`; per angle of incidence
//! a line `TIS <value>` and one row per azimuth holding the BRDF (1/sr) at every radial angle; `DataEnd`.
//!
//! Geometry: the incident direction is wi = (theta_i, phi = 0) in gonio's sample frame (towards the source), the
//! specular direction s its mirror image. Radial angle r is the angle from s; azimuth a is measured about s from
//! the direction pointing from s towards the sample normal (a = 0), so a scatter direction is
//! `cos r s + sin r (cos a t0 + sin a t1)` with t0 the unit vector from s towards the normal and t1 = s x t0;
//! its cosine to the normal is `cos r cos theta_i + sin r sin theta_i cos a`. At normal incidence t0 points
//! towards the source's azimuth (the limit of the oblique case).
//!
//! Values: gonio's interpolant of the run ([`crate::iso::IsoGrid`]: log-trilinear between measured nodes, with
//! reciprocity, never extrapolated), clamped at 0 ([`crate::hemispherical::covered_value`]). The format has no
//! "no data" mark: cells outside the measured region and below the horizon are written as 0, and the file's
//! comments say so and give, per block, the share of the hemisphere's projected solid angle that was covered.
//! The angles of incidence are the run's measured ones (theta_i nodes of its valid points); the azimuth and
//! radial grids are [`azimuths_deg`] and [`radials_deg`].
//!
//! TIS: the directional-hemispherical reflectance of the same interpolant over the measured region
//! ([`crate::hemispherical`]). The table's own quadrature (trapezoid rule in r and a with weight
//! `sin r cos theta_s`) is written in the comments beside it; on the grids used they agree to a few parts in a
//! thousand for smooth data (tests/cli/export.rs checks it with a reader written from the specification).

use std::fmt::Write as _;

use gonio_brdf::geometry::Direction;

use crate::error::ResultsError;
use crate::hemispherical::{Hemispherical, covered_value, directional_hemispherical};
use crate::iso::{IsoGrid, IsoPoint, cluster};
use crate::provenance_summary::{ExportSetup, provenance_lines};
use crate::run::{BAND_TOLERANCE_NM, Run};

/// Step of the scatter azimuth grid, degrees (0 to 180 inclusive).
pub const AZIMUTH_STEP_DEG: f64 = 5.0;

/// The scatter azimuths, degrees.
pub fn azimuths_deg() -> Vec<f64> {
    (0..=36).map(|k| k as f64 * AZIMUTH_STEP_DEG).collect()
}

/// The radial angles, degrees: fine near the specular direction where a lobe is (0.25 degree to 2 degrees, 0.5
/// to 20), then 1 degree out to `max_deg` (at most 180), so that the grid reaches the horizon on every side.
pub fn radials_deg(max_deg: f64) -> Vec<f64> {
    let max_deg = max_deg.clamp(20.0, 180.0).ceil();
    let mut r: Vec<f64> = (0..8).map(|k| k as f64 * 0.25).collect();
    r.extend((0..36).map(|k| 2.0 + k as f64 * 0.5));
    let mut x = 20.0;
    while x <= max_deg {
        r.push(x);
        x += 1.0;
    }
    r
}

/// The scatter direction at radial angle `r` and azimuth `a` (radians) about the specular direction of an
/// incidence at `theta_i` (module doc), as (x, y, z) in the sample frame; it may point below the horizon.
pub fn scatter_direction(theta_i: f64, a: f64, r: f64) -> [f64; 3] {
    let (si, ci) = theta_i.sin_cos();
    // s = (-sin ti, 0, cos ti), t0 = (cos ti, 0, sin ti), t1 = s x t0 = (0, 1, 0).
    let (sr, cr) = r.sin_cos();
    let (sa, ca) = a.sin_cos();
    [-cr * si + sr * ca * ci, sr * sa, cr * ci + sr * ca * si]
}

/// One angle of incidence.
#[derive(Debug, Clone)]
pub struct ZemaxBlock {
    pub theta_i_deg: f64,
    /// Gonio's hemispherical integrals at this incidence; `reflectance` is the block's TIS.
    pub integrals: Hemispherical,
    /// The trapezoid rule over the written table (module doc).
    pub table_tis: f64,
    /// BRDF (1/sr), one row per azimuth, `radial` values each.
    pub rows: Vec<Vec<f64>>,
}

/// One band resampled for the format.
#[derive(Debug, Clone)]
pub struct ZemaxExport {
    pub band_nm: f64,
    pub azimuth_deg: Vec<f64>,
    pub radial_deg: Vec<f64>,
    pub blocks: Vec<ZemaxBlock>,
}

/// The trapezoid rule of the table: `2 * sum over (a, r) cells of f cos(theta_s) sin r da dr` (the factor 2 for
/// the mirrored half of the azimuths).
fn table_integral(rows: &[Vec<f64>], theta_i: f64, azimuth_deg: &[f64], radial_deg: &[f64]) -> f64 {
    let weights = |nodes: &[f64]| -> Vec<f64> {
        (0..nodes.len())
            .map(|k| {
                let lo = if k > 0 { nodes[k] - nodes[k - 1] } else { 0.0 };
                let hi = if k + 1 < nodes.len() {
                    nodes[k + 1] - nodes[k]
                } else {
                    0.0
                };
                0.5 * (lo + hi).to_radians()
            })
            .collect()
    };
    let (wa, wr) = (weights(azimuth_deg), weights(radial_deg));
    let mut sum = 0.0;
    for (row, (a, wa)) in rows.iter().zip(azimuth_deg.iter().zip(&wa)) {
        for (f, (r, wr)) in row.iter().zip(radial_deg.iter().zip(&wr)) {
            let d = scatter_direction(theta_i, a.to_radians(), r.to_radians());
            sum += f * d[2].max(0.0) * r.to_radians().sin() * wa * wr;
        }
    }
    2.0 * sum
}

/// Resamples band `band_nm` of the run (module doc).
pub fn to_zemax(run: &Run, band_nm: f64) -> Result<ZemaxExport, ResultsError> {
    let band = run.band(band_nm)?;
    let points: Vec<IsoPoint> = run
        .points
        .iter()
        .filter(|p| (p.band_nm - band).abs() <= BAND_TOLERANCE_NM)
        .filter_map(IsoPoint::from_point)
        .collect();
    let incidences = cluster(points.iter().map(|p| p.angles.theta_i).collect());
    if incidences.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: format!("no valid point above the horizon at {band} nm"),
        });
    }
    let grid = IsoGrid::build(&points);
    let azimuth_deg = azimuths_deg();
    let max_theta_i_deg = incidences.iter().fold(0.0f64, |m, t| m.max(t.to_degrees()));
    let radial_deg = radials_deg(90.0 + max_theta_i_deg);
    let blocks = incidences
        .iter()
        .map(|&theta_i| {
            let wi = Direction::from_spherical(theta_i, 0.0);
            let rows: Vec<Vec<f64>> = azimuth_deg
                .iter()
                .map(|a| {
                    radial_deg
                        .iter()
                        .map(|r| {
                            let [x, y, z] = scatter_direction(theta_i, a.to_radians(), r.to_radians());
                            Direction::new(x, y, z)
                                .and_then(|wo| covered_value(&grid, &wi, &wo))
                                .unwrap_or(0.0)
                        })
                        .collect()
                })
                .collect();
            ZemaxBlock {
                theta_i_deg: theta_i.to_degrees(),
                integrals: directional_hemispherical(&grid, theta_i),
                table_tis: table_integral(&rows, theta_i, &azimuth_deg, &radial_deg),
                rows,
            }
        })
        .collect();
    Ok(ZemaxExport {
        band_nm: band,
        azimuth_deg,
        radial_deg,
        blocks,
    })
}

/// An angle as written: at most 4 decimals, no trailing zeros.
fn angle(deg: f64) -> String {
    let s = format!("{:.4}", deg + 0.0);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.to_string() }
}

fn joined(values: &[f64]) -> String {
    values.iter().map(|v| angle(*v)).collect::<Vec<_>>().join(" ")
}

/// The file's text (module doc); `exported_by` and `setup` feed its provenance comments.
pub fn write(export: &ZemaxExport, run: &Run, exported_by: &str, setup: Option<&ExportSetup>) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# BSDF Data Interchange file (Zemax OpticStudio tabular BSDF / LightTools) written by gonio"
    );
    let bandwidth = setup
        .and_then(|st| st.bandwidth_nm(export.band_nm))
        .map_or_else(|| "unknown".into(), |w| format!("{w} nm FWHM"));
    let _ = writeln!(s, "# band_nm: {} (filter bandwidth {bandwidth})", export.band_nm);
    for (k, v) in provenance_lines(run, exported_by, setup) {
        let _ = writeln!(s, "# provenance.{k}: {v}");
    }
    for line in [
        "# Values: BRDF in 1/sr (no cosine factor), resampled from the measured points with gonio's interpolant",
        "#   (log-trilinear in theta_i, theta_o and |phi_o - phi_i| between measured nodes, with reciprocity; the",
        "#   run is treated as isotropic), never extrapolated.",
        "# NOT MEASURED: cells outside the measured region, and cells below the horizon, are written as 0. The",
        "#   format has no 'no data' mark; the share of the projected solid angle covered is listed per block.",
        "# Angles: degrees. Radial: angle from the specular direction. Azimuth: about the specular direction, 0",
        "#   pointing from it towards the sample normal; 0 to 180 (plane symmetry about the plane of incidence).",
        "# TIS: directional-hemispherical reflectance of the interpolant over the measured region (gonio's adaptive",
        "#   quadrature, error estimate below); 'table' is the trapezoid rule over this file's grid, for comparison.",
    ] {
        s.push_str(line);
        s.push('\n');
    }
    for b in &export.blocks {
        let _ = writeln!(
            s,
            "# AngleOfIncidence {}: TIS {:.6} +- {:.1e}, table {:.6}, covered {:.1}% of the projected solid angle",
            angle(b.theta_i_deg),
            b.integrals.reflectance.value,
            b.integrals.reflectance.error,
            b.table_tis,
            100.0 * b.integrals.covered_projected_sr.value / std::f64::consts::PI
        );
    }
    let _ = writeln!(s, "Source  Measured");
    let _ = writeln!(s, "Symmetry  PlaneSymmetrical");
    let _ = writeln!(s, "SpectralContent  Monochrome");
    let _ = writeln!(s, "ScatterType  BRDF");
    let _ = writeln!(s, "SampleRotation  1\n0");
    let incidences: Vec<f64> = export.blocks.iter().map(|b| b.theta_i_deg).collect();
    let _ = writeln!(
        s,
        "AngleOfIncidence  {}\n{}",
        incidences.len(),
        joined(&incidences)
    );
    let _ = writeln!(
        s,
        "ScatterAzimuth  {}\n{}",
        export.azimuth_deg.len(),
        joined(&export.azimuth_deg)
    );
    let _ = writeln!(
        s,
        "ScatterRadial  {}\n{}",
        export.radial_deg.len(),
        joined(&export.radial_deg)
    );
    s.push_str("\nMonochrome\nDataBegin\n");
    for b in &export.blocks {
        let _ = writeln!(s, "TIS {:.6}", b.integrals.reflectance.value);
        for row in &b.rows {
            let line: Vec<String> = row.iter().map(|v| format!("{v:.6e}")).collect();
            s.push_str(&line.join(" "));
            s.push('\n');
        }
    }
    s.push_str("DataEnd\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scatter_directions_follow_the_specular_frame() {
        let ti = 30f64.to_radians();
        // r = 0 is the mirror direction.
        let d = scatter_direction(ti, 1.0, 0.0);
        assert!((d[0] + ti.sin()).abs() < 1e-15 && (d[2] - ti.cos()).abs() < 1e-15);
        // Azimuth 0 moves towards the normal: r = theta_i reaches it.
        let d = scatter_direction(ti, 0.0, ti);
        assert!((d[2] - 1.0).abs() < 1e-15, "{d:?}");
        // Azimuth 180 moves away from it: r = 90 - theta_i reaches the horizon.
        let d = scatter_direction(ti, std::f64::consts::PI, 60f64.to_radians());
        assert!(d[2].abs() < 1e-15, "{d:?}");
        // Unit length everywhere.
        let d = scatter_direction(0.7, 2.1, 1.3);
        assert!((d.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn grids_are_ascending_and_reach_the_horizon() {
        let r = radials_deg(150.0);
        assert!(r.windows(2).all(|w| w[1] > w[0]));
        assert_eq!((r[0], *r.last().expect("nodes")), (0.0, 150.0));
        assert_eq!(azimuths_deg().len(), 37);
        assert_eq!(angle(0.25), "0.25");
        assert_eq!(angle(20.0), "20");
        assert_eq!(angle(-0.0), "0");
    }
}
