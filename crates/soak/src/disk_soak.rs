//! The disk soak: the store becomes genuinely full several times during one campaign, and room comes back each
//! time.
//!
//! "Full" is SQLite's own: the store is capped at the pages it holds at that moment (`Store::set_max_pages`,
//! SQLite's `max_page_count`), so the next write that needs a page fails with SQLITE_FULL exactly as on a full
//! disk, whoever runs the soak (root ignores read-only permissions, so a read-only directory cannot be simulated
//! this way; see the report). The campaign runs through the real engine and drivers on the simulated instrument
//! (`engine::run_campaign` on a `Rig`, paused tokio clock, time scale 1).
//!
//! At each fill, checked and measured:
//! - the campaign pauses by itself (the engine returns `paused`), with a reason in its state event and in the
//!   store's record that names the store file and SQLite's error;
//! - nothing moves while it waits: the pose is the same after a hold of simulated minutes, and no move or home
//!   command reaches any axis from the pause until the resume (the simulator's motion record);
//! - every row committed before the fill is still there, byte for byte ([`Snapshot`]), at the pause and at the end;
//! - once the cap is lifted, running the campaign again (the operator's resume) carries on from the first point
//!   not committed.
//!
//! At the end: one row per planned point, in index order, every value valid against the simulator's ground truth.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gonio_engine::store::{CampaignState, STORE_FILE, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_campaign};
use gonio_instrument::InstrumentFile;
use gonio_simulator::recording::MotionCommand;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::SoakError;
use crate::rows::{RowSummary, Snapshot};
use crate::setup::{SoakCampaign, SoakInstrument, build_campaign};
use crate::truth_check::Tolerance;

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct DiskSoakConfig {
    /// Planned points of the campaign.
    pub points: u64,
    /// Times the store becomes full.
    pub fills: u32,
    pub seed: u64,
    /// An empty directory for the store.
    pub data_dir: PathBuf,
    /// Simulated seconds the campaign is left paused on a full store before room comes back.
    pub hold_s: f64,
    /// The instrument file the campaign runs on.
    pub instrument: SoakInstrument,
}

/// One fill: the store capped, the campaign paused, room given back.
#[derive(Debug, Clone, PartialEq)]
pub struct Fill {
    /// Point rows committed when the store was capped.
    pub rows_at_cap: u64,
    /// The cap (pages), which is what the store held.
    pub cap_pages: u64,
    /// How the run ended.
    pub ended: CampaignState,
    /// The reason in the paused state event, with the data directory written `<data>`.
    pub reason: Option<String>,
    /// The store's record at the pause agrees (state paused, last error = the reason).
    pub record_agrees: bool,
    /// Point rows at the pause.
    pub rows_at_pause: u64,
    /// Largest change of any axis position over the hold (deg).
    pub pose_change_deg: f64,
    /// Move or home commands received by any axis from the pause to the resume.
    pub moves_while_paused: u64,
    /// Simulated seconds from the pause to the resume.
    pub paused_s: f64,
    /// Rows committed before the cap changed or vanished at the pause (first difference).
    pub changed_at_pause: Option<String>,
}

/// Everything the disk soak measured.
#[derive(Debug, Clone)]
pub struct DiskSoakReport {
    pub config: DiskSoakConfig,
    pub campaign: SoakCampaign,
    pub fills: Vec<Fill>,
    pub final_state: CampaignState,
    pub last_error: Option<String>,
    /// The final points against the plan and the simulator's ground truth.
    pub committed: RowSummary,
    /// Rows committed before a fill that changed or vanished by the end (one entry per fill with a difference).
    pub changed: Vec<String>,
    pub hung: bool,
    /// Simulated seconds at the end.
    pub instrument_s: f64,
    pub wall_s: f64,
}

impl DiskSoakReport {
    /// Every broken invariant, in words; empty when the soak passed.
    pub fn violations(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.hung {
            v.push("the campaign did not end within its instrument-time budget (hang)".into());
        }
        if self.fills.len() != self.config.fills as usize {
            v.push(format!(
                "{} fills planned, {} happened (the campaign ended first)",
                self.config.fills,
                self.fills.len()
            ));
        }
        for (i, f) in self.fills.iter().enumerate() {
            let n = i + 1;
            if f.ended != CampaignState::Paused {
                v.push(format!(
                    "fill {n}: the campaign ended {} instead of pausing",
                    f.ended
                ));
            }
            match &f.reason {
                Some(r) if r.contains(STORE_FILE) && r.contains("full") => {}
                other => v.push(format!(
                    "fill {n}: the pause reason does not name the store and the full disk: {other:?}"
                )),
            }
            if !f.record_agrees {
                v.push(format!(
                    "fill {n}: the store's record does not show the pause and its reason"
                ));
            }
            if f.pose_change_deg != 0.0 || f.moves_while_paused > 0 {
                v.push(format!(
                    "fill {n}: motion while paused ({} move commands, pose changed by {} deg)",
                    f.moves_while_paused, f.pose_change_deg
                ));
            }
            if let Some(c) = &f.changed_at_pause {
                v.push(format!("fill {n}: committed rows changed at the pause: {c}"));
            }
        }
        if self.final_state != CampaignState::Completed {
            v.push(format!(
                "the campaign ended {} ({})",
                self.final_state,
                self.last_error.clone().unwrap_or_default()
            ));
        }
        v.extend(self.committed.violations());
        for c in &self.changed {
            v.push(format!("committed rows changed: {c}"));
        }
        v
    }

    /// Points lost or wrong: missing rows, changed rows, silently wrong values, points without value or reason.
    pub fn data_lost(&self) -> u64 {
        self.committed.lost()
            + self.changed.len() as u64
            + self.fills.iter().filter(|f| f.changed_at_pause.is_some()).count() as u64
    }
}

/// The point counts at which the store is capped: `fills` distinct values spread over 5 % to 85 % of the
/// campaign, at random (seeded).
fn fill_moments(points: u64, fills: u32, seed: u64) -> Vec<u64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xd15c_f011);
    let lo = (points / 20).max(1);
    let hi = (points * 17 / 20).max(lo + u64::from(fills));
    let span = (hi - lo) / u64::from(fills.max(1));
    // One moment in each of `fills` equal slices, so that they are distinct and spread out.
    (0..u64::from(fills))
        .map(|k| lo + k * span + rng.random_range(0..span.max(1)))
        .collect()
}

/// Run the disk soak.
pub fn run_disk_soak(cfg: &DiskSoakConfig) -> Result<DiskSoakReport, SoakError> {
    let wall = Instant::now();
    let file = cfg.instrument.file()?;
    let campaign = build_campaign("disk-soak", cfg.points, cfg.seed, &file)?;
    std::fs::create_dir_all(&cfg.data_dir)
        .map_err(SoakError::io(format!("cannot create {}", cfg.data_dir.display())))?;
    let mut store = Store::open(&cfg.data_dir)?;
    if !store.campaigns()?.is_empty() {
        return Err(SoakError::Setup(format!(
            "{} already holds a store with campaigns: give the disk soak an empty directory",
            cfg.data_dir.display()
        )));
    }
    let prepared = prepare_campaign(&campaign.text, "disk-soak.toml", Path::new("."), &file)?;
    let id = store.create_campaign(&prepared.new_campaign(&campaign.text, &cfg.instrument.text))?;
    let store = Arc::new(Mutex::new(store));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(SoakError::io("cannot start the async runtime"))?;
    let moments = fill_moments(campaign.total_points, cfg.fills, cfg.seed);
    let budget =
        Duration::from_secs_f64(campaign.predicted_s * 5.0 + 3600.0 + cfg.hold_s * f64::from(cfg.fills));
    let driven = runtime.block_on(async {
        tokio::time::timeout(budget, drive(Arc::clone(&store), id, &file, cfg, &moments)).await
    });
    drop(runtime);
    let (fills, snapshots, instrument_s, hung) = match driven {
        Ok(d) => {
            let d = d?;
            (d.fills, d.snapshots, d.sim_s, false)
        }
        Err(_) => (Vec::new(), Vec::new(), f64::NAN, true),
    };
    let end = Snapshot::read(&cfg.data_dir)?;
    let changed = snapshots
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.prefix_of(&end).err().map(|e| format!("fill {}: {e}", i + 1)))
        .collect();
    let s = store.lock().unwrap_or_else(|e| e.into_inner());
    let record = s.campaign(id)?;
    let points = s.points(id)?;
    drop(s);
    let committed = RowSummary::of(campaign.total_points, &points, &Tolerance::of(&file));
    Ok(DiskSoakReport {
        config: cfg.clone(),
        campaign,
        committed,
        fills,
        final_state: record.state,
        last_error: record.last_error,
        changed,
        hung,
        instrument_s,
        wall_s: wall.elapsed().as_secs_f64(),
    })
}

fn lock(s: &Mutex<Store>) -> std::sync::MutexGuard<'_, Store> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

struct Driven {
    fills: Vec<Fill>,
    /// The raw rows just before each cap.
    snapshots: Vec<Snapshot>,
    sim_s: f64,
}

async fn drive(
    store: Arc<Mutex<Store>>,
    id: gonio_engine::store::CampaignId,
    file: &InstrumentFile,
    cfg: &DiskSoakConfig,
    moments: &[u64],
) -> Result<Driven, SoakError> {
    let rig = Rig::connect_with_time_scale(file, None, 1.0).await?;
    let sim = rig
        .sim()
        .ok_or_else(|| SoakError::Setup("the simulated instrument has no simulator".into()))?
        .clone();
    sim.start_motion_recording();
    let data = cfg.data_dir.display().to_string();
    let mut fills = Vec::new();
    let mut snapshots = Vec::new();
    let mut next = moments.iter().copied().peekable();
    loop {
        let control = Control::new();
        let mut rx = control.subscribe();
        let mut task = {
            let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
            tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
        };
        // Wait for the next fill moment (or the end of the run).
        let mut capped: Option<(u64, u64)> = None;
        let mut reason = None;
        let joined = loop {
            tokio::select! {
                r = &mut task => break r,
                event = rx.recv() => match event {
                    Ok(Event::Point { point, .. }) => {
                        if capped.is_none() && next.peek().is_some_and(|m| point.index + 1 >= *m) {
                            next.next();
                            // Between two commits: the engine takes the store only to write.
                            let mut s = lock(&store);
                            snapshots.push(Snapshot::read(&cfg.data_dir)?);
                            let pages = s.page_count()?;
                            s.set_max_pages(Some(pages))?;
                            let rows = snapshots.last().map_or(0, |s| s.points.len() as u64);
                            capped = Some((rows, pages));
                        }
                    }
                    Ok(Event::State { state: CampaignState::Paused, message, .. }) => reason = message,
                    Ok(_) => {}
                    // Missed events only matter for the pause reason, which the store's record also holds.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => {}
                },
            }
        };
        let ended = joined.map_err(|e| SoakError::Setup(format!("engine task: {e}")))??;
        // Events sent just before the run returned.
        while let Ok(event) = rx.try_recv() {
            if let Event::State {
                state: CampaignState::Paused,
                message,
                ..
            } = event
            {
                reason = message;
            }
        }
        let Some((rows_at_cap, cap_pages)) = capped else {
            // No fill in this run: it ran to its end.
            return Ok(Driven {
                fills,
                snapshots,
                sim_s: sim.now_s(),
            });
        };
        let paused_at = sim.now_s();
        let record = lock(&store).campaign(id)?;
        let record_agrees =
            record.state == CampaignState::Paused && reason.is_some() && record.last_error == reason;
        let at_pause = Snapshot::read(&cfg.data_dir)?;
        let changed_at_pause = snapshots.last().and_then(|s| s.prefix_of(&at_pause).err());
        // Nothing moves while the campaign waits for room.
        let pose = sim.pose();
        tokio::time::sleep(Duration::from_secs_f64(cfg.hold_s)).await;
        let after = sim.pose();
        let pose_change_deg = [
            (pose.light_deg, after.light_deg),
            (pose.detector_deg, after.detector_deg),
            (pose.tilt_deg, after.tilt_deg),
            (pose.rotation_deg, after.rotation_deg),
        ]
        .iter()
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
        let resumed_at = sim.now_s();
        let moves_while_paused = sim
            .motion_records()
            .iter()
            .flat_map(|(_, r)| r.commands.iter())
            .filter(|c| {
                matches!(c.command, MotionCommand::MoveTo { .. } | MotionCommand::Home)
                    && c.t_s >= paused_at
                    && c.t_s <= resumed_at
            })
            .count() as u64;
        fills.push(Fill {
            rows_at_cap,
            cap_pages,
            ended,
            reason: reason.map(|r| r.replace(&data, "<data>")),
            record_agrees,
            rows_at_pause: at_pause.points.len() as u64,
            pose_change_deg,
            moves_while_paused,
            paused_s: resumed_at - paused_at,
            changed_at_pause,
        });
        // Room again; the next run is the operator's resume.
        lock(&store).set_max_pages(None)?;
        if ended != CampaignState::Paused {
            return Ok(Driven {
                fills,
                snapshots,
                sim_s: sim.now_s(),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_moments_are_distinct_and_inside_the_campaign() {
        for (points, fills) in [(40u64, 2u32), (600, 5), (10, 3)] {
            let m = fill_moments(points, fills, 8);
            assert_eq!(m.len(), fills as usize);
            assert!(m.windows(2).all(|w| w[0] < w[1]), "{m:?}");
            assert!(m.iter().all(|&x| x >= 1 && x < points), "{m:?}");
        }
    }
}
