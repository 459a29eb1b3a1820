//! `gonio report RUN [--out report.html] [--model M,...]`: the run's measurement report, one self-contained
//! HTML page (gonio_results::report has the layout): the sample, the instrument, the plan and its coverage,
//! the calibration and drift, the alignment and characterisation, plots, the sweeps (`--points-only` leaves
//! them out), the uncertainty, the fitted models,
//! in dry-runs the error against the simulator's truth, and how to reproduce the run. The models are fitted as
//! `gonio fit` fits them (averaged over the run's detector aperture); the best by its cosine-weighted residual
//! is plotted against the measurement. The page goes to `--out`, by default `report.html` in the run
//! directory (`<campaign>-report.html` in the current directory for a run read from a daemon's store); its
//! path is printed on stdout.

use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

use gonio_results::fit::FitModel;

use crate::CliError;
use crate::export::RunSource;

#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    #[command(flatten)]
    pub source: RunSource,
    /// The HTML file to write (default: report.html in the run directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The models to fit and compare, comma-separated (default: all of them).
    #[arg(long, value_delimiter = ',', value_parser = ["lambertian", "oren-nayar", "conductor", "plastic", "phong"])]
    pub models: Vec<String>,
    /// Fit no model (a faster report; the fit section says none was fitted).
    #[arg(long, conflicts_with = "models")]
    pub no_fit: bool,
    /// Leave the run's sweep readings out (by default the page has a section on them, draws them averaged
    /// along their arcs and fits them with the points).
    #[arg(long)]
    pub points_only: bool,
}

pub fn run(args: ReportArgs) -> Result<(), CliError> {
    let run = args.source.load()?;
    let sweeps = if args.points_only {
        Vec::new()
    } else {
        args.source.sweep_readings()?
    };
    let models: Vec<FitModel> = if args.no_fit {
        Vec::new()
    } else if args.models.is_empty() {
        FitModel::ALL.to_vec()
    } else {
        args.models
            .iter()
            .map(|m| {
                FitModel::from_name(m)
                    .ok_or_else(|| CliError::input(format!("--models: unknown model {m:?}")))
            })
            .collect::<Result<_, _>>()?
    };
    let now_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64());
    let (page, summary) = gonio_engine::export::report(&run, &sweeps, &models, now_s, |m| {
        eprintln!("gonio: fitting {} ...", m.name());
    })
    .map_err(|e| CliError::input(e.to_string()))?;
    let out = args.out.clone().unwrap_or_else(|| {
        if args.source.run.is_some() {
            args.source.default_dir().join("report.html")
        } else {
            PathBuf::from(format!("{}-report.html", run.name))
        }
    });
    std::fs::write(&out, page).map_err(|e| CliError::io(format!("cannot write {}", out.display()), e))?;
    eprintln!(
        "gonio: report of {} ({} points): sections {}; figures {}",
        run.name,
        run.points.len(),
        summary.sections.join(", "),
        summary.figures.join(", ")
    );
    println!("{}", out.display());
    Ok(())
}
