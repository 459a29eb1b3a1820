//! The sections of what was measured and how: summary, sample, instrument, plan and coverage, calibration and
//! drift, alignment and characterisation.

use std::collections::BTreeMap;

use toml::Value as Toml;

use super::super::html::{self, esc, facts, figure, note, num, pct, table};
use super::super::{CoverageSummary, PlanCoverage, ReportInput, text_sha256};
use super::{
    campaign_toml, duration, get, instrument_toml, median, parsed, relative_u, table_facts, toml_text,
};
use crate::export::CONVENTIONS;
use crate::points::Point;
use crate::provenance_summary::iso8601_utc;
use crate::run::{Run, list_nm};

pub fn summary(input: &ReportInput<'_>) -> String {
    let run = input.run;
    let record = run.provenance.as_ref();
    let valid: Vec<&Point> = run.valid_points().collect();
    let median_u = median(relative_u(&valid)).map(|u| 2.0 * u);
    let mut rows = vec![
        ("campaign", esc(&run.name)),
        (
            "kind",
            if run.dry_run {
                "dry-run against the simulated instrument (values carry the simulator's truth)".into()
            } else {
                "measured on the instrument".into()
            },
        ),
    ];
    if let Some(r) = record {
        rows.push(("state", esc(&r.campaign.state)));
        if let Some(e) = &r.campaign.last_error {
            rows.push(("last error", esc(e)));
        }
        rows.push((
            "points",
            format!(
                "{} of {} done: {} valid, {} failed, {} flagged",
                r.campaign.points_done,
                r.campaign.total_points,
                r.campaign.valid_points,
                r.campaign.failed_points,
                r.campaign
                    .points_done
                    .saturating_sub(r.campaign.valid_points + r.campaign.failed_points)
            ),
        ));
        if let Some(t) = r.campaign.created_unix_s {
            rows.push(("stored", esc(&iso8601_utc(t))));
        }
        rows.push((
            "instrument time",
            format!(
                "{} measured, {} predicted",
                duration(Some(r.timing.actual_instrument_s)),
                duration(r.timing.predicted_instrument_s)
            ),
        ));
    } else {
        rows.push(("points", format!("{} ({} valid)", run.points.len(), valid.len())));
        rows.push((
            "provenance",
            "none: only the points CSV was found (no run.json beside it)".into(),
        ));
    }
    rows.push(("bands", esc(&list_nm(&run.bands_nm()))));
    rows.push((
        "median relative uncertainty",
        format!("{} (k = 2)", pct(median_u, 2)),
    ));
    if let Some(f) = input.fits.first() {
        rows.push((
            "best model",
            format!(
                "{}: cos-weighted relative rms residual {}",
                esc(f.model.name()),
                pct(Some(f.residuals.cos_weighted_relative_rms), 2)
            ),
        ));
    }
    facts(&rows)
}

pub fn sample(run: &Run) -> String {
    let c = campaign_toml(run);
    let mut rows: Vec<(&str, String)> = Vec::new();
    if let Some(d) = get(c.as_ref(), &["campaign", "description"]) {
        rows.push(("description", esc(&toml_text(d))));
    }
    rows.extend(table_facts(get(c.as_ref(), &["sample"]), &[]));
    rows.push((
        "coordinate system",
        esc(CONVENTIONS
            .iter()
            .find(|(k, _)| *k == "frame")
            .map_or("", |(_, v)| v)),
    ));
    let mut s = facts(&rows);
    if run.dry_run {
        match get(c.as_ref(), &["material"]) {
            Some(m) => {
                s.push_str(&html::p("The simulated sample's material (the dry-run's truth):"));
                s.push_str(&facts(&table_facts(Some(m), &[])));
            }
            None => s.push_str(&note("The simulated material is not in the stored campaign.")),
        }
    }
    if c.is_none() {
        s.push_str(&note("The campaign file is not known (no run.json)."));
    }
    s
}

pub fn instrument(run: &Run) -> String {
    let Some(config) = run.config() else {
        return note("The instrument is not known: this run has no run.json.");
    };
    let i = instrument_toml(run);
    let ins = get(i.as_ref(), &["instrument"]);
    let mut rows = vec![
        (
            "name",
            get(ins, &["name"]).map_or("&ndash;".into(), |v| esc(&toml_text(v))),
        ),
        (
            "geometry",
            get(ins, &["geometry"]).map_or("&ndash;".into(), |v| esc(&toml_text(v))),
        ),
        (
            "instrument file SHA-256",
            format!("<code>{}</code>", text_sha256(&config.instrument_toml)),
        ),
    ];
    let det = get(ins, &["detector"]);
    let f = |k: &str| get(det, &[k]).and_then(Toml::as_float);
    if let (Some(a), Some(d)) = (f("aperture_radius_mm"), f("distance_mm"))
        && a > 0.0
        && d > 0.0
    {
        let half = a.atan2(d);
        let omega = 2.0 * std::f64::consts::PI * (1.0 - half.cos());
        rows.push((
            "receiver",
            format!(
                "aperture radius {a} mm at {d} mm: half-angle {} deg, solid angle {} sr",
                num(Some(half.to_degrees()), 4),
                num(Some(omega), 4)
            ),
        ));
    }
    if let Some(r) = get(det, &["ranges_w"]) {
        rows.push(("meter ranges (W, full scale)", esc(&toml_text(r))));
    }
    let src = get(ins, &["source"]);
    if let Some(s) = src {
        rows.push((
            "source",
            table_facts(Some(s), &[])
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect::<Vec<_>>()
                .join(", "),
        ));
    }
    let mut s = facts(&rows);
    // Devices: the file's declaration and the identity each reported during the run.
    let identities: BTreeMap<&str, &str> = run
        .provenance
        .as_ref()
        .map(|r| {
            r.devices
                .iter()
                .map(|d| (d.name.as_str(), d.identity.as_str()))
                .collect()
        })
        .unwrap_or_default();
    let declared = get(ins, &["devices"]).and_then(Toml::as_array);
    let mut device_rows: Vec<Vec<String>> = Vec::new();
    for d in declared.into_iter().flatten() {
        let name = get(Some(d), &["name"]).map(toml_text).unwrap_or_default();
        device_rows.push(vec![
            esc(&name),
            get(Some(d), &["protocol"]).map_or(String::new(), |v| esc(&toml_text(v))),
            get(Some(d), &["port"]).map_or(String::new(), |v| esc(&toml_text(v))),
            identities
                .get(name.as_str())
                .map_or("not recorded".into(), |v| esc(v)),
        ]);
    }
    s.push_str(&table(
        "devices",
        &["device", "protocol", "port", "identity reported"],
        &device_rows,
    ));
    // The filter bands the run used.
    let bands = run.bands_nm();
    let positions = get(ins, &["filter_wheel", "positions"]).and_then(Toml::as_array);
    let band_rows: Vec<Vec<String>> = positions
        .into_iter()
        .flatten()
        .filter_map(|p| {
            let nm =
                get(Some(p), &["band_nm"]).and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))?;
            bands.iter().any(|b| (b - nm).abs() <= 0.5).then(|| {
                vec![
                    num(Some(nm), 4),
                    get(Some(p), &["bandwidth_nm"]).map_or("&ndash;".into(), |v| esc(&toml_text(v))),
                    get(Some(p), &["position"]).map_or("&ndash;".into(), |v| esc(&toml_text(v))),
                ]
            })
        })
        .collect();
    if !band_rows.is_empty() {
        s.push_str(&table(
            "bands",
            &["band (nm)", "bandwidth (nm, FWHM)", "wheel position"],
            &band_rows,
        ));
    }
    s
}

pub fn plan(run: &Run, plan: Option<&PlanCoverage>, svg: &str, coverage: &CoverageSummary) -> String {
    let c = campaign_toml(run);
    let mut s = String::new();
    let mut rows: Vec<(&str, String)> =
        table_facts(get(c.as_ref(), &["plan"]), &["grid", "calibration", "adaptive"]);
    if let Some(g) = get(c.as_ref(), &["plan", "grid"]) {
        rows.push((
            "grid",
            table_facts(Some(g), &[])
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect::<Vec<_>>()
                .join("; "),
        ));
    }
    if let Some(a) = get(c.as_ref(), &["plan", "adaptive"]) {
        rows.push(("adaptive", esc(&toml_text(a))));
    }
    if let Some(a) = get(c.as_ref(), &["acquisition"]) {
        rows.push((
            "acquisition",
            table_facts(Some(a), &[])
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect::<Vec<_>>()
                .join(", "),
        ));
    }
    s.push_str(&facts(&rows));
    match plan {
        Some(p) => {
            s.push_str(&html::p(&format!(
                "The planner kept {} of the {} (geometry, band) pairs asked for{}.",
                p.kept,
                p.requested,
                if p.adaptive {
                    " in the first pass; later passes were placed at run time from the points measured"
                } else {
                    ""
                }
            )));
            if !p.skipped.is_empty() {
                let rows: Vec<Vec<String>> = p
                    .skipped
                    .iter()
                    .map(|(why, n)| vec![esc(why), n.to_string()])
                    .collect();
                s.push_str(&table("skipped", &["skipped because", "pairs"], &rows));
            }
        }
        None => s.push_str(&note(
            "The stored campaign and instrument files could not be planned again: what the planner skipped is \
             not known.",
        )),
    }
    // Points the run did not measure, by reason.
    if let Some(r) = &run.provenance
        && !r.campaign.flags.is_empty()
    {
        let rows: Vec<Vec<String>> = r
            .campaign
            .flags
            .iter()
            .map(|(flag, n)| vec![esc(flag), n.to_string()])
            .collect();
        s.push_str(&table("flags", &["flag on points", "points"], &rows));
    }
    s.push_str(&figure(
        "coverage",
        svg,
        &format!(
            "Coverage of the hemisphere of outgoing directions, one disc per incidence angle ({} deg), seen from \
             above: radius theta_o (rings at 30, 60 and 90 deg), angle phi_o - phi_i with the source on the left \
             and the specular direction (blue ring) on the right. {} directions measured (black dots), {} with no \
             valid value in any band (red crosses).",
            coverage
                .discs_deg
                .iter()
                .map(|d| html::deg(*d))
                .collect::<Vec<_>>()
                .join(", "),
            coverage.measured,
            coverage.not_measured
        ),
    ));
    s
}

pub fn calibration(run: &Run, drift_svg: Option<&str>) -> String {
    let Some(r) = &run.provenance else {
        return note("The calibration is not known: this run has no run.json.");
    };
    let c = campaign_toml(run);
    let mut rows: Vec<(&str, String)> = table_facts(get(c.as_ref(), &["calibration"]), &[]);
    rows.extend(
        table_facts(get(c.as_ref(), &["plan", "calibration"]), &[])
            .into_iter()
            .collect::<Vec<_>>(),
    );
    let mut s = facts(&rows);
    let mut by_kind: BTreeMap<(&str, String), (usize, f64, f64)> = BTreeMap::new();
    for cal in &r.calibrations {
        let band = cal.band_nm.map_or("&ndash;".to_string(), |b| num(Some(b), 4));
        let e = by_kind
            .entry((cal.kind.as_str(), band))
            .or_insert((0, f64::INFINITY, f64::NEG_INFINITY));
        e.0 += 1;
        e.1 = e.1.min(cal.value_w);
        e.2 = e.2.max(cal.value_w);
    }
    let rows: Vec<Vec<String>> = by_kind
        .iter()
        .map(|((kind, band), (n, lo, hi))| {
            vec![
                esc(kind),
                band.clone(),
                n.to_string(),
                num(Some(*lo), 5),
                num(Some(*hi), 5),
                if *lo > 0.0 {
                    pct(Some(hi / lo - 1.0), 3)
                } else {
                    "&ndash;".into()
                },
            ]
        })
        .collect();
    s.push_str(&table(
        "calibrations",
        &[
            "reading",
            "band (nm)",
            "readings",
            "lowest (W)",
            "highest (W)",
            "spread",
        ],
        &rows,
    ));
    match drift_svg {
        Some(svg) => s.push_str(&figure(
            "drift",
            svg,
            "The normalisation readings over the run's instrument time, each band relative to its first: the \
             source's drift the calibration interpolates between readings.",
        )),
        None => s.push_str(&note(
            "Fewer than two normalisation readings: no drift history to show.",
        )),
    }
    s
}

pub fn alignment(run: &Run) -> String {
    let Some(config) = run.config() else {
        return note("Not known: this run has no run.json.");
    };
    let Some(text) = &config.alignment_toml else {
        return note(
            "No alignment or characterisation was applied: every pose is the instrument file's nominal one, no \
             range correction was made and no instrument signature was subtracted.",
        );
    };
    let Some(a) = parsed(Some(text)) else {
        return note("The stored alignment is not TOML any more; it is shown as stored.")
            + &html::folded_text("alignment (as stored)", text);
    };
    let mut s = facts(&table_facts(get(Some(&a), &["calibration"]), &[]));
    let values = get(Some(&a), &["values"]).and_then(Toml::as_array);
    let rows: Vec<Vec<String>> = values
        .into_iter()
        .flatten()
        .map(|v| {
            let g = |k: &str| get(Some(v), &[k]);
            vec![
                g("name").map_or(String::new(), |x| esc(&toml_text(x))),
                num(g("value").and_then(Toml::as_float), 5),
                num(g("u").and_then(Toml::as_float), 3),
                g("unit").map_or(String::new(), |x| esc(&toml_text(x))),
                match g("observable").and_then(Toml::as_bool) {
                    Some(false) => "no (not applied)".into(),
                    _ => "yes".into(),
                },
            ]
        })
        .collect();
    s.push_str(&html::p("The geometric alignment applied to every pose:"));
    s.push_str(&table(
        "alignment",
        &["parameter", "value", "standard uncertainty", "unit", "observable"],
        &rows,
    ));
    match get(Some(&a), &["detector"]) {
        Some(d) => {
            let ranges = get(Some(d), &["ranges"]);
            let signature = get(Some(d), &["signature"]).and_then(Toml::as_array);
            s.push_str(&html::p(&format!(
                "Characterisation applied: {}; the instrument signature (stray light with the holder empty) {}.",
                match ranges {
                    Some(_) => "every reading corrected by the meter ranges' measured gains and darks",
                    None => "no range correction (the ranges were not characterised)",
                },
                match signature {
                    Some(s) if !s.is_empty() => format!("measured in {} band(s) and subtracted from every value", s.len()),
                    _ => "was not measured".into(),
                }
            )));
        }
        None => s.push_str(&note(
            "No characterisation was applied (no range correction, no signature subtracted).",
        )),
    }
    if let Some(src) = get(Some(&a), &["source"]) {
        s.push_str(&html::p("The source's warm-up and drift, as watched:"));
        s.push_str(&facts(&table_facts(Some(src), &[])));
    }
    s
}
