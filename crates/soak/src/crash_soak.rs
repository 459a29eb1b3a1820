//! The crash soak: one campaign on the daemon ([`crate::worker`], a child process), killed with SIGKILL at chosen
//! and random moments and restarted each time, until the campaign completes.
//!
//! The moments (seeded): the first kill at a random instant of start-up (connecting, homing, calibrating, maybe
//! the first commits); then, shuffled, about a third mid-move and a third mid-commit (placed exactly by the
//! worker itself, see [`crate::worker`]), and the rest from outside at a random instant after a random number of
//! new units (`kill -9` by the parent, wherever the daemon happens to be). A unit is a committed point or sweep
//! segment. With sweeps (`[[plan.sweeps]]`, issue 41) a quarter of the kills after start-up are mid-sweep: the
//! worker kills itself at a random reply read while a sweep's arm moves and its meter is read back to back;
//! they come last, once the points are in.
//!
//! After every kill the store is read with SQLite directly ([`Snapshot`]): the rows committed before the kill must
//! all be there, byte for byte, after every later restart (points, calibrations, sweep segments and their
//! readings). At the end there must be exactly one row per planned point, in index order, each planned sweep
//! segment once with all its readings and none twice ([`SweepSummary`]), and the campaign completed.

use std::io::{BufRead as _, BufReader};
use std::os::unix::process::ExitStatusExt as _;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gonio_engine::store::{CampaignState, Store};
use gonio_instrument::{Faults, InstrumentFile};
use rand::seq::SliceRandom as _;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::SoakError;
use crate::rows::{RowSummary, Snapshot, SweepSummary};
use crate::setup::{
    SoakCampaign, SoakInstrument, build_campaign_with_sweeps, instrument_with_faults, soak_sweeps,
};
use crate::truth_check::Tolerance;
use crate::worker::{DieAt, EXIT_COMPLETED, WorkerArgs};

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct CrashSoakConfig {
    /// Planned points of the campaign.
    pub points: u64,
    /// Kills before the campaign is let finish.
    pub kills: u32,
    pub seed: u64,
    /// An empty directory: the daemon's data directory plus the campaign and instrument files.
    pub work_dir: PathBuf,
    /// The worker command: program and the arguments before the worker's own (`[exe, "worker"]`).
    pub worker: Vec<String>,
    /// Longest a daemon may run without being killed or finishing (wall time).
    pub round_timeout: Duration,
    /// The instrument file the daemon runs on (no faults: the kills are the faults).
    pub instrument: SoakInstrument,
    /// The campaign sweeps after its points ([`crate::setup::soak_sweeps`]), and a quarter of the kills land
    /// mid-sweep.
    pub sweeps: bool,
}

/// Where a kill was planned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KillPlan {
    /// From outside, this long after the start (start-up, calibration, maybe the first points).
    StartUp { after_ms: u64 },
    /// By the worker, at the first move after this many new units (points and sweep segments).
    MidMove { after_units: u64 },
    /// By the worker, at the first store write after this many new units.
    MidCommit { after_units: u64 },
    /// By the worker, at this reply read after the first sweep started after this many new units.
    MidSweep { after_units: u64, reads: u32 },
    /// From outside, this long after the daemon reported this many new units.
    External { after_units: u64, extra_us: u64 },
}

impl KillPlan {
    pub fn describe(&self) -> String {
        match self {
            KillPlan::StartUp { after_ms } => format!("start-up, {after_ms} ms after launch (kill -9)"),
            KillPlan::MidMove { after_units } => {
                format!("mid-move, first move after {after_units} new units")
            }
            KillPlan::MidCommit { after_units } => {
                format!("mid-commit, first store write after {after_units} new units")
            }
            KillPlan::MidSweep { after_units, reads } => {
                format!("mid-sweep, reply {reads} of the first sweep after {after_units} new units")
            }
            KillPlan::External {
                after_units,
                extra_us,
            } => {
                format!("random, {extra_us} us after the {after_units}th new unit (kill -9)")
            }
        }
    }

    pub fn kind(&self) -> &'static str {
        match self {
            KillPlan::StartUp { .. } => "start-up",
            KillPlan::MidMove { .. } => "mid-move",
            KillPlan::MidCommit { .. } => "mid-commit",
            KillPlan::MidSweep { .. } => "mid-sweep",
            KillPlan::External { .. } => "random",
        }
    }
}

/// One round: a daemon started, then killed (or let finish).
#[derive(Debug, Clone, PartialEq)]
pub struct Round {
    pub plan: Option<KillPlan>,
    /// Point rows in the store when the daemon started (where it resumed).
    pub resumed_at: u64,
    /// Died of SIGKILL.
    pub killed: bool,
    /// Its exit code when it exited by itself.
    pub exit_code: Option<i32>,
    /// What the daemon last said before it died (its last stdout lines).
    pub last_words: Vec<String>,
    /// Point, calibration and sweep segment rows in the store after it ended.
    pub points_after: u64,
    pub calibrations_after: u64,
    pub segments_after: u64,
    /// For a mid-commit kill: whether the record being written was found in the store afterwards.
    pub note: String,
    pub wall_s: f64,
}

/// Everything the crash soak measured.
#[derive(Debug, Clone)]
pub struct CrashSoakReport {
    pub config: CrashSoakConfig,
    pub campaign: SoakCampaign,
    pub rounds: Vec<Round>,
    /// Rows that changed or vanished after a kill (must be empty).
    pub changed: Vec<String>,
    pub final_state: Option<CampaignState>,
    /// The final points against the plan and the simulator's ground truth (every restart recalibrated); their
    /// indices in order in the raw rows too.
    pub committed: RowSummary,
    /// The final sweep segments against the plan (none planned without sweeps).
    pub sweeps: SweepSummary,
    /// Instrument time of the campaign (s): its last point or calibration.
    pub instrument_s: f64,
    pub wall_s: f64,
    /// Anything else that went wrong (a hang, a daemon that could not start).
    pub problems: Vec<String>,
}

impl CrashSoakReport {
    pub fn kills(&self) -> usize {
        self.rounds.iter().filter(|r| r.killed).count()
    }

    pub fn kills_of(&self, kind: &str) -> usize {
        self.rounds
            .iter()
            .filter(|r| r.killed && r.plan.is_some_and(|p| p.kind() == kind))
            .count()
    }

    /// Every broken invariant, in words; empty when the soak passed.
    pub fn violations(&self) -> Vec<String> {
        let mut v = self.problems.clone();
        v.extend(self.changed.iter().cloned());
        if self.kills() < self.config.kills as usize {
            v.push(format!(
                "only {} of {} planned kills landed before the campaign ended",
                self.kills(),
                self.config.kills
            ));
        }
        if self.final_state != Some(CampaignState::Completed) {
            v.push(format!("the campaign ended {:?}", self.final_state));
        }
        v.extend(self.committed.violations());
        v.extend(self.sweeps.violations());
        v
    }
}

/// The kill plan: a start-up kill, then a shuffled mix of mid-move, mid-commit and random kills (their unit
/// counts are drawn when each round starts, from the units left); with `sweeps`, a quarter mid-sweep, last.
fn kill_kinds(kills: u32, sweeps: bool, rng: &mut ChaCha8Rng) -> Vec<&'static str> {
    let n = kills as usize;
    if n == 0 {
        return Vec::new();
    }
    let rest = n - 1;
    let cycle: &[&'static str] = if sweeps {
        &["mid-move", "mid-commit", "random", "mid-sweep"]
    } else {
        &["mid-move", "mid-commit", "random"]
    };
    let (mut kinds, mid_sweep): (Vec<&'static str>, Vec<&'static str>) = (0..rest)
        .map(|i| cycle[i % cycle.len()])
        .partition(|k| *k != "mid-sweep");
    kinds.shuffle(rng);
    let mut all = vec!["start-up"];
    all.extend(kinds);
    all.extend(mid_sweep);
    all
}

/// Run the crash soak.
pub fn run_crash_soak(cfg: &CrashSoakConfig) -> Result<CrashSoakReport, SoakError> {
    let wall = Instant::now();
    let (file, instrument_text): (InstrumentFile, String) =
        instrument_with_faults(&cfg.instrument, &Faults::default())?;
    let sweeps = if cfg.sweeps { soak_sweeps() } else { Vec::new() };
    let campaign = build_campaign_with_sweeps("crash-soak", cfg.points, cfg.seed, &file, &sweeps)?;
    let total_units = campaign.total_points + campaign.sweep_segments;
    let data = cfg.work_dir.join("data");
    if data.join(gonio_engine::store::STORE_FILE).exists() {
        return Err(SoakError::Setup(format!(
            "{} already holds a store: give the crash soak an empty directory",
            data.display()
        )));
    }
    std::fs::create_dir_all(&data).map_err(SoakError::io(format!("cannot create {}", data.display())))?;
    let campaign_path = cfg.work_dir.join("crash-soak.toml");
    let instrument_path = cfg.work_dir.join("instrument.toml");
    std::fs::write(&campaign_path, &campaign.text)
        .map_err(SoakError::io(format!("cannot write {}", campaign_path.display())))?;
    std::fs::write(&instrument_path, &instrument_text).map_err(SoakError::io(format!(
        "cannot write {}",
        instrument_path.display()
    )))?;
    let log_path = cfg.work_dir.join("daemon.log");

    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x00c4_a5b0_0c4a_5b00);
    let kinds = kill_kinds(cfg.kills, campaign.sweep_segments > 0, &mut rng);
    let mut rounds: Vec<Round> = Vec::new();
    let mut snapshots: Vec<Snapshot> = Vec::new();
    let mut changed = Vec::new();
    let mut problems = Vec::new();
    let mut before = Snapshot::default();
    for round in 0..=kinds.len() {
        let resumed_at = before.points.len() as u64;
        let units_done = resumed_at + before.sweep_segments.len() as u64;
        let kills_left = (kinds.len() - round.min(kinds.len())) as u64;
        let budget = (total_units.saturating_sub(units_done) / (kills_left + 1)).max(1);
        // A mid-sweep kill waits for the points left, then for a few of the segments left.
        let points_left = campaign.total_points.saturating_sub(resumed_at);
        let segments_left = campaign
            .sweep_segments
            .saturating_sub(before.sweep_segments.len() as u64);
        let plan = kinds.get(round).map(|kind| match *kind {
            "start-up" => KillPlan::StartUp {
                after_ms: rng.random_range(0..60),
            },
            "mid-move" => KillPlan::MidMove {
                after_units: rng.random_range(0..=budget),
            },
            "mid-commit" => KillPlan::MidCommit {
                after_units: rng.random_range(1..=budget),
            },
            "mid-sweep" => KillPlan::MidSweep {
                after_units: points_left
                    + rng.random_range(
                        0..=(segments_left / (kills_left + 1)).min(segments_left.saturating_sub(1)),
                    ),
                reads: rng.random_range(1..=200),
            },
            _ => KillPlan::External {
                after_units: rng.random_range(1..=budget),
                extra_us: rng.random_range(0..3000),
            },
        });
        let args = WorkerArgs {
            data: data.clone(),
            campaign: campaign_path.clone(),
            instrument: instrument_path.clone(),
            die: match plan {
                Some(KillPlan::MidMove { after_units }) => Some((DieAt::MidMove, after_units)),
                Some(KillPlan::MidCommit { after_units }) => Some((DieAt::MidCommit, after_units)),
                Some(KillPlan::MidSweep { after_units, reads }) => {
                    Some((DieAt::MidSweep { reads }, after_units))
                }
                _ => None,
            },
        };
        let started = Instant::now();
        let mut daemon = Daemon::spawn(&cfg.worker, &args, &log_path)?;
        let mut hung = false;
        let status = loop {
            if let Some(s) = daemon
                .child
                .try_wait()
                .map_err(SoakError::io("cannot wait for the daemon"))?
            {
                break s;
            }
            let due = match plan {
                Some(KillPlan::StartUp { after_ms }) => started.elapsed() >= Duration::from_millis(after_ms),
                Some(KillPlan::External {
                    after_units,
                    extra_us,
                }) if daemon.units() >= after_units => {
                    std::thread::sleep(Duration::from_micros(extra_us));
                    true
                }
                _ => false,
            };
            if started.elapsed() >= cfg.round_timeout {
                hung = true;
            }
            if due || hung {
                // std's Child::kill is SIGKILL on Unix: kill -9.
                let _ = daemon.child.kill();
                break daemon
                    .child
                    .wait()
                    .map_err(SoakError::io("cannot wait for the daemon"))?;
            }
            std::thread::sleep(Duration::from_micros(200));
        };
        let last_words = daemon.finish();
        if hung {
            problems.push(format!(
                "round {round}: the daemon neither finished nor was killed within {:?} (hang?); last words {last_words:?}",
                cfg.round_timeout
            ));
        }
        let after = Snapshot::read(&data)?;
        if let Err(e) = before.prefix_of(&after) {
            changed.push(format!("after round {round} ({plan:?}): {e}"));
        }
        let killed = status.signal() == Some(nix::sys::signal::Signal::SIGKILL as i32);
        let note = match plan {
            Some(KillPlan::MidCommit { after_units }) if killed => {
                let armed_at = units_done + after_units;
                let units_after = (after.points.len() + after.sweep_segments.len()) as u64;
                if units_after > armed_at {
                    format!(
                        "unit {armed_at} (a point or a sweep segment) was being committed: it is in the store"
                    )
                } else {
                    format!(
                        "the record being written (unit {armed_at} or a calibration reading) is not in the store"
                    )
                }
            }
            Some(KillPlan::MidSweep { .. }) if killed => {
                let segments = after.sweep_segments.len();
                format!(
                    "{segments} sweep segments committed, {} readings; the one under way is not in the store",
                    after.sweep_readings.len()
                )
            }
            _ => String::new(),
        };
        rounds.push(Round {
            plan,
            resumed_at,
            killed,
            exit_code: status.code(),
            last_words,
            points_after: after.points.len() as u64,
            calibrations_after: after.calibrations.len() as u64,
            segments_after: after.sweep_segments.len() as u64,
            note,
            wall_s: started.elapsed().as_secs_f64(),
        });
        snapshots.push(after.clone());
        before = after;
        if hung {
            break;
        }
        if !killed {
            if status.code() != Some(EXIT_COMPLETED) {
                problems.push(format!(
                    "round {round}: the daemon exited with {status} without being killed; last words {:?}",
                    rounds.last().map(|r| r.last_words.clone()).unwrap_or_default()
                ));
            }
            // It finished by itself: nothing left to kill.
            break;
        }
    }

    // Every snapshot is a prefix of the final store, byte for byte.
    let last = snapshots.last().cloned().unwrap_or_default();
    for (i, s) in snapshots.iter().enumerate() {
        if let Err(e) = s.prefix_of(&last) {
            changed.push(format!(
                "rows committed before kill {} changed by the end: {e}",
                i + 1
            ));
        }
    }
    let store = Store::open(&data)?;
    let record = store.campaigns()?.into_iter().find(|c| c.name == campaign.name);
    let (final_state, committed, instrument_s) = match &record {
        Some(c) => {
            let points = store.points(c.id)?;
            let mut committed = RowSummary::of(campaign.total_points, &points, &Tolerance::of(&file));
            let cals = store.calibrations(c.id)?;
            let t = points
                .iter()
                .map(|p| p.t_s)
                .chain(cals.iter().map(|c| c.t_s))
                .fold(0.0f64, f64::max);
            committed.indices_in_order &= last.points.iter().enumerate().all(|(i, r)| r.key.1 == i as i64);
            (Some(c.state), committed, t)
        }
        None => (
            None,
            RowSummary {
                planned: campaign.total_points,
                ..RowSummary::default()
            },
            0.0,
        ),
    };
    drop(store);
    let sweeps = SweepSummary::read(&data, campaign.sweep_segments)?;
    Ok(CrashSoakReport {
        config: cfg.clone(),
        campaign,
        rounds,
        changed,
        final_state,
        committed,
        sweeps,
        instrument_s,
        wall_s: wall.elapsed().as_secs_f64(),
        problems,
    })
}

/// A running worker and its stdout.
struct Daemon {
    child: Child,
    lines: Arc<Mutex<Lines>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

#[derive(Default)]
struct Lines {
    /// Points and sweep segments reported committed.
    units: u64,
    last: Vec<String>,
}

/// Lines of the daemon's stdout kept as its last words.
const LAST_WORDS: usize = 8;

impl Daemon {
    fn spawn(worker: &[String], args: &WorkerArgs, log: &std::path::Path) -> Result<Daemon, SoakError> {
        let Some((program, lead)) = worker.split_first() else {
            return Err(SoakError::Setup("no worker command".into()));
        };
        let stderr = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .map_err(SoakError::io(format!("cannot open {}", log.display())))?;
        let mut child = Command::new(program)
            .args(lead)
            .args(args.to_args())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::from(stderr))
            .spawn()
            .map_err(SoakError::io(format!("cannot start the daemon {program}")))?;
        let lines = Arc::new(Mutex::new(Lines::default()));
        let reader = child.stdout.take().map(|out| {
            let lines = Arc::clone(&lines);
            std::thread::spawn(move || {
                for line in BufReader::new(out).lines().map_while(Result::ok) {
                    let mut l = lines.lock().unwrap_or_else(|e| e.into_inner());
                    if line.starts_with("point ") || line.starts_with("sweep ") {
                        l.units += 1;
                    }
                    l.last.push(line);
                    if l.last.len() > LAST_WORDS {
                        l.last.remove(0);
                    }
                }
            })
        });
        Ok(Daemon { child, lines, reader })
    }

    /// Points and sweep segments the daemon reported committed so far.
    fn units(&self) -> u64 {
        self.lines.lock().unwrap_or_else(|e| e.into_inner()).units
    }

    /// After the process ended: its last lines.
    fn finish(mut self) -> Vec<String> {
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        self.lines.lock().unwrap_or_else(|e| e.into_inner()).last.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_starts_with_start_up_and_mixes_the_rest() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let kinds = kill_kinds(20, false, &mut rng);
        assert_eq!(kinds.len(), 20);
        assert_eq!(kinds[0], "start-up");
        for (kind, n) in [("mid-move", 7), ("mid-commit", 6), ("random", 6)] {
            assert_eq!(kinds.iter().filter(|k| **k == kind).count(), n, "{kind}");
        }
        let with_sweeps = kill_kinds(20, true, &mut rng);
        for (kind, n) in [
            ("mid-move", 5),
            ("mid-commit", 5),
            ("random", 5),
            ("mid-sweep", 4),
        ] {
            assert_eq!(with_sweeps.iter().filter(|k| **k == kind).count(), n, "{kind}");
        }
        assert_eq!(
            with_sweeps[16..],
            ["mid-sweep"; 4],
            "the mid-sweep kills come last"
        );
        let three = kill_kinds(3, false, &mut rng);
        assert_eq!(three[0], "start-up");
        assert!(
            three.contains(&"mid-move") && three.contains(&"mid-commit"),
            "{three:?}"
        );
    }
}
