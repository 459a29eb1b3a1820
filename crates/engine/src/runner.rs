//! The run loop: [`run_campaign`] and [`run_prepared_campaign`].
//!
//! The run drives the instrument through the engine's parts, which know nothing of campaigns or stores:
//! [`crate::motion`] (device supervision, collision-safe moves, homing) and [`crate::acquisition`] (the meter's
//! configuration, a reading, the measurement equation as a pure function). Its own parts (each an `impl Run`
//! block): `acquire` (wheel, detector, one point committed), `calibrate` (darks, normalisation, the operator
//! protocol), `passes` (an adaptive plan's passes), `reference` (the relative method's transfer), `sweep` (the
//! sweeps after the points, a segment per transaction); this file:
//! start-up, the loop over the steps, pause requests and the final state.
//!
//! Order of work: rebuild the campaign (plan and schedule) from the text stored with it, materials included
//! (its `[resolved]` table: no file is read), or take the prepared campaign it was handed when that is provably
//! the same (`PreparedCampaign::reuse_for`); connect the sample (dry-runs); home axes that lost their
//! reference; a calibration preamble (darks for every band, then the normalisation readings for every band:
//! direct beam for the absolute method, reference sample for the relative one) on every start and resume; then
//! the schedule's steps from the first uncommitted point, with the schedule's own dark and normalisation steps in
//! between; for an adaptive plan, pass after pass (`passes`).
//!
//! Per point: plan the move from where the axes really are (read-back) to the step's pose with the scheduler's
//! time model (arm-collision-safe phases, backlash approach waypoints), run each phase's axes concurrently
//! (`start_move` on each, then `wait_arrived`), settle, select the band, read, subtract the dark, apply the
//! measurement equation with the normalisation reading extrapolated in time from the last two (source drift),
//! commit. Absolute: `f = (S - S_dark) / (P Omega cos theta_o)` with `P` the direct beam. Relative: the reference
//! sample read at its reference geometry, see [`reference`].
//!
//! Operator steps (remove the sample for the direct beam; swap the reference in and out) put the campaign in
//! `waiting-operator` with the instruction until confirmed; in dry-runs the simulated sample holder changes on
//! the confirmation (or at once with `simulate_operator`), so the simulator measures what a person would have
//! mounted.
//!
//! States: `running`; `pausing` as soon as a pause is requested (a watcher beside the loop records it in the
//! store and says so in an event), `running` again if it is withdrawn first; `paused` at the next safe point.
//!
//! Faults: transient errors (timeouts, garbled replies) are retried a bounded number of times; a lost device
//! is reconnected (and re-homed when it lost its reference); what still fails becomes a failed-point record with
//! the device's reason, and three failed points in a row, any calibration failure, or a device that cannot be
//! reconnected pause the campaign with the reason. Nothing waits without a deadline: the drivers bound every
//! exchange.
//!
//! Disk trouble: a store write that fails with a condition a person can fix (disk or quota full, read-only
//! file or directory, I/O error, file cannot be opened; see `StoreError::is_write_failure`) pauses the campaign
//! at once, before any further move, with a reason naming the store file and SQLite's error. The point being
//! committed is not in the store (each point is one transaction), so resuming measures it again: nothing
//! committed is lost and nothing is stored twice. When even the pause cannot be written, the store keeps the
//! state in memory for status requests (`Store::set_state`).

mod acquire;
mod calibrate;
mod eta;
mod finish;
mod passes;
mod reference;
mod sweep;

use crate::align::correction::PoseCorrection;
use crate::align::file::CalibrationFile;
use crate::characterise::correction::DetectorCorrection;
use std::sync::{Arc, Mutex};

use gonio_brdf::measurement::Reading;
use gonio_instrument::InstrumentFile;
use gonio_instrument::signature::SignatureUncertainty;
use gonio_scheduler::schedule::{Step, StepKind};

use crate::calibration::{Darks, Normalisations};
use crate::control::{Control, Event};
use crate::error::EngineError;
use crate::motion::{Device, Motion, MotionError};
use crate::prepare::PreparedCampaign;
use crate::rig::{Held as Holder, Rig, SampleHolder};
use crate::store::{CalibrationRecord, CampaignId, CampaignState, PointRecord, Store, StoreError};
use gonio_campaign::{Method, NextPass, Prepared, Sources};
use reference::Transfer;

/// Failed points in a row after which the campaign pauses instead of recording more failures.
const MAX_FAILED_IN_ROW: u32 = 3;

/// Why the loop stopped before the end.
#[derive(Debug)]
enum Interrupt {
    /// Something a person must see to: pause with the reason (logged as a warning).
    Pause(String),
    /// A person asked for the pause: pause with this message (logged at info: nothing went wrong).
    PauseRequested(&'static str),
    /// A person asked for the abort.
    Abort,
    Estop,
    /// Store write failure (disk full, read-only): pause with the reason.
    StoreWrite(String),
    /// Anything else the engine cannot continue after.
    Fatal(EngineError),
}

impl From<MotionError> for Interrupt {
    fn from(e: MotionError) -> Interrupt {
        match e {
            MotionError::Estop => Interrupt::Estop,
            MotionError::NeedsOperator(reason) => Interrupt::Pause(reason),
            // A device's reason becomes a failed point (or a pause, during calibration); no safe move pauses.
            MotionError::Device(reason) | MotionError::Impossible(reason) => {
                Interrupt::Fatal(EngineError::Device(reason))
            }
        }
    }
}

/// The relative method's reference at run time.
struct ReferenceRun {
    name: String,
    transfer: Transfer,
    geometry: gonio_scheduler::kinematics::Geometry,
}

struct Run<'a> {
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &'a Rig,
    control: Control,
    /// The axes (where they are, safe moves) and the supervision of every device.
    motion: Motion<'a>,
    c: Prepared,
    file: InstrumentFile,
    axis_names: Vec<String>,
    /// Instrument time of this session's start in campaign time (continues across resumes).
    t_base: f64,
    t_clock0: f64,
    configured_nm: Option<f64>,
    /// The samples a reading averages that the meter was last configured for by `read_parts` (None: not yet).
    configured_averaging: Option<u32>,
    wheel_at: Option<u8>,
    darks: Darks,
    /// Normalisation readings per band, net of dark, in time order: direct beam (absolute) or reference sample
    /// (relative).
    norm: Normalisations,
    failed_in_row: u32,
    /// Dry-runs: the sample holder the (simulated) operator works, with the sample's ground truth.
    holder: Option<Arc<dyn SampleHolder>>,
    reference: Option<ReferenceRun>,
    /// The stored alignment calibration applied to every point's pose (crate::align::correction).
    correction: Option<PoseCorrection>,
    /// The stored characterisation applied to every reading and value (crate::characterise::correction).
    detector: Option<DetectorCorrection>,
    /// The instrument signature as the instrument file knows it: the uncertainty of every value no measured
    /// signature was subtracted from.
    signature_u: SignatureUncertainty,
    done: u64,
    total: u64,
    /// The pass being measured: its predicted duration, the index after its last point, and the predicted
    /// seconds per point of all passes so far (ETA of an adaptive plan).
    pass_total_s: f64,
    pass_end: u64,
    s_per_point: f64,
    /// Predicted time from the campaign's start to the start of the pass being measured (s).
    pass_start_s: f64,
    /// This run's first measured point: (instrument time, predicted time since the campaign's start), from which
    /// the ETA learns how the instrument keeps to the prediction ([`Run::eta_pace`]).
    eta_anchor: Option<(f64, f64)>,
    /// An adaptive plan's committed points read back so far (geometry, BRDF), and the index they reach.
    measured: Vec<(gonio_scheduler::kinematics::Geometry, Option<f64>)>,
    measured_to: u64,
    /// The adaptive planner's memory of the passes before (each candidate's nearest measured points).
    batch_memo: gonio_scheduler::adaptive::BatchMemo,
    /// An adaptive plan's first pass of sweeps as its planner takes it (binned readings), once read.
    swept: Option<Vec<(gonio_scheduler::kinematics::Geometry, Option<f64>)>>,
    /// The lag of each swept axis (by name) behind its commanded profile (s), from the last sweep that measured
    /// it: a sweep too short to measure its own uses it (runner::sweep).
    sweep_lags: std::collections::BTreeMap<String, f64>,
}

/// Run (or resume from `store.next_index(id)`) one stored campaign to a final or paused state.
/// The stored text is parsed and ordered again.
pub async fn run_campaign(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &Rig,
    control: Control,
) -> Result<CampaignState, EngineError> {
    run(store, id, rig, control, None).await
}

/// [`run_campaign`] for a campaign this process just prepared: `prepared` is taken instead of parsing and
/// ordering the stored text again when it is provably what that text parses to (crate::prepare's module doc).
pub async fn run_prepared_campaign(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &Rig,
    control: Control,
    prepared: &PreparedCampaign,
) -> Result<CampaignState, EngineError> {
    run(store, id, rig, control, Some(prepared)).await
}

pub(crate) async fn run(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &Rig,
    control: Control,
    prepared: Option<&PreparedCampaign>,
) -> Result<CampaignState, EngineError> {
    control.clear_requests();
    control.attach_rig(rig);
    let rec = lock(&store).campaign(id)?;
    if rec.state.is_final() {
        return Ok(rec.state);
    }
    let not_runnable = |message: String| EngineError::NotRunnable { id, message };
    let file = InstrumentFile::parse(&rec.instrument_toml, "<stored instrument file>")
        .map_err(|e| not_runnable(format!("its stored instrument file is no longer valid: {e}")))?;
    if file.instrument != rig.file().instrument {
        return Err(not_runnable(format!(
            "it was submitted for instrument {:?}, the connected instrument is {:?} with a different description",
            file.instrument.name,
            rig.file().instrument.name
        )));
    }
    // Prepared in this process moments ago (`gonio run`, the daemon's queue): the very campaign the stored text
    // parses to, already planned and ordered (crate::prepare's module doc). Otherwise the stored text is parsed.
    let c = match prepared.and_then(|p| p.reuse_for(&rec.campaign_toml, &file)) {
        Some(c) => c,
        None => {
            let origin = format!("<stored campaign {id}>");
            gonio_campaign::load_and_prepare(&rec.campaign_toml, &origin, &Sources::Stored, &file)
                .map_err(|e| not_runnable(format!("its stored campaign file no longer validates: {e}")))?
        }
    };
    let total = c.total_points();
    // An adaptive campaign that reached its target error early records the points it measured as its total.
    let adaptive_ended_early = c.adaptive.is_some() && rec.total_points < total;
    if total != rec.total_points && !adaptive_ended_early {
        return Err(not_runnable(format!(
            "the stored campaign plans {total} points now but {} when submitted",
            rec.total_points
        )));
    }
    let total = total.min(rec.total_points);
    if c.campaign.dry_run != rig.is_dry_run() {
        return Err(not_runnable(
            "the campaign's dry-run flag does not match the connected instrument".into(),
        ));
    }
    let relative = match (&c.campaign.calibration.reference, c.campaign.calibration.method) {
        (Some(r), Method::Relative) => Some(r),
        _ => None,
    };
    let holder = match &c.campaign.material {
        Some(m) => rig.sample_holder(m, relative.map(|r| &r.material), c.campaign.sample_radius_mm)?,
        None => None,
    };
    let reference = relative.map(|r| ReferenceRun {
        name: r.name.clone(),
        transfer: Transfer::new(r.material.clone(), &r.geometry),
        geometry: r.geometry,
    });
    // The alignment stored with the campaign: the same on every resume, and only for the instrument file it was
    // made for.
    let (correction, detector) = match &rec.alignment_toml {
        Some(text) => {
            let origin = format!("<alignment stored with campaign {id}>");
            let cal = CalibrationFile::parse(text, &origin)
                .and_then(|cal| cal.check_instrument(&rec.instrument_toml, &origin).map(|()| cal))
                .map_err(|e| not_runnable(e.to_string()))?;
            (
                Some(PoseCorrection::new(
                    &file.instrument,
                    cal.params(&file.instrument),
                )),
                cal.detector.clone().map(DetectorCorrection::new),
            )
        }
        None => (None, None),
    };
    let signature_u = SignatureUncertainty::from_detector(&file.instrument.detector)
        .map_err(|e| not_runnable(e.to_string()))?;
    let faults_to = control.clone();
    let motion = Motion::new(
        rig,
        c.time.clone(),
        c.campaign.acquisition.retries,
        control.clone(),
    )
    .report_faults_to(Arc::new(move |message: &str| {
        tracing::warn!(campaign = %id, "{message}");
        faults_to.emit(Event::Fault {
            campaign: id,
            message: message.to_string(),
        });
    }));
    let clock = motion.clock();
    let (done, t_last) = {
        let s = lock(&store);
        let done = s.next_index(id)?;
        let last_point = s
            .points_from(id, done.saturating_sub(1))?
            .last()
            .map(|p| p.t_s)
            .unwrap_or(0.0);
        let last_cal = s.calibrations(id)?.iter().map(|c| c.t_s).fold(0.0f64, f64::max);
        (done, last_point.max(last_cal))
    };
    let axis_names = file.instrument.axes.iter().map(|a| a.name.clone()).collect();
    let mut run = Run {
        store,
        id,
        rig,
        control,
        motion,
        c,
        file,
        axis_names,
        t_base: if done > 0 || t_last > 0.0 {
            t_last + 1.0
        } else {
            0.0
        },
        t_clock0: clock.now_s(),
        configured_nm: None,
        configured_averaging: None,
        wheel_at: None,
        darks: Darks::default(),
        norm: Normalisations::default(),
        failed_in_row: 0,
        holder,
        reference,
        correction,
        detector,
        signature_u,
        done,
        total,
        pass_total_s: 0.0,
        pass_end: total,
        s_per_point: 0.0,
        pass_start_s: 0.0,
        eta_anchor: None,
        measured: Vec::new(),
        measured_to: 0,
        batch_memo: gonio_scheduler::adaptive::BatchMemo::new(),
        swept: None,
        sweep_lags: std::collections::BTreeMap::new(),
    };
    let outcome = {
        let watch = follow_pause_requests(Arc::clone(&run.store), id, run.control.clone());
        tokio::select! {
            outcome = run.go() => outcome,
            never = watch => match never {},
        }
    };
    run.finish(outcome).await
}

/// Beside the run loop: reflect pause requests in the store and the events at once (`running` -> `pausing`,
/// and back when the pause is withdrawn before the safe point). Other states are the loop's to set.
async fn follow_pause_requests(
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    control: Control,
) -> std::convert::Infallible {
    loop {
        let n = control.notified();
        tokio::pin!(n);
        n.as_mut().enable();
        reflect_pause(&store, id, &control);
        n.await;
    }
}

fn reflect_pause(store: &Arc<Mutex<Store>>, id: CampaignId, control: &Control) {
    let mut s = lock(store);
    let Ok(now) = s.state(id) else { return };
    let next = match (now, control.pause_requested()) {
        (CampaignState::Running, true) => CampaignState::Pausing,
        (CampaignState::Pausing, false) => CampaignState::Running,
        _ => return,
    };
    match s.set_state(id, next, None) {
        Ok(()) => {
            drop(s);
            tracing::info!(campaign = %id, state = %next, "pause request");
            control.emit(Event::State {
                campaign: id,
                state: next,
                message: (next == CampaignState::Pausing)
                    .then(|| "pause requested: pausing at the next safe point".to_string()),
            });
        }
        // The loop meets the same store at its next write and pauses for it.
        Err(e) => tracing::warn!(campaign = %id, "cannot record the state {next}: {e}"),
    }
}

fn lock(store: &Arc<Mutex<Store>>) -> std::sync::MutexGuard<'_, Store> {
    store.lock().unwrap_or_else(|e| e.into_inner())
}

impl<'a> Run<'a> {
    fn t(&self) -> f64 {
        self.t_base + (self.motion.clock().now_s() - self.t_clock0)
    }

    fn emit_state(&self, state: CampaignState, message: Option<String>) {
        self.control.emit(Event::State {
            campaign: self.id,
            state,
            message,
        });
    }

    /// A store operation; write failures pause, anything else is fatal.
    fn st<T>(&self, f: impl FnOnce(&mut Store) -> Result<T, StoreError>) -> Result<T, Interrupt> {
        let mut s = lock(&self.store);
        f(&mut s).map_err(|e| {
            if e.is_write_failure() {
                Interrupt::StoreWrite(e.to_string())
            } else {
                Interrupt::Fatal(e.into())
            }
        })
    }

    /// A pending request at a safe point.
    fn safe_point(&self) -> Result<(), Interrupt> {
        if self.control.estop_requested() {
            return Err(Interrupt::Estop);
        }
        if self.control.abort_requested() {
            return Err(Interrupt::Abort);
        }
        if self.control.pause_requested() {
            return Err(Interrupt::PauseRequested("paused by request"));
        }
        Ok(())
    }

    async fn go(&mut self) -> Result<(), Interrupt> {
        self.st(|s| s.set_state(self.id, CampaignState::Running, None))?;
        self.emit_state(CampaignState::Running, None);
        self.progress(None);

        let ids = self.rig.identities().await;
        for (name, identity) in &ids {
            self.st(|s| s.record_device(self.id, name, identity))?;
        }
        // Reference every axis (the arms in a collision-safe order) and learn where it is.
        self.motion.reference_all().await?;

        // An adaptive plan's first pass of sweeps, before any point (their closing calibration is the points'
        // preamble when they ran in this session).
        let mut swept_now = false;
        if self.c.sweeps_first() && self.done == 0 {
            let left = self.c.sweeps.as_ref().map_or(0, |s| s.schedule.steps.len());
            if (self.st(|s| s.sweep_segments_done(self.id))? as usize) < left {
                self.run_sweeps(false).await?;
                swept_now = true;
            }
        }
        if self.done >= self.total {
            // The points are all in (or there are none): what is left is the sweeps.
            return self.run_sweeps(false).await;
        }
        // The pass holding the first uncommitted point: the schedule itself, or for an adaptive plan the pass the
        // committed points lead to (replayed from the store: gonio_campaign::passes).
        let Some(mut pass) = self.locate_pass()? else {
            // An adaptive campaign whose planner had already stopped when it was interrupted.
            return self.run_sweeps(false).await;
        };
        let steps = &pass.schedule.steps;
        let within = self.done - pass.first_index;
        let start = steps
            .iter()
            .enumerate()
            .filter(|(_, s)| s.kind == StepKind::Measure)
            .nth(usize::try_from(within).unwrap_or(usize::MAX))
            .map_or(steps.len(), |(i, _)| i);
        if self.done > 0 {
            tracing::info!(campaign = %self.id, from = self.done, "resuming");
        }

        let bands = self.c.plan.bands_nm.clone();
        let fresh = self.done == 0 && self.t_base == 0.0 && !swept_now;
        if fresh {
            let steps = pass.schedule.steps.clone();
            self.start_up(&steps).await?;
        }
        // Calibration preamble: darks and the normalisation readings (direct beam or reference sample) for every
        // band, on every (re)start. On a fresh start the schedule's own leading dark and reference steps are that
        // preamble (so the run follows the predicted steps); a resume, or a plan without them, gets the engine's
        // own.
        let leading = pass.schedule.steps.get(..start).unwrap_or_default();
        let scheduled_preamble = fresh
            && leading.iter().any(|s| s.kind == StepKind::Dark)
            && leading.iter().any(|s| s.kind == StepKind::Reference);
        let mut i = if scheduled_preamble || swept_now {
            0
        } else {
            self.darks_all(&bands).await?;
            self.normalise(&bands, None).await?;
            start
        };
        loop {
            self.follow_pass(&pass);
            self.run_steps(&pass.schedule.steps, i, &bands).await?;
            match self.next_pass(&pass)? {
                Some(next) => {
                    pass = next;
                    i = 0;
                }
                None => {
                    self.close_passes(&pass, &bands).await?;
                    return self.run_sweeps(true).await;
                }
            }
        }
    }

    /// The schedule's steps from `i` on.
    async fn run_steps(&mut self, steps: &[Step], mut i: usize, bands: &[f64]) -> Result<(), Interrupt> {
        while i < steps.len() {
            self.safe_point()?;
            let Some(step) = steps.get(i) else { break };
            match step.kind {
                StepKind::Dark => {
                    self.darks_all(bands).await?;
                    i += 1;
                }
                StepKind::Reference => {
                    // One operator session for a run of consecutive reference steps.
                    let mut group = Vec::new();
                    let pose = step.pose;
                    while let Some(s) = steps.get(i).filter(|s| s.kind == StepKind::Reference) {
                        if let Some(b) = s.band_nm {
                            group.push(b);
                        }
                        i += 1;
                    }
                    if group.is_empty() {
                        group = bands.to_vec();
                    }
                    self.normalise(&group, Some(pose)).await?;
                }
                StepKind::Measure => {
                    let next_start = steps.get(i + 1).map(|s| s.start_s);
                    self.measure(step, next_start).await?;
                    i += 1;
                }
            }
        }
        Ok(())
    }

    /// Bring the instrument to the state the schedule starts from (its first step's pose, the wheel on its first
    /// step's position), then start the campaign's clock. Homing before this and the move here depend on where
    /// the devices were found, which no plan can know: they are start-up, logged, and not instrument time of
    /// the plan (so that the schedule's predicted duration is comparable with the run's).
    async fn start_up(&mut self, steps: &[Step]) -> Result<(), Interrupt> {
        if let Some(first) = steps.first() {
            self.motion.move_to(&first.pose).await?;
        }
        if let Some(p) = steps.iter().find_map(|s| s.wheel_position) {
            self.wheel_to(p).await?;
        }
        let now = self.motion.clock().now_s();
        tracing::info!(campaign = %self.id, start_up_s = now - self.t_clock0, "instrument referenced and at the schedule's start");
        self.t_clock0 = now;
        Ok(())
    }
}
