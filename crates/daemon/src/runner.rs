//! The run loop behind [`crate::engine::run_campaign`].
//!
//! Order of work: rebuild the campaign (plan and schedule) from the text stored with it, materials included
//! (its `[resolved]` table: no file is read), or take it as this process just prepared it when that is provably
//! the same (`crate::engine::take_prepared`); connect the sample (dry-runs); home axes that lost their
//! reference; a calibration preamble (darks for every band, then the normalisation readings for every band:
//! direct beam for the absolute method, reference sample for the relative one) on every start and resume; then
//! the schedule's steps from the first uncommitted point, with the schedule's own dark and normalisation steps in
//! between.
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

mod reference;
mod rehome;

use std::collections::BTreeMap;
use std::future::Future;
use std::sync::{Arc, Mutex};

use gonio_brdf::measurement::{
    AbsoluteReadings, Footprint, MeasurementError, MeasurementGeometry, Reading, RelativeReadings,
    ValidityLimits, absolute_brdf, relative_brdf,
};
use gonio_brdf::{Direction, Wavelength};
use gonio_driver::{DetectorConfig, DriverError, ErrorKind, PowerRange};
use gonio_instrument::{AxisRole, InstrumentFile};
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose, ROLES};
use gonio_scheduler::schedule::{Step, StepKind};
use gonio_simulator::optics::{Optics, SampleSpec};

use crate::control::{Control, Event};
use crate::engine::{EngineError, PreparedCampaign};
use crate::rig::{Rig, RigAxis, futures_join_all};
use crate::store::{CalibrationRecord, CampaignId, CampaignState, PointRecord, Store, StoreError};
use gonio_campaign::{Method, NextPass, Prepared, Range, Sources};
use reference::Transfer;

/// Failed points in a row after which the campaign pauses instead of recording more failures.
const MAX_FAILED_IN_ROW: u32 = 3;
/// Relative standard uncertainty of one reading from the source's short-term noise and the meter's linearity.
const READING_REL_STD: f64 = 2.0e-4;
/// Standard uncertainty of one reading from the range (converter resolution, offset), relative to full scale.
const READING_RANGE_STD: f64 = 2.0e-5;
/// Relative standard uncertainty of the detector's solid angle (aperture radius and distance as calibrated).
const SOLID_ANGLE_REL_STD: f64 = 1.0e-3;
/// Direct-beam readings closer in time than this are not used to extrapolate drift (s).
const MIN_DRIFT_BASE_S: f64 = 30.0;

/// Why the loop stopped before the end.
#[derive(Debug)]
enum Interrupt {
    Pause(String),
    Abort,
    Estop,
    /// Store write failure (disk full, read-only): pause with the reason.
    StoreWrite(String),
    /// Anything else the engine cannot continue after.
    Fatal(EngineError),
}

/// Instrument time: the simulator's clock in dry-runs, else tokio's.
#[derive(Debug, Clone, Copy)]
enum Clock {
    Sim(gonio_simulator::clock::SimClock),
    Tokio(tokio::time::Instant),
}

impl Clock {
    fn now_s(&self) -> f64 {
        match self {
            Clock::Sim(c) => c.now_s(),
            Clock::Tokio(t0) => t0.elapsed().as_secs_f64(),
        }
    }
    async fn sleep_s(&self, s: f64) {
        if !(s.is_finite() && s > 0.0) {
            return;
        }
        match self {
            Clock::Sim(c) => c.sleep_s(s).await,
            Clock::Tokio(_) => tokio::time::sleep(std::time::Duration::from_secs_f64(s.min(3600.0))).await,
        }
    }
}

/// A multi-axis phase in which some axes failed (the rest were stopped): which, and the first reason.
struct PhaseBroken {
    failed: Vec<usize>,
    reason: String,
}

/// Which device an operation talks to (for recovery).
#[derive(Clone, Copy)]
enum Dev<'a> {
    Axis(&'a RigAxis),
    Detector,
    Wheel,
}

fn band_key(nm: f64) -> u64 {
    nm.to_bits()
}

/// What the (simulated) operator leaves in the sample holder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Holder {
    /// Nothing: the direct beam reaches the detector.
    Empty,
    /// The campaign's sample.
    Sample,
    /// The relative method's reference sample.
    Reference,
}

/// The relative method's reference at run time.
struct ReferenceRun {
    name: String,
    transfer: Transfer,
    geometry: gonio_scheduler::kinematics::Geometry,
    /// Dry-runs: the reference's own optics, swapped into the simulator while it is mounted.
    optics: Option<Arc<Optics>>,
}

struct Run<'a> {
    store: Arc<Mutex<Store>>,
    id: CampaignId,
    rig: &'a Rig,
    control: Control,
    c: Prepared,
    file: InstrumentFile,
    axis_names: Vec<String>,
    clock: Clock,
    /// Instrument time of this session's start in campaign time (continues across resumes).
    t_base: f64,
    t_clock0: f64,
    /// Where the axes are (physical degrees, read back).
    current: Pose,
    readback: Vec<f64>,
    configured_nm: Option<f64>,
    wheel_at: Option<u8>,
    darks: BTreeMap<u64, (f64, Reading)>,
    /// Normalisation readings per band, net of dark, in time order: direct beam (absolute) or reference sample
    /// (relative).
    norm: BTreeMap<u64, Vec<(f64, Reading)>>,
    failed_in_row: u32,
    /// Dry-runs: the campaign's sample in the simulator (ground truth comes from it).
    optics: Option<Arc<Optics>>,
    reference: Option<ReferenceRun>,
    done: u64,
    total: u64,
    /// The pass being measured: its predicted duration, the index after its last point, and the predicted
    /// seconds per point of all passes so far (ETA of an adaptive plan).
    pass_total_s: f64,
    pass_end: u64,
    s_per_point: f64,
}

/// One pass of the schedule: a fixed plan's only one, or one of an adaptive plan's.
struct Pass {
    schedule: gonio_scheduler::schedule::Schedule,
    /// Index of its first point.
    first_index: u64,
    /// Predicted instrument time of this pass and every one before it (s).
    elapsed_s: f64,
    number: u32,
}

impl Pass {
    fn end_index(&self) -> u64 {
        self.first_index + self.schedule.measure_steps().count() as u64
    }
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
    // parses to, already planned and ordered (crate::engine's module doc). Otherwise the stored text is parsed.
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
    let sample_spec = |material: &gonio_brdf::material::Material| SampleSpec {
        material: material.clone(),
        radius_mm: c.campaign.sample_radius_mm,
        orientation_deg: 0.0,
    };
    let optics = match (&c.campaign.material, rig.is_dry_run()) {
        (Some(m), true) => Some(rig.mount_sample(sample_spec(m), file.simulator.seed)?),
        _ => None,
    };
    let reference = match (&c.campaign.calibration.reference, c.campaign.calibration.method) {
        (Some(r), Method::Relative) => Some(ReferenceRun {
            name: r.name.clone(),
            transfer: Transfer::new(r.material.clone(), &r.geometry),
            geometry: r.geometry,
            optics: if optics.is_some() {
                // Same seed: the same source as the sample's optics.
                Some(rig.build_optics(sample_spec(&r.material), file.simulator.seed)?)
            } else {
                None
            },
        }),
        _ => None,
    };
    let clock = match rig.sim() {
        Some(s) => Clock::Sim(s.clock()),
        None => Clock::Tokio(tokio::time::Instant::now()),
    };
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
        c,
        file,
        axis_names,
        clock,
        t_base: if done > 0 || t_last > 0.0 {
            t_last + 1.0
        } else {
            0.0
        },
        t_clock0: clock.now_s(),
        current: Pose::new(0.0, 0.0, 0.0, 0.0),
        readback: Vec::new(),
        configured_nm: None,
        wheel_at: None,
        darks: BTreeMap::new(),
        norm: BTreeMap::new(),
        failed_in_row: 0,
        optics,
        reference,
        done,
        total,
        pass_total_s: 0.0,
        pass_end: total,
        s_per_point: 0.0,
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
        self.t_base + (self.clock.now_s() - self.t_clock0)
    }

    fn emit_state(&self, state: CampaignState, message: Option<String>) {
        self.control.emit(Event::State {
            campaign: self.id,
            state,
            message,
        });
    }

    fn fault(&self, message: String) {
        tracing::warn!(campaign = %self.id, "{message}");
        self.control.emit(Event::Fault {
            campaign: self.id,
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
            return Err(Interrupt::Pause("paused by request".into()));
        }
        Ok(())
    }

    /// Resolves when an emergency stop is requested.
    async fn estop_signal(&self) {
        loop {
            let n = self.control.notified();
            tokio::pin!(n);
            n.as_mut().enable();
            if self.control.estop_requested() {
                return;
            }
            n.await;
        }
    }

    /// Run a device operation with bounded retries and recovery; an emergency stop cancels it at once.
    async fn device<T, F, Fut>(&self, dev: Dev<'_>, what: &str, mut op: F) -> Result<T, Interrupt>
    where
        F: FnMut() -> Fut,
        Fut: Future<Output = Result<T, DriverError>>,
    {
        let attempts = self.c.campaign.acquisition.retries + 1;
        let mut last = String::new();
        for attempt in 1..=attempts {
            // Biased, the stop first: an emergency stop requested at the same instant must win before the
            // operation sends anything (an unbiased select polls in random order; crates/soak/tests/safety_soak.rs).
            let r = tokio::select! {
                biased;
                _ = self.estop_signal() => return Err(Interrupt::Estop),
                r = op() => r,
            };
            let e = match r {
                Ok(v) => return Ok(v),
                Err(e) => e,
            };
            if self.control.estop_requested() {
                return Err(Interrupt::Estop);
            }
            last = e.to_string();
            self.fault(format!("{what}: {e} (attempt {attempt} of {attempts})"));
            match e.kind() {
                ErrorKind::Timeout
                | ErrorKind::Protocol
                | ErrorKind::Disconnected
                | ErrorKind::Unavailable => {
                    if matches!(e.kind(), ErrorKind::Disconnected | ErrorKind::Unavailable) || attempt > 1 {
                        self.recover(dev).await?;
                    }
                }
                ErrorKind::NotReferenced => {
                    if let Dev::Axis(a) = dev {
                        self.home(a).await?;
                    }
                }
                // An absolute move that stopped short is safe to command again once.
                ErrorKind::MotionFault if matches!(dev, Dev::Axis(_)) => {
                    self.recover(dev).await?;
                }
                _ => break,
            }
        }
        // Out of attempts: the device's own reason, for a failed point (or a pause, during calibration).
        Err(Interrupt::Fatal(EngineError::Device(last)))
    }

    /// Reconnect a device, with a few spaced attempts; re-home an axis that lost its reference.
    async fn recover(&self, dev: Dev<'_>) -> Result<(), Interrupt> {
        let mut last = String::new();
        for wait_s in [0.0, 0.5, 2.0, 5.0, 10.0] {
            self.clock.sleep_s(wait_s).await;
            if self.control.estop_requested() {
                return Err(Interrupt::Estop);
            }
            let r = match dev {
                Dev::Axis(a) => match a.driver.reconnect().await {
                    Ok(_) => Ok(()),
                    Err(e) if e.kind() == ErrorKind::NotReferenced => return self.home(a).await,
                    Err(e) => Err(e),
                },
                Dev::Detector => self.rig.detector().reconnect().await,
                Dev::Wheel => match self.rig.wheel() {
                    Some(w) => w.reconnect().await,
                    None => Ok(()),
                },
            };
            match r {
                Ok(()) => {
                    tracing::info!("device reconnected");
                    return Ok(());
                }
                Err(e) => {
                    last = e.to_string();
                    self.fault(format!("reconnect: {e}"));
                }
            }
        }
        Err(Interrupt::Pause(format!(
            "a device cannot be reconnected: {last}"
        )))
    }

    /// Home an axis that lost its reference, never sweeping an arm through the other ([`rehome`]).
    async fn home(&self, a: &RigAxis) -> Result<(), Interrupt> {
        self.home_safely(a).await
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
        let mut unreferenced = Vec::new();
        for a in self.rig.axes() {
            let status = self
                .device(Dev::Axis(a), &format!("status of {}", a.config.name), || {
                    a.driver.status()
                })
                .await?;
            if !status.referenced {
                unreferenced.push(a);
            }
        }
        self.home_at_start_up(&unreferenced).await?;
        self.read_positions().await?;

        if self.done >= self.total {
            return Ok(());
        }
        // The pass holding the first uncommitted point: the schedule itself, or for an adaptive plan the pass the
        // committed points lead to (replayed from the store: gonio_campaign::passes).
        let Some(mut pass) = self.locate_pass()? else {
            // An adaptive campaign whose planner had already stopped when it was interrupted.
            return Ok(());
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
        let fresh = self.done == 0 && self.t_base == 0.0;
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
        let mut i = if scheduled_preamble {
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
                None => return Ok(()),
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

    /// The pass that holds point `self.done`: the schedule of a fixed plan; for an adaptive one, the passes are
    /// derived again from the committed points, exactly as the run that committed them derived them. None when
    /// the adaptive planner stops before that point.
    fn locate_pass(&mut self) -> Result<Option<Pass>, Interrupt> {
        let mut pass = Pass {
            schedule: self.c.schedule.clone(),
            first_index: 0,
            elapsed_s: self.c.schedule.breakdown.total_s(),
            number: 0,
        };
        while self.c.adaptive.is_some() && self.done >= pass.end_index() {
            match self.next_pass(&pass)? {
                Some(next) => pass = next,
                None => return Ok(None),
            }
        }
        Ok(Some(pass))
    }

    /// The pass after `pass` (an adaptive plan; a fixed one has one pass), from every point committed up to the
    /// end of `pass`, read back from the store. When the planner stops, a total below the budget becomes the
    /// campaign's total.
    fn next_pass(&mut self, pass: &Pass) -> Result<Option<Pass>, Interrupt> {
        let Some(adaptive) = &self.c.adaptive else {
            return Ok(None);
        };
        let end = pass.end_index();
        let points = self.st(|s| s.points_from(self.id, 0))?;
        let measured =
            gonio_campaign::measured_geometries(points.iter().take_while(|p| p.index < end).map(|p| {
                (
                    Geometry::new(p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg),
                    p.brdf_sr,
                )
            }));
        match adaptive.next_pass(&measured, pass.elapsed_s, &pass.schedule) {
            NextPass::Pass {
                schedule,
                error_estimate,
            } => {
                let points = schedule.measure_steps().count();
                tracing::info!(
                    campaign = %self.id,
                    pass = pass.number + 1,
                    first_point = end,
                    points,
                    error_estimate,
                    "adaptive plan: next pass placed from the points measured"
                );
                Ok(Some(Pass {
                    elapsed_s: pass.elapsed_s + schedule.breakdown.total_s(),
                    schedule,
                    first_index: end,
                    number: pass.number + 1,
                }))
            }
            NextPass::Done {
                reason,
                error_estimate,
            } => {
                tracing::info!(campaign = %self.id, points = end, ?reason, error_estimate, "adaptive plan complete");
                if end < self.total {
                    self.st(|s| s.set_total_points(self.id, end))?;
                    self.total = end;
                }
                Ok(None)
            }
        }
    }

    /// Progress and ETA follow `pass`: the rest of its predicted time, plus, for an adaptive plan, the rest of
    /// the budget at the predicted time per point of the passes placed so far.
    fn follow_pass(&mut self, pass: &Pass) {
        self.pass_total_s = pass.schedule.breakdown.total_s();
        self.pass_end = pass.end_index();
        self.s_per_point = pass.elapsed_s / pass.end_index().max(1) as f64;
    }

    /// Bring the instrument to the state the schedule starts from (its first step's pose, the wheel on its first
    /// step's position), then start the campaign's clock. Homing before this and the move here depend on where
    /// the devices were found, which no plan can know: they are start-up, logged, and not instrument time of
    /// the plan (so that the schedule's predicted duration is comparable with the run's).
    async fn start_up(&mut self, steps: &[Step]) -> Result<(), Interrupt> {
        if let Some(first) = steps.first() {
            self.move_to(&first.pose).await?;
        }
        if let Some(p) = steps.iter().find_map(|s| s.wheel_position) {
            self.wheel_to(p).await?;
        }
        let now = self.clock.now_s();
        tracing::info!(campaign = %self.id, start_up_s = now - self.t_clock0, "instrument referenced and at the schedule's start");
        self.t_clock0 = now;
        Ok(())
    }

    fn progress(&self, next_start_s: Option<f64>) {
        let eta_s = next_start_s.map(|s| {
            let later = self.total.saturating_sub(self.pass_end) as f64 * self.s_per_point;
            (self.pass_total_s - s).max(0.0) + later
        });
        self.control.emit(Event::Progress {
            campaign: self.id,
            done: self.done,
            total: self.total,
            eta_s,
        });
    }

    async fn read_positions(&mut self) -> Result<(), Interrupt> {
        let mut readback = Vec::new();
        for a in self.rig.axes() {
            let p = self
                .device(Dev::Axis(a), &format!("position of {}", a.config.name), || {
                    a.driver.position_deg()
                })
                .await?;
            self.current.set(a.config.role, p);
            readback.push(p);
        }
        self.readback = readback;
        Ok(())
    }

    /// Move to `target` (physical pose) along a safe, backlash-aware move planned from where the axes are.
    async fn move_to(&mut self, target: &Pose) -> Result<(), Interrupt> {
        // A phase of several axes is collision-safe only as a whole: when one of its axes fails (a stall), the
        // others are stopped and the move is planned again from where the axes really are, instead of retrying
        // the failed axis alone while the others go on (issue #8: crates/soak/tests/safety_soak.rs).
        // Each axis gets the retries a single operation gets (`acquisition.retries`); every round charges at
        // least one axis, so the loop is bounded.
        let attempts = self.c.campaign.acquisition.retries + 1;
        let mut failures: BTreeMap<usize, u32> = BTreeMap::new();
        loop {
            let PhaseBroken { failed, reason } = match self.move_once(target).await {
                Ok(r) => return r,
                Err(broken) => broken,
            };
            for idx in &failed {
                *failures.entry(*idx).or_default() += 1;
            }
            // (Every broken phase names the axis that failed first; without one, nothing bounds the loop.)
            let worst = if failed.is_empty() {
                attempts
            } else {
                failures.values().copied().max().unwrap_or(0)
            };
            self.fault(format!(
                "{reason} (attempt {worst} of {attempts}); the other axes were stopped"
            ));
            if worst >= attempts {
                return Err(Interrupt::Fatal(EngineError::Device(reason)));
            }
            for idx in failed {
                if let Some(a) = self.rig.axes().get(idx) {
                    self.recover(Dev::Axis(a)).await?;
                }
            }
            // Plan again from where every axis really is.
            self.read_positions().await?;
        }
    }

    /// One planned move; `Err(PhaseBroken)` when an axis of a multi-axis phase failed (the phase is stopped).
    async fn move_once(&mut self, target: &Pose) -> Result<Result<(), Interrupt>, PhaseBroken> {
        // An axis already within its arrival tolerance of the target does not move: the read-back differs from
        // the nominal pose by up to that tolerance after every move, and re-commanding it would cost a move,
        // a status poll and a settle at every reading of a pose (each band, each repeat at one geometry) that
        // the schedule rightly predicts as free.
        let mut from = self.current;
        for a in self.rig.axes() {
            let r = a.config.role;
            if (from.get(r) - target.get(r)).abs() <= a.config.tolerance_deg {
                from.set(r, target.get(r));
            }
        }
        let movement = match self.c.time.plan_move(&from, target) {
            Ok(m) => m,
            Err(reason) => match self.separating_move(target) {
                Some(m) => m,
                None => {
                    return Ok(Err(Interrupt::Fatal(EngineError::Device(format!(
                        "no safe move from {:?} to {:?}: {}",
                        self.current,
                        target,
                        reason.name()
                    )))));
                }
            },
        };
        let axes = self.rig.axes();
        // Where each axis finally goes in this move: its last leg in its last phase. Every other leg is a via
        // point (a backlash overshoot, the parted pose of a separating move), verified within the wider via-point
        // tolerance since the load lags the motor there.
        let mut last_phase: BTreeMap<usize, usize> = BTreeMap::new();
        for (p, phase) in movement.phases.iter().enumerate() {
            for m in phase {
                last_phase.insert(m.axis_index, p);
            }
        }
        let last_phase = &last_phase;
        let mut arrived = Vec::new();
        for (phase_index, phase) in movement.phases.iter().enumerate() {
            let this = &*self;
            // Set by the first axis of the phase that fails; the others then fail because they were stopped.
            let stopping = std::sync::atomic::AtomicBool::new(false);
            let stopping = &stopping;
            let moves = phase.iter().map(|m| async move {
                let a = axes.get(m.axis_index).ok_or_else(|| {
                    Interrupt::Fatal(EngineError::Instrument(format!(
                        "the move plan names axis #{}",
                        m.axis_index
                    )))
                })?;
                let Some(last) = m.waypoints_deg.last() else {
                    return Ok(Ok((m.axis_index, f64::NAN)));
                };
                let phys = a.config.physical_from_controller_deg(*last);
                let what = format!("move {} to {phys:.4} deg", a.config.name);
                let final_leg = last_phase.get(&m.axis_index) == Some(&phase_index);
                let arrival = |to: f64, destination: bool| {
                    if destination {
                        a.driver.wait_arrived(to)
                    } else {
                        a.driver.wait_passed_via(to)
                    }
                };
                if phase.len() < 2 {
                    // Alone in its phase: with a backlash overshoot, the driver's own approach runs the same
                    // waypoints.
                    let op = || async {
                        if m.waypoints_deg.len() > 1 {
                            a.driver.move_to(phys).await
                        } else {
                            a.driver.start_move(phys).await?;
                            arrival(phys, final_leg).await
                        }
                    };
                    let pos = this.device(Dev::Axis(a), &what, op).await?;
                    return Ok::<_, Interrupt>(Ok((m.axis_index, pos)));
                }
                // One attempt inside a multi-axis phase; on failure stop the phase's other axes at once. The
                // legs (overshoot, approach) are commanded here one by one rather than by the driver's own
                // approach, so that an axis told to stop never starts its next leg.
                let stopped = || stopping.load(std::sync::atomic::Ordering::SeqCst);
                let legs = async {
                    let mut pos = f64::NAN;
                    let n = m.waypoints_deg.len();
                    for (i, waypoint) in m.waypoints_deg.iter().enumerate() {
                        if stopped() || this.control.estop_requested() {
                            return Err(None::<DriverError>);
                        }
                        let to = a.config.physical_from_controller_deg(*waypoint);
                        a.driver.start_move(to).await.map_err(Some)?;
                        if stopped() {
                            // The phase's stop may have gone out just before this leg started: stop again.
                            let _ = a.driver.stop().await;
                            return Err(None);
                        }
                        pos = arrival(to, final_leg && i + 1 == n).await.map_err(Some)?;
                    }
                    Ok(pos)
                };
                let r = tokio::select! {
                    biased;
                    _ = this.estop_signal() => return Err(Interrupt::Estop),
                    r = legs => r,
                };
                match r {
                    Ok(pos) => Ok(Ok((m.axis_index, pos))),
                    // Stopped short by us: not this axis's fault.
                    Err(None) => Ok(Err((None, String::new()))),
                    Err(Some(_)) if stopped() => Ok(Err((None, String::new()))),
                    Err(Some(e)) => {
                        stopping.store(true, std::sync::atomic::Ordering::SeqCst);
                        for other in phase.iter().filter(|o| o.axis_index != m.axis_index) {
                            if let Some(b) = axes.get(other.axis_index) {
                                let _ = b.driver.stop().await;
                            }
                        }
                        Ok(Err((Some(m.axis_index), format!("{what}: {e}"))))
                    }
                }
            });
            let results = futures_join_all(moves).await;
            let mut broken = PhaseBroken {
                failed: Vec::new(),
                reason: String::new(),
            };
            let mut any_failed = false;
            for r in results {
                match r {
                    Err(i) => return Ok(Err(i)),
                    Ok(Ok(done)) => arrived.push(done),
                    Ok(Err((idx, reason))) => {
                        any_failed = true;
                        broken.failed.extend(idx);
                        if broken.reason.is_empty() {
                            broken.reason = reason;
                        }
                    }
                }
            }
            if any_failed {
                // The others were stopped short of their targets too: their read-back is re-read by the caller.
                return Err(broken);
            }
            for (idx, pos) in arrived.drain(..).filter(|(_, p)| p.is_finite()) {
                if let (Some(a), Some(slot)) = (axes.get(idx), self.readback.get_mut(idx)) {
                    *slot = pos;
                    self.current.set(a.config.role, pos);
                }
            }
        }
        if !movement.phases.is_empty() {
            // The campaign's extra settling is already part of each axis's settle time in `self.c.time`
            // (see `campaign::parse`), hence of `movement.settle_s`.
            self.clock.sleep_s(movement.settle_s).await;
        }
        // Physical targets the plan reached: nominal pose for axes that did not need to move.
        for r in ROLES {
            if self.rig.axes().iter().all(|a| a.config.role != r) {
                self.current.set(r, target.get(r));
            }
        }
        Ok(Ok(()))
    }

    /// The arms start closer than the safety separation (e.g. both at zero after power-up): the scheduler's
    /// planner refuses any move from there. Moving both arms at once is safe when each moves away from the other
    /// (or stays), so that their separation only grows. When the target has each arm on its side of the other,
    /// that is the whole move (every axis at once, see `simultaneous_phases`). Otherwise the arms are first
    /// parted about their midpoint into the target's order (each moving away from the other), and the planner
    /// takes it from there. None when neither is possible (e.g. the parted pose is beyond a limit).
    fn separating_move(&self, target: &Pose) -> Option<gonio_scheduler::timing::Move> {
        let min_sep = self.c.time.min_arm_separation_deg;
        let (l0, d0) = (self.current.light_deg, self.current.detector_deg);
        let (l1, d1) = (target.light_deg, target.detector_deg);
        if (l0 - d0).abs() >= min_sep {
            return None;
        }
        // Which side each arm ends on decides "away"; both must move apart (or not at all).
        let side = (l1 - d1).signum();
        if side == 0.0 || (l1 - d1).abs() < min_sep {
            return None;
        }
        let away = |from: f64, to: f64, sign: f64| (to - from) * sign >= 0.0;
        if away(l0, l1, side) && away(d0, d1, -side) {
            let (phases, settle_s) = self.simultaneous_phases(&self.current, target);
            tracing::info!(
                "arms closer than the safety separation: separating them in one simultaneous move"
            );
            return Some(gonio_scheduler::timing::Move {
                phases,
                motion_s: 0.0,
                settle_s,
            });
        }
        // Part them: a quarter more than the separation (room for a backlash overshoot), about their midpoint.
        let half = 0.5 * 1.25 * min_sep;
        let mid = 0.5 * (l0 + d0);
        let mut parted = self.current;
        parted.light_deg = mid + side * half;
        parted.detector_deg = mid - side * half;
        let within = |role: AxisRole, v: f64| {
            self.rig
                .axes()
                .iter()
                .filter(|a| a.config.role == role)
                .all(|a| (a.config.min_deg..=a.config.max_deg).contains(&v))
        };
        if !(within(AxisRole::LightArm, parted.light_deg)
            && within(AxisRole::DetectorArm, parted.detector_deg))
        {
            return None;
        }
        let rest = self.c.time.plan_move(&parted, target).ok()?;
        let (mut phases, settle_s) = self.simultaneous_phases(&self.current, &parted);
        tracing::info!(
            ?parted,
            "arms closer than the safety separation: parting them into the target's order first"
        );
        phases.extend(rest.phases);
        Some(gonio_scheduler::timing::Move {
            phases,
            motion_s: rest.motion_s,
            settle_s: settle_s.max(rest.settle_s),
        })
    }

    /// Every axis moved from `from` to `to` at once, as phases that each take every moving axis one leg further
    /// (first every backlash overshoot point, then the approaches), and the longest settle time of the axes that
    /// move. The overshoot point lies beyond the target in the direction of travel, so while the arms are parted
    /// each only moves away from the other until both reach it: their separation only grows before they are
    /// apart. (A single phase would let one arm come back from its overshoot while the other, stalled early, is
    /// still close: caught by crates/soak/tests/safety_soak.rs.)
    fn simultaneous_phases(
        &self,
        from: &Pose,
        to: &Pose,
    ) -> (Vec<Vec<gonio_scheduler::timing::AxisMotion>>, f64) {
        let mut phases: Vec<Vec<gonio_scheduler::timing::AxisMotion>> = Vec::new();
        let mut settle = 0.0f64;
        for (i, role) in ROLES.iter().enumerate() {
            let Some(model) = self.c.time.axes.get(i).and_then(|m| m.as_ref()) else {
                continue;
            };
            let mut at = model.controller_deg(from.get(*role));
            let end = model.controller_deg(to.get(*role));
            let waypoints = model.waypoints(at, end);
            if waypoints.is_empty() {
                continue;
            }
            settle = settle.max(model.settle_s);
            for (leg, waypoint) in waypoints.into_iter().enumerate() {
                if phases.len() <= leg {
                    phases.push(Vec::new());
                }
                phases[leg].push(gonio_scheduler::timing::AxisMotion {
                    role: *role,
                    axis_index: model.axis_index,
                    duration_s: model.travel_time_s(at, &[waypoint]),
                    waypoints_deg: vec![waypoint],
                });
                at = waypoint;
            }
        }
        (phases, settle)
    }

    async fn wheel_to(&mut self, position: u8) -> Result<(), Interrupt> {
        if self.wheel_at == Some(position) {
            return Ok(());
        }
        if let Some(w) = self.rig.wheel() {
            self.device(
                Dev::Wheel,
                &format!("filter wheel to position {position}"),
                || w.go_to(position),
            )
            .await?;
        }
        self.wheel_at = Some(position);
        Ok(())
    }

    fn blank_position(&self) -> Option<u8> {
        self.file
            .instrument
            .filter_wheel
            .as_ref()?
            .positions
            .iter()
            .find(|p| p.blank)
            .map(|p| p.position)
    }

    fn band_position(&self, nm: f64) -> Option<u8> {
        self.file
            .instrument
            .filter_wheel
            .as_ref()?
            .positions
            .iter()
            .find(|p| !p.blank && p.band_nm == Some(nm))
            .map(|p| p.position)
    }

    /// One detector reading at wavelength `nm`: (value, standard uncertainty, overload).
    async fn read(&mut self, nm: f64) -> Result<(f64, f64, bool), Interrupt> {
        let det = self.rig.detector();
        if self.configured_nm != Some(nm) {
            let config = DetectorConfig {
                wavelength_nm: nm,
                averaging: self.c.campaign.acquisition.averaging,
                range: match self.c.campaign.acquisition.range {
                    Range::Auto => PowerRange::Auto,
                    Range::FixedW(w) => PowerRange::Fixed { full_scale_w: w },
                },
            };
            self.device(Dev::Detector, "configure the detector", || det.configure(config))
                .await?;
            self.configured_nm = Some(nm);
        }
        let r = self
            .device(Dev::Detector, "read the detector", || async {
                let r = det.read_power().await;
                if let Err(e) = &r
                    && matches!(e.kind(), ErrorKind::Disconnected | ErrorKind::Unavailable)
                {
                    // After a reconnect the meter is back at its defaults.
                    det.configure(config_for(nm, &self.c)).await?;
                }
                r
            })
            .await?;
        // Under auto-range the meter may report its largest range; the resolution is that of the smallest range
        // holding the reading, which is what auto-ranging settles on.
        let range_w = match self.c.campaign.acquisition.range {
            Range::Auto => self
                .file
                .instrument
                .detector
                .ranges_w
                .iter()
                .copied()
                .find(|fs| *fs > r.power_w.abs())
                .unwrap_or(r.range_w)
                .min(r.range_w),
            Range::FixedW(_) => r.range_w,
        };
        let u = ((range_w * READING_RANGE_STD).powi(2) + (r.power_w * READING_REL_STD).powi(2)).sqrt();
        Ok((r.power_w, u, r.overload))
    }

    /// Dark readings (wheel on the blank) at every band's wavelength setting.
    async fn darks_all(&mut self, bands: &[f64]) -> Result<(), Interrupt> {
        let Some(blank) = self.blank_position() else {
            // No blank: darks are zero with no uncertainty (the instrument file says there is no way to take one).
            for b in bands {
                self.darks.insert(band_key(*b), (self.t(), Reading::exact(0.0)));
            }
            return Ok(());
        };
        self.wheel_to(blank).await.map_err(calibration_failure)?;
        for b in bands {
            let (v, u, overload) = self.read(*b).await.map_err(calibration_failure)?;
            if overload {
                return Err(Interrupt::Pause(format!(
                    "dark reading at {b} nm overloads the detector"
                )));
            }
            let t = self.t();
            self.darks.insert(band_key(*b), (t, Reading::new(v, u)));
            let rec = CalibrationRecord {
                kind: "dark".into(),
                band_nm: Some(*b),
                t_s: t,
                value_w: v,
                u_w: u,
            };
            self.st(|s| s.record_calibration(self.id, &rec))?;
        }
        Ok(())
    }

    /// Ask the operator to do something and wait for the confirmation; in dry-runs the simulated sample holder
    /// then holds `holder` (at once with the simulated operator).
    async fn operator(&mut self, message: &str, holder: Holder) -> Result<(), Interrupt> {
        let simulated = self.optics.is_some() && self.c.campaign.calibration.simulate_operator;
        if !simulated {
            // A confirmation given before the question does not count: dropped before the question is announced,
            // since an operator (or a script) may answer as soon as it is, before this task runs again.
            let _ = self.control.take_confirm();
            self.st(|s| s.set_state(self.id, CampaignState::WaitingOperator, None))?;
            self.st(|s| s.set_operator_message(self.id, Some(message)))?;
            self.emit_state(CampaignState::WaitingOperator, Some(message.to_string()));
            loop {
                let n = self.control.notified();
                tokio::pin!(n);
                n.as_mut().enable();
                if self.control.take_confirm() {
                    break;
                }
                if self.control.estop_requested() {
                    return Err(Interrupt::Estop);
                }
                if self.control.abort_requested() {
                    return Err(Interrupt::Abort);
                }
                if self.control.pause_requested() {
                    return Err(Interrupt::Pause("paused while waiting for the operator".into()));
                }
                n.await;
            }
            self.st(|s| s.set_operator_message(self.id, None))?;
            // A pause requested at this very moment is already on its way: say so rather than `running`.
            let state = if self.control.pause_requested() {
                CampaignState::Pausing
            } else {
                CampaignState::Running
            };
            self.st(|s| s.set_state(self.id, state, None))?;
            self.emit_state(state, None);
        }
        self.simulated_holder(holder);
        Ok(())
    }

    /// Dry-runs: put `holder` in the simulated sample holder, as the operator just did.
    fn simulated_holder(&self, holder: Holder) {
        let Some(sample) = &self.optics else { return };
        match holder {
            Holder::Empty | Holder::Sample => {
                self.rig.show_optics(Arc::clone(sample));
                sample.set_sample_mounted(holder == Holder::Sample);
            }
            Holder::Reference => {
                if let Some(r) = self.reference.as_ref().and_then(|r| r.optics.as_ref()) {
                    r.set_sample_mounted(true);
                    self.rig.show_optics(Arc::clone(r));
                }
            }
        }
    }

    /// The normalisation readings of `bands` for the campaign's method: direct beam (at `pose`, else the plan's
    /// reference pose) or reference sample (at the reference geometry).
    async fn normalise(&mut self, bands: &[f64], pose: Option<Pose>) -> Result<(), Interrupt> {
        match self.c.campaign.calibration.method {
            Method::Absolute => self.direct_beam(bands, pose).await,
            Method::Relative => self.reference_sample(bands).await,
        }
    }

    /// Reference-sample readings of `bands` (relative method): the operator swaps the reference in, one reading
    /// per band at the reference geometry, and the sample goes back.
    async fn reference_sample(&mut self, bands: &[f64]) -> Result<(), Interrupt> {
        let Some(name) = self.reference.as_ref().map(|r| r.name.clone()) else {
            return Err(Interrupt::Fatal(EngineError::NotRunnable {
                id: self.id,
                message: "the relative method needs a reference, and the stored campaign has none".into(),
            }));
        };
        // Close the beam while the operator works.
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(
            &format!(
                "Reference calibration: take the sample out of the holder and mount the reference sample \
                 ({name}) in its place, then confirm."
            ),
            Holder::Reference,
        )
        .await?;
        let result = async {
            let (geometry, pose) = {
                let r = self.reference.as_ref().ok_or_else(|| {
                    Interrupt::Fatal(EngineError::Device("the reference went missing".into()))
                })?;
                let kinematics = Kinematics::new(&self.file.instrument);
                (
                    r.geometry,
                    reference::pose_for(&kinematics, &self.c.time, &r.geometry, &self.current),
                )
            };
            let pose = pose.ok_or_else(|| {
                Interrupt::Pause(format!(
                    "no safe move from {:?} to the reference geometry {geometry:?}",
                    self.current
                ))
            })?;
            self.move_to(&pose).await?;
            let tol_deg = self.file.instrument.axes.iter().map(|a| a.tolerance_deg).fold(0.0f64, f64::max);
            let angle_std_rad = tol_deg.to_radians() / 3f64.sqrt();
            for b in bands {
                if let Some(p) = self.band_position(*b) {
                    self.wheel_to(p).await?;
                }
                let (v, u, overload) = self.read(*b).await?;
                if overload {
                    return Err(Interrupt::Pause(format!(
                        "the reference sample at {b} nm overloads the detector: choose a larger range"
                    )));
                }
                let dark = self.dark(*b);
                let net_w = v - dark.value_w;
                if net_w <= 0.0 {
                    return Err(Interrupt::Pause(format!(
                        "no signal from the reference sample at {b} nm ({v} W read, dark {} W): is it mounted, \
                         the source on and the path clear?",
                        dark.value_w
                    )));
                }
                let positioning = match (Wavelength::from_nm(*b), &self.reference) {
                    (Ok(wl), Some(r)) => r.transfer.positioning_rel_std(wl, angle_std_rad) * net_w,
                    _ => 0.0,
                };
                let net = Reading::new(net_w, u.hypot(dark.std_w).hypot(positioning));
                self.keep_normalisation("reference", *b, net, v, u)?;
            }
            Ok(())
        }
        .await;
        self.end_normalisation(
            result,
            "Reference calibration done: take the reference sample out and mount the sample again, then confirm.",
        )
        .await
    }

    /// Direct-beam readings of `bands`: sample out, detector facing the source, one reading per band.
    async fn direct_beam(&mut self, bands: &[f64], pose: Option<Pose>) -> Result<(), Interrupt> {
        let pose = match pose {
            Some(p) => p,
            None if !self.c.plan.calibration.reference_overrides.is_empty() => {
                self.c.plan.calibration.reference_pose(&self.current)
            }
            // No reference pose in the plan: the detector arm facing the light arm at -90 deg, stage at zero.
            None => {
                let p = Optics::direct_beam_pose(-90.0);
                Pose::new(p.light_deg, p.detector_deg, 0.0, 0.0)
            }
        };
        // Close the beam while the operator works.
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(
            "Direct-beam calibration: remove the sample from the holder, then confirm.",
            Holder::Empty,
        )
        .await?;
        let result = async {
            self.move_to(&pose).await?;
            for b in bands {
                let pos = self.band_position(*b);
                if let Some(p) = pos {
                    self.wheel_to(p).await?;
                }
                let (v, u, overload) = self.read(*b).await?;
                if overload {
                    return Err(Interrupt::Pause(format!(
                        "the direct beam at {b} nm overloads the detector: choose a larger range or attenuate"
                    )));
                }
                let dark = self.dark(*b);
                let net = Reading::new(v - dark.value_w, u.hypot(dark.std_w));
                if net.value_w <= 0.0 {
                    return Err(Interrupt::Pause(format!(
                        "no direct beam at {b} nm ({v} W read, dark {} W): is the source on and the path clear?",
                        dark.value_w
                    )));
                }
                self.keep_normalisation("direct-beam", *b, net, v, u)?;
            }
            Ok(())
        }
        .await;
        self.end_normalisation(
            result,
            "Direct-beam calibration done: mount the sample again, then confirm.",
        )
        .await
    }

    /// The last dark reading of band `nm` (zero, exactly, when none was taken).
    fn dark(&self, nm: f64) -> Reading {
        self.darks
            .get(&band_key(nm))
            .map(|d| d.1)
            .unwrap_or(Reading::exact(0.0))
    }

    /// Keep a band's net normalisation reading for the drift extrapolation, and store the raw one as `kind`.
    fn keep_normalisation(
        &mut self,
        kind: &str,
        nm: f64,
        net: Reading,
        value_w: f64,
        u_w: f64,
    ) -> Result<(), Interrupt> {
        let t = self.t();
        self.norm.entry(band_key(nm)).or_default().push((t, net));
        let rec = CalibrationRecord {
            kind: kind.into(),
            band_nm: Some(nm),
            t_s: t,
            value_w,
            u_w,
        };
        self.st(|s| s.record_calibration(self.id, &rec))
    }

    /// The end of a normalisation sequence: its failure is a calibration failure; then the beam is closed and
    /// the operator puts the sample back (`message`).
    async fn end_normalisation(
        &mut self,
        result: Result<(), Interrupt>,
        message: &str,
    ) -> Result<(), Interrupt> {
        result.map_err(calibration_failure)?;
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(message, Holder::Sample).await
    }

    /// The normalisation reading (net direct beam, or net reference signal) at time `t` for a band,
    /// extrapolating the drift from the last two readings of this session when they are far enough apart.
    fn normalisation(&self, nm: f64, t: f64) -> Option<Reading> {
        let list = self.norm.get(&band_key(nm))?;
        let (t2, r2) = *list.last()?;
        if list.len() >= 2
            && let Some((t1, r1)) = list.get(list.len() - 2).copied()
            && t2 - t1 >= MIN_DRIFT_BASE_S
        {
            let slope = (r2.value_w - r1.value_w) / (t2 - t1);
            let x = (t - t2) / (t2 - t1);
            let value = r2.value_w + slope * (t - t2);
            let std = (r2.std_w * (1.0 + x)).hypot(r1.std_w * x);
            return Some(Reading::new(value, std));
        }
        Some(r2)
    }

    async fn measure(&mut self, step: &Step, next_start_s: Option<f64>) -> Result<(), Interrupt> {
        let index = self.done;
        let Some(g) = step.geometry else {
            return Err(Interrupt::Fatal(EngineError::NotRunnable {
                id: self.id,
                message: format!("measure step for point {index} has no geometry"),
            }));
        };
        let band_nm = step
            .band_nm
            .or(self.file.instrument.source.wavelength_nm)
            .unwrap_or(f64::NAN);
        let acquired = async {
            self.move_to(&step.pose).await?;
            if let Some(p) = step.wheel_position {
                self.wheel_to(p).await?;
            }
            self.read(band_nm).await
        }
        .await;
        let mut flags = Vec::new();
        let (signal, u_signal, overload) = match acquired {
            Ok(r) => r,
            Err(Interrupt::Fatal(EngineError::Device(reason))) => {
                self.failed_in_row += 1;
                if self.failed_in_row >= MAX_FAILED_IN_ROW {
                    return Err(Interrupt::Pause(format!(
                        "{MAX_FAILED_IN_ROW} points in a row failed; last: {reason}"
                    )));
                }
                flags.push(format!("failed: {reason}"));
                // Where the axes are now is uncertain after a failure: ask them.
                let _ = self.read_positions().await;
                (f64::NAN, f64::NAN, false)
            }
            Err(other) => return Err(other),
        };
        let t = self.t();
        let dark = self.dark(band_nm);
        let incident = self.normalisation(band_nm, t).unwrap_or(Reading::exact(f64::NAN));
        let wi = Direction::from_spherical_deg(g.theta_i_deg, g.phi_i_deg);
        let wo = Direction::from_spherical_deg(g.theta_o_deg, g.phi_o_deg);
        let (mut brdf, mut brdf_u) = (None, None);
        if flags.is_empty() {
            self.failed_in_row = 0;
            if overload {
                flags.push("saturated".to_string());
            } else {
                match self.equation(signal, u_signal, dark, incident, band_nm, wi, wo) {
                    Ok(v) => {
                        brdf = Some(v.value_per_sr);
                        brdf_u = Some(v.std_per_sr);
                    }
                    Err(e) => flags.push(flag_for(&e)),
                }
            }
        }
        let (truth_point_sr, truth_aperture_sr) = match (&self.optics, Wavelength::from_nm(band_nm)) {
            (Some(o), Ok(wl)) => (
                o.truth(&wi, &wo, wl).ok(),
                o.truth_aperture(&wi, &wo, wl).ok().map(|a| a.average_sr),
            ),
            _ => (None, None),
        };
        let point = PointRecord {
            index,
            band_nm,
            theta_i_deg: g.theta_i_deg,
            phi_i_deg: g.phi_i_deg,
            theta_o_deg: g.theta_o_deg,
            phi_o_deg: g.phi_o_deg,
            signal_w: signal,
            dark_w: dark.value_w,
            incident_w: incident.value_w,
            brdf_sr: brdf,
            brdf_u_sr: brdf_u,
            flags,
            t_s: t,
            readback_deg: self
                .axis_names
                .iter()
                .cloned()
                .zip(self.readback.iter().copied())
                .collect(),
            truth_point_sr,
            truth_aperture_sr,
        };
        self.st(|s| s.commit_point(self.id, &point))?;
        self.done += 1;
        self.control.emit(Event::Point {
            campaign: self.id,
            point,
        });
        self.progress(next_start_s);
        Ok(())
    }

    /// The measurement equation of the campaign's method; `norm` is the normalisation reading (net direct beam,
    /// or net reference signal) at the time of the reading.
    #[allow(clippy::too_many_arguments)]
    fn equation(
        &self,
        signal: f64,
        u_signal: f64,
        dark: Reading,
        norm: Reading,
        band_nm: f64,
        wi: Direction,
        wo: Direction,
    ) -> Result<gonio_brdf::measurement::BrdfValue, MeasurementError> {
        let inst = &self.file.instrument;
        // Positioning: the arms' arrival tolerance as a uniform distribution.
        let tol_deg = inst.axes.iter().map(|a| a.tolerance_deg).fold(0.0f64, f64::max);
        let geometry = MeasurementGeometry {
            wi,
            wo,
            angle_std_rad: tol_deg.to_radians() / 3f64.sqrt(),
        };
        let footprint = Footprint {
            beam_radius_mm: inst.source.beam_radius_mm,
            sample_radius_mm: self.c.campaign.sample_radius_mm,
            detector_field_radius_mm: Some(inst.detector.field_radius_mm),
        };
        let limits = ValidityLimits {
            min_cos_theta_o: inst.safety.grazing_limit_deg.to_radians().cos(),
        };
        if let Some(r) = &self.reference {
            let wavelength = Wavelength::from_nm(band_nm).map_err(MeasurementError::Reference)?;
            return relative_brdf(
                &RelativeReadings {
                    signal: Reading::new(signal, u_signal),
                    signal_dark: dark,
                    reference: norm,
                    reference_dark: Reading::exact(0.0),
                    reference_brdf_rel_std: self.c.campaign.calibration.reference_rel_std,
                },
                &r.transfer,
                wavelength,
                &geometry,
                &footprint,
                &limits,
            );
        }
        let omega = gonio_brdf::radiometry::aperture_solid_angle_sr(
            inst.detector.aperture_radius_mm,
            inst.detector.distance_mm,
        );
        absolute_brdf(
            &AbsoluteReadings {
                signal: Reading::new(signal, u_signal),
                signal_dark: dark,
                direct_beam: norm,
                direct_beam_dark: Reading::exact(0.0),
                detector_solid_angle_sr: omega,
                detector_solid_angle_std_sr: omega * SOLID_ANGLE_REL_STD,
            },
            &geometry,
            &footprint,
            &limits,
        )
    }

    /// Leave the run in a consistent state and say how it ended.
    async fn finish(mut self, outcome: Result<(), Interrupt>) -> Result<CampaignState, EngineError> {
        // Close the beam whatever happened (best effort: the wheel may be the device that failed).
        if let Some(blank) = self.blank_position()
            && let Some(w) = self.rig.wheel()
            && self.wheel_at != Some(blank)
        {
            match tokio::time::timeout(std::time::Duration::from_secs(10), w.go_to(blank)).await {
                Ok(Ok(())) => self.wheel_at = Some(blank),
                Ok(Err(e)) => tracing::warn!("closing the beam: {e}"),
                Err(_) => tracing::warn!("closing the beam: the filter wheel did not answer in 10 s"),
            }
        }
        let (state, message) = match outcome {
            Ok(()) => (CampaignState::Completed, None),
            Err(Interrupt::Abort) => (CampaignState::Aborted, Some("aborted by request".to_string())),
            Err(Interrupt::Estop) => (CampaignState::Paused, Some("emergency stop".to_string())),
            Err(Interrupt::Pause(reason)) => (CampaignState::Paused, Some(reason)),
            Err(Interrupt::StoreWrite(reason)) => (
                CampaignState::Paused,
                Some(format!(
                    "{reason}: the campaign paused before moving on. Every committed point is kept; free space or \
                     make the store writable, then resume (it continues from the first point not committed)"
                )),
            ),
            Err(Interrupt::Fatal(EngineError::Device(reason))) => (CampaignState::Paused, Some(reason)),
            Err(Interrupt::Fatal(e)) => {
                let msg = e.to_string();
                let _ = lock(&self.store).set_state(self.id, CampaignState::Failed, Some(&msg));
                self.emit_state(CampaignState::Failed, Some(msg));
                return Err(e);
            }
        };
        if let Some(m) = &message {
            tracing::warn!(campaign = %self.id, state = %state, "{m}");
        }
        {
            let mut s = lock(&self.store);
            let _ = s.set_operator_message(self.id, None);
            if let Err(e) = s.set_state(self.id, state, message.as_deref()) {
                // A store that cannot be written cannot record the pause: the store shows it from memory (status
                // requests see it), and the file still says "running", which a restart resumes.
                tracing::warn!("cannot record the campaign state {state}: {e}");
            }
        }
        self.emit_state(state, message);
        Ok(state)
    }
}

fn config_for(nm: f64, c: &Prepared) -> DetectorConfig {
    DetectorConfig {
        wavelength_nm: nm,
        averaging: c.campaign.acquisition.averaging,
        range: match c.campaign.acquisition.range {
            Range::Auto => PowerRange::Auto,
            Range::FixedW(w) => PowerRange::Fixed { full_scale_w: w },
        },
    }
}

/// A device failure during calibration pauses the campaign (there is no valid normalisation without it).
fn calibration_failure(i: Interrupt) -> Interrupt {
    match i {
        Interrupt::Fatal(EngineError::Device(reason)) => Interrupt::Pause(format!("calibration: {reason}")),
        other => other,
    }
}

/// The flag for a refused measurement.
fn flag_for(e: &MeasurementError) -> String {
    match e {
        MeasurementError::OverfillsSample { .. } | MeasurementError::OverfillsDetectorField { .. } => {
            "overfilled".into()
        }
        MeasurementError::GrazingDetector { .. } => "grazing".into(),
        MeasurementError::SourceBelowHorizon { .. } => "below-horizon".into(),
        MeasurementError::NoDirectBeam { .. } => "no-direct-beam".into(),
        MeasurementError::NoReferenceSignal { .. } => "no-reference-signal".into(),
        other => format!("invalid: {other}"),
    }
}
