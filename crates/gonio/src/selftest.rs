//! `gonio selftest [--instrument FILE] [--json REPORT.json] [--write FILE]`: the instrument file held against
//! the hardware (`gonio_engine::selftest`). Prints each figure measured against configured with a verdict,
//! exits 1 naming each key the hardware contradicts, and with `--write` writes the instrument file with the
//! measured values (and a comment of when they were measured). The settle times and backlash need the holder
//! emptied and then the alignment mirror mounted: prompted on hardware, done by the simulated operator on a
//! dry-run (as `gonio align` does).

use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

use gonio_engine::Control;
use gonio_engine::selftest::{DEFAULT_TOLERANCE, SelftestReport, Verdict, run_selftest};
use gonio_results::provenance_summary::iso8601_utc;
use gonio_scheduler::timing::TimeModel;

use gonio_brdf::material::Material;
use gonio_engine::align::Placement;

use crate::CliError;
use crate::align::{MIRROR_RADIUS_MM, operator_step};
use crate::instrument_arg::{InstrumentArg, connect, in_process, read_instrument};

/// Device operations are retried this many times during the self-test.
const RETRIES: u32 = 2;

#[derive(Debug, clap::Args)]
pub struct SelftestArgs {
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the instrument file with the measured values here.
    #[arg(long)]
    pub write: Option<PathBuf>,
    /// Relative tolerance of a measured figure against the file's (0.1 = 10 %).
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    pub tolerance: f64,
}

pub fn run(args: SelftestArgs) -> Result<(), CliError> {
    if !(args.tolerance.is_finite() && args.tolerance > 0.0) {
        return Err(CliError::input(format!(
            "--tolerance {}: must be > 0",
            args.tolerance
        )));
    }
    let InstrumentArg { text, file, .. } = read_instrument(args.instrument.as_deref())?;
    let runtime = crate::run::instrument_runtime(in_process(&file))?;
    let report = runtime.block_on(async {
        let rig = connect(&file).await?;
        let mirror = Material::preset("mirror").map_err(|e| CliError::input(e.to_string()))?;
        let holder = rig
            .alignment_holder(&mirror, None, MIRROR_RADIUS_MM)
            .map_err(|e| CliError::input(e.to_string()))?;
        let operator = |p: Placement| operator_step(holder.as_deref(), p);
        let mut motion = gonio_engine::motion::Motion::new(
            &rig,
            TimeModel::new(&file.instrument),
            RETRIES,
            Control::new(),
        );
        run_selftest(&mut motion, args.tolerance, &operator)
            .await
            .map_err(|e| CliError::input(format!("self-test stopped: {e}")))
    })?;
    runtime.shutdown_timeout(std::time::Duration::from_millis(200));
    print!("{}", report_text(&report));
    if let Some(path) = &args.json {
        let json = serde_json::to_string_pretty(&report)
            .map_err(|e| CliError::input(format!("cannot encode the report: {e}")))?;
        std::fs::write(path, json)
            .map_err(|e| CliError::io(format!("cannot write {}", path.display()), e))?;
    }
    if let Some(path) = &args.write {
        let written = measured_file(&text, &report).map_err(CliError::input)?;
        std::fs::write(path, written)
            .map_err(|e| CliError::io(format!("cannot write {}", path.display()), e))?;
        eprintln!("wrote the measured instrument file to {}", path.display());
    }
    let failed = report.failed_keys();
    if failed.is_empty() {
        Ok(())
    } else {
        Err(CliError::CheckFailed(format!(
            "the hardware contradicts the instrument file beyond {:.0} %: {}",
            100.0 * report.tolerance,
            failed.join(", ")
        )))
    }
}

/// The report for a person: one line per figure.
pub fn report_text(r: &SelftestReport) -> String {
    let mut s = format!(
        "self-test of {}{} ({:.1} s of instrument time)\n",
        r.instrument,
        if r.dry_run { " (simulated)" } else { "" },
        r.instrument_s
    );
    for (name, id) in &r.devices {
        s.push_str(&format!("  device {name:<8} {id}\n"));
    }
    s.push_str(&format!(
        "  {:<44} {:>14} {:>14}  verdict\n",
        "key", "configured", "measured"
    ));
    for c in &r.checks {
        // A key the file does not hold: what the engine assumes without it, marked so.
        let configured = match (c.configured, c.assumed) {
            (Some(v), true) => format!("({})", format_value(v)),
            (Some(v), false) => format_value(v),
            (None, _) => "-".into(),
        };
        let verdict = match c.verdict {
            Verdict::Pass => "ok",
            Verdict::Fail => "FAIL",
            Verdict::Info => "",
        };
        s.push_str(&format!(
            "  {:<44} {configured:>14} {:>14} {} {verdict}\n",
            c.key,
            format_value(c.measured),
            c.unit
        ));
    }
    if r.checks.iter().any(|c| c.assumed) {
        s.push_str("  (in brackets: a key the file does not hold, and what gonio assumes without it)\n");
    }
    for m in &r.not_measured {
        s.push_str(&format!("  not measured: {m}\n"));
    }
    s
}

fn format_value(v: f64) -> String {
    if v != 0.0 && (v.abs() < 1e-3 || v.abs() >= 1e5) {
        format!("{v:.4e}")
    } else {
        format!("{v:.4}")
    }
}

/// The instrument file `text` with every pass/fail key set to its measured value, and a header saying when.
fn measured_file(text: &str, r: &SelftestReport) -> Result<String, String> {
    let mut doc: toml::Table = toml::from_str(text).map_err(|e| format!("the instrument file: {e}"))?;
    let mut written = Vec::new();
    for c in r.checks.iter().filter(|c| c.configured.is_some()) {
        // A backlash or a settle time measured a hair below zero is none within the measurement's noise; the
        // file takes no negative value. (A sampling instant may be below zero: it is written as measured.)
        let value = if c.key.ends_with(".backlash_deg") || c.key.ends_with(".settle_s") {
            c.measured.max(0.0)
        } else {
            c.measured
        };
        if set_key(&mut doc, &c.key, value) {
            written.push(c.key.clone());
        }
    }
    let body = toml::to_string_pretty(&doc).map_err(|e| format!("cannot write TOML: {e}"))?;
    let when = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(f64::NAN);
    Ok(format!(
        "# Written by gonio selftest {} at {}: measured values for {}.\n\
         # (The original file's comments are not kept: compare with it before replacing it.)\n\n{body}",
        env!("CARGO_PKG_VERSION"),
        iso8601_utc(when),
        if written.is_empty() {
            "no key".to_string()
        } else {
            written.join(", ")
        }
    ))
}

/// Set `axes.<name>.<key>` (in `[[instrument.axes]]`), `devices.<name>.<key>` (in `[[instrument.devices]]`) or
/// `<table>.<key>` under `[instrument]`.
fn set_key(doc: &mut toml::Table, key: &str, value: f64) -> bool {
    let Some(instrument) = doc.get_mut("instrument").and_then(toml::Value::as_table_mut) else {
        return false;
    };
    let parts: Vec<&str> = key.split('.').collect();
    match parts.as_slice() {
        ["axes", name, field] => instrument
            .get_mut("axes")
            .and_then(toml::Value::as_array_mut)
            .and_then(|axes| {
                axes.iter_mut()
                    .filter_map(toml::Value::as_table_mut)
                    .find(|a| a.get("name").and_then(toml::Value::as_str) == Some(name))
            })
            .map(|a| a.insert((*field).to_string(), toml::Value::Float(value)))
            .is_some(),
        ["devices", name, field] => instrument
            .get_mut("devices")
            .and_then(toml::Value::as_array_mut)
            .and_then(|devices| {
                devices
                    .iter_mut()
                    .filter_map(toml::Value::as_table_mut)
                    .find(|d| d.get("name").and_then(toml::Value::as_str) == Some(name))
            })
            .map(|d| d.insert((*field).to_string(), toml::Value::Float(value)))
            .is_some(),
        [table, field] => instrument
            .get_mut(*table)
            .and_then(toml::Value::as_table_mut)
            .map(|t| t.insert((*field).to_string(), toml::Value::Float(value)))
            .is_some(),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};

    #[test]
    fn measured_keys_are_written_where_the_file_has_them() {
        let mut doc: toml::Table = toml::from_str(SIMULATED_INSTRUMENT_TOML).expect("toml");
        assert!(set_key(&mut doc, "axes.detector.max_speed_deg_s", 9.5));
        assert!(set_key(&mut doc, "filter_wheel.seconds_per_position", 1.25));
        assert!(!set_key(&mut doc, "axes.elbow.max_speed_deg_s", 1.0));
        assert!(set_key(&mut doc, "devices.arms.reply_latency_ms", 10.0));
        assert!(!set_key(&mut doc, "devices.elbow.reply_latency_ms", 1.0));
        let text = toml::to_string(&doc).expect("toml");
        let file = InstrumentFile::parse(&text, "written").expect("still a valid instrument file");
        let det = file
            .instrument
            .axes
            .iter()
            .find(|a| a.name == "detector")
            .expect("detector");
        assert_eq!(det.max_speed_deg_s, 9.5);
        assert_eq!(
            file.instrument
                .filter_wheel
                .as_ref()
                .map(|w| w.seconds_per_position),
            Some(1.25)
        );
        assert_eq!(
            file.instrument.device("arms").and_then(|d| d.reply_latency_ms),
            Some(10.0)
        );
    }
}
