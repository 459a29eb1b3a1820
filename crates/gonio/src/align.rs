//! `gonio align [--instrument FILE] --out CAL.toml [--json REPORT.json] [--mirror M] [--material M]
//! [--steps S,...] [--warmup-watch-s S]`: the alignment (`gonio_engine::align`) and the characterisation
//! (`gonio_engine::characterise`) on the instrument, a short report per value, and a dated calibration file: every
//! value with its standard uncertainty, how it was measured, and the instrument file it belongs to (name and
//! SHA-256) with the software version. On the simulated instrument the operator's steps (empty the holder, mount
//! the mirror, then the sample) are done by the simulated operator; on hardware each is prompted and waits for
//! Enter.

use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

use gonio_brdf::material::Material;
use gonio_engine::Control;
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::align::{AlignOptions, AlignmentReport, OperatorStep, Placement, run_alignment};
use gonio_engine::characterise::{CharacterisationReport, CharacteriseOptions};
use gonio_engine::rig::SampleHolder;
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
    pub mirror: String,
    /// Dry-runs: the sample the simulated operator mounts for the steps that use it (a preset name; the
    /// characterisation reads its reflection for the meter's smallest ranges).
    #[arg(long, default_value = "coloured-plastic")]
    pub material: String,
    /// The procedures to run, comma-separated: `alignment` (always: the others need the beam it finds),
    /// `characterisation` (the meter's ranges, the instrument signature, the source's warm-up) and
    /// `sample-alignment` (the sample's own tilt from its specular lobe, used in place of the mirror's; the
    /// sample must have a specular peak).
    #[arg(long, value_delimiter = ',', default_value = "alignment,characterisation")]
    pub steps: Vec<Step>,
    /// How long the characterisation watches the direct beam for the source's warm-up (s of instrument time).
    #[arg(long, default_value_t = 1800.0)]
    pub warmup_watch_s: f64,
}

/// One procedure of `--steps`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Step {
    Alignment,
    Characterisation,
    SampleAlignment,
}

pub fn run(args: AlignArgs) -> Result<(), CliError> {
    if !(args.warmup_watch_s.is_finite() && args.warmup_watch_s >= 0.0) {
        return Err(CliError::input(format!(
            "--warmup-watch-s {}: give a number of seconds, 0 or more",
            args.warmup_watch_s
        )));
    }
    let options = AlignOptions {
        characterise: args
            .steps
            .contains(&Step::Characterisation)
            .then_some(CharacteriseOptions {
                warmup_watch_s: args.warmup_watch_s,
            }),
        on_sample: args.steps.contains(&Step::SampleAlignment),
    };
    let InstrumentArg { text, file, .. } = read_instrument(args.instrument.as_deref())?;
    let mirror = Material::preset(&args.mirror)
        .map_err(|e| CliError::input(format!("--mirror {}: {e}", args.mirror)))?;
    let sample = Material::preset(&args.material)
        .map_err(|e| CliError::input(format!("--material {}: {e}", args.material)))?;
    let runtime = crate::run::instrument_runtime(in_process(&file))?;
    let report = runtime.block_on(async {
        let rig = connect(&file).await?;
        let holder = rig
            .alignment_holder(&mirror, Some(&sample), MIRROR_RADIUS_MM)
            .map_err(|e| CliError::input(e.to_string()))?;
        // The answer is ready when the closure returns: a person's Enter is read right there (this command has
        // nothing else to do meanwhile).
        let operator = |p: Placement| -> OperatorStep<'_> {
            Box::pin(std::future::ready(operator_step(holder.as_deref(), p)))
        };
        let mut motion = gonio_engine::motion::Motion::new(
            &rig,
            TimeModel::new(&file.instrument),
            RETRIES,
            Control::new(),
        );
        run_alignment(&mut motion, &operator, options)
            .await
            .map_err(|e| CliError::input(format!("alignment stopped: {e}")))
    })?;
    runtime.shutdown_timeout(std::time::Duration::from_millis(200));
    print!("{}", report_text(&report));
    if let Some(path) = &args.json {
        // The whole report, and the estimates under run.json's `simulator_truth` keys (`estimated`).
        let json = report
            .to_json_pretty()
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
            h.hold(p.held());
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
        s.push_str(&value_line(&e.name, e.value, e.u, &e.unit, e.observable));
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
    if let Some(c) = &r.characterisation {
        s.push_str(&characterisation_text(c));
    }
    s
}

/// The characterisation's part of the report: one line per range, per band and for the source.
fn characterisation_text(c: &CharacterisationReport) -> String {
    let mut s = format!(
        "characterisation with the holder empty: {:.0} s of instrument time, {} overlaps, {} darks\n",
        c.instrument_s,
        c.overlaps.len(),
        c.darks.len()
    );
    if let Some(rc) = &c.detector.ranges {
        s.push_str(&format!(
            "  meter ranges (gains relative to range {}; reduced chi2 {:.2}):\n",
            rc.reference_range, rc.reduced_chi2
        ));
        for r in &rc.ranges {
            s.push_str(&format!(
                "    range {} ({:.0e} W): gain {:+.5} +- {:.5}, nonlinearity {:+.5} +- {:.5}, offset {:+.3e} +- {:.1e} W{}\n",
                r.index,
                r.full_scale_w,
                r.gain,
                r.gain_u,
                r.nonlinearity,
                r.nonlinearity_u,
                r.offset_w,
                r.offset_w_u,
                if r.observable { "" } else { " (not observable: no overlap reaches it)" }
            ));
        }
    }
    for b in &c.detector.signature {
        let far = b.brdf_sr.last().copied().unwrap_or(f64::NAN);
        let near = b.brdf_sr.first().copied().unwrap_or(f64::NAN);
        s.push_str(&format!(
            "  signature at {} nm: {:.2e} 1/sr at {:.1} deg from the beam, {:.2e} 1/sr at {:.1} deg; NEBRDF {:.2e} \
             1/sr per sample along the normal\n",
            b.band_nm,
            near,
            b.alpha_deg.first().copied().unwrap_or(f64::NAN),
            far,
            b.alpha_deg.last().copied().unwrap_or(f64::NAN),
            b.nebrdf_one_sample_sr
        ));
    }
    if let Some(d) = &c.source {
        s.push_str(&format!(
            "  source at {} nm over {:.0} s ({} readings): {:.4} % below its settled power at the first reading \
             (+- {:.4} %), time constant {:.0} s, drifting {:+.4} % per hour at the end, {:.4} % rms besides\n",
            d.band_nm,
            d.last_s - d.first_s,
            d.readings,
            100.0 * d.warmup_deficit,
            100.0 * d.warmup_deficit_u,
            d.warmup_time_s,
            100.0 * d.drift_per_hour_at_end,
            100.0 * d.residual_rms
        ));
    }
    for n in &c.not_done {
        s.push_str(&format!("  not done: {n}\n"));
    }
    s
}

/// One fitted value for a person (`gonio align`'s report, `gonio ctl align`'s summary).
pub fn value_line(name: &str, value: f64, u: f64, unit: &str, observable: bool) -> String {
    format!(
        "  {name:<28} {value:>11.5} +- {u:<9.5} {unit:<4} {}\n",
        if observable { "" } else { "(not observable)" }
    )
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
