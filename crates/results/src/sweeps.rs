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
pub fn truth_summary(readings: &[SweepReading]) -> Option<SweepTruthSummary> {
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
