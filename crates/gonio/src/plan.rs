//! `gonio plan`: owned by the scheduler work; see issue 5.

use std::path::PathBuf;

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    /// Campaign file (TOML with [campaign] and [plan]).
    pub campaign: PathBuf,
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Write the ordered points as CSV to this file.
    #[arg(long)]
    pub points: Option<PathBuf>,
}

pub fn run(_args: PlanArgs) -> Result<(), CliError> {
    Err(CliError::input("gonio plan is not built yet"))
}
