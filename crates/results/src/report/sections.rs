//! The report's sections as HTML fragments, each from the run record, its stored configuration texts and its
//! points (module doc of [`super`]): what was measured and how (setup.rs: summary, sample, instrument, plan,
//! calibration, alignment), what came of it (results.rs: uncertainty, fit, truth, reproduction; sweeps.rs: the
//! sweep readings); here the
//! helpers both share.

mod results;
mod setup;
mod sweeps;

pub use results::{fit, reproduce, truth, uncertainty};
pub use setup::{alignment, calibration, instrument, plan, sample, summary};
pub use sweeps::sweeps;

use toml::Value as Toml;

use super::html::{esc, num};
use crate::points::Point;
use crate::run::Run;

/// A stored configuration text as TOML (`None` when absent or no longer TOML).
pub(super) fn parsed(text: Option<&String>) -> Option<Toml> {
    text.and_then(|t| t.parse::<toml::Table>().ok()).map(Toml::Table)
}

pub(super) fn campaign_toml(run: &Run) -> Option<Toml> {
    parsed(run.config().map(|c| &c.campaign_toml))
}

pub(super) fn instrument_toml(run: &Run) -> Option<Toml> {
    parsed(run.config().map(|c| &c.instrument_toml))
}

/// A TOML value as a short text (tables and arrays inline).
pub(super) fn toml_text(v: &Toml) -> String {
    match v {
        Toml::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// A table's scalar keys as facts (`prefix.key`), skipping `skip`.
pub(super) fn table_facts<'a>(t: Option<&'a Toml>, skip: &[&str]) -> Vec<(&'a str, String)> {
    t.and_then(Toml::as_table)
        .map(|t| {
            t.iter()
                .filter(|(k, _)| !skip.contains(&k.as_str()))
                .map(|(k, v)| {
                    let text = match v {
                        // As written when short (12.5), else to five significant digits.
                        Toml::Float(f) if format!("{f}").len() > 8 => num(Some(*f), 5),
                        other => esc(&toml_text(other)),
                    };
                    (k.as_str(), text)
                })
                .collect()
        })
        .unwrap_or_default()
}

pub(super) fn get<'a>(v: Option<&'a Toml>, path: &[&str]) -> Option<&'a Toml> {
    path.iter().try_fold(v?, |v, k| v.get(k))
}

pub(super) fn duration(s: Option<f64>) -> String {
    match s.filter(|s| s.is_finite()) {
        None => "&ndash;".into(),
        Some(s) if s < 120.0 => format!("{s:.0} s"),
        Some(s) if s < 7200.0 => format!("{s:.0} s ({:.1} min)", s / 60.0),
        Some(s) => format!("{s:.0} s ({:.2} h)", s / 3600.0),
    }
}

/// Median of the finite values (the fit's, crate::fit::observations); `None` for none.
pub(super) fn median(v: Vec<f64>) -> Option<f64> {
    Some(crate::fit::observations::median(v)).filter(|m| m.is_finite())
}

/// The valid points' relative standard uncertainties (k = 1).
pub(super) fn relative_u(points: &[&Point]) -> Vec<f64> {
    points
        .iter()
        .filter_map(|p| match (p.value(), p.brdf_u_sr) {
            (Some(f), Some(u)) if f != 0.0 => Some(u / f.abs()),
            _ => None,
        })
        .collect()
}
