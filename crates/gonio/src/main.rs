//! The `gonio` command line: wires the library crates together and turns their typed errors into messages
//! that say what went wrong and where.
//!
//! One module per subcommand family; each exposes `run(args) -> Result<(), CliError>`.

mod align;
mod brdf_check;
mod brdf_eval;
mod calibration;
#[cfg(test)]
mod cli_reference;
mod ctl;
mod daemon;
mod devices;
mod error;
mod export;
mod fit;
mod instrument_arg;
mod plan;
mod plot;
mod report;
mod run;
mod selftest;
mod sim;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub use error::CliError;

#[derive(Debug, Parser)]
#[command(name = "gonio", version, about = "Acquisition system for gonioreflectometers")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Evaluate and check BRDF models and material files.
    #[command(subcommand)]
    Brdf(BrdfCommand),
    /// List serial ports and USB instruments this machine can see.
    Devices(devices::DevicesArgs),
    /// Build, check and order a campaign's measurement plan, and predict its duration.
    Plan(plan::PlanArgs),
    /// Serve the simulated instrument's devices on pseudo-terminals until interrupted.
    Sim(sim::SimArgs),
    /// Run one campaign in the foreground (resuming it if interrupted), then write points.csv and run.json.
    Run(run::RunArgs),
    /// Hold the instrument file against the hardware: identify and exercise every device, measure speeds,
    /// accelerations, the wheel's time, latencies and the meter's dark and noise; exit 1 naming wrong keys.
    Selftest(selftest::SelftestArgs),
    /// Align the instrument: scans through the direct beam and a mirror's reflection, the geometric errors
    /// fitted with their uncertainties, written as a dated calibration file.
    Align(align::AlignArgs),
    /// Run the acquisition service: campaign queue and HTTP/JSON control API (loopback unless given a token).
    Daemon(daemon::DaemonArgs),
    /// Control a running daemon: campaigns (submit, status, pause, resume, abort, confirm, estop, watch, points)
    /// and the console (state, move, jog, home, filter, read).
    Ctl(ctl::CtlArgs),
    /// Export a run as CSV or JSON (units and full provenance) or as a MERL binary (resampled, for renderers).
    Export(export::ExportArgs),
    /// Fit an analytic model to a run (robust, weighted); print parameters with uncertainties, write a material.
    Fit(fit::FitArgs),
    /// Plot a run as SVG: in-plane polar slices, heat maps per incidence, and measurement against a model.
    Plot(plot::PlotArgs),
    /// Write a run's measurement report: one self-contained HTML page (sample, instrument, plan and coverage,
    /// calibration, alignment, plots, uncertainty, fitted models, reproduction).
    Report(report::ReportArgs),
}

#[derive(Debug, Subcommand)]
enum BrdfCommand {
    /// Read `theta_i phi_i theta_o phi_o` lines (degrees) on stdin, write f in 1/sr per line on stdout.
    Eval(brdf_eval::EvalArgs),
    /// Check a material against the physical laws (reciprocity, energy, positivity, finiteness).
    Check(brdf_check::CheckArgs),
}

fn main() -> ExitCode {
    init_tracing();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Brdf(BrdfCommand::Eval(args)) => brdf_eval::run(args),
        Command::Brdf(BrdfCommand::Check(args)) => brdf_check::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Run(args) => run::run(args),
        Command::Selftest(args) => selftest::run(args),
        Command::Align(args) => align::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Daemon(args) => daemon::run(args),
        Command::Ctl(args) => ctl::run(args),
        Command::Export(args) => export::run(args),
        Command::Fit(args) => fit::run(args),
        Command::Plot(args) => plot::run(args),
        Command::Report(args) => report::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("gonio: {e}");
            e.exit_code()
        }
    }
}

/// Logs go to stderr; `RUST_LOG` selects them (default: warnings only, so stdout stays clean for data, and the
/// daemon's record of console actions and alignments, who sent each, and of the calibrations it keeps and
/// applies, at info: the operator's log of who moved what and which calibration campaigns got). Colour
/// only on a terminal: a log file or a pipe gets plain text that grep and a lab's log viewer read as written.
fn init_tracing() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(
            "warn,gonio_daemon::service::console=info,gonio_daemon::service::align=info,\
                 gonio_daemon::service::calibration=info",
        )
    });
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
}
