//! `gonio align [--instrument FILE] --out CAL.toml [--json REPORT.json] [--material M]`: the alignment
//! (`gonio_engine::align`) on the instrument, a short report per fitted value, and a dated calibration file: every
//! value with its standard uncertainty, how it was measured, and the instrument file it belongs to (name and
//! SHA-256) with the software version. On the simulated instrument the operator's steps (empty the holder, mount
//! the mirror) are done by the simulated operator; on hardware each is prompted and waits for Enter.

use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

use gonio_brdf::material::Material;
use gonio_engine::Control;
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::align::{AlignmentReport, Placement, run_alignment};
use gonio_engine::rig::{Held, SampleHolder};
use gonio_scheduler::timing::TimeModel;

use crate::CliError;
use crate::instrument_arg::{InstrumentArg, connect, in_process, read_instrument};

/// Device operations are retried this many times during the alignment.
const RETRIES: u32 = 2;
/// The simulated alignment mirror's radius (mm).
pub const MIRROR_RADIUS_MM: f64 = 25.0;

#[derive(Debug, clap::Args)]
pub struct AlignArgs {
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Write the calibration file here.
    #[arg(long)]
    pub out: PathBuf,
    /// Write the whole report (every scan, every estimate, the covariance) as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Dry-runs: the material the simulated operator mounts as the alignment mirror (a preset name).
    #[arg(long, default_value = "mirror")]
    pub material: String,
}

pub fn run(args: AlignArgs) -> Result<(), CliError> {
    let InstrumentArg { text, file, .. } = read_instrument(args.instrument.as_deref())?;
    let mirror = Material::preset(&args.material)
        .map_err(|e| CliError::input(format!("--material {}: {e}", args.material)))?;
    let runtime = crate::run::instrument_runtime(in_process(&file))?;
    let report = runtime.block_on(async {
        let rig = connect(&file).await?;
        let holder = rig
            .alignment_holder(&mirror, MIRROR_RADIUS_MM)
            .map_err(|e| CliError::input(e.to_string()))?;
        let operator = |p: Placement| operator_step(holder.as_deref(), p);
        let mut motion = gonio_engine::motion::Motion::new(
            &rig,
            TimeModel::new(&file.instrument),
            RETRIES,
            Control::new(),
        );
        run_alignment(&mut motion, &operator)
            .await
            .map_err(|e| CliError::input(format!("alignment stopped: {e}")))
    })?;
    runtime.shutdown_timeout(std::time::Duration::from_millis(200));
    print!("{}", report_text(&report));
    if let Some(path) = &args.json {
        // The whole report, and the estimates under run.json's `simulator_truth` keys (`estimated`).
        let mut value = serde_json::to_value(&report)
            .map_err(|e| CliError::input(format!("cannot encode the report: {e}")))?;
        if let Some(map) = value.as_object_mut() {
            map.insert("estimated".into(), report.estimated());
        }
        let json = serde_json::to_string_pretty(&value)
            .map_err(|e| CliError::input(format!("cannot encode the report: {e}")))?;
        std::fs::write(path, json)
            .map_err(|e| CliError::io(format!("cannot write {}", path.display()), e))?;
    }
    let toml = calibration_toml(&report, &text)?;
    std::fs::write(&args.out, toml)
        .map_err(|e| CliError::io(format!("cannot write {}", args.out.display()), e))?;
    eprintln!("wrote the calibration to {}", args.out.display());
    Ok(())
}

/// The operator's step `p` of the alignment's procedure (also the self-test's): done by the simulated operator
/// on a dry-run's `holder`, else prompted on the terminal.
pub fn operator_step(holder: Option<&dyn SampleHolder>, p: Placement) -> Result<(), String> {
    match holder {
        Some(h) => {
            eprintln!("simulated operator: {}", p.instruction());
            h.hold(match p {
                Placement::Empty => Held::Empty,
                Placement::Mirror => Held::Sample,
            });
            Ok(())
        }
        None => prompt(p),
    }
}

/// Ask the operator to make `placement` and wait for Enter (hardware).
fn prompt(placement: Placement) -> Result<(), String> {
    eprint!("operator: {}; press Enter when done: ", placement.instruction());
    std::io::stderr().flush().ok();
    let mut line = String::new();
    match std::io::stdin().lock().read_line(&mut line) {
        Ok(0) => Err(format!("{} (standard input closed)", placement.instruction())),
        Ok(_) => Ok(()),
        Err(e) => Err(format!("{}: {e}", placement.instruction())),
    }
}

/// The report for a person: one line per value.
pub fn report_text(r: &AlignmentReport) -> String {
    let mut s = format!(
        "alignment of {}{} at {} nm: {} scans, {:.0} s of instrument time, reduced chi2 {:.3}\n",
        r.instrument,
        if r.dry_run { " (simulated)" } else { "" },
        r.band_nm,
        r.scans.len(),
        r.instrument_s,
        r.reduced_chi2
    );
    for e in &r.estimates {
        s.push_str(&format!(
            "  {:<28} {:>11.5} +- {:<9.5} {:<4} {}\n",
            e.name,
            e.value,
            e.u,
            e.unit,
            if e.observable { "" } else { "(not observable)" }
        ));
    }
    for (name, at) in [
        ("detector error at 30 deg", 30.0),
        ("detector error at 90 deg", 90.0),
    ] {
        let (v, u) = r.detector_error_deg(at);
        s.push_str(&format!(
            "  {name:<28} {v:>11.5} +- {u:<9.5} deg (zero and encoder together)\n"
        ));
    }
    for m in &r.unobservable {
        s.push_str(&format!("  not observable: {m}\n"));
    }
    s
}

fn calibration_toml(r: &AlignmentReport, instrument_text: &str) -> Result<String, CliError> {
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(f64::NAN);
    CalibrationFile::from_report(r, instrument_text, now)
        .to_toml()
        .map_err(|e| CliError::input(format!("cannot encode the calibration: {e}")))
}
