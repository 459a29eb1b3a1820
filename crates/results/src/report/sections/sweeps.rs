//! The report's sweeps section: what the arms measured while turning (`[[plan.sweeps]]`), per band, and in
//! dry-runs how the readings met the simulator's truth at their arcs' middles.

use std::collections::{BTreeMap, BTreeSet};

use super::super::html::{self, num, pct, table};
use super::median;
use crate::run::BAND_TOLERANCE_NM;
use crate::sweeps::{PLOT_BIN_DEG, SweepReading, truth_summary};

/// The section: a note when the campaign swept nothing, else a table per band.
pub fn sweeps(readings: &[SweepReading], dry_run: bool) -> String {
    if readings.is_empty() {
        return html::p(
            "No sweeps: this campaign measured points only, stop and go. A campaign asks for sweeps, arcs read \
             while an arm turns, with [[plan.sweeps]] (docs/reference/campaign-file.md).",
        );
    }
    let segments: BTreeSet<u32> = readings.iter().map(|r| r.segment).collect();
    let mut s = html::p(&format!(
        "{} readings in {} sweeps (each an arc in one band), read back to back while an arm turned; each \
         value is attributed to the middle of the arc it covered, corrected to it and to the nominal geometry \
         when the campaign completed. The plots show them averaged over {PLOT_BIN_DEG} deg of arc per sweep; \
         the fits take every reading.",
        readings.len(),
        segments.len()
    ));
    // Bands as the points' are: within the tolerance one band.
    let mut bands: Vec<(f64, Vec<&SweepReading>)> = Vec::new();
    for r in readings {
        match bands
            .iter_mut()
            .find(|(nm, _)| (nm - r.band_nm).abs() <= BAND_TOLERANCE_NM)
        {
            Some((_, v)) => v.push(r),
            None => bands.push((r.band_nm, vec![r])),
        }
    }
    bands.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut header = vec![
        "band (nm)",
        "sweeps",
        "readings",
        "valid",
        "flagged",
        "arcs (deg)",
        "median k = 2 relative u",
    ];
    if dry_run {
        header.extend(["k = 2 holds the truth", "cos-weighted relative rms"]);
    }
    let rows: Vec<Vec<String>> = bands
        .iter()
        .map(|(nm, rs)| {
            let valid: Vec<&SweepReading> = rs
                .iter()
                .copied()
                .filter(|r| r.brdf_sr.is_some_and(f64::is_finite))
                .collect();
            let flagged = rs.iter().filter(|r| !r.flags.is_empty()).count();
            let (lo, hi) = rs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
                (
                    lo.min(r.arc_from_deg.min(r.arc_to_deg)),
                    hi.max(r.arc_from_deg.max(r.arc_to_deg)),
                )
            });
            let rel_u: Vec<f64> = valid
                .iter()
                .filter_map(|r| match (r.brdf_sr, r.brdf_u_sr) {
                    (Some(f), Some(u)) if f != 0.0 => Some(u / f.abs()),
                    _ => None,
                })
                .collect();
            let mut row = vec![
                html::deg(*nm),
                rs.iter()
                    .map(|r| r.segment)
                    .collect::<BTreeSet<_>>()
                    .len()
                    .to_string(),
                rs.len().to_string(),
                valid.len().to_string(),
                flagged.to_string(),
                if lo.is_finite() {
                    format!("{} to {}", html::deg(lo), html::deg(hi))
                } else {
                    "&ndash;".into()
                },
                pct(median(rel_u).map(|u| 2.0 * u), 2),
            ];
            if dry_run {
                let t = truth_summary(rs.iter().copied());
                row.push(pct(t.map(|t| t.coverage_k2), 3));
                row.push(num(t.and_then(|t| t.cos_weighted_relative_rms), 3));
            }
            row
        })
        .collect();
    s.push_str(&table("sweeps", &header, &rows));
    let mut flags: BTreeMap<&str, usize> = BTreeMap::new();
    for f in readings.iter().flat_map(|r| &r.flags) {
        *flags.entry(f.as_str()).or_default() += 1;
    }
    if !flags.is_empty() {
        let list: Vec<String> = flags.iter().map(|(f, n)| format!("{f} {n}")).collect();
        s.push_str(&html::p(&format!(
            "Flags on sweep readings: {}.",
            list.join(", ")
        )));
    }
    s
}
