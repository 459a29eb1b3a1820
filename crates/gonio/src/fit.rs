//! `gonio fit RUN --model <lambertian|oren-nayar|conductor|plastic|phong> [--wavelength NM]`: least-squares fit
//! of an analytic model to a measured run (gonio_results::fit has the method), printing the parameters with
//! their standard uncertainties and the residual error, and writing a material file (the schema of
//! config/materials/*.toml) that `gonio brdf eval --material` and a campaign's `[material]` accept.
//!
//! A run's sweep readings (`[[plan.sweeps]]`) are fitted with its points unless `--points-only`: each at the
//! middle of the arc it covered, weighted by its own uncertainty.
//!
//! The material goes to `--out FILE`, by default `fit-<model>.toml` (or `fit-<model>-<nm>nm.toml` for one band)
//! in the run directory, or in the current directory when the run comes from a daemon's store.

use std::path::PathBuf;

use gonio_brdf::microfacet::{Distribution, Masking};
use gonio_results::fit::{self, FitModel, FitOptions, Loss};

use crate::CliError;
use crate::export::{RunSource, resolved_config};

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    #[command(flatten)]
    pub source: RunSource,
    /// The model to fit.
    #[arg(long, value_parser = ["lambertian", "oren-nayar", "conductor", "plastic", "phong"])]
    pub model: String,
    /// Fit one band only (nm); default: every band, spectral parameters as tables over the bands.
    #[arg(long)]
    pub wavelength: Option<f64>,
    /// Robust loss against outliers.
    #[arg(long, default_value = "cauchy", value_parser = ["cauchy", "huber", "none"])]
    pub loss: String,
    /// conductor/plastic: the microfacet distribution (named, not fitted).
    #[arg(long, default_value = "ggx", value_parser = ["ggx", "beckmann"])]
    pub distribution: String,
    /// conductor/plastic: the masking-shadowing function (named, not fitted).
    #[arg(long, default_value = "height-correlated", value_parser = ["height-correlated", "separable"])]
    pub masking: String,
    /// The material file to write (default: fit-<model>.toml in the run directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the report as JSON on stdout (parameters, uncertainties, residuals, material, file).
    #[arg(long)]
    pub json: bool,
    /// Leave the run's sweep readings out (by default they are fitted with its points, each at the middle of
    /// the arc it covered, weighted by its own uncertainty).
    #[arg(long)]
    pub points_only: bool,
}

pub fn run(args: FitArgs) -> Result<(), CliError> {
    let model = FitModel::from_name(&args.model)
        .ok_or_else(|| CliError::input(format!("--model: unknown model {:?}", args.model)))?;
    let loss = Loss::from_name(&args.loss)
        .ok_or_else(|| CliError::input(format!("--loss: unknown {:?}", args.loss)))?;
    if let Some(nm) = args.wavelength
        && !(nm.is_finite() && nm > 0.0)
    {
        return Err(CliError::input(format!(
            "--wavelength: {nm} is not a wavelength in nm"
        )));
    }
    let (run, readings) = args.source.load_with_sweeps(args.points_only)?;
    if readings > 0 && !args.json {
        println!(
            "fitting {} points and {readings} sweep readings (--points-only leaves the readings out)",
            run.points.len() - readings
        );
    }
    let mut opts = FitOptions::new(model);
    opts.wavelength_nm = args.wavelength;
    opts.loss = loss;
    opts.distribution = if args.distribution == "beckmann" {
        Distribution::Beckmann
    } else {
        Distribution::Ggx
    };
    opts.masking = if args.masking == "separable" {
        Masking::Separable
    } else {
        Masking::HeightCorrelated
    };
    opts.aperture_half_angle_rad = run
        .config()
        .and_then(|c| gonio_engine::export::aperture_half_angle_rad(&c.instrument_toml));
    let report = fit::fit(&run, &opts).map_err(|e| CliError::input(e.to_string()))?;
    let out = args.out.clone().unwrap_or_else(|| {
        let name = match (args.wavelength, &args.source.run) {
            (Some(nm), Some(_)) => format!("fit-{}-{nm}nm.toml", model.name()),
            (None, Some(_)) => format!("fit-{}.toml", model.name()),
            (Some(nm), None) => format!("fit-{}-{}-{nm}nm.toml", run.name, model.name()),
            (None, None) => format!("fit-{}-{}.toml", run.name, model.name()),
        };
        args.source.default_dir().join(name)
    });
    std::fs::write(&out, report.material_toml())
        .map_err(|e| CliError::io(format!("cannot write {}", out.display()), e))?;
    // In a dry-run the simulated material is known: show it next to the fit.
    let truth = resolved_config(&run, &args.source.default_dir())
        .and_then(|r| r.get("material").cloned())
        .filter(|m| !m.is_null());
    if args.json {
        let mut v = report.to_json();
        v["material_file"] = serde_json::json!(out.display().to_string());
        v["dry_run_material"] = truth.unwrap_or(serde_json::Value::Null);
        println!("{}", serde_json::to_string_pretty(&v).unwrap_or_default());
    } else {
        println!("{}", report.summary());
        if let Some(t) = truth {
            println!("dry-run: the simulated material was {t}");
        }
        println!("material: {}", out.display());
    }
    Ok(())
}
