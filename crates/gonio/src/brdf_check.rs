//! `gonio brdf check`: checks a material against the physical laws and prints the report
//! ([`gonio_brdf::checks`]). Exit 0 when every law holds, 1 (`CliError::CheckFailed`) when one is broken,
//! 2 for bad input (unknown preset, unreadable file, wavelength outside the material's tables).

use gonio_brdf::Wavelength;
use gonio_brdf::checks::{CheckOptions, check_brdf};
use gonio_brdf::material::Material;

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// A material TOML file with a [material] table, or a preset name.
    #[arg(long)]
    pub material: String,
    /// Wavelength in nm (default 550).
    #[arg(long)]
    pub wavelength: Option<f64>,
}

pub fn run(args: CheckArgs) -> Result<(), CliError> {
    let wavelength = match args.wavelength {
        None => Wavelength::DEFAULT,
        Some(nm) => Wavelength::from_nm(nm).map_err(|e| CliError::input(format!("--wavelength: {e}")))?,
    };
    let material =
        Material::from_file_or_preset(&args.material).map_err(|e| CliError::input(e.to_string()))?;
    // Resolve the spectral parameters once: the checks evaluate the model many thousands of times.
    let material = material
        .resolved(wavelength)
        .map_err(|e| CliError::input(format!("{}: {e}", args.material)))?;
    let options = CheckOptions {
        wavelength,
        ..CheckOptions::default()
    };
    let report =
        check_brdf(&material, &options).map_err(|e| CliError::input(format!("{}: {e}", args.material)))?;
    println!("material: {} ({})", args.material, material.model().name());
    println!("{report}");
    if report.passed() {
        Ok(())
    } else {
        Err(CliError::CheckFailed(format!(
            "{}: {} physical law(s) broken (see the report above)",
            args.material,
            report.failures().len()
        )))
    }
}
