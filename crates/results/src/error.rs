//! The errors of this crate. Each message names the file (or the source of the data) and what is wrong with it.

use std::path::PathBuf;

use gonio_brdf::merl::MerlError;

#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    /// A file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    /// A file could not be written.
    #[error("cannot write {}: {source}", path.display())]
    Write { path: PathBuf, source: std::io::Error },
    /// A line of a points CSV is malformed (`line` is 1-based; 0 for a problem with the whole file).
    #[error("{origin}{}: {message}", if *line > 0 { format!(", line {line}") } else { String::new() })]
    Csv {
        origin: String,
        line: usize,
        message: String,
    },
    /// A run.json (or another JSON document) is malformed.
    #[error("{origin}: {message}")]
    Json { origin: String, message: String },
    /// The run holds nothing this operation can use (no valid points, no such band, ...).
    #[error("{origin}: {message}")]
    NoData { origin: String, message: String },
    /// A request that does not fit the data or the model (a bad option value).
    #[error("{0}")]
    Invalid(String),
    /// Writing the MERL file failed.
    #[error(transparent)]
    Merl(#[from] MerlError),
    /// The fit could not be carried out.
    #[error("fit of {model} to {origin}: {message}")]
    Fit {
        model: String,
        origin: String,
        message: String,
    },
    /// Drawing a plot failed.
    #[error("cannot draw the plot: {message}")]
    Plot { message: String },
}
