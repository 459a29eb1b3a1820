//! A measurement report a lab can attach: one self-contained HTML page per run, after the reporting
//! conventions of ASTM E1392 / E2387 (the sample and its coordinate system, the geometry and wavelengths, the
//! receiver solid angle, the instrument signature, the calibration method, the uncertainty).
//!
//! The page works offline: its style is inline, its plots are inline SVG, it has no script, and its Content
//! Security Policy (`default-src 'none'`) forbids the browser to fetch anything. Every number comes from the
//! run ([`Run`]: points.csv and run.json, or the same read from a store) and from the fits the caller made with
//! [`crate::fit`] as `gonio fit` makes them; the report recomputes nothing the exports state differently.
//!
//! Sections, in this order (each a `<section id=...>`, [`SECTIONS`]): the summary; the sample; the instrument;
//! the plan and its coverage of the hemisphere; the calibration and drift history; the alignment and
//! characterisation; the plots; the sweeps (their readings per band, or a line saying the plan had none); the
//! uncertainty; the fit; in dry-runs only, the error against the simulator's truth (a run on hardware has none
//! and says so in the uncertainty section); how to reproduce the run. A run's sweep readings are drawn with its
//! points averaged along their arcs ([`crate::sweeps::binned`]) and fitted whole, as `gonio plot` and
//! `gonio fit` take them.

use crate::error::ResultsError;
use crate::fit::{self, FitModel, FitOptions, FitReport};
use crate::plot::{self, PlotOptions};
use crate::provenance_summary::{iso8601_utc, sha256_hex};
use crate::run::{Run, list_nm};
use crate::sweeps::SweepReading;

mod figures;
mod html;
mod sections;

pub use figures::{CoverageSummary, incidences_deg};

/// The section ids, in page order. `truth` is present in dry-runs only.
pub const SECTIONS: [&str; 12] = [
    "summary",
    "sample",
    "instrument",
    "plan",
    "calibration",
    "alignment",
    "plots",
    "sweeps",
    "uncertainty",
    "fit",
    "truth",
    "reproduce",
];

/// What the planner kept of the campaign's plan and what it skipped, by reason (from the stored campaign and
/// instrument texts, planned as the run planned them).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanCoverage {
    /// (geometry, band) pairs the campaign asked for.
    pub requested: usize,
    /// (geometry, band) pairs the plan kept.
    pub kept: usize,
    /// Skipped pairs by reason.
    pub skipped: Vec<(String, usize)>,
    /// An adaptive plan: its points are placed at run time (the first pass is what `kept` counts).
    pub adaptive: bool,
}

/// A fit that could not be made, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FitFailure {
    pub model: String,
    pub reason: String,
}

/// Everything the report shows.
#[derive(Debug, Clone)]
pub struct ReportInput<'a> {
    pub run: &'a Run,
    /// The run's sweep readings (sweeps.csv, or the store's); empty for a plan of points only.
    pub sweeps: &'a [SweepReading],
    /// The fits made (the first is the one plotted and tabulated in full); may be empty.
    pub fits: Vec<FitReport>,
    pub fit_failures: Vec<FitFailure>,
    /// `None` when the stored configuration no longer plans (the section says so).
    pub plan: Option<PlanCoverage>,
    /// The software writing the report, e.g. "gonio 0.1.0".
    pub generated_by: String,
    /// When the report was written, Unix seconds.
    pub generated_unix_s: f64,
    /// The command line that reproduces the run, when the caller knows its files.
    pub reproduce_command: Option<String>,
}

/// What the page holds: its sections and figures, in order (for the caller's message and the tests).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReportSummary {
    pub sections: Vec<&'static str>,
    pub figures: Vec<String>,
    pub coverage: CoverageSummary,
}

/// The page's style: a print-friendly single column.
const STYLE: &str = "body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;\
color:#111;line-height:1.4}h1{margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;\
margin-top:2em}table{border-collapse:collapse;margin:.6em 0}th,td{border:1px solid #ccc;padding:.25em .5em;\
text-align:left;vertical-align:top}thead th{background:#f3f3f3}table.facts th{background:#f8f8f8;\
font-weight:600;width:16em}td{font-variant-numeric:tabular-nums}figure{margin:1em 0;overflow-x:auto}\
figure svg{max-width:100%;height:auto}figcaption{color:#444;font-size:.92em;margin-top:.3em}\
.note{background:#fff8e0;border-left:4px solid #e0b000;padding:.4em .8em}pre{background:#f6f6f6;\
padding:.6em;overflow-x:auto;font-size:.85em}nav a{margin-right:.8em}@media print{nav{display:none}}";

/// The report page and what it holds.
pub fn render(input: &ReportInput<'_>) -> Result<(String, ReportSummary), ResultsError> {
    let run = input.run;
    let mut summary = ReportSummary::default();
    let mut body = String::new();
    let mut add = |id: &'static str, title: &str, content: String, summary: &mut ReportSummary| {
        summary.sections.push(id);
        body.push_str(&format!(
            "<section id=\"{id}\"><h2>{}</h2>{content}</section>\n",
            html::esc(title)
        ));
    };
    add("summary", "Summary", sections::summary(input), &mut summary);
    add("sample", "Sample", sections::sample(run), &mut summary);
    add(
        "instrument",
        "Instrument",
        sections::instrument(run),
        &mut summary,
    );
    let (coverage_svg, coverage) = figures::coverage_svg(run)?;
    summary.coverage = coverage.clone();
    summary.figures.push("coverage".into());
    add(
        "plan",
        "Plan and coverage",
        sections::plan(run, input.plan.as_ref(), &coverage_svg, &coverage),
        &mut summary,
    );
    let drift = match run.provenance.as_ref() {
        Some(r) => figures::drift_svg(&r.calibrations)?,
        None => None,
    };
    if drift.is_some() {
        summary.figures.push("drift".into());
    }
    add(
        "calibration",
        "Calibration and drift",
        sections::calibration(run, drift.as_deref()),
        &mut summary,
    );
    add(
        "alignment",
        "Alignment and characterisation",
        sections::alignment(run),
        &mut summary,
    );
    let plot_opts = PlotOptions {
        heat_band_nm: None,
        model: input
            .fits
            .first()
            .map(|f| (f.material.clone(), format!("fitted {}", f.model.name()))),
    };
    // The sweep readings joined to the points for the picture, thinned along their arcs.
    let drawn = (!input.sweeps.is_empty()).then(|| {
        crate::sweeps::with_readings(
            run.clone(),
            &crate::sweeps::binned(input.sweeps, crate::sweeps::PLOT_BIN_DEG),
        )
    });
    let plots = match plot::render(drawn.as_ref().unwrap_or(run), &plot_opts) {
        Ok((svg, plot_summary)) => {
            summary.figures.push("brdf".into());
            let caption = format!(
                "The measured BRDF: {}. Polar panels: in-plane slices per band, log radius over {} decades; \
                 heat maps: the BRDF over (phi_o - phi_i, theta_o) per incidence, log colour scale{}.",
                plot_summary.panels.join("; "),
                plot::DECADES,
                if plot_opts.model.is_some() {
                    "; the fitted model's curves over the measured ranges, and its values against the measured ones \
                     with the 1:1 line (the residuals are the distances from it)"
                } else {
                    ""
                }
            );
            html::figure("brdf", &svg, &caption)
        }
        Err(e) => html::note(&format!("No plot: {e}")),
    };
    add("plots", "Plots", plots, &mut summary);
    add(
        "sweeps",
        "Sweeps",
        sections::sweeps(input.sweeps, run.dry_run),
        &mut summary,
    );
    add(
        "uncertainty",
        "Uncertainty",
        sections::uncertainty(run),
        &mut summary,
    );
    add("fit", "Model fit", sections::fit(input), &mut summary);
    if run.dry_run {
        add(
            "truth",
            "Error against the simulator's truth",
            sections::truth(run),
            &mut summary,
        );
    }
    add(
        "reproduce",
        "Software and reproduction",
        sections::reproduce(input),
        &mut summary,
    );
    let nav: String = summary
        .sections
        .iter()
        .map(|id| format!("<a href=\"#{id}\">{id}</a>"))
        .collect();
    let title = format!("BRDF measurement report: {}", run.name);
    let page = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; style-src 'unsafe-inline'\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{}</title><style>{STYLE}</style></head>\n<body><h1>{}</h1>\
         <p>{} &middot; written {} by {} &middot; bands {}</p><nav>{nav}</nav>\n{body}</body></html>\n",
        html::esc(&title),
        html::esc(&title),
        html::esc(&run.origin),
        html::esc(&iso8601_utc(input.generated_unix_s)),
        html::esc(&input.generated_by),
        html::esc(&list_nm(&run.bands_nm())),
    );
    Ok((page, summary))
}

/// The SHA-256 of a configuration text, as the exports name files.
fn text_sha256(text: &str) -> String {
    sha256_hex(text.as_bytes())
}

/// Each model fitted as `gonio fit` fits it (every band, the default robust loss, the model averaged over the
/// detector's aperture when its half-angle is known), best first by the cosine-weighted relative rms
/// residual; the models that could not be fitted, with the reason. `on_model` hears of each fit as it starts
/// (a fit takes seconds).
pub fn fit_models(
    run: &Run,
    models: &[FitModel],
    aperture_half_angle_rad: Option<f64>,
    mut on_model: impl FnMut(FitModel),
) -> (Vec<FitReport>, Vec<FitFailure>) {
    let (mut fits, mut failures) = (Vec::new(), Vec::new());
    for &model in models {
        let mut opts = FitOptions::new(model);
        opts.aperture_half_angle_rad = aperture_half_angle_rad;
        on_model(model);
        match fit::fit(run, &opts) {
            Ok(f) => fits.push(f),
            Err(e) => failures.push(FitFailure {
                model: model.name().to_string(),
                reason: e.to_string(),
            }),
        }
    }
    let key = |f: &FitReport| {
        let r = f.residuals.cos_weighted_relative_rms;
        if r.is_finite() { r } else { f64::INFINITY }
    };
    fits.sort_by(|a, b| key(a).total_cmp(&key(b)));
    (fits, failures)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::Point;

    /// A run on hardware, read from its CSV alone: Lambertian values at 30 deg incidence, no truth.
    fn hardware_run() -> Run {
        let points = (0..12)
            .map(|k| Point {
                index: k,
                signal_w: Some(1e-7),
                dark_w: Some(1e-10),
                incident_w: Some(5e-4),
                brdf_u_sr: Some(0.0006),
                t_s: Some(k as f64),
                ..Point::at(550.0, [30.0, 0.0, 5.0 * k as f64, 180.0], 0.3)
            })
            .collect();
        Run {
            origin: "bench/points.csv".into(),
            name: "paper".into(),
            points,
            axis_names: Vec::new(),
            dry_run: false,
            provenance: None,
        }
    }

    #[test]
    fn a_run_on_hardware_claims_no_truth_and_says_what_it_does_not_know() {
        let run = hardware_run();
        let (fits, failures) = fit_models(&run, &[FitModel::Lambertian], None, |_| {});
        assert!(failures.is_empty(), "{failures:?}");
        let input = ReportInput {
            run: &run,
            sweeps: &[],
            fits,
            fit_failures: Vec::new(),
            plan: None,
            generated_by: "gonio test".into(),
            generated_unix_s: 0.0,
            reproduce_command: None,
        };
        let (page, summary) = render(&input).expect("renders");
        assert!(!summary.sections.contains(&"truth"), "{:?}", summary.sections);
        assert!(!page.contains("<section id=\"truth\">"));
        assert!(page.contains("there is no ground truth"), "no hardware note");
        assert!(
            page.contains("no run.json"),
            "the missing provenance is not named"
        );
        assert!(page.contains("no per-point uncertainty budget"));
        // Lambertian at 0.3 1/sr: albedo pi * 0.3.
        assert!(page.contains("0.942478"), "albedo");
        assert_eq!(summary.coverage.measured, 12);
        assert_eq!(summary.coverage.discs_deg, vec![30.0]);
    }
}
