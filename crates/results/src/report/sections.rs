//! The report's sections as HTML fragments, each from the run record, its stored configuration texts and its
//! points (module doc of [`super`]).

use std::collections::BTreeMap;

use toml::Value as Toml;

use super::html::{self, esc, facts, figure, note, num, pct, table};
use super::{CoverageSummary, PlanCoverage, ReportInput, text_sha256};
use crate::angular_class::AngularClass;
use crate::export::CONVENTIONS;
use crate::fit::FitReport;
use crate::points::Point;
use crate::provenance::TruthErrors;
use crate::provenance_summary::iso8601_utc;
use crate::run::{Run, list_nm};

/// A stored configuration text as TOML (`None` when absent or no longer TOML).
fn parsed(text: Option<&String>) -> Option<Toml> {
    text.and_then(|t| t.parse::<toml::Table>().ok()).map(Toml::Table)
}

fn campaign_toml(run: &Run) -> Option<Toml> {
    parsed(run.config().map(|c| &c.campaign_toml))
}

fn instrument_toml(run: &Run) -> Option<Toml> {
    parsed(run.config().map(|c| &c.instrument_toml))
}

/// A TOML value as a short text (tables and arrays inline).
fn toml_text(v: &Toml) -> String {
    match v {
        Toml::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// A table's scalar keys as facts (`prefix.key`), skipping `skip`.
fn table_facts<'a>(t: Option<&'a Toml>, skip: &[&str]) -> Vec<(&'a str, String)> {
    t.and_then(Toml::as_table)
        .map(|t| {
            t.iter()
                .filter(|(k, _)| !skip.contains(&k.as_str()))
                .map(|(k, v)| {
                    let text = match v {
                        // As written when short (12.5), else to five significant digits.
                        Toml::Float(f) if format!("{f}").len() > 8 => num(Some(*f), 5),
                        other => esc(&toml_text(other)),
                    };
                    (k.as_str(), text)
                })
                .collect()
        })
        .unwrap_or_default()
}

fn get<'a>(v: Option<&'a Toml>, path: &[&str]) -> Option<&'a Toml> {
    path.iter().try_fold(v?, |v, k| v.get(k))
}

fn duration(s: Option<f64>) -> String {
    match s.filter(|s| s.is_finite()) {
        None => "&ndash;".into(),
        Some(s) if s < 120.0 => format!("{s:.0} s"),
        Some(s) if s < 7200.0 => format!("{s:.0} s ({:.1} min)", s / 60.0),
        Some(s) => format!("{s:.0} s ({:.2} h)", s / 3600.0),
    }
}

/// Median of the finite values; `None` for none.
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// The valid points' relative standard uncertainties (k = 1).
fn relative_u(points: &[&Point]) -> Vec<f64> {
    points
        .iter()
        .filter_map(|p| match (p.value(), p.brdf_u_sr) {
            (Some(f), Some(u)) if f != 0.0 => Some(u / f.abs()),
            _ => None,
        })
        .collect()
}

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

/// One angular class's row: points, median k = 2 relative uncertainty, and in dry-runs the coverage of the
/// point truth and the rms of (value - truth) / u.
fn class_row(name: String, points: &[&Point], dry_run: bool) -> Vec<String> {
    let rel = relative_u(points);
    let mut row = vec![
        name,
        points.len().to_string(),
        pct(median(rel.clone()).map(|u| 2.0 * u), 2),
    ];
    if dry_run {
        let z: Vec<f64> = points
            .iter()
            .filter_map(|p| match (p.value(), p.brdf_u_sr, p.truth_point_sr) {
                (Some(f), Some(u), Some(t)) if u > 0.0 && t.is_finite() => Some((f - t) / u),
                _ => None,
            })
            .collect();
        let covered = z.iter().filter(|z| z.abs() <= 2.0).count();
        let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len().max(1) as f64).sqrt();
        let rel_err: Vec<f64> = points
            .iter()
            .filter_map(|p| match (p.value(), p.truth_point_sr) {
                (Some(f), Some(t)) if t != 0.0 && t.is_finite() => Some(((f - t) / t).abs()),
                _ => None,
            })
            .collect();
        row.push(if z.is_empty() {
            "&ndash;".into()
        } else {
            pct(Some(covered as f64 / z.len() as f64), 3)
        });
        row.push(if z.is_empty() {
            "&ndash;".into()
        } else {
            num(Some(rms), 3)
        });
        row.push(pct(median(rel_err), 3));
    }
    row
}

pub fn uncertainty(run: &Run) -> String {
    let valid: Vec<&Point> = run.valid_points().collect();
    let mut s = html::p(
        "Each value's standard uncertainty (brdf_u_sr, k = 1) is stated in points.csv; here its median over the \
         valid points per angular class, expanded to k = 2.",
    );
    let mut header = vec!["angular class", "points", "median relative u (k = 2)"];
    if run.dry_run {
        header.extend([
            "k = 2 interval holds the truth",
            "rms of (value - truth) / u",
            "median |error|",
        ]);
    }
    let mut rows: Vec<Vec<String>> = AngularClass::ALL
        .iter()
        .map(|class| {
            let pts: Vec<&Point> = valid
                .iter()
                .copied()
                .filter(|p| AngularClass::of(p) == *class)
                .collect();
            class_row(
                format!("{} ({})", class.name(), esc(&class.description())),
                &pts,
                run.dry_run,
            )
        })
        .collect();
    rows.push(class_row("all".into(), &valid, run.dry_run));
    s.push_str(&table("uncertainty-classes", &header, &rows));
    match run.provenance.as_ref().and_then(|r| r.uncertainty.as_ref()) {
        Some(u) => {
            let mut components: Vec<(&String, &crate::budget_summary::ComponentSummary)> =
                u.components.iter().collect();
            components.sort_by(|a, b| b.1.median_relative_u.total_cmp(&a.1.median_relative_u));
            let rows: Vec<Vec<String>> = components
                .iter()
                .map(|(name, c)| {
                    vec![
                        esc(name),
                        pct(Some(c.median_relative_u), 4),
                        format!("{} of {}", c.largest_in, u.points),
                        if c.shared_by.is_empty() {
                            "independent per point".into()
                        } else {
                            format!("shared by {}", esc(&c.shared_by.join(", ")))
                        },
                    ]
                })
                .collect();
            s.push_str(&html::p(
                "The budget's components, largest first (run.json's uncertainty summary; each point's budget is in \
                 points.csv's budget column):",
            ));
            s.push_str(&table(
                "budget",
                &["component", "median relative u (k = 1)", "largest in points", "correlation"],
                &rows,
            ));
        }
        None => s.push_str(&note(
            "This run has no per-point uncertainty budget (it was measured before budgets were recorded): only the \
             combined uncertainty is known.",
        )),
    }
    if !run.dry_run {
        s.push_str(&note(
            "Measured on hardware: there is no ground truth to compare with; the accuracy stated is the \
             uncertainty above.",
        ));
    }
    s
}

fn fit_row(f: &FitReport) -> Vec<String> {
    vec![
        esc(f.model.name()),
        f.residuals.points.to_string(),
        pct(Some(f.residuals.cos_weighted_relative_rms), 2),
        num(Some(f.residuals.log_rms), 3),
        num(Some(f.residuals.chi2_per_dof), 3),
        f.downweighted.to_string(),
    ]
}

pub fn fit(input: &ReportInput<'_>) -> String {
    let Some(best) = input.fits.first() else {
        let mut s = note("No model was fitted.");
        for f in &input.fit_failures {
            s.push_str(&html::p(&format!("{}: {}", f.model, f.reason)));
        }
        return s;
    };
    let mut s = html::p(&format!(
        "Models fitted as `gonio fit` fits them (robust {} loss, weighted by the stated uncertainties and the \
         cosines{}), best first by the cosine-weighted relative rms residual:",
        best.options.loss.name(),
        match best.options.aperture_half_angle_rad {
            Some(a) => format!(
                ", averaged over the detector's {:.3} deg aperture",
                a.to_degrees()
            ),
            None => String::new(),
        }
    ));
    let rows: Vec<Vec<String>> = input.fits.iter().map(fit_row).collect();
    s.push_str(&table(
        "fits",
        &[
            "model",
            "points",
            "cos-weighted relative rms",
            "log rms",
            "chi2/dof",
            "outliers",
        ],
        &rows,
    ));
    for f in &input.fit_failures {
        s.push_str(&note(&format!("{} could not be fitted: {}", f.model, f.reason)));
    }
    s.push_str(&html::p(&format!(
        "The parameters of {} (standard uncertainties, k = 1):",
        best.model.name()
    )));
    let rows: Vec<Vec<String>> = best
        .params
        .iter()
        .map(|p| {
            vec![
                esc(&FitReport::label(p)),
                num(Some(p.value), 6),
                p.std_uncertainty
                    .map_or("undetermined".into(), |u| num(Some(u), 3)),
                num(p.shared_uncertainty, 3),
                if p.at_bound {
                    "at its bound".into()
                } else {
                    String::new()
                },
            ]
        })
        .collect();
    s.push_str(&table(
        "parameters",
        &["parameter", "value", "u, independent", "u, shared", ""],
        &rows,
    ));
    s.push_str(&html::p(&format!(
        "Standard uncertainties (k = 1). Independent: from the points' scatter about the model. Shared: from what \
         the points have in common (the solid angle, a band's normalisation, a range's gain), which moves them \
         together and leaves no residual; the fit is repeated with each such group moved by its uncertainty. \
         Combine the two in quadrature for the total. chi2/dof compares the residuals with the points' \
         independent uncertainties: {:.3} for {}: {}.",
        best.residuals.chi2_per_dof,
        best.model.name(),
        crate::fit::chi2_meaning(best.residuals.chi2_per_dof)
    )));
    s
}

fn truth_row(name: &str, t: Option<&TruthErrors>) -> Vec<String> {
    match t {
        None => vec![
            esc(name),
            "&ndash;".into(),
            "&ndash;".into(),
            "&ndash;".into(),
            "&ndash;".into(),
            "&ndash;".into(),
        ],
        Some(t) => vec![
            esc(name),
            t.points.to_string(),
            pct(t.cos_weighted_relative_rms, 3),
            num(Some(t.log_rms), 3),
            pct(Some(t.max_relative_error), 2),
            num(Some(t.max_normalised_error), 3),
        ],
    }
}

pub fn truth(run: &Run) -> String {
    let Some(r) = &run.provenance else {
        return note("No run.json: the truth summary is not known.");
    };
    let mut s = html::p(
        "A dry-run: the simulator knows the BRDF it rendered. The point truth is the BRDF at the nominal \
         geometry; the aperture truth is its average over the detector's aperture, what an ideal instrument \
         reads.",
    );
    s.push_str(&table(
        "truth",
        &[
            "against",
            "points",
            "cos-weighted relative rms",
            "log rms",
            "largest relative error",
            "largest |error| / u",
        ],
        &[
            truth_row("point truth", r.truth.against_point_value.as_ref()),
            truth_row("aperture average", r.truth.against_aperture_average.as_ref()),
        ],
    ));
    if let Some(check) = r
        .uncertainty
        .as_ref()
        .and_then(|u| u.against_point_truth.as_ref())
    {
        s.push_str(&html::p(&format!(
            "The k = 2 intervals hold the point truth for {} of {} points; the rms of (value - truth) / u is {} \
             (1 for an honest budget).",
            pct(Some(check.coverage_k2), 3).replace("&ndash;", "-"),
            check.points,
            num(Some(check.rms_z), 3)
        )));
    }
    match &r.simulator_truth {
        Some(t) => {
            let text = serde_json::to_string_pretty(t).unwrap_or_default();
            s.push_str(&html::folded_text(
                "the simulated instrument's hidden imperfections (run.json's simulator_truth)",
                &text,
            ));
        }
        None => s.push_str(&html::p(
            "The simulated instrument was ideal: no hidden imperfection.",
        )),
    }
    s
}

pub fn reproduce(input: &ReportInput<'_>) -> String {
    let run = input.run;
    let mut rows = vec![("report written by", esc(&input.generated_by))];
    if let Some(r) = &run.provenance {
        rows.push(("measured with", esc(&r.software_version)));
    }
    if let Some(c) = run.config() {
        rows.push((
            "campaign file SHA-256",
            format!("<code>{}</code>", text_sha256(&c.campaign_toml)),
        ));
        rows.push((
            "instrument file SHA-256",
            format!("<code>{}</code>", text_sha256(&c.instrument_toml)),
        ));
        if let Some(a) = &c.alignment_toml {
            rows.push((
                "calibration file SHA-256",
                format!("<code>{}</code>", text_sha256(a)),
            ));
        }
    }
    let mut s = facts(&rows);
    match &input.reproduce_command {
        Some(cmd) => {
            s.push_str(&html::p(
                "To measure again with the same configuration, save the files below under the names the command \
                 uses, then run:",
            ));
            s.push_str(&format!("<pre>{}</pre>", esc(cmd)));
        }
        None => s.push_str(&note("The configuration is not known: this run has no run.json.")),
    }
    if let Some(c) = run.config() {
        s.push_str(&html::folded_text(
            "campaign.toml (as stored with the run)",
            &c.campaign_toml,
        ));
        s.push_str(&html::folded_text(
            "instrument.toml (as stored with the run)",
            &c.instrument_toml,
        ));
        if let Some(a) = &c.alignment_toml {
            s.push_str(&html::folded_text("calibration.toml (the alignment applied)", a));
        }
    }
    s
}
