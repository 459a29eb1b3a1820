//! Benchmark (item 3): end-to-end dry-run throughput through the real engine and drivers against the simulator.
//!
//! - In process: `Rig::connect_with_time_scale` with every device on the embedded simulator (`port = "sim"`),
//!   a tokio runtime on the PAUSED clock at time scale 1: simulated device time (moves, settling, integration)
//!   takes no wall time, so the wall time per point is what the engine, the drivers, the protocol emulation, the
//!   simulator's optics and the store cost. That wall time per point is reported as the daemon overhead per point
//!   with device time excluded (an upper bound: it includes the simulator's own CPU time).
//! - Over pseudo-terminals: the serial devices (arms, stage, wheel) served on real pseudo-terminals
//!   (`port = "sim-pty"`) and opened by path like real ports; the power meter stays in process (USB). This needs
//!   the real clock; the simulator runs at the largest time scale given, so device time shrinks to tokio's 1 ms
//!   timer tick per wait.
//! - Both run a stored campaign from `run_campaign` to `completed`, committing every point in its own transaction
//!   to a SQLite store in a directory under the system temp dir (`TMPDIR`, e.g. `TMPDIR=/dev/shm` for tmpfs).
//!   These are dry-runs, which the store commits with `synchronous = NORMAL` in WAL mode (no fsync per point;
//!   survives `kill -9` of the process, not an OS crash: crates/engine/src/store.rs); campaigns on the real
//!   instrument commit with `synchronous = FULL`.
//! - Start-up: `prepare_campaign` plans and orders the campaign before the clock starts; the engine then takes
//!   that prepared campaign instead of ordering the stored text again (crates/engine/src/prepare.rs), so the
//!   overall wall time covers homing, the first calibration and the points.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use gonio_campaign::{AcquisitionSection, CalibrationSection, CampaignFile};
use gonio_engine::store::{CampaignState, PointRecord, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_prepared_campaign};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_scheduler::plan::{GridKind, GridSpec, PlanSpec};

/// Time scale of the pseudo-terminal runs (simulated seconds per real second).
pub const PTY_TIME_SCALE: f64 = 1e6;

#[derive(Debug, Clone)]
pub struct Throughput {
    pub points: u64,
    pub wall_s: f64,
    /// Simulated instrument time of the run (last point's time stamp).
    pub instrument_s: f64,
    /// Wall time from the first point's event to the last one's: the steady state, without start-up (planning,
    /// homing, the first calibration).
    pub steady_wall_s: f64,
}

impl Throughput {
    pub fn points_per_s(&self) -> f64 {
        self.points as f64 / self.wall_s
    }
    pub fn ms_per_point(&self) -> f64 {
        1e3 * self.wall_s / self.points as f64
    }
    /// Points per second between the first and the last point.
    pub fn steady_points_per_s(&self) -> f64 {
        (self.points.saturating_sub(1)) as f64 / self.steady_wall_s
    }
    pub fn steady_ms_per_point(&self) -> f64 {
        1e3 * self.steady_wall_s / (self.points.saturating_sub(1)).max(1) as f64
    }
}

/// An isotropic grid (theta 0-80 at `step_deg`, delta phi at twice that) on coloured plastic at `bands_nm`, with
/// darks every 200 points and direct-beam references at start and end (simulated operator).
pub fn campaign_text(id: &str, step_deg: f64, bands_nm: &[f64]) -> String {
    let mut grid = GridSpec::new(GridKind::Isotropic);
    grid.theta_i_deg = Some(GridSpec::range_deg(0.0, 80.0, step_deg));
    grid.theta_o_deg = Some(GridSpec::range_deg(0.0, 80.0, step_deg));
    grid.delta_phi_deg = Some(GridSpec::range_deg(0.0, 180.0, 2.0 * step_deg));
    let mut plan = PlanSpec {
        bands_nm: Some(bands_nm.to_vec()),
        grid: Some(grid),
        ..PlanSpec::default()
    };
    plan.calibration.dark_every_points = Some(200);
    CampaignFile::new(id, 12.5, plan)
        .with_calibration(CalibrationSection::default())
        .with_acquisition(AcquisitionSection {
            averaging: Some(10),
            ..AcquisitionSection::default()
        })
        .with_material_preset("coloured-plastic")
        .to_toml()
        .expect("a campaign of numbers and names serialises")
}

/// A fresh directory under `base` (removed by the caller).
fn scratch_dir_in(base: &Path, tag: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    base.join(format!("gonio-bench-{tag}-{}-{nanos}", std::process::id()))
}

/// A fresh directory under the system temp dir (removed by the caller).
fn scratch_dir(tag: &str) -> PathBuf {
    scratch_dir_in(&std::env::temp_dir(), tag)
}

async fn run_once(
    text: &str,
    file: &InstrumentFile,
    instrument_toml: &str,
    time_scale: f64,
    dir: &Path,
) -> Result<(Vec<PointRecord>, f64, f64, f64), String> {
    let prepared = prepare_campaign(text, "bench.toml", dir, file).map_err(|e| format!("campaign: {e}"))?;
    let mut store = Store::open(dir).map_err(|e| e.to_string())?;
    let id = store
        .create_campaign(&prepared.new_campaign(text, instrument_toml))
        .map_err(|e| e.to_string())?;
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(file, None, time_scale)
        .await
        .map_err(|e| format!("rig: {e}"))?;
    let control = Control::new();
    let mut rx = control.subscribe();
    // Drain events as a client would (a lagging receiver only skips; the engine never waits for it).
    // The first and last point's wall instants (std clock: the tokio clock may be paused).
    let seen: Arc<Mutex<(Option<Instant>, Option<Instant>)>> = Arc::new(Mutex::new((None, None)));
    let seen_by_listener = Arc::clone(&seen);
    let listener = tokio::spawn(async move {
        loop {
            match rx.recv().await {
                Ok(Event::Point { .. }) => {
                    let now = Instant::now();
                    if let Ok(mut s) = seen_by_listener.lock() {
                        s.0.get_or_insert(now);
                        s.1 = Some(now);
                    }
                }
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
            }
        }
    });
    let start = Instant::now();
    let state = run_prepared_campaign(Arc::clone(&store), id, &rig, control, &prepared)
        .await
        .map_err(|e| format!("run: {e}"))?;
    let wall_s = start.elapsed().as_secs_f64();
    if state != CampaignState::Completed {
        return Err(format!("campaign ended {state:?}"));
    }
    listener.abort();
    let points = store
        .lock()
        .map_err(|_| "store lock poisoned".to_string())?
        .points(id)
        .map_err(|e| e.to_string())?;
    let instrument_s = points.iter().map(|p| p.t_s).fold(0.0f64, f64::max);
    let steady_wall_s = match *seen.lock().map_err(|_| "lock poisoned".to_string())? {
        (Some(a), Some(b)) => (b - a).as_secs_f64(),
        _ => f64::NAN,
    };
    Ok((points, wall_s, instrument_s, steady_wall_s))
}

/// In process, paused clock, the store under the system temp dir.
pub fn in_process(text: &str) -> Result<Throughput, String> {
    in_process_in(text, &std::env::temp_dir())
}

/// In process, paused clock, the store in a directory under `base`.
pub fn in_process_in(text: &str, base: &Path) -> Result<Throughput, String> {
    let file = InstrumentFile::simulated();
    in_process_on(text, &file, SIMULATED_INSTRUMENT_TOML, base).map(|(_, t)| t)
}

/// A campaign run in process to completion (paused clock, the store under the system temp dir): its committed
/// points.
pub fn in_process_points(text: &str) -> Result<Vec<PointRecord>, String> {
    let file = InstrumentFile::simulated();
    in_process_on(text, &file, SIMULATED_INSTRUMENT_TOML, &std::env::temp_dir()).map(|(p, _)| p)
}

/// A campaign run in process to completion on the instrument `file` (whose text is `instrument_toml`), the store
/// in a directory under `base`: its committed points and its throughput.
pub fn in_process_on(
    text: &str,
    file: &InstrumentFile,
    instrument_toml: &str,
    base: &Path,
) -> Result<(Vec<PointRecord>, Throughput), String> {
    // The runtime `gonio run` gives an in-process dry-run: current thread, paused clock, timers only.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .map_err(|e| e.to_string())?;
    let dir = scratch_dir_in(base, "inproc");
    let result = rt.block_on(run_once(text, file, instrument_toml, 1.0, &dir));
    let _ = std::fs::remove_dir_all(&dir);
    let (points, wall_s, instrument_s, steady_wall_s) = result?;
    let throughput = Throughput {
        points: points.len() as u64,
        wall_s,
        instrument_s,
        steady_wall_s,
    };
    Ok((points, throughput))
}

/// Serial devices on pseudo-terminals, real clock at [`PTY_TIME_SCALE`].
pub fn over_ptys(text: &str) -> Result<Throughput, String> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    let toml = SIMULATED_INSTRUMENT_TOML
        .replace(
            "protocol = \"smc100\"\nport = \"sim\"",
            "protocol = \"smc100\"\nport = \"sim-pty\"",
        )
        .replace(
            "protocol = \"zaber-ascii\"\nport = \"sim\"",
            "protocol = \"zaber-ascii\"\nport = \"sim-pty\"",
        )
        .replace(
            "protocol = \"fw102c\"\nport = \"sim\"",
            "protocol = \"fw102c\"\nport = \"sim-pty\"",
        );
    if toml.matches("sim-pty").count() != 3 {
        return Err("could not put the serial devices on pseudo-terminals (instrument file changed?)".into());
    }
    let file = InstrumentFile::parse(&toml, "simulated-pty").map_err(|e| e.to_string())?;
    let dir = scratch_dir("pty");
    let result = rt.block_on(run_once(text, &file, &toml, PTY_TIME_SCALE, &dir));
    let _ = std::fs::remove_dir_all(&dir);
    let (points, wall_s, instrument_s, steady_wall_s) = result?;
    Ok(Throughput {
        points: points.len() as u64,
        wall_s,
        instrument_s,
        steady_wall_s,
    })
}

/// `gonio run` of a campaign through the release binary: (points, wall s), or why not measured.
pub fn gonio_run(binary: &Path, text: &str) -> Result<(u64, f64), String> {
    crate::time_model::dry_run(binary, text, None).map(|r| (r.points, r.wall_s))
}
