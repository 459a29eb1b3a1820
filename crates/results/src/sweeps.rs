//! Sweep readings as results: the `sweeps.csv` a run writes beside `points.csv`, and a dry-run's summary of
//! them against the simulator's truth.
//!
//! CSV columns, one row per reading in run order: `segment` (the sweep, in run order), `k` (the reading within
//! it), `band_nm`, `t_s` (instrument time of the middle of the integration), `integration_s`, the geometry at the
//! middle of the arc the reading covered (`theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg`), the swept angle at
//! the start and the end of the integration (`arc_from_deg,arc_to_deg`: signed, as in `[[plan.sweeps]]`),
//! `signal_w`, `brdf_sr` (corrected to the nominal geometry when the campaign completed), `brdf_u_sr` (standard
//! uncertainty), `brdf_aperture_sr` (the aperture average it was corrected from), `flags` (`;`-separated), and for dry-runs
//! `brdf_true_sr` (the simulator's BRDF at the arc's middle, nominal geometry). Missing values are empty.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use crate::budget::Budget;
use crate::error::ResultsError;
use crate::points::{Point, split_record};
use crate::run::Run;

/// One sweep reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepReading {
    pub segment: u32,
    pub k: u32,
    pub band_nm: f64,
    pub t_s: f64,
    pub integration_s: f64,
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    pub arc_from_deg: f64,
    pub arc_to_deg: f64,
    pub signal_w: Option<f64>,
    /// The normalisation the reading was divided by while running (W): the direct beam, or the reference
    /// sample's signal (relative method).
    pub incident_w: Option<f64>,
    pub brdf_sr: Option<f64>,
    pub brdf_u_sr: Option<f64>,
    /// The aperture average `brdf_sr` was corrected from (1/sr); `None` when no correction was made.
    pub brdf_aperture_sr: Option<f64>,
    pub flags: Vec<String>,
    pub truth_point_sr: Option<f64>,
}

/// The CSV (module doc); `dry_run` adds the truth column.
pub fn write_sweeps_csv(readings: &[SweepReading], dry_run: bool) -> String {
    let mut s = String::from(
        "segment,k,band_nm,t_s,integration_s,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,arc_from_deg,arc_to_deg,\
         signal_w,brdf_sr,brdf_u_sr,brdf_aperture_sr,flags",
    );
    if dry_run {
        s.push_str(",brdf_true_sr");
    }
    s.push('\n');
    let opt = |v: Option<f64>| {
        v.filter(|v| v.is_finite())
            .map(|v| v.to_string())
            .unwrap_or_default()
    };
    for r in readings {
        let _ = write!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.segment,
            r.k,
            r.band_nm,
            r.t_s,
            r.integration_s,
            r.theta_i_deg,
            r.phi_i_deg,
            r.theta_o_deg,
            r.phi_o_deg,
            r.arc_from_deg,
            r.arc_to_deg,
            opt(r.signal_w),
            opt(r.brdf_sr),
            opt(r.brdf_u_sr),
            opt(r.brdf_aperture_sr),
            r.flags.join(";").replace(',', " ")
        );
        if dry_run {
            let _ = write!(s, ",{}", opt(r.truth_point_sr));
        }
        s.push('\n');
    }
    s
}

/// Reads a `sweeps.csv` ([`write_sweeps_csv`]'s columns, found by name; `brdf_true_sr` only in dry-runs).
/// `origin` names the file in errors, with the line.
pub fn parse_sweeps_csv(text: &str, origin: &str) -> Result<Vec<SweepReading>, ResultsError> {
    let err = |line: usize, message: String| ResultsError::Csv {
        origin: origin.to_string(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate();
    let Some((_, header)) = lines.next() else {
        return Err(err(0, "the file is empty (expected a header line)".into()));
    };
    let header: Vec<String> = split_record(header.trim_end_matches('\r'))
        .map_err(|m| err(1, m))?
        .into_iter()
        .map(|h| h.trim().to_string())
        .collect();
    let column = |name: &str| header.iter().position(|h| h == name);
    let required = |name: &str| column(name).ok_or_else(|| err(1, format!("no `{name}` column")));
    let [segment, k, band, t, integration, ti, pi, to, po, arc_from, arc_to] = [
        "segment",
        "k",
        "band_nm",
        "t_s",
        "integration_s",
        "theta_i_deg",
        "phi_i_deg",
        "theta_o_deg",
        "phi_o_deg",
        "arc_from_deg",
        "arc_to_deg",
    ]
    .map(required);
    let (segment, k, band, t, integration) = (segment?, k?, band?, t?, integration?);
    let (ti, pi, to, po, arc_from, arc_to) = (ti?, pi?, to?, po?, arc_from?, arc_to?);
    let (signal, brdf, u, aperture, flags, truth) = (
        column("signal_w"),
        column("brdf_sr"),
        column("brdf_u_sr"),
        column("brdf_aperture_sr"),
        column("flags"),
        column("brdf_true_sr"),
    );
    let mut readings = Vec::new();
    for (i, raw) in lines {
        let line = raw.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        let fields = split_record(line).map_err(|m| err(i + 1, m))?;
        if fields.len() != header.len() {
            return Err(err(
                i + 1,
                format!(
                    "{} fields, but the header has {} columns",
                    fields.len(),
                    header.len()
                ),
            ));
        }
        let cell = |c: usize| fields[c].trim();
        let number = |c: usize| -> Result<f64, ResultsError> {
            cell(c)
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    err(
                        i + 1,
                        format!("column `{}`: {:?} is not a finite number", header[c], cell(c)),
                    )
                })
        };
        let index = |c: usize| -> Result<u32, ResultsError> {
            cell(c).parse::<u32>().map_err(|_| {
                err(
                    i + 1,
                    format!("column `{}`: {:?} is not a count", header[c], cell(c)),
                )
            })
        };
        let optional = |c: Option<usize>| -> Result<Option<f64>, ResultsError> {
            match c.map(cell) {
                None | Some("") => Ok(None),
                Some(_) => number(c.unwrap_or_default()).map(Some),
            }
        };
        readings.push(SweepReading {
            segment: index(segment)?,
            k: index(k)?,
            band_nm: number(band)?,
            t_s: number(t)?,
            integration_s: number(integration)?,
            theta_i_deg: number(ti)?,
            phi_i_deg: number(pi)?,
            theta_o_deg: number(to)?,
            phi_o_deg: number(po)?,
            arc_from_deg: number(arc_from)?,
            arc_to_deg: number(arc_to)?,
            signal_w: optional(signal)?,
            incident_w: None,
            brdf_sr: optional(brdf)?,
            brdf_u_sr: optional(u)?,
            brdf_aperture_sr: optional(aperture)?,
            flags: flags
                .map(|c| {
                    cell(c)
                        .split(';')
                        .map(str::trim)
                        .filter(|f| !f.is_empty())
                        .map(str::to_string)
                        .collect()
                })
                .unwrap_or_default(),
            truth_point_sr: optional(truth)?,
        });
    }
    Ok(readings)
}

impl SweepReading {
    /// The reading as a point of a run (index `index`), for the fits and exports that take sweep readings
    /// like points: its geometry is its arc's middle; its budget is its standard uncertainty as one
    /// independent `signal-noise` component (the store keeps a reading's total only); no read-back.
    pub fn to_point(&self, index: u64) -> Point {
        let mut budget = Budget::default();
        if let Some(u) = self.brdf_u_sr.filter(|u| u.is_finite() && *u > 0.0) {
            budget.add(crate::budget::components::SIGNAL_NOISE, u, None);
        }
        Point {
            index,
            band_nm: self.band_nm,
            theta_i_deg: self.theta_i_deg,
            phi_i_deg: self.phi_i_deg,
            theta_o_deg: self.theta_o_deg,
            phi_o_deg: self.phi_o_deg,
            signal_w: self.signal_w,
            dark_w: None,
            incident_w: self.incident_w,
            brdf_sr: self.brdf_sr,
            brdf_u_sr: self.brdf_u_sr,
            flags: self.flags.clone(),
            t_s: Some(self.t_s),
            readback_deg: Vec::new(),
            brdf_aperture_sr: self.brdf_aperture_sr,
            budget,
            truth_point_sr: self.truth_point_sr,
            truth_aperture_sr: None,
        }
    }
}

/// A run with `readings` appended to its points (indices after its last point), for the fits and exports
/// that take sweep readings like points. The read-back columns of the appended points are empty.
pub fn with_readings(mut run: Run, readings: &[SweepReading]) -> Run {
    let first = run.points.iter().map(|p| p.index + 1).max().unwrap_or(0);
    let axes = run.axis_names.clone();
    run.points.extend(readings.iter().zip(first..).map(|(r, i)| {
        let mut p = r.to_point(i);
        p.readback_deg = axes.iter().map(|a| (a.clone(), None)).collect();
        p
    }));
    run
}

/// How wide the bins are that a picture averages sweep readings in (degrees of arc): `gonio plot` and the
/// report draw about two marks per degree, not the tens of readings a degree holds.
pub const PLOT_BIN_DEG: f64 = 0.5;

/// The sweep readings thinned for a picture: per segment (one arc in one band), the valid readings (a value, no
/// flag) in bins of `bin_deg` of arc (by their arc's middle), each bin one reading: the mean value, the
/// uncertainty of that mean (independent readings), and the geometry and time of the bin's middle reading.
/// What a plot draws, never what is stored or exported. Empty for a `bin_deg` not positive.
pub fn binned(readings: &[SweepReading], bin_deg: f64) -> Vec<SweepReading> {
    if !(bin_deg.is_finite() && bin_deg > 0.0) {
        return Vec::new();
    }
    let mid = |r: &SweepReading| 0.5 * (r.arc_from_deg + r.arc_to_deg);
    let mut groups: std::collections::BTreeMap<(u32, i64), Vec<&SweepReading>> = Default::default();
    for r in readings
        .iter()
        .filter(|r| r.flags.is_empty() && r.brdf_sr.is_some_and(f64::is_finite) && mid(r).is_finite())
    {
        let bin = (mid(r) / bin_deg).floor() as i64;
        groups.entry((r.segment, bin)).or_default().push(r);
    }
    groups
        .into_values()
        .filter_map(|mut group| {
            group.sort_by(|a, b| mid(a).total_cmp(&mid(b)));
            let centre = *group.get(group.len() / 2)?;
            let n = group.len() as f64;
            let value = group.iter().filter_map(|r| r.brdf_sr).sum::<f64>() / n;
            let u = group
                .iter()
                .map(|r| r.brdf_u_sr.map(|u| u * u))
                .sum::<Option<f64>>()
                .map(|v| v.sqrt() / n);
            Some(SweepReading {
                brdf_sr: Some(value),
                brdf_u_sr: u,
                brdf_aperture_sr: None,
                signal_w: None,
                truth_point_sr: None,
                ..centre.clone()
            })
        })
        .collect()
}

/// A dry-run's sweep readings against the simulator's truth at their arcs' middles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SweepTruthSummary {
    /// Readings with a value and a truth.
    pub readings: u64,
    /// `sqrt(sum(((f - t) cos theta_i)^2) / sum((t cos theta_i)^2))`.
    pub cos_weighted_relative_rms: Option<f64>,
    /// Share of the readings whose `|f - t| <= 2 u` (k = 2 coverage).
    pub coverage_k2: f64,
}

/// [`SweepTruthSummary`] over the readings with a value, an uncertainty and a truth; `None` without any.
pub fn truth_summary<'a>(readings: impl IntoIterator<Item = &'a SweepReading>) -> Option<SweepTruthSummary> {
    let (mut n, mut covered, mut num, mut den) = (0u64, 0u64, 0.0, 0.0);
    for r in readings {
        let (Some(f), Some(u), Some(t)) = (r.brdf_sr, r.brdf_u_sr, r.truth_point_sr) else {
            continue;
        };
        if !(f.is_finite() && u.is_finite() && t.is_finite()) {
            continue;
        }
        let c = r.theta_i_deg.to_radians().cos();
        n += 1;
        covered += u64::from((f - t).abs() <= 2.0 * u);
        num += ((f - t) * c).powi(2);
        den += (t * c).powi(2);
    }
    (n > 0).then(|| SweepTruthSummary {
        readings: n,
        cos_weighted_relative_rms: (den > 0.0).then(|| (num / den).sqrt()),
        coverage_k2: covered as f64 / n as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(k: u32, f: Option<f64>, u: f64, t: f64) -> SweepReading {
        SweepReading {
            segment: 3,
            k,
            band_nm: 550.0,
            t_s: 1.5,
            integration_s: 0.003,
            theta_i_deg: 60.0,
            phi_i_deg: 0.0,
            theta_o_deg: 20.0,
            phi_o_deg: 180.0,
            arc_from_deg: 19.99,
            arc_to_deg: 20.01,
            signal_w: f.map(|_| 1e-9),
            incident_w: Some(1e-3),
            brdf_sr: f,
            brdf_u_sr: Some(u),
            brdf_aperture_sr: None,
            flags: if f.is_none() {
                vec!["failed: timeout, twice".into()]
            } else {
                vec![]
            },
            truth_point_sr: Some(t),
        }
    }

    #[test]
    fn readings_are_binned_per_segment_with_the_mean_and_its_uncertainty() {
        // Segment 3: readings every 0.1 deg from 20.0 to 20.9 (values 1..10), one failed; segment 4 at 20.05.
        let mut rows: Vec<SweepReading> = (0..10)
            .map(|k| {
                let mut r = reading(k, Some(f64::from(k + 1)), 0.3, 0.5);
                r.arc_from_deg = 20.0 + 0.1 * f64::from(k) - 0.01;
                r.arc_to_deg = r.arc_from_deg + 0.02;
                r.t_s = f64::from(k);
                r
            })
            .collect();
        rows.push(reading(10, None, 0.3, 0.5));
        rows.push(SweepReading {
            segment: 4,
            arc_from_deg: 20.04,
            arc_to_deg: 20.06,
            ..reading(11, Some(7.0), 0.3, 0.5)
        });
        let bins = binned(&rows, 0.5);
        assert_eq!(bins.len(), 3, "{bins:?}");
        // 20.0..20.4 (values 1..5) and 20.5..20.9 (values 6..10) in segment 3, then segment 4's one.
        let (a, b, c) = (&bins[0], &bins[1], &bins[2]);
        assert_eq!((a.segment, b.segment, c.segment), (3, 3, 4));
        assert!((a.brdf_sr.unwrap() - 3.0).abs() < 1e-12 && (b.brdf_sr.unwrap() - 8.0).abs() < 1e-12);
        // The uncertainty of a mean of five independent readings of u = 0.3.
        assert!((a.brdf_u_sr.unwrap() - 0.3 / 5f64.sqrt()).abs() < 1e-12);
        // The geometry and time of the bin's middle reading; the truth is not carried.
        assert_eq!((a.k, a.t_s), (2, 2.0));
        assert_eq!(a.truth_point_sr, None);
        assert_eq!(c.brdf_sr, Some(7.0));
        assert!(binned(&rows, 0.0).is_empty() && binned(&rows, f64::NAN).is_empty());
    }

    #[test]
    fn the_csv_has_a_row_per_reading_and_empty_cells_for_missing_values() {
        let rows = [reading(0, Some(0.5), 0.01, 0.5), reading(1, None, 0.01, 0.5)];
        let csv = write_sweeps_csv(&rows, true);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        let header: Vec<&str> = lines[0].split(',').collect();
        assert_eq!(header.len(), 17);
        assert_eq!(header[16], "brdf_true_sr");
        for line in &lines[1..] {
            assert_eq!(line.split(',').count(), header.len(), "{line}");
        }
        assert!(
            lines[2].contains(",,,0.01,,failed: timeout  twice,0.5"),
            "{}",
            lines[2]
        );
        assert_eq!(
            write_sweeps_csv(&rows, false)
                .lines()
                .next()
                .unwrap()
                .split(',')
                .count(),
            16
        );
    }

    #[test]
    fn the_csv_reads_back_as_written_and_errors_name_the_line() {
        let mut rows = vec![reading(0, Some(0.5), 0.01, 0.5), reading(1, None, 0.01, 0.5)];
        rows[0].brdf_aperture_sr = Some(0.49);
        rows[1].flags = vec!["failed: timeout".into(), "below-nebrdf".into()];
        for dry_run in [true, false] {
            let back = parse_sweeps_csv(&write_sweeps_csv(&rows, dry_run), "sweeps.csv").expect("parses");
            assert_eq!(back.len(), 2);
            for (a, b) in rows.iter().zip(&back) {
                let want = SweepReading {
                    incident_w: None,
                    truth_point_sr: a.truth_point_sr.filter(|_| dry_run),
                    ..a.clone()
                };
                assert_eq!(*b, want);
            }
        }
        let bad = "segment,k\n0,1\n";
        let e = parse_sweeps_csv(bad, "x/sweeps.csv")
            .expect_err("columns missing")
            .to_string();
        assert!(e.contains("x/sweeps.csv") && e.contains("band_nm"), "{e}");
        let mut text = write_sweeps_csv(&rows, false);
        text = text.replacen(",0.5,", ",oops,", 1);
        let e = parse_sweeps_csv(&text, "s.csv")
            .expect_err("not a number")
            .to_string();
        assert!(e.contains("line 2") && e.contains("oops"), "{e}");
    }

    #[test]
    fn readings_join_a_run_as_points_after_its_last_one() {
        let run = Run {
            origin: "r".into(),
            name: "r".into(),
            points: vec![Point::at(550.0, [0.0, 0.0, 30.0, 180.0], 0.3)],
            axis_names: vec!["light".into()],
            dry_run: true,
            provenance: None,
        };
        let rows = [reading(0, Some(0.5), 0.01, 0.5), reading(1, None, 0.01, 0.5)];
        let joined = with_readings(run, &rows);
        assert_eq!(joined.points.len(), 3);
        assert_eq!(joined.points[1].index, 1);
        assert_eq!(joined.points[2].index, 2);
        let p = &joined.points[1];
        assert_eq!(
            (p.theta_o_deg, p.brdf_sr, p.brdf_u_sr),
            (20.0, Some(0.5), Some(0.01))
        );
        assert_eq!(p.budget.total_sr(), 0.01);
        assert_eq!(p.readback_deg, vec![("light".to_string(), None)]);
        assert!(p.is_valid() && !joined.points[2].is_valid());
    }

    #[test]
    fn the_summary_counts_coverage_at_k2_and_weights_by_cos_theta_i() {
        // Errors of 1, 3 and 0 standard uncertainties: two of three covered.
        let rows = [
            reading(0, Some(1.01), 0.01, 1.0),
            reading(1, Some(1.03), 0.01, 1.0),
            reading(2, Some(1.0), 0.01, 1.0),
            reading(3, None, 0.01, 1.0),
        ];
        let s = truth_summary(&rows).unwrap();
        assert_eq!(s.readings, 3);
        assert!((s.coverage_k2 - 2.0 / 3.0).abs() < 1e-12);
        // cos 60 = 1/2 on both sums: the relative RMS is sqrt((0.01^2 + 0.03^2) / 3).
        let want = ((0.01f64.powi(2) + 0.03f64.powi(2)) / 3.0).sqrt();
        assert!((s.cos_weighted_relative_rms.unwrap() - want).abs() < 1e-12);
        assert!(truth_summary(&rows[3..]).is_none());
    }
}
