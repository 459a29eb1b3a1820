//! The safety soak: random campaigns with random interleavings of pause, abort and emergency stop, run by the
//! real engine on the simulated instrument, and checked against what the simulator recorded of every motion
//! command and every axis trajectory (`gonio_simulator::recording`). Through the public API, with seeded cases so
//! that the report's numbers are reproducible, and the margins measured instead of only asserted:
//!
//! - the closest the arms came, at any instant, once they were first apart (motors and loads with backlash),
//!   computed exactly on the quadratic pieces of both trajectories, against `safety.min_arm_separation_deg`; the
//!   simulator powers up with both arms at zero, so before they are first apart their separation may only grow;
//! - every commanded target and every trajectory against the axis limits (the smallest margin seen);
//! - the time from each emergency-stop request to the stop command at every axis, on the simulated clock, against
//!   [`ESTOP_DEADLINE_S`] (66 ms: a controller in its pause after a set command takes no stop before the pause is
//!   over); and no axis commanded to move again before the campaign is resumed (after the stop in the order of the
//!   wire, which the record keeps: a move sent at the same simulated instant just before the stop is overridden);
//! - every measured point's read-back pose against the scheduler's own constraint checks (`Constraints`,
//!   `Pose::arm_separation_deg`): the independent reference for what is measured; every sweep reading's geometry
//!   against the same direction rules.
//!
//! A third of the cases sweep (`[[plan.sweeps]]`, issue 41: an arm turning at a constant speed while the meter
//! reads), half of those with no points at all, and with one more emergency stop aimed at a sweep under way
//! ([`Act::EstopInSweep`]), so that the interruptions land in sweeps too: the trajectories
//! above then include every swept path, and an emergency stop is counted as during a sweep when an arm was
//! cruising at one of the case's sweep speeds at that instant (point moves cruise at the arm's top speed, above
//! every sweep's).
//!
//! Each case runs on its own current-thread runtime with tokio's paused clock, the simulator at time scale 1: the
//! instrument takes its real time, the wall clock almost none.
//!
//! The same runs and checks serve the tests (`tests/safety_soak.rs`): a property over random seeds, and the fixed
//! cases of [`scenarios`] (regressions, controllers reset behind the engine's back), checked by [`check`] and
//! inspected through [`Outcome`].

pub mod scenarios;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gonio_campaign::{AcquisitionSection, CalibrationSection, CampaignFile};
use gonio_engine::store::{CampaignState, PointRecord, Store};
use gonio_engine::{Control, Rig, prepare_campaign, run_campaign};
use gonio_instrument::{Axis, AxisRole, InstrumentFile};

use crate::setup::SoakInstrument;
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Kinematics, Pose};
use gonio_scheduler::plan::{GridKind, GridSpec, PlanSpec, SweepSpec};
use gonio_simulator::recording::{MotionCommand, MotionRecord, Piece, check_arm_separation, physical_pieces};
use gonio_simulator::scene::Pose as SimPose;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::SoakError;
pub use scenarios::Sabotage;

mod checks;
mod running;
mod sweeps;

pub use checks::{CaseResult, Rule, check, check_separation, sweep_speeds, sweeping_at};
pub use running::Outcome;
use running::run_case;

/// Longest time from an emergency-stop request to the stop command at every axis (simulated seconds): one
/// pause of the SMC100 driver after a set command ([`SET_GAP`], 65 ms) and one tokio timer tick (1 ms). The
/// engine sends the stop at once (its own latency is well under a millisecond); but the simulated SMC100s lose
/// input for 60 ms after a set command (`[simulator.quirks] smc100_min_command_gap_ms`: the recorded variant,
/// the most demanding reading of the pacing real-hardware drivers use, which every soak sets explicitly
/// ([`crate::setup::recorded_quirks`]); the ideal instrument's default takes every line), so a stop requested
/// just after a move was sent cannot reach that controller before the 60 ms are over: the driver sends it again
/// the moment its pause is over.
/// (The deadline was 50 ms before the controllers lost input; no host can beat 60 ms in that case.)
///
/// [`SET_GAP`]: gonio_driver::smc100::SET_GAP
pub const ESTOP_DEADLINE_S: f64 = gonio_driver::smc100::SET_GAP.as_secs_f64() + 0.001;
/// Slack on angle comparisons (floating-point rounding of degree arithmetic).
const EPS_DEG: f64 = 1e-9;
/// Sample radius of every case (mm).
const SAMPLE_RADIUS_MM: f64 = 12.5;

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetySoakConfig {
    /// Random cases (campaign, interruptions, fault level).
    pub cases: u32,
    pub seed: u64,
    /// The instrument file the cases run on (its faults replaced by each case's).
    pub instrument: SoakInstrument,
}

/// An operator's request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Act {
    Pause,
    Abort,
    Estop,
    /// An emergency stop once an arm has cruised at one of the case's sweep speeds for `after_s` (simulated
    /// seconds, counted from the previous request or the run's start): aimed at a sweep under way. None when
    /// the run ends first.
    EstopInSweep,
}

/// A request made `after_s` simulated seconds after the previous one (or after the run started); for
/// [`Act::EstopInSweep`], after that long of sweeping.
#[derive(Debug, Clone, PartialEq)]
pub struct Interruption {
    pub after_s: f64,
    pub act: Act,
    /// Simulated seconds before a paused campaign is resumed.
    pub resume_after_s: f64,
}

/// Injected device faults (the simulator's): stalled moves, garbled and lost replies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultLevel {
    pub seed: u64,
    pub stall_rate: f64,
    pub garble_rate: f64,
    pub drop_rate: f64,
}

impl FaultLevel {
    pub fn any(&self) -> bool {
        self.stall_rate > 0.0 || self.garble_rate > 0.0 || self.drop_rate > 0.0
    }
}

/// One random case.
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    pub campaign: String,
    pub interruptions: Vec<Interruption>,
    pub faults: FaultLevel,
}

fn round1(x: f64) -> f64 {
    (x * 10.0).round() / 10.0
}

/// A grid of one of three kinds: explicit geometries (tilt and rotation move), an in-plane sweep, or a small
/// isotropic grid; always with one geometry that every constraint allows.
fn random_grid(rng: &mut ChaCha8Rng) -> GridSpec {
    match rng.random_range(0..3u32) {
        0 => {
            let n = rng.random_range(1..8usize);
            let mut points = vec![[30.0, 0.0, 30.0, 180.0]];
            for _ in 0..n {
                let (ti, pi, to, po) = (
                    rng.random_range(0.0..70.0f64),
                    rng.random_range(0.0..360.0f64),
                    rng.random_range(0.0..80.0f64),
                    rng.random_range(0.0..360.0f64),
                );
                points.push([round1(ti), round1(pi), round1(to), round1(po)]);
            }
            let mut grid = GridSpec::new(GridKind::Points);
            grid.points = Some(points);
            grid
        }
        1 => {
            let (ti, step, from, plane) = (
                rng.random_range(0.0..60.0f64),
                rng.random_range(5.0..40.0f64),
                rng.random_range(-70.0..0.0f64),
                rng.random_range(0.0..180.0f64),
            );
            let mut grid = GridSpec::new(GridKind::InPlane);
            grid.theta_i_deg = Some(GridSpec::list_deg(&[round1(ti), 30.0]));
            grid.theta_o_deg = Some(GridSpec::range_deg(round1(from), 70.0, round1(step)));
            grid.plane_phi_deg = Some(GridSpec::list_deg(&[round1(plane)]));
            grid
        }
        _ => {
            let (step, dphi) = (rng.random_range(10.0..60.0f64), rng.random_range(20.0..90.0f64));
            let mut grid = GridSpec::new(GridKind::Isotropic);
            grid.theta_i_deg = Some(GridSpec::range_deg(0.0, 60.0, round1(step)));
            grid.theta_o_deg = Some(GridSpec::list_deg(&[20.0, 50.0]));
            grid.delta_phi_deg = Some(GridSpec::range_deg(0.0, 180.0, round1(dphi)));
            grid
        }
    }
}

fn campaign_text(rng: &mut ChaCha8Rng, (sweeps, sweeps_only): (Vec<SweepSpec>, bool)) -> String {
    let grid = random_grid(rng);
    let all = [450.0, 550.0, 650.0];
    let mut bands: Vec<f64> = all
        .iter()
        .copied()
        .filter(|_| rng.random_bool(0.5))
        .take(2)
        .collect();
    if bands.is_empty() {
        bands.push(all[rng.random_range(0..all.len())]);
    }
    let repeats = rng.random_range(1..=2u32);
    let dark = rng.random_range(1..6u32);
    let reference = rng.random_range(2..9u32);
    let light = round1(rng.random_range(-99.0..-81.0f64));
    let averaging = rng.random_range(1..4u32);
    let settle = round1(rng.random_range(0.0..0.2f64));
    let material = if rng.random_bool(0.5) {
        "coloured-plastic"
    } else {
        "spectralon"
    };
    let mut plan = PlanSpec {
        bands_nm: Some(bands),
        repeats,
        reciprocity: false,
        grid: (!sweeps_only).then_some(grid),
        sweeps,
        ..PlanSpec::default()
    };
    plan.calibration.dark_every_points = Some(dark);
    plan.calibration.reference_every_points = Some(reference);
    // The detector faces the source: the direct beam.
    plan.calibration.reference_pose_deg = Some(
        [
            ("light".to_string(), light),
            ("detector".to_string(), light + 180.0),
        ]
        .into_iter()
        .collect(),
    );
    CampaignFile::new("safety", SAMPLE_RADIUS_MM, plan)
        .with_calibration(CalibrationSection::default())
        .with_acquisition(AcquisitionSection {
            averaging: Some(averaging),
            settle_s: Some(settle),
            ..AcquisitionSection::default()
        })
        .with_material_preset(material)
        .to_toml()
        .expect("a campaign of numbers and names serialises")
}

fn interruption(rng: &mut ChaCha8Rng) -> Interruption {
    // Weights 2 : 1 : 4 (pause, abort, emergency stop), as the property test.
    let act = match rng.random_range(0..7u32) {
        0 | 1 => Act::Pause,
        2 => Act::Abort,
        _ => Act::Estop,
    };
    // Mostly within the first tens of seconds of a run, sometimes at once (start-up, homing, calibration).
    let after_s = if rng.random_range(0..5u32) == 0 {
        rng.random_range(0.0..0.5)
    } else {
        rng.random_range(0.5..40.0)
    };
    Interruption {
        after_s,
        act,
        resume_after_s: rng.random_range(0.0..5.0),
    }
}

fn faults(rng: &mut ChaCha8Rng) -> FaultLevel {
    if rng.random_range(0..3u32) < 2 {
        return FaultLevel::NONE;
    }
    let seed = rng.random::<u64>();
    let stall_rate = [0.0, 0.05, 0.2][rng.random_range(0..3usize)];
    let garble_rate = [0.0, 0.01][rng.random_range(0..2usize)];
    FaultLevel {
        seed,
        stall_rate,
        garble_rate,
        drop_rate: garble_rate / 2.0,
    }
}

/// The `index`-th case of `seed`: each case has its own stream, so a case can be rerun alone.
pub fn case(seed: u64, index: u32) -> Case {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (u64::from(index) << 32) ^ 0x5afe_7e57);
    let mut sweep_rng = ChaCha8Rng::seed_from_u64(seed ^ (u64::from(index) << 32) ^ 0x5eeb_5eeb);
    let sweeps = sweeps::random_sweeps(&mut sweep_rng);
    let sweeping = !sweeps.0.is_empty();
    let campaign = campaign_text(&mut rng, sweeps);
    let n = rng.random_range(0..6usize);
    let mut interruptions: Vec<Interruption> = (0..n).map(|_| interruption(&mut rng)).collect();
    if sweeping {
        // The sweeps come after start-up, calibration and the points, mostly later than the interruptions
        // above: one more emergency stop, aimed at a sweep under way.
        interruptions.push(Interruption {
            after_s: sweep_rng.random_range(0.05..3.0),
            act: Act::EstopInSweep,
            resume_after_s: sweep_rng.random_range(0.0..5.0),
        });
    }
    let faults = faults(&mut rng);
    Case {
        campaign,
        interruptions,
        faults,
    }
}

/// Longest simulated time a random case may take (under the paused clock a hang turns into it at once).
const CASE_LIMIT: Duration = Duration::from_secs(7 * 24 * 3600);
/// Longest simulated time a fixed scenario may take (a few points).
const SCENARIO_LIMIT: Duration = Duration::from_secs(24 * 3600);

/// Run `case` with `sabotage` on a runtime of its own with tokio's paused clock, within `limit` of simulated time.
/// The outer `Err`: no runtime or directory; the inner one: the case could not run.
fn run_paused(
    case: &Case,
    sabotage: &Sabotage,
    limit: Duration,
    instrument: &SoakInstrument,
) -> Result<Result<Outcome, String>, SoakError> {
    let dir = tempfile::tempdir().map_err(SoakError::io("temporary directory for a safety case"))?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(SoakError::io("cannot start the async runtime"))?;
    Ok(rt.block_on(async {
        tokio::time::timeout(limit, run_case(case, dir.path(), sabotage, instrument))
            .await
            .unwrap_or_else(|_| {
                Err(format!(
                    "no end within {} simulated hours",
                    limit.as_secs() / 3600
                ))
            })
    }))
}

/// Run one case on the ideal simulated instrument and check it.
pub fn run_and_check(index: u32, case: &Case) -> Result<CaseResult, SoakError> {
    run_and_check_on(index, case, &SoakInstrument::simulated())
}

/// Run one case on `instrument` and check it.
pub fn run_and_check_on(
    index: u32,
    case: &Case,
    instrument: &SoakInstrument,
) -> Result<CaseResult, SoakError> {
    Ok(
        match run_paused(case, &Sabotage::default(), CASE_LIMIT, instrument)? {
            Ok(o) => check(index, case, &o),
            Err(e) => CaseResult {
                index,
                faults: case.faults.any(),
                acts: [0; 3],
                final_state: None,
                planned_points: 0,
                points: 0,
                planned_segments: 0,
                segments: 0,
                sweep_readings: 0,
                move_commands: 0,
                closest_motor_deg: f64::NAN,
                closest_load_deg: f64::NAN,
                command_margin_deg: f64::NAN,
                trajectory_margin_deg: f64::NAN,
                extreme_command: None,
                estop_latencies_s: Vec::new(),
                estops_in_sweeps_s: Vec::new(),
                violations: vec![format!("case did not run: {e}")],
                broken: vec![Rule::Other],
            },
        },
    )
}

/// Run a fixed case under `sabotage` (none: `Sabotage::default()`) and return what happened, for [`check`] and a
/// test's own questions; a case that could not run is an error.
pub fn run_scenario(case: &Case, sabotage: &Sabotage) -> Result<Outcome, SoakError> {
    run_paused(case, sabotage, SCENARIO_LIMIT, &SoakInstrument::simulated())?.map_err(SoakError::Setup)
}

/// Run case `index` of `seed` again and describe it for an investigation ([`describe`]).
pub fn trace(seed: u64, index: u32, from_s: f64, to_s: f64) -> Result<String, SoakError> {
    let case = case(seed, index);
    let o = run_paused(
        &case,
        &Sabotage::default(),
        CASE_LIMIT,
        &SoakInstrument::simulated(),
    )?
    .map_err(SoakError::Setup)?;
    let result = check(index, &case, &o);
    Ok(describe(&case, &o, &result, from_s, to_s))
}

/// A case for an investigation: the case, its verdict, what the soak did when, and every motion command and
/// profile change of the arms (physical degrees; the segments of each profile in controller degrees) between
/// `from_s` and `to_s` of simulated time.
pub fn describe(case: &Case, o: &Outcome, result: &CaseResult, from_s: f64, to_s: f64) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(out, "{case:#?}\n{result:#?}");
    for (t, what) in &o.timeline {
        let _ = writeln!(out, "{t:10.4} s  {what}");
    }
    for (axis, record) in &o.records {
        if !matches!(axis.role, AxisRole::LightArm | AxisRole::DetectorArm) {
            continue;
        }
        let phys = |p: f64| f64::from(axis.direction) * (p - axis.zero_offset_deg);
        for c in record
            .commands
            .iter()
            .filter(|c| c.t_s >= from_s && c.t_s <= to_s)
        {
            let _ = writeln!(out, "{:>9} {:10.4} s  command {:?}", axis.name, c.t_s, c.command);
        }
        for c in record.changes.iter().filter(|c| c.t_s >= from_s && c.t_s <= to_s) {
            let _ = writeln!(
                out,
                "{:>9} {:10.4} s  change {:?}: motor {:.4} deg, load {:.4} deg, rest {:.4} deg, end {:?}, \
                 segments (t0, end, p0) {:?}",
                axis.name,
                c.t_s,
                c.kind,
                phys(c.motor_deg),
                phys(c.load_deg),
                phys(c.rest_deg),
                c.end,
                c.segments
                    .iter()
                    .map(|s| (s.t0_s, s.end_s(), s.p0_deg))
                    .collect::<Vec<_>>()
            );
        }
    }
    out
}

/// Everything the safety soak measured.
#[derive(Debug, Clone)]
pub struct SafetySoakReport {
    pub config: SafetySoakConfig,
    pub min_separation_deg: f64,
    pub cases: Vec<CaseResult>,
    pub wall_s: f64,
}

impl SafetySoakReport {
    /// Every broken invariant, in words; empty when the soak passed.
    pub fn violations(&self) -> Vec<String> {
        self.cases
            .iter()
            .flat_map(|c| c.violations.iter().map(move |v| format!("case {}: {v}", c.index)))
            .collect()
    }

    /// Cases that broke `rule`.
    pub fn broke(&self, rule: Rule) -> usize {
        self.cases.iter().filter(|c| c.broken.contains(&rule)).count()
    }

    /// Pause, abort and emergency-stop requests, all cases together.
    pub fn acts(&self) -> [u64; 3] {
        let mut a = [0; 3];
        for c in &self.cases {
            for (total, n) in a.iter_mut().zip(c.acts) {
                *total += n;
            }
        }
        a
    }

    pub fn move_commands(&self) -> u64 {
        self.cases.iter().map(|c| c.move_commands).sum()
    }

    /// Smallest finite value of a per-case measure.
    fn min_of(&self, f: impl Fn(&CaseResult) -> f64) -> f64 {
        self.cases
            .iter()
            .map(f)
            .filter(|x| x.is_finite())
            .fold(f64::INFINITY, f64::min)
    }

    pub fn closest_motor_deg(&self) -> f64 {
        self.min_of(|c| c.closest_motor_deg)
    }
    pub fn closest_load_deg(&self) -> f64 {
        self.min_of(|c| c.closest_load_deg)
    }
    pub fn command_margin_deg(&self) -> f64 {
        self.min_of(|c| c.command_margin_deg)
    }
    pub fn trajectory_margin_deg(&self) -> f64 {
        self.min_of(|c| c.trajectory_margin_deg)
    }

    /// The case and axis of the commanded target closest to a limit.
    pub fn extreme_command(&self) -> Option<(String, f64, f64)> {
        self.cases
            .iter()
            .filter(|c| c.command_margin_deg.is_finite())
            .min_by(|a, b| a.command_margin_deg.total_cmp(&b.command_margin_deg))
            .and_then(|c| c.extreme_command.clone())
    }

    /// Cases that planned sweeps; sweep readings committed, all cases.
    pub fn sweep_cases(&self) -> usize {
        self.cases.iter().filter(|c| c.planned_segments > 0).count()
    }
    pub fn sweep_readings(&self) -> u64 {
        self.cases.iter().map(|c| c.sweep_readings).sum()
    }

    /// Emergency stops requested during a sweep: the time to the stop at the last axis (s), sorted.
    pub fn estops_in_sweeps_s(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self
            .cases
            .iter()
            .flat_map(|c| c.estops_in_sweeps_s.iter().copied())
            .collect();
        v.sort_by(f64::total_cmp);
        v
    }

    pub fn estop_latencies_s(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self
            .cases
            .iter()
            .flat_map(|c| c.estop_latencies_s.iter().copied())
            .collect();
        v.sort_by(f64::total_cmp);
        v
    }

    /// Final states: completed, aborted, paused (by faults), did not run.
    pub fn final_states(&self) -> [u64; 4] {
        let mut s = [0; 4];
        for c in &self.cases {
            let k = match c.final_state {
                Some(CampaignState::Completed) => 0,
                Some(CampaignState::Aborted) => 1,
                Some(_) => 2,
                None => 3,
            };
            s[k] += 1;
        }
        s
    }
}

/// Run the safety soak: `cases` seeded random cases, each checked.
pub fn run_safety_soak(cfg: &SafetySoakConfig) -> Result<SafetySoakReport, SoakError> {
    let wall = Instant::now();
    let file = cfg.instrument.file()?;
    let mut cases = Vec::new();
    for i in 0..cfg.cases {
        cases.push(run_and_check_on(i, &case(cfg.seed, i), &cfg.instrument)?);
    }
    Ok(SafetySoakReport {
        config: cfg.clone(),
        min_separation_deg: file.instrument.safety.min_arm_separation_deg,
        cases,
        wall_s: wall.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases_are_reproducible_and_valid() {
        let file = InstrumentFile::simulated();
        let (mut sweeping, mut sweeps_only) = (0, 0);
        for i in 0..60 {
            let a = case(3, i);
            assert_eq!(a, case(3, i));
            let p = prepare_campaign(&a.campaign, "safety.toml", Path::new("."), &file)
                .unwrap_or_else(|e| panic!("case {i}: {e}\n{}", a.campaign));
            sweeping += usize::from(p.sweep_segments > 0);
            sweeps_only += usize::from(p.sweep_segments > 0 && p.total_points == 0);
        }
        assert_ne!(case(3, 0), case(3, 1));
        // About a third of the cases sweep, half of those without points.
        assert!((10..=30).contains(&sweeping), "{sweeping} of 60 cases sweep");
        assert!(sweeps_only >= 3, "{sweeps_only} cases sweep only");
    }
}
