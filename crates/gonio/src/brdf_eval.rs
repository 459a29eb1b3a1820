//! `gonio brdf eval`: owned by the brdf-models work; see issue 2.

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// A material TOML file with a [material] table, or a preset name (e.g. gold, spectralon).
    #[arg(long)]
    pub material: String,
    /// Wavelength in nm (default 550).
    #[arg(long)]
    pub wavelength: Option<f64>,
}

pub fn run(_args: EvalArgs) -> Result<(), CliError> {
    Err(CliError::input("gonio brdf eval is not built yet"))
}
