//! `gonio sim`: owned by the simulator work; see issue 3.

use std::path::PathBuf;

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Simulated seconds per real second (1.0 = real time).
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
}

pub fn run(_args: SimArgs) -> Result<(), CliError> {
    Err(CliError::input("gonio sim is not built yet"))
}
