//! Running one case: the campaign on the simulated instrument (ideal or imperfect: [`SoakInstrument`]) with its interruptions and faults, the axes'
//! trajectories recorded for the checks.

use super::*;
use gonio_results::sweeps::SweepReading;

/// What happened during a case, for the checks.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub file: InstrumentFile,
    /// The simulator's record of every axis.
    pub records: Vec<(Axis, MotionRecord)>,
    /// Simulated seconds at the end.
    pub end_s: f64,
    /// Emergency stops: (requested at, next run started at, or the end).
    pub estops: Vec<(f64, f64)>,
    pub points: Vec<PointRecord>,
    /// Sweep readings committed (issue 41), and the segments planned.
    pub sweep_readings: Vec<SweepReading>,
    pub planned_segments: u64,
    pub final_state: CampaignState,
    pub planned_points: u64,
    /// Pause, abort and emergency-stop requests made.
    pub acts: [u64; 3],
    /// What the soak did and when (simulated seconds): runs started and ended, requests made.
    pub timeline: Vec<(f64, String)>,
    /// A sabotage during the run ([`Sabotage::reset_detector_behind_light`]): when the detector's controller was
    /// reset (simulated s), and the arms' pose then.
    pub sabotaged: Option<(f64, SimPose)>,
}

impl Outcome {
    /// Home commands the axis of `role` received at or after `t_s` (simulated).
    pub fn homes_after(&self, role: AxisRole, t_s: f64) -> usize {
        self.records
            .iter()
            .filter(|(a, _)| a.role == role)
            .flat_map(|(_, r)| r.commands.iter())
            .filter(|c| matches!(c.command, MotionCommand::Home) && c.t_s >= t_s)
            .count()
    }
}

pub(super) async fn run_case(
    case: &Case,
    data_dir: &Path,
    sabotage: &Sabotage,
    instrument: &SoakInstrument,
) -> Result<Outcome, String> {
    let mut file = instrument.file().map_err(|e| e.to_string())?;
    let f = &mut file.simulator.faults;
    (f.seed, f.stall_rate, f.garble_rate, f.drop_rate) = (
        case.faults.seed,
        case.faults.stall_rate,
        case.faults.garble_rate,
        case.faults.drop_rate,
    );
    let prepared = prepare_campaign(&case.campaign, "safety.toml", Path::new("."), &file)
        .map_err(|e| format!("generated campaign refused: {e}"))?;
    let mut store = Store::open(data_dir).map_err(|e| e.to_string())?;
    let id = store
        .create_campaign(&prepared.new_campaign(&case.campaign, &instrument.text))
        .map_err(|e| e.to_string())?;
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(&file, None, 1.0)
        .await
        .map_err(|e| e.to_string())?;
    let sim = rig
        .sim()
        .ok_or("the simulated instrument has no simulator")?
        .clone();
    let clock = sim.clock();
    // Held to the end of the case: closing them is not part of the scenario.
    let _ports = scenarios::set_up(&sim, sabotage).await?;
    sim.start_motion_recording();
    let control = Control::new();
    let saboteur = scenarios::spawn_saboteur(&sim, sabotage);
    let sweep_speeds = super::sweep_speeds(case);

    let mut pending = case.interruptions.iter();
    let mut estops: Vec<(f64, f64)> = Vec::new();
    let mut open_estop: Option<f64> = None;
    let mut final_state = None;
    let mut acts = [0u64; 3];
    let mut timeline = Vec::new();
    // Faults may pause a campaign by themselves (three failed points in a row): resume it a few times.
    let runs = case.interruptions.len() + if case.faults.any() { 6 } else { 2 };
    let mut state = CampaignState::Queued;
    for _run in 0..runs {
        if let Some(t) = open_estop.take() {
            estops.push((t, sim.now_s()));
        }
        timeline.push((sim.now_s(), "run started".to_string()));
        let mut task = {
            let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
            tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
        };
        let mut resume_after_s = 0.0;
        let joined = loop {
            let Some(next) = pending.next() else {
                break (&mut task).await;
            };
            let wait = async {
                match next.act {
                    Act::EstopInSweep => sweep_under_way(&sim, &sweep_speeds, next.after_s).await,
                    _ => clock.sleep_s(next.after_s).await,
                }
            };
            tokio::select! {
                r = &mut task => break r,
                _ = wait => {
                    timeline.push((sim.now_s(), format!("{:?} requested", next.act)));
                    resume_after_s = next.resume_after_s;
                    match next.act {
                        Act::Pause => { acts[0] += 1; control.pause() }
                        Act::Abort => { acts[1] += 1; control.abort() }
                        Act::Estop | Act::EstopInSweep => {
                            acts[2] += 1;
                            open_estop.get_or_insert(sim.now_s());
                            control.estop();
                        }
                    }
                }
            }
        };
        state = joined
            .map_err(|e| format!("engine task: {e}"))?
            .map_err(|e| format!("engine error: {e}"))?;
        let progress = store
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .campaign(id)
            .map(|c| format!("{} points done, last error {:?}", c.points_done, c.last_error))
            .unwrap_or_else(|e| format!("no record: {e}"));
        timeline.push((sim.now_s(), format!("run ended {state}: {progress}")));
        match state {
            CampaignState::Completed | CampaignState::Aborted => {
                final_state = Some(state);
                break;
            }
            CampaignState::Paused => {
                clock.sleep_s(resume_after_s).await;
                control.resume();
            }
            other => {
                let last = store
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .campaign(id)
                    .ok()
                    .and_then(|c| c.last_error);
                return Err(format!("run ended {other}: {last:?}"));
            }
        }
    }
    let final_state = match final_state {
        Some(s) => s,
        // Under injected faults a campaign may still be paused by them: the motion checks apply all the same.
        // So may a sabotage (its test then checks the motion before the state).
        None if (case.faults.any() || sabotage.any()) && state == CampaignState::Paused => state,
        None => return Err("the campaign neither completed nor was aborted".into()),
    };
    let end_s = sim.now_s();
    let sabotaged = match saboteur {
        Some(task) if task.is_finished() => {
            let (at, pose, _port) = task.await.map_err(|e| format!("saboteur: {e}"))??;
            Some((at, pose))
        }
        Some(task) => {
            task.abort();
            None
        }
        None => None,
    };
    if let Some(t) = open_estop.take() {
        estops.push((t, end_s));
    }
    let (points, sweep_readings) = {
        let store = store.lock().unwrap_or_else(|e| e.into_inner());
        (
            store.points(id).map_err(|e| e.to_string())?,
            store.sweep_readings(id).map_err(|e| e.to_string())?,
        )
    };
    Ok(Outcome {
        file,
        records: sim.motion_records(),
        end_s,
        estops,
        points,
        sweep_readings,
        planned_segments: prepared.sweep_segments,
        final_state,
        planned_points: prepared.total_points,
        acts,
        timeline,
        sabotaged,
    })
}

/// Returns once an arm has cruised at one of `speeds_deg_s` (a sweep's) for `for_s` simulated seconds in all,
/// sampling the simulated arms' pose every 20 ms; never when no sweep runs.
async fn sweep_under_way(sim: &gonio_simulator::SimInstrument, speeds_deg_s: &[f64], for_s: f64) {
    const STEP_S: f64 = 0.02;
    let clock = sim.clock();
    let mut swept_s = 0.0;
    let mut last = sim.pose();
    loop {
        clock.sleep_s(STEP_S).await;
        let now = sim.pose();
        let speeds = [
            (now.light_deg - last.light_deg).abs() / STEP_S,
            (now.detector_deg - last.detector_deg).abs() / STEP_S,
        ];
        last = now;
        if speeds
            .iter()
            .any(|v| speeds_deg_s.iter().any(|s| (v - s).abs() <= 0.01 * s))
        {
            swept_s += STEP_S;
            if swept_s >= for_s {
                return;
            }
        }
    }
}
