//! `gonio-soak`: runs the fault soak, the crash soak, the disk soak, the HTTP abuse soak, the safety soak and the
//! input census, and writes `RELIABILITY.md` at the repository root (`cargo run --release -p gonio-soak`). Exits 1
//! when an invariant broke (the report says which), 2 when a soak could not run. `--quick` shrinks every part (a
//! smoke run of a minute or two; its report says `--quick` in its command line). The fault, crash, disk and safety
//! soaks run twice: on the ideal `config/instruments/simulated.toml`, then on the imperfect
//! `config/instruments/realistic.toml` (`--instrument <path>` for another file, `--ideal-only` for none).
//!
//! `gonio-soak worker ...` is the daemon process the crash soak starts and kills (see `gonio_soak::worker`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};
use gonio_soak::crash_soak::{CrashSoakConfig, run_crash_soak};
use gonio_soak::disk_soak::{DiskSoakConfig, run_disk_soak};
use gonio_soak::fault_soak::{FaultSoakConfig, run_fault_soak};
use gonio_soak::http_abuse::{HttpAbuseConfig, run_http_abuse};
use gonio_soak::inputs::run_inputs;
use gonio_soak::report::{InstrumentPass, Report};
use gonio_soak::safety_soak::{SafetySoakConfig, run_safety_soak};
use gonio_soak::setup::SoakInstrument;
use gonio_soak::worker::{DieAt, EXIT_ERROR, WorkerArgs, run_worker};

const DEFAULT_SEED: u64 = 8;
const DEFAULT_POINTS: u64 = 2000;
const DEFAULT_CRASH_POINTS: u64 = 600;
const DEFAULT_KILLS: u32 = 20;
const DEFAULT_PARSER_INPUTS: u64 = 20_000;
const DEFAULT_LOADER_INPUTS: u64 = 1_000;
const DEFAULT_DISK_POINTS: u64 = 600;
const DEFAULT_FILLS: u32 = 5;
const DEFAULT_HTTP_POINTS: u64 = 300;
const DEFAULT_SAFETY_CASES: u32 = 40;
/// Instrument time the disk soak leaves a campaign paused on a full store (s).
const DISK_HOLD_S: f64 = 120.0;

#[derive(Debug, Parser)]
#[command(
    name = "gonio-soak",
    about = "Reliability soaks of gonio; writes RELIABILITY.md"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    soak: SoakArgs,
}

#[derive(Debug, Args)]
struct SoakArgs {
    /// Seed of every random draw (geometries, faults, kill moments, inputs).
    #[arg(long, default_value_t = DEFAULT_SEED)]
    seed: u64,
    /// Points of the fault soak's campaign.
    #[arg(long, default_value_t = DEFAULT_POINTS)]
    points: u64,
    /// Points of the crash soak's campaign.
    #[arg(long, default_value_t = DEFAULT_CRASH_POINTS)]
    crash_points: u64,
    /// Kills in the crash soak.
    #[arg(long, default_value_t = DEFAULT_KILLS)]
    kills: u32,
    /// Inputs per wire parser.
    #[arg(long, default_value_t = DEFAULT_PARSER_INPUTS)]
    parser_inputs: u64,
    /// Inputs per file loader.
    #[arg(long, default_value_t = DEFAULT_LOADER_INPUTS)]
    loader_inputs: u64,
    /// Points of the disk soak's campaign.
    #[arg(long, default_value_t = DEFAULT_DISK_POINTS)]
    disk_points: u64,
    /// Times the disk soak makes the store full.
    #[arg(long, default_value_t = DEFAULT_FILLS)]
    fills: u32,
    /// Points of the campaign the daemon runs under HTTP abuse.
    #[arg(long, default_value_t = DEFAULT_HTTP_POINTS)]
    http_points: u64,
    /// Random campaigns of the safety soak.
    #[arg(long, default_value_t = DEFAULT_SAFETY_CASES)]
    safety_cases: u32,
    /// Every part small (a smoke run of seconds; the fault soak at the CI test's higher fault rates): overrides
    /// the sizes above.
    #[arg(long)]
    quick: bool,
    /// The imperfect instrument the fault, crash, disk and safety soaks run on after the ideal
    /// config/instruments/simulated.toml (default: config/instruments/realistic.toml, embedded).
    #[arg(long, value_name = "PATH")]
    instrument: Option<PathBuf>,
    /// Run those soaks on the ideal instrument only.
    #[arg(long, conflicts_with = "instrument")]
    ideal_only: bool,
    /// Where to write the report (default: RELIABILITY.md at the repository root).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Keep the stores and logs in this (empty) directory instead of a temporary one.
    #[arg(long)]
    work: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The daemon process of the crash soak (started by the soak itself).
    #[command(hide = true)]
    Worker(WorkerCli),
}

#[derive(Debug, Args)]
struct WorkerCli {
    #[arg(long)]
    data: PathBuf,
    #[arg(long)]
    campaign: PathBuf,
    #[arg(long)]
    instrument: PathBuf,
    /// mid-move, mid-commit or mid-sweep:N (at the Nth reply read after a sweep started)
    #[arg(long)]
    die: Option<String>,
    #[arg(long, default_value_t = 0)]
    after: u64,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Worker(w)) => {
            let die = match w.die.as_deref().map(DieAt::parse) {
                None => None,
                Some(Some(at)) => Some((at, w.after)),
                Some(None) => {
                    eprintln!("gonio-soak worker: --die takes mid-move, mid-commit or mid-sweep:N");
                    return ExitCode::from(EXIT_ERROR as u8);
                }
            };
            let code = run_worker(&WorkerArgs {
                data: w.data,
                campaign: w.campaign,
                instrument: w.instrument,
                die,
            });
            ExitCode::from(u8::try_from(code).unwrap_or(1))
        }
        None => match soak(&cli.soak) {
            Ok(true) => ExitCode::SUCCESS,
            Ok(false) => ExitCode::from(1),
            Err(e) => {
                eprintln!("gonio-soak: {e}");
                ExitCode::from(2)
            }
        },
    }
}

/// The command as typed to get these settings.
fn command_line(a: &SoakArgs) -> String {
    let mut instrument = match &a.instrument {
        Some(path) => format!(" --instrument {}", path.display()),
        None => String::new(),
    };
    if a.ideal_only {
        instrument.push_str(" --ideal-only");
    }
    if a.quick {
        // `--quick` sets every size itself.
        let seed = if a.seed == DEFAULT_SEED {
            String::new()
        } else {
            format!(" --seed {}", a.seed)
        };
        return format!("cargo run --release -p gonio-soak -- --quick{seed}{instrument}");
    }
    let mut extra = Vec::new();
    for (flag, value, default) in [
        ("--seed", a.seed, DEFAULT_SEED),
        ("--points", a.points, DEFAULT_POINTS),
        ("--crash-points", a.crash_points, DEFAULT_CRASH_POINTS),
        ("--kills", u64::from(a.kills), u64::from(DEFAULT_KILLS)),
        ("--parser-inputs", a.parser_inputs, DEFAULT_PARSER_INPUTS),
        ("--loader-inputs", a.loader_inputs, DEFAULT_LOADER_INPUTS),
        ("--disk-points", a.disk_points, DEFAULT_DISK_POINTS),
        ("--fills", u64::from(a.fills), u64::from(DEFAULT_FILLS)),
        ("--http-points", a.http_points, DEFAULT_HTTP_POINTS),
        (
            "--safety-cases",
            u64::from(a.safety_cases),
            u64::from(DEFAULT_SAFETY_CASES),
        ),
    ] {
        if value != default {
            extra.push(format!("{flag} {value}"));
        }
    }

    if extra.is_empty() && instrument.is_empty() {
        "cargo run --release -p gonio-soak".into()
    } else {
        format!(
            "cargo run --release -p gonio-soak -- {}{instrument}",
            extra.join(" ")
        )
        .replace("--  --", "-- --")
    }
}

/// The sizes `--quick` runs with.
fn quick(a: &SoakArgs) -> SoakArgs {
    SoakArgs {
        seed: a.seed,
        points: 240,
        crash_points: 60,
        kills: 4,
        parser_inputs: 2_000,
        loader_inputs: 100,
        disk_points: 60,
        fills: 2,
        http_points: 40,
        safety_cases: 4,
        quick: true,
        instrument: a.instrument.clone(),
        ideal_only: a.ideal_only,
        out: a.out.clone(),
        work: a.work.clone(),
    }
}

fn soak(a: &SoakArgs) -> Result<bool, Box<dyn std::error::Error>> {
    let quick_args;
    let a = if a.quick {
        quick_args = quick(a);
        &quick_args
    } else {
        a
    };
    let wall = Instant::now();
    let temp = tempfile::tempdir()?;
    let work = a.work.clone().unwrap_or_else(|| temp.path().to_path_buf());
    std::fs::create_dir_all(&work)?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../RELIABILITY.md")));

    let ideal = soaks_on(a, &work.join("ideal"), &SoakInstrument::simulated())?;
    let imperfect = match &a.instrument {
        _ if a.ideal_only => None,
        Some(path) => Some(soaks_on(
            a,
            &work.join("imperfect"),
            &SoakInstrument::load(path)?,
        )?),
        None => Some(soaks_on(
            a,
            &work.join("imperfect"),
            &SoakInstrument::realistic(),
        )?),
    };

    eprintln!(
        "gonio-soak: HTTP abuse, a {}-point campaign on the daemon ...",
        a.http_points
    );
    let http_dir = work.join("http-abuse");
    let http_cfg = if a.quick {
        HttpAbuseConfig::quick(a.http_points, a.seed, http_dir)
    } else {
        HttpAbuseConfig::full(a.http_points, a.seed, http_dir)
    };
    let http = run_http_abuse(&http_cfg)?;
    eprintln!(
        "gonio-soak: HTTP abuse: {} status requests, slowest {:.0} ms ({} violations)",
        http.probes(),
        http.latency_quantile_s(1.0) * 1e3,
        http.violations().len()
    );

    eprintln!("gonio-soak: inputs ...");
    let inputs = run_inputs(a.seed, a.parser_inputs, a.loader_inputs);

    let report = Report {
        command: command_line(a),
        seed: a.seed,
        fault: ideal.fault,
        crash: ideal.crash,
        disk: ideal.disk,
        http,
        safety: ideal.safety,
        imperfect,
        inputs,
        wall_s: wall.elapsed().as_secs_f64(),
    };
    std::fs::write(&out, report.to_markdown())?;
    let violations = report.violations();
    for v in &violations {
        eprintln!("gonio-soak: VIOLATION: {v}");
    }
    eprintln!(
        "gonio-soak: wrote {} (data lost: {})",
        out.display(),
        report.data_lost()
    );
    if a.work.is_some() {
        eprintln!("gonio-soak: stores and logs kept in {}", work.display());
    }
    Ok(violations.is_empty())
}

/// The soaks that run on each instrument: fault, crash, disk, safety.
fn soaks_on(
    a: &SoakArgs,
    work: &Path,
    instrument: &SoakInstrument,
) -> Result<InstrumentPass, Box<dyn std::error::Error>> {
    let on = &instrument.name;
    std::fs::create_dir_all(work)?;
    eprintln!("gonio-soak: [{on}] fault soak, {} points ...", a.points);
    // A short run sees every kind of fault only at the higher rates of the CI test.
    let mut fault_cfg = if a.quick {
        FaultSoakConfig::stressed(a.points, a.seed, work.join("fault-soak"))
    } else {
        FaultSoakConfig::issue_8(a.points, a.seed, work.join("fault-soak"))
    };
    fault_cfg.log_file = Some(work.join("fault-soak.log"));
    fault_cfg.instrument = instrument.clone();
    let fault = run_fault_soak(&fault_cfg)?;
    eprintln!(
        "gonio-soak: [{on}] fault soak: {} ({} violations)",
        fault.final_state,
        fault.violations().len()
    );

    eprintln!(
        "gonio-soak: [{on}] crash soak, {} kills of a {}-point campaign ...",
        a.kills, a.crash_points
    );
    let exe = std::env::current_exe()?;
    let crash_cfg = CrashSoakConfig {
        points: a.crash_points,
        kills: a.kills,
        seed: a.seed,
        work_dir: work.join("crash-soak"),
        worker: vec![exe.display().to_string(), "worker".into()],
        round_timeout: Duration::from_secs(600),
        instrument: instrument.clone(),
        sweeps: true,
    };
    std::fs::create_dir_all(&crash_cfg.work_dir)?;
    let crash = run_crash_soak(&crash_cfg)?;
    eprintln!(
        "gonio-soak: [{on}] crash soak: {} kills ({} violations)",
        crash.kills(),
        crash.violations().len()
    );

    eprintln!(
        "gonio-soak: [{on}] disk soak, {} fills of a {}-point campaign ...",
        a.fills, a.disk_points
    );
    let disk = run_disk_soak(&DiskSoakConfig {
        points: a.disk_points,
        fills: a.fills,
        seed: a.seed,
        data_dir: work.join("disk-soak"),
        hold_s: DISK_HOLD_S,
        instrument: instrument.clone(),
    })?;
    eprintln!(
        "gonio-soak: [{on}] disk soak: {} ({} violations)",
        disk.final_state,
        disk.violations().len()
    );

    eprintln!(
        "gonio-soak: [{on}] safety, {} random campaigns ...",
        a.safety_cases
    );
    let safety = run_safety_soak(&SafetySoakConfig {
        cases: a.safety_cases,
        seed: a.seed,
        instrument: instrument.clone(),
    })?;
    eprintln!(
        "gonio-soak: [{on}] safety: {} move commands ({} violations)",
        safety.move_commands(),
        safety.violations().len()
    );
    Ok(InstrumentPass {
        instrument: instrument.name.clone(),
        fault,
        crash,
        disk,
        safety,
    })
}
