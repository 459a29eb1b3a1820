//! The `--instrument FILE` option the commands that drive an instrument share: the file read and parsed (the
//! embedded simulated instrument without it), and the instrument connected as its devices need.

use std::path::Path;

use gonio_engine::Rig;
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};

use crate::CliError;

/// An instrument file as given: its text (stored and hashed verbatim), where it came from, and its parse.
pub struct InstrumentArg {
    pub text: String,
    pub origin: String,
    pub file: InstrumentFile,
}

/// Read and parse `path`, or take the embedded simulated instrument.
pub fn read_instrument(path: Option<&Path>) -> Result<InstrumentArg, CliError> {
    let (text, origin) = match path {
        Some(p) => (
            std::fs::read_to_string(p)
                .map_err(|e| CliError::io(format!("cannot read instrument file {}", p.display()), e))?,
            p.display().to_string(),
        ),
        None => (
            SIMULATED_INSTRUMENT_TOML.to_string(),
            "<embedded simulated instrument>".to_string(),
        ),
    };
    let file = InstrumentFile::parse(&text, &origin).map_err(|e| CliError::input(e.to_string()))?;
    Ok(InstrumentArg { text, origin, file })
}

/// True when every device is simulated in process: such an instrument runs on a paused clock (its own time, no
/// wall time: `crate::run::instrument_runtime`). Simulated devices on pseudo-terminals need the real clock.
pub fn in_process(file: &InstrumentFile) -> bool {
    let devices = &file.instrument.devices;
    devices.iter().all(|d| d.is_simulated()) && !devices.iter().any(|d| d.is_sim_pty())
}

/// Connect to the instrument: an in-process simulated one at its own time scale, anything else as it comes.
pub async fn connect(file: &InstrumentFile) -> Result<Rig, CliError> {
    if in_process(file) {
        Rig::connect_with_time_scale(file, None, 1.0).await
    } else {
        Rig::connect(file, None).await
    }
    .map_err(|e| CliError::input(e.to_string()))
}
