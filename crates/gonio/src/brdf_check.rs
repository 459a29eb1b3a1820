//! `gonio brdf check`: owned by the brdf-radiometry work; see issue 2.

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

pub fn run(_args: CheckArgs) -> Result<(), CliError> {
    Err(CliError::input("gonio brdf check is not built yet"))
}
