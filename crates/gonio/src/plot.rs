//! `gonio plot RUN [--out FILE.svg] [--model MATERIAL] [--band NM]`: SVG pictures of a run
//! (gonio_results::plot has the layout): in-plane polar slices per band, a (theta_o, phi_o) heat map per
//! incidence angle, and, with `--model` (a fitted material file, or any material file or preset), the model
//! against the measurement. The SVG goes to `--out`, by default `plot.svg` in the run directory (the current
//! directory for a run read from a daemon's store); its path is printed on stdout. A run's sweep readings are
//! drawn with its points, averaged in bins of `PLOT_BIN_DEG` (gonio_results::sweeps) of arc per sweep (a picture of a hundred
//! thousand readings would be megabytes; the readings themselves are in sweeps.csv); `--points-only` leaves
//! them out.

use std::path::PathBuf;

use gonio_brdf::Material;
use gonio_results::plot::{self, PlotOptions};
use gonio_results::sweeps::PLOT_BIN_DEG;

use crate::CliError;
use crate::export::RunSource;

#[derive(Debug, clap::Args)]
pub struct PlotArgs {
    #[command(flatten)]
    pub source: RunSource,
    /// The SVG file to write (default: plot.svg in the run directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// A material to compare with (e.g. the file `gonio fit` wrote), or a preset name.
    #[arg(long)]
    pub model: Option<String>,
    /// The band of the heat maps, nm (default: the band nearest 550 nm).
    #[arg(long)]
    pub band: Option<f64>,
    /// Leave the run's sweep readings out (by default they are drawn, averaged in bins of 0.5 deg of arc).
    #[arg(long)]
    pub points_only: bool,
}

pub fn run(args: PlotArgs) -> Result<(), CliError> {
    let mut run = args.source.load()?;
    if !args.points_only {
        let readings = args.source.sweep_readings()?;
        if !readings.is_empty() {
            let bins = gonio_results::sweeps::binned(&readings, PLOT_BIN_DEG);
            eprintln!(
                "gonio: {} sweep readings drawn as {} averages over {PLOT_BIN_DEG} deg of arc (--points-only leaves \
                 them out)",
                readings.len(),
                bins.len()
            );
            run = gonio_results::sweeps::with_readings(run, &bins);
        }
    }
    let model = match &args.model {
        Some(m) => Some((
            Material::from_file_or_preset(m).map_err(|e| CliError::input(format!("--model: {e}")))?,
            m.clone(),
        )),
        None => None,
    };
    let opts = PlotOptions {
        heat_band_nm: args.band,
        model,
    };
    let (svg, summary) = plot::render(&run, &opts).map_err(|e| CliError::input(e.to_string()))?;
    let out = args.out.clone().unwrap_or_else(|| {
        if args.source.run.is_some() {
            args.source.default_dir().join("plot.svg")
        } else {
            PathBuf::from(format!("{}.svg", run.name))
        }
    });
    std::fs::write(&out, svg).map_err(|e| CliError::io(format!("cannot write {}", out.display()), e))?;
    eprintln!(
        "gonio: {} panels, {} curves: {}",
        summary.panels.len(),
        summary.series.len(),
        summary.panels.join("; ")
    );
    println!("{}", out.display());
    Ok(())
}
