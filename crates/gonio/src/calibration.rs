//! Reading a `gonio align` calibration file for `gonio run --calibration` and `gonio daemon --calibration`.

use gonio_engine::align::file::CalibrationFile;

use crate::CliError;

/// The text of the calibration file at `path`, checked to be one made for the instrument file `instrument_text`
/// (`gonio run --calibration`, `gonio daemon --calibration`); says on stderr which one is applied.
pub fn read_calibration(path: &std::path::Path, instrument_text: &str) -> Result<String, CliError> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::io(format!("cannot read calibration file {origin}"), e))?;
    let cal = CalibrationFile::parse(&text, &origin).map_err(|e| CliError::input(e.to_string()))?;
    cal.check_instrument(instrument_text, &origin)
        .map_err(|e| CliError::input(e.to_string()))?;
    eprintln!(
        "gonio: applying calibration {origin} (instrument {}, made {})",
        cal.calibration.instrument, cal.calibration.created_utc
    );
    Ok(text)
}
