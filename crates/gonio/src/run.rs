//! `gonio run CAMPAIGN [--instrument FILE] [--out DIR]`: one campaign in the foreground.
//!
//! The store lives in DIR (default `out/<campaign id>`). Running the same command again on the same DIR resumes
//! an interrupted campaign from its first uncommitted point, with the configuration stored when it started (the
//! current files are not re-read). A progress bar on stderr (points, rate, ETA from the time model), then a
//! summary; `DIR/points.csv` and `DIR/run.json` are written at the end (also after an interruption, with the
//! points so far).
//!
//! Dry-runs (every device simulated) run on a paused tokio clock: the simulated instrument takes its real
//! instrument time, and no wall time is spent waiting for it; except with `port = "sim-pty"` devices (real
//! pseudo-terminal I/O), which run on the real clock with the simulator sped up. SIGINT/SIGTERM stop all motion, close the beam,
//! leave the store consistent and exit with code 4 and a message saying how to resume.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use gonio_engine::export;
use gonio_engine::store::{CampaignId, CampaignState, NewCampaign, Store};
use gonio_engine::{self as engine, Control, Event, Rig};
use gonio_instrument::InstrumentFile;
use gonio_results::points;
use gonio_results::sweeps::{truth_summary, write_sweeps_csv};

use crate::CliError;
use crate::instrument_arg::{InstrumentArg, read_instrument};

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Campaign file (TOML: [campaign], [sample], [plan], [calibration], [acquisition], [material]).
    pub campaign: PathBuf,
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Output directory holding the store, points.csv and run.json (default: out/<campaign id>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// No progress bar (for logs and tests).
    #[arg(long)]
    pub quiet: bool,
    /// Calibration file from `gonio align` for this instrument file: every point's pose is corrected with it
    /// (refused when it was made for another instrument file).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
}

pub fn run(args: RunArgs) -> Result<(), CliError> {
    let wall = Instant::now();
    let origin = args.campaign.display().to_string();
    let text = std::fs::read_to_string(&args.campaign)
        .map_err(|e| CliError::io(format!("cannot read campaign file {origin}"), e))?;
    let InstrumentArg {
        text: instrument_text,
        origin: instrument_origin,
        file,
    } = read_instrument(args.instrument.as_deref())?;
    let alignment_toml = args
        .calibration
        .as_deref()
        .map(|p| crate::calibration::read_calibration(p, &instrument_text))
        .transpose()?;
    let base_dir = args.campaign.parent().map(Path::to_path_buf).unwrap_or_default();
    let prepared = engine::prepare_campaign(&text, &origin, &base_dir, &file)
        .map_err(|e| CliError::input(e.to_string()))?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(&prepared.name));
    let mut store = Store::open(&out).map_err(|e| CliError::input(e.to_string()))?;

    // One campaign per output directory: the one with this name, resumed; else a new one.
    let existing = store
        .campaigns()
        .map_err(|e| CliError::input(e.to_string()))?
        .into_iter()
        .rfind(|c| c.name == prepared.name);
    let id = match existing {
        Some(c) if c.state == CampaignState::Completed => {
            eprintln!(
                "gonio: campaign {} in {} is already complete; writing its results again",
                c.name,
                out.display()
            );
            c.id
        }
        Some(c) if !c.state.is_final() => {
            // Stored: the text plus the materials it resolved to (which also notices a changed material file).
            let stored_text = prepared.stored_campaign_toml(&text);
            if c.campaign_toml != stored_text || c.instrument_toml != instrument_text {
                eprintln!(
                    "gonio: note: {} changed since the campaign started; resuming with the configuration stored then",
                    if c.campaign_toml != stored_text {
                        origin.as_str()
                    } else {
                        instrument_origin.as_str()
                    }
                );
            }
            if c.alignment_toml != alignment_toml {
                eprintln!(
                    "gonio: note: {}",
                    if c.alignment_toml.is_some() {
                        "the campaign started with another alignment calibration, stored with it: resuming with that one"
                    } else {
                        "the campaign started without an alignment calibration: resuming without one (use another \
                         --out directory to run it aligned)"
                    }
                );
            }
            eprintln!(
                "gonio: resuming campaign {} ({}) in {} at point {} of {}",
                c.name,
                c.state,
                out.display(),
                c.points_done,
                c.total_points
            );
            c.id
        }
        Some(c) => {
            return Err(CliError::input(format!(
                "campaign {} in {} ended {}{}; use another --out directory to run it again",
                c.name,
                out.display(),
                c.state,
                c.last_error.map(|e| format!(" ({e})")).unwrap_or_default()
            )));
        }
        None => store
            .create_campaign(&NewCampaign {
                alignment_toml: alignment_toml.clone(),
                ..prepared.new_campaign(&text, &instrument_text)
            })
            .map_err(|e| CliError::input(e.to_string()))?,
    };
    let record = store.campaign(id).map_err(|e| CliError::input(e.to_string()))?;
    // The run uses the stored instrument text (the same on a first run).
    let file = InstrumentFile::parse(&record.instrument_toml, "<stored instrument file>")
        .map_err(|e| CliError::input(e.to_string()))?;
    let store = Arc::new(Mutex::new(store));

    // A paused clock cannot drive real terminal I/O (`port = "sim-pty"`): the serial reads happen in blocking
    // threads, and auto-advance would fire read timeouts while bytes are in flight. Those dry-runs run the
    // simulator on the real clock, sped up instead.
    let paused_clock = record.dry_run && !file.instrument.devices.iter().any(|d| d.is_sim_pty());
    let runtime = instrument_runtime(paused_clock)?;

    let outcome = if record.state == CampaignState::Completed {
        Ok((CampaignState::Completed, false))
    } else {
        runtime.block_on(drive(
            Arc::clone(&store),
            id,
            &file,
            &prepared,
            paused_clock,
            args.quiet,
        ))
    };
    runtime.shutdown_timeout(std::time::Duration::from_millis(200));
    let (state, interrupted) = outcome?;

    let wall_s = wall.elapsed().as_secs_f64();
    let summary = write_results(&store, id, &out, wall_s)?;
    eprintln!("{summary}");
    match state {
        CampaignState::Completed => {
            println!("{}", out.display());
            Ok(())
        }
        _ => {
            let rec = lock(&store).campaign(id).ok();
            let why = rec
                .and_then(|r| r.last_error)
                .unwrap_or_else(|| state.to_string());
            let how = format!(
                "re-run `gonio run {}{} --out {}` to resume from the first uncommitted point",
                args.campaign.display(),
                args.instrument
                    .as_ref()
                    .map(|p| format!(" --instrument {}", p.display()))
                    .unwrap_or_default(),
                out.display()
            );
            let head = if interrupted {
                "interrupted: motion stopped, beam closed, store consistent".to_string()
            } else {
                format!("campaign {state}: {why}")
            };
            Err(CliError::Interrupted(format!("{head}; {how}")))
        }
    }
}

/// The runtime a command drives the instrument on: with `paused_clock` (a dry-run, every device in process) a
/// paused current-thread clock, where the simulated instrument takes its real time and no wall time; else a
/// multi-threaded runtime with I/O on the real clock.
pub(crate) fn instrument_runtime(paused_clock: bool) -> Result<tokio::runtime::Runtime, CliError> {
    if paused_clock {
        // Timers only: every device is in process, and polling an I/O driver at each step of the simulated clock
        // cost about a fifth of an in-process dry-run's time (0.43 against 0.34 ms per point, measured with
        // gonio-bench). Signals are watched on a thread of their own (`watch_signals`).
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .start_paused(true)
            .build()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
    }
    .map_err(|e| CliError::io("cannot start the async runtime", e))
}

fn lock(store: &Arc<Mutex<Store>>) -> std::sync::MutexGuard<'_, Store> {
    store.lock().unwrap_or_else(|e| e.into_inner())
}

/// Connect, run with a progress bar, stop cleanly on SIGINT/SIGTERM. Returns the final state and whether a
/// signal interrupted the run.
async fn drive(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    file: &InstrumentFile,
    prepared: &engine::PreparedCampaign,
    paused_clock: bool,
    quiet: bool,
) -> Result<(CampaignState, bool), CliError> {
    let rig = if paused_clock {
        // Paused clock: simulated time advances as fast as the run can go.
        Rig::connect_with_time_scale(file, None, 1.0).await
    } else {
        // Real hardware, or simulated devices on pseudo-terminals at the default dry-run time scale.
        Rig::connect(file, None).await
    }
    .map_err(|e| CliError::input(e.to_string()))?;
    let control = Control::new();
    control.attach_rig(&rig);
    let (done0, total) = {
        let s = lock(&store);
        let c = s.campaign(id).map_err(|e| CliError::input(e.to_string()))?;
        (c.points_done, c.total_points)
    };

    let bar = if quiet {
        indicatif::ProgressBar::hidden()
    } else {
        let b =
            indicatif::ProgressBar::with_draw_target(Some(total), indicatif::ProgressDrawTarget::stderr());
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} points  {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b.set_position(done0);
        b
    };
    let mut events = control.subscribe();
    let bar2 = bar.clone();
    let ctl2 = control.clone();
    let started = Instant::now();
    let listener = tokio::spawn(async move {
        let mut last_done = done0;
        loop {
            match events.recv().await {
                Ok(Event::Progress {
                    done, total, eta_s, ..
                }) => {
                    // An adaptive campaign that stops at its target error ends with fewer points than its budget.
                    bar2.set_length(total);
                    bar2.set_position(done);
                    let rate = (done - done0.min(done)) as f64 / started.elapsed().as_secs_f64().max(1e-3);
                    let eta = eta_s
                        .map(|s| format!("instrument ETA {:.0} s", s))
                        .unwrap_or_default();
                    bar2.set_message(format!("{rate:.1} points/s wall, {eta}"));
                    last_done = done;
                }
                Ok(Event::State {
                    state: CampaignState::WaitingOperator,
                    message,
                    ..
                }) => {
                    bar2.suspend(|| {
                        eprintln!(
                            "operator: {} (press Enter to confirm)",
                            message.unwrap_or_default()
                        )
                    });
                    let c = ctl2.clone();
                    tokio::task::spawn_blocking(move || {
                        let mut line = String::new();
                        if std::io::stdin().read_line(&mut line).is_ok() {
                            c.confirm();
                        }
                    });
                }
                Ok(Event::Fault { message, .. }) => bar2.suspend(|| eprintln!("device fault: {message}")),
                Ok(_) => {}
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => break,
            }
        }
        last_done
    });

    let run = engine::run_prepared_campaign(Arc::clone(&store), id, &rig, control.clone(), prepared);
    tokio::pin!(run);
    let mut signalled = watch_signals();
    let mut interrupted = false;
    let result = loop {
        tokio::select! {
            r = &mut run => break r,
            Ok(()) = &mut signalled, if !interrupted => {
                interrupted = true;
                bar.suspend(|| eprintln!("gonio: signal received: stopping all motion"));
                control.estop();
            }
        }
    };
    bar.finish_and_clear();
    listener.abort();
    let state = result.map_err(|e| CliError::input(e.to_string()))?;
    Ok((state, interrupted))
}

/// Fires at the first SIGINT or SIGTERM. The handlers need tokio's I/O driver, which the paused-clock runtime of
/// a dry-run does without: they run on a thread of their own with a small runtime that has it. When that thread
/// cannot start, the sender is dropped (never `Ok`) and the default action of a signal (terminate) applies; the
/// store stays consistent anyway.
fn watch_signals() -> tokio::sync::oneshot::Receiver<()> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    let watcher = std::thread::Builder::new()
        .name("gonio-signals".into())
        .spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build();
            if let Ok(runtime) = runtime {
                runtime.block_on(signal());
                let _ = tx.send(());
            }
        });
    if let Err(e) = watcher {
        tracing::warn!("cannot watch for signals: {e}");
    }
    rx
}

/// SIGINT or SIGTERM.
async fn signal() {
    use tokio::signal::unix::{SignalKind, signal};
    let (Ok(mut int), Ok(mut term)) = (signal(SignalKind::interrupt()), signal(SignalKind::terminate()))
    else {
        // Without signal handlers the default action (terminate) applies; the store stays consistent anyway.
        std::future::pending::<()>().await;
        return;
    };
    tokio::select! {
        _ = int.recv() => {}
        _ = term.recv() => {}
    }
}

/// Write points.csv and run.json (both from the store, as `gonio export --data` reads it); returns the summary
/// text, which adds this process's wall time (not part of run.json: it is not in the store, and a resumed run
/// would only know its last part).
fn write_results(
    store: &Arc<Mutex<Store>>,
    id: CampaignId,
    out: &Path,
    wall_s: f64,
) -> Result<String, CliError> {
    let (table, record) = {
        let s = lock(store);
        let rec = s.campaign(id).map_err(|e| CliError::input(e.to_string()))?;
        export::run_record(&s, &rec).map_err(|e| CliError::input(e.to_string()))?
    };
    let csv_path = out.join("points.csv");
    std::fs::write(&csv_path, points::write_points_csv(&table))
        .map_err(|e| CliError::io(format!("cannot write {}", csv_path.display()), e))?;
    let json_path = out.join("run.json");
    std::fs::write(&json_path, record.to_json_text())
        .map_err(|e| CliError::io(format!("cannot write {}", json_path.display()), e))?;
    let sweeps = export::sweep_readings(&lock(store), id).map_err(|e| CliError::input(e.to_string()))?;
    let mut sweep_lines = String::new();
    if !sweeps.is_empty() {
        let sweeps_path = out.join("sweeps.csv");
        std::fs::write(&sweeps_path, write_sweeps_csv(&sweeps, record.campaign.dry_run))
            .map_err(|e| CliError::io(format!("cannot write {}", sweeps_path.display()), e))?;
        let valid = sweeps.iter().filter(|r| r.brdf_sr.is_some()).count();
        let segments = sweeps
            .iter()
            .map(|r| r.segment)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        sweep_lines.push_str(&format!(
            "sweeps: {} readings in {segments} sweeps ({valid} valid), {}\n",
            sweeps.len(),
            sweeps_path.display()
        ));
        if let Some(t) = truth_summary(&sweeps) {
            sweep_lines.push_str(&format!(
                "dry-run sweep readings vs the BRDF at their arcs' middles: cos-weighted relative RMS {}, k=2 \
                 coverage {:.1} % ({} readings)\n",
                t.cos_weighted_relative_rms
                    .map(|r| format!("{r:.2e}"))
                    .unwrap_or_else(|| "undefined (zero truth)".into()),
                100.0 * t.coverage_k2,
                t.readings
            ));
        }
    }

    let c = &record.campaign;
    let mut summary = format!(
        "campaign {} {}: {} of {} points ({} valid, {} failed{})\n",
        c.name,
        c.state,
        table.points.len(),
        c.total_points,
        c.valid_points,
        c.failed_points,
        c.flags
            .iter()
            .filter(|(k, _)| k.as_str() != "failed")
            .map(|(k, n)| format!(", {n} {k}"))
            .collect::<String>()
    );
    let predicted = record
        .timing
        .predicted_instrument_s
        .map(|p| format!("predicted {p:.0} s"))
        .unwrap_or_else(|| "no prediction".into());
    summary.push_str(&format!(
        "instrument time {:.0} s ({predicted}), wall time {wall_s:.1} s\n",
        record.timing.actual_instrument_s
    ));
    for (truth, e) in [
        (
            "the BRDF at the nominal geometry",
            &record.truth.against_point_value,
        ),
        ("the aperture average", &record.truth.against_aperture_average),
    ] {
        let Some(e) = e else { continue };
        let rms = e
            .cos_weighted_relative_rms
            .map(|r| format!("{r:.2e}"))
            .unwrap_or_else(|| "undefined (zero truth)".into());
        summary.push_str(&format!(
            "dry-run error vs {truth}: cos-weighted relative RMS {rms}, log RMS {:.2e}, max relative {:.2e} ({} points)\n",
            e.log_rms, e.max_relative_error, e.points
        ));
    }
    summary.push_str(&sweep_lines);
    summary.push_str(&format!(
        "results: {} and {}",
        csv_path.display(),
        json_path.display()
    ));
    Ok(summary)
}
