//! The sections of what came of the run: uncertainty, model fit, the error against the simulator's truth,
//! and how to reproduce it.

use super::super::html::{self, esc, facts, note, num, pct, table};
use super::super::{ReportInput, text_sha256};
use super::{median, relative_u};
use crate::angular_class::AngularClass;
use crate::fit::FitReport;
use crate::points::Point;
use crate::provenance::TruthErrors;
use crate::run::Run;

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
         the points have in common (the solid angle, a band's normalisation, a range's gain, a dark reading, an \
         alignment parameter), which moves them together; the fit's response to each such group moved by its \
         uncertainty. Combine the two in quadrature for the total. chi2/dof compares the residuals with the \
         points' whole budget, what they share with its correlations: {:.3} for {}: {} ({:.3} against the \
         independent uncertainties alone).",
        best.residuals.chi2_per_dof,
        best.model.name(),
        crate::fit::chi2_meaning(best.residuals.chi2_per_dof),
        best.residuals.chi2_per_dof_independent
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
