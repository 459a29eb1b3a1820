//! `gonio devices`: owned by the driver work; see issue 4.

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct DevicesArgs {}

pub fn run(_args: DevicesArgs) -> Result<(), CliError> {
    Err(CliError::input("gonio devices is not built yet"))
}
