//! What the self-test reports: each figure measured against what the instrument file claims, with a verdict.

use serde::Serialize;

/// How a measured figure stands against the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// Within the tolerance of the file's value.
    Pass,
    /// The hardware contradicts the file beyond the tolerance: the key should change.
    Fail,
    /// Measured for the record; the file claims nothing to hold it against.
    Info,
}

/// One line of the self-test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check {
    /// The instrument file's key (`axes.detector.max_speed_deg_s`, `filter_wheel.seconds_per_position`), or
    /// the figure's name for a figure the file does not hold (`latency.arms_ms`).
    pub key: String,
    /// What was measured, for a person.
    pub what: String,
    pub unit: String,
    /// The file's value (None for an `Info` line).
    pub configured: Option<f64>,
    /// The file does not hold the key: `configured` is what the engine assumes without it.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub assumed: bool,
    pub measured: f64,
    pub verdict: Verdict,
}

/// The whole self-test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SelftestReport {
    pub instrument: String,
    pub dry_run: bool,
    /// Relative tolerance of the pass/fail lines.
    pub tolerance: f64,
    /// Each device's identity.
    pub devices: Vec<(String, String)>,
    pub checks: Vec<Check>,
    /// What could not be measured on this instrument, and why.
    pub not_measured: Vec<String>,
    /// Instrument time the test took (s).
    pub instrument_s: f64,
}

impl SelftestReport {
    /// The keys the hardware contradicts.
    pub fn failed_keys(&self) -> Vec<&str> {
        self.checks
            .iter()
            .filter(|c| c.verdict == Verdict::Fail)
            .map(|c| c.key.as_str())
            .collect()
    }
}

/// A measured figure against a claimed one: pass within `tolerance` (relative), fail beyond.
pub fn against(key: String, what: &str, unit: &str, configured: f64, measured: f64, tolerance: f64) -> Check {
    within(
        key,
        what,
        unit,
        configured,
        measured,
        tolerance * configured.abs(),
    )
}

/// A measured figure against a claimed one: pass within `allowed` (absolute, in the figure's unit), fail beyond.
/// For a figure whose claim may be 0 (a backlash), where a relative tolerance would allow nothing.
pub fn within(key: String, what: &str, unit: &str, configured: f64, measured: f64, allowed: f64) -> Check {
    line(
        key,
        what,
        unit,
        configured,
        measured,
        (measured - configured).abs() <= allowed,
    )
}

/// A measured figure against a claimed upper bound: pass when it is at most the claim plus `tolerance`
/// (relative), fail when the hardware needs more. For a wait the engine makes (a settle time): hardware that
/// needs less than the file waits for is not wrong, only slower than it could be.
pub fn at_most(key: String, what: &str, unit: &str, configured: f64, measured: f64, tolerance: f64) -> Check {
    line(
        key,
        what,
        unit,
        configured,
        measured,
        measured <= configured * (1.0 + tolerance),
    )
}

/// A measured figure against a claimed one with the caller's verdict.
pub(super) fn line(key: String, what: &str, unit: &str, configured: f64, measured: f64, pass: bool) -> Check {
    Check {
        key,
        what: what.to_string(),
        unit: unit.to_string(),
        configured: Some(configured),
        assumed: false,
        measured,
        verdict: if pass { Verdict::Pass } else { Verdict::Fail },
    }
}

/// A figure for the record.
pub fn info(key: String, what: &str, unit: &str, measured: f64) -> Check {
    Check {
        key,
        what: what.to_string(),
        unit: unit.to_string(),
        configured: None,
        assumed: false,
        measured,
        verdict: Verdict::Info,
    }
}
