//! The alignment as an action of the daemon: `gonio align`'s procedure ([`gonio_engine::align::run_alignment`])
//! on the daemon's instrument, its result kept in the store as a new calibration that becomes current
//! (`calibration`).
//!
//! The action takes the instrument for its whole duration ([`Service::take_instrument`]), so it is refused,
//! naming the campaign, while a campaign runs or waits for its operator, and the queue starts nothing until it
//! ends; console actions are refused meanwhile. It runs in its own task and reports its progress in an
//! [`AlignStatus`] the API serves (`GET /api/align`) until the next alignment starts. The operator's steps
//! (empty the holder, mount the mirror) are done by the simulated operator in a dry-run (unless asked not to);
//! on hardware they wait, as a campaign's do, for the operator's confirmation through the service's [`Control`]
//! (`POST /api/align/confirm`; `POST /api/align/abort` or the emergency stop end the wait, within
//! [`OPERATOR_WAIT`] at most). A step that fails stores nothing.
//!
//! [`Control`]: gonio_engine::control::Control

use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use super::{CONSOLE_RETRIES, InstrumentLease, Service, ServiceError, lock};
use gonio_brdf::Material;
use gonio_engine::align::file::CalibrationFile;
use gonio_engine::align::{AlignOptions, OperatorStep, Placement, run_alignment};
use gonio_engine::characterise::CharacteriseOptions;
use gonio_engine::rig::SampleHolder;
use gonio_engine::store::InstrumentCalibrationId;

/// The preset the simulated operator mounts as the alignment mirror, unless the request names another.
pub const DEFAULT_ALIGNMENT_MIRROR: &str = "mirror";
/// The preset the simulated operator mounts as the sample for the steps that use it, unless the request names
/// another (the demo's).
pub const DEFAULT_ALIGNMENT_SAMPLE: &str = "coloured-plastic";

/// Which procedures an alignment runs besides the geometric one (as `gonio align --steps`).
#[derive(Debug, Clone, PartialEq)]
pub struct AlignProcedures {
    /// The detector's and the source's characterisation (crate::characterise in the engine).
    pub characterise: bool,
    /// The alignment on the sample's own specular lobe.
    pub on_sample: bool,
    /// The characterisation's warm-up watch (s of instrument time).
    pub warmup_watch_s: f64,
    /// Dry-runs: the sample the simulated operator mounts (a preset).
    pub material: Option<String>,
}

impl Default for AlignProcedures {
    fn default() -> Self {
        AlignProcedures {
            characterise: true,
            on_sample: false,
            warmup_watch_s: CharacteriseOptions::default().warmup_watch_s,
            material: None,
        }
    }
}

impl AlignProcedures {
    fn options(&self) -> AlignOptions {
        AlignOptions {
            characterise: self.characterise.then_some(CharacteriseOptions {
                warmup_watch_s: self.warmup_watch_s,
            }),
            on_sample: self.on_sample,
        }
    }
}

/// The simulated alignment mirror's radius (mm), as `gonio align`'s.
const MIRROR_RADIUS_MM: f64 = 25.0;
/// How long an operator step waits for its confirmation before the alignment gives the instrument back.
const OPERATOR_WAIT: Duration = Duration::from_secs(3600);
/// How often a waiting operator step looks for its confirmation.
const OPERATOR_POLL: Duration = Duration::from_millis(100);

/// Where an alignment is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AlignPhase {
    /// None has run since the daemon started.
    #[default]
    Idle,
    Running,
    WaitingOperator,
    Completed,
    Failed,
}

impl AlignPhase {
    /// The alignment holds the instrument.
    pub fn in_progress(self) -> bool {
        matches!(self, AlignPhase::Running | AlignPhase::WaitingOperator)
    }

    /// The name the API gives it.
    pub fn as_str(self) -> &'static str {
        match self {
            AlignPhase::Idle => "idle",
            AlignPhase::Running => "running",
            AlignPhase::WaitingOperator => "waiting-operator",
            AlignPhase::Completed => "completed",
            AlignPhase::Failed => "failed",
        }
    }
}

/// Ends the status of an alignment whose task ends without saying how (it cannot, short of a bug): the status
/// must not say `running` for ever, refusing every later alignment.
struct EndsTheStatus(Service);

impl Drop for EndsTheStatus {
    fn drop(&mut self) {
        let mut status = lock(&self.0.shared.align);
        if status.state.in_progress() {
            status.state = AlignPhase::Failed;
            status.operator_message = None;
            status.error = Some("the alignment's task ended unexpectedly".into());
        }
    }
}

/// The alignment in progress, or how the last one ended (module doc).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct AlignStatus {
    pub state: AlignPhase,
    /// Who started it (the token holder, or loopback).
    pub started_by: Option<String>,
    pub started_unix_s: Option<f64>,
    pub dry_run: Option<bool>,
    /// What it is doing now.
    pub step: Option<String>,
    /// The operator's instruction while it waits for them.
    pub operator_message: Option<String>,
    /// Instrument time the procedure took (s), once completed.
    pub instrument_s: Option<f64>,
    /// The stored calibration it made, once completed.
    pub calibration_id: Option<InstrumentCalibrationId>,
    /// Why it failed.
    pub error: Option<String>,
}

fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(f64::NAN)
}

impl Service {
    /// Start the alignment for `who`; `mirror` names the simulated operator's alignment mirror (a preset; default
    /// [`DEFAULT_ALIGNMENT_MIRROR`]); `simulate_operator` false: in a dry-run too, each operator step waits for a
    /// person's confirmation (then the simulated holder follows), as a campaign's `simulate_operator = false`.
    /// Refused (`Conflict`) while a campaign or a person holds the instrument, or another alignment runs.
    /// Answers at once with the status; the alignment goes on in its own task.
    pub fn start_alignment(
        &self,
        who: &str,
        mirror: Option<&str>,
        simulate_operator: bool,
        procedures: AlignProcedures,
    ) -> Result<AlignStatus, ServiceError> {
        let name = mirror.unwrap_or(DEFAULT_ALIGNMENT_MIRROR);
        let mirror =
            Material::preset(name).map_err(|e| ServiceError::Invalid(format!("mirror {name:?}: {e}")))?;
        let sample_name = procedures.material.as_deref().unwrap_or(DEFAULT_ALIGNMENT_SAMPLE);
        let sample = Material::preset(sample_name)
            .map_err(|e| ServiceError::Invalid(format!("material {sample_name:?}: {e}")))?;
        if !(procedures.warmup_watch_s.is_finite() && procedures.warmup_watch_s >= 0.0) {
            return Err(ServiceError::Invalid(format!(
                "warmup_watch_s {}: give a number of seconds, 0 or more",
                procedures.warmup_watch_s
            )));
        }
        let options = procedures.options();
        let instrument_toml = self
            .shared
            .runner
            .instrument_toml()
            .ok_or_else(|| ServiceError::Conflict("this daemon has no instrument of its own".into()))?
            .to_string();
        let mut status = lock(&self.shared.align);
        if status.state.in_progress() {
            return Err(ServiceError::Conflict(format!(
                "an alignment started by {} is in progress",
                status.started_by.as_deref().unwrap_or("someone")
            )));
        }
        let lease = self.take_instrument(&format!("the alignment ({who})"))?;
        let dry_run = lease.rig().map(|r| r.is_dry_run());
        *status = AlignStatus {
            state: AlignPhase::Running,
            started_by: Some(who.to_string()),
            started_unix_s: Some(unix_now_s()),
            dry_run,
            step: Some("homing the axes".into()),
            ..AlignStatus::default()
        };
        let answer = status.clone();
        drop(status);
        tracing::info!(%who, mirror = %name, simulate_operator, "alignment started");
        let (service, who) = (self.clone(), who.to_string());
        tokio::spawn(async move {
            let _ends = EndsTheStatus(service.clone());
            let outcome = service
                .align_with(
                    &lease,
                    (&mirror, &sample),
                    simulate_operator,
                    options,
                    &instrument_toml,
                    &who,
                )
                .await;
            let mut status = lock(&service.shared.align);
            status.operator_message = None;
            match outcome {
                Ok((id, instrument_s)) => {
                    tracing::info!(%who, calibration = %id, "alignment completed");
                    status.state = AlignPhase::Completed;
                    status.step = Some("done".into());
                    status.calibration_id = Some(id);
                    status.instrument_s = Some(instrument_s);
                }
                Err(e) => {
                    tracing::warn!(%who, "alignment failed: {e}");
                    status.state = AlignPhase::Failed;
                    status.error = Some(e);
                }
            }
            drop(status);
            // Only now may the queue start the next campaign.
            drop(lease);
        });
        Ok(answer)
    }

    /// The alignment in progress, or how the last one ended.
    pub fn alignment_status(&self) -> AlignStatus {
        lock(&self.shared.align).clone()
    }

    /// The operator did what the waiting alignment asked.
    pub fn confirm_alignment(&self, who: &str) -> Result<AlignStatus, ServiceError> {
        let status = lock(&self.shared.align);
        if status.state != AlignPhase::WaitingOperator {
            return Err(ServiceError::Conflict(format!(
                "the alignment is not waiting for the operator (it is {})",
                status.state.as_str()
            )));
        }
        tracing::info!(%who, "alignment: operator step confirmed");
        self.shared.control.confirm();
        Ok(status.clone())
    }

    /// End an alignment waiting for its operator (one that is scanning stops with the emergency stop).
    pub fn abort_alignment(&self, who: &str) -> Result<AlignStatus, ServiceError> {
        let status = lock(&self.shared.align);
        match status.state {
            AlignPhase::WaitingOperator => {
                tracing::info!(%who, "alignment: abort requested");
                self.shared.control.abort();
                Ok(status.clone())
            }
            AlignPhase::Running => Err(ServiceError::Conflict(
                "the alignment is moving the instrument: use the emergency stop to halt it".into(),
            )),
            _ => Err(ServiceError::Conflict("no alignment is in progress".into())),
        }
    }

    fn set_align_step(&self, step: &str) {
        lock(&self.shared.align).step = Some(step.to_string());
    }

    /// The procedure on the held instrument, its calibration stored and made current: its id and the
    /// instrument time taken.
    async fn align_with(
        &self,
        lease: &InstrumentLease,
        (mirror, sample): (&Material, &Material),
        simulate_operator: bool,
        options: AlignOptions,
        instrument_toml: &str,
        who: &str,
    ) -> Result<(InstrumentCalibrationId, f64), String> {
        let rig = lease.rig().ok_or("this daemon has no instrument of its own")?;
        let holder = rig
            .alignment_holder(mirror, Some(sample), MIRROR_RADIUS_MM)
            .map_err(|e| e.to_string())?;
        let mut motion = lease
            .motion(CONSOLE_RETRIES)
            .ok_or("this daemon has no instrument of its own")?;
        let operator = |p: Placement| -> OperatorStep<'_> {
            Box::pin(self.operator_step(holder.as_ref(), simulate_operator, p))
        };
        let report = run_alignment(&mut motion, &operator, options)
            .await
            .map_err(|e| format!("alignment stopped: {e}"))?;
        drop(motion);
        self.set_align_step("storing the calibration");
        let file = CalibrationFile::from_report(&report, instrument_toml, unix_now_s());
        let text = file
            .to_toml()
            .map_err(|e| format!("cannot encode the calibration: {e}"))?;
        let report_json = report
            .to_json_pretty()
            .map_err(|e| tracing::warn!("the alignment report is not kept: {e}"))
            .ok();
        let id = self
            .keep_calibration(
                &file,
                &text,
                &format!("alignment by the daemon ({who})"),
                report_json,
            )
            .map_err(|e| e.to_string())?;
        self.make_current(id, &text);
        Ok((id, report.instrument_s))
    }

    /// One operator step: the simulated operator's in a dry-run (unless the person asked to do them), else a
    /// person's, confirmed through the API; a dry-run's simulated holder then holds what the step asked for.
    async fn operator_step(
        &self,
        holder: Option<&Arc<dyn SampleHolder>>,
        simulate_operator: bool,
        p: Placement,
    ) -> Result<(), String> {
        match holder {
            Some(_) if simulate_operator => {
                tracing::info!("alignment: simulated operator: {}", p.instruction());
            }
            _ => self.wait_for_operator(p).await?,
        }
        if let Some(h) = holder {
            h.hold(p.held());
        }
        self.set_align_step(match p {
            Placement::Empty => "scans through the direct beam (the holder empty)",
            Placement::Mirror => "scans through the mirror's reflection",
            Placement::Sample => "the sample's reflection (its own lobe, the smallest ranges' overlaps)",
        });
        Ok(())
    }

    /// Ask the operator for `p` and wait for the confirmation, as a campaign's operator step does (or for an
    /// abort, the emergency stop, the deadline).
    async fn wait_for_operator(&self, p: Placement) -> Result<(), String> {
        let control = self.shared.control.clone();
        // A confirmation given before the question does not count.
        let _ = control.take_confirm();
        {
            let mut status = lock(&self.shared.align);
            status.state = AlignPhase::WaitingOperator;
            status.operator_message = Some(p.instruction().to_string());
            status.step = Some(format!("waiting for the operator: {}", p.instruction()));
        }
        tracing::info!("alignment: waiting for the operator: {}", p.instruction());
        let deadline = tokio::time::Instant::now() + OPERATOR_WAIT;
        let outcome = loop {
            if control.take_confirm() {
                break Ok(());
            }
            if control.estop_requested() {
                break Err("emergency stop while waiting for the operator".to_string());
            }
            if control.abort_requested() {
                break Err("aborted while waiting for the operator".to_string());
            }
            if tokio::time::Instant::now() >= deadline {
                break Err(format!(
                    "no confirmation within {} s: {}",
                    OPERATOR_WAIT.as_secs(),
                    p.instruction()
                ));
            }
            tokio::time::sleep(OPERATOR_POLL).await;
        };
        let mut status = lock(&self.shared.align);
        status.state = AlignPhase::Running;
        status.operator_message = None;
        outcome
    }
}
