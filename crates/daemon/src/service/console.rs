//! The console's requests: a person's hands on the instrument through the API, under the one-owner rule.
//!
//! Each console action takes the instrument for its duration ([`Service::take_instrument`], `ownership`), so it
//! is refused, naming the campaign, while a campaign runs or waits for its operator, and allowed while the
//! campaign is paused (a resumed campaign reads the axes back, re-homes what lost its reference and moves to its
//! next point from where the axes really are). Console actions run one at a time, in the order they came;
//! each is logged with who sent it. The action runs in its own task: a client that goes away does not stop a
//! move half-way (the emergency stop does).

use serde::Serialize;
use serde_json::Value;

use super::{Service, ServiceError};
use gonio_engine::console::{Console, ConsoleError, FilterChoice};
use gonio_scheduler::kinematics::Geometry;

/// Retries of a device operation for a console action (a campaign takes its own from its file).
pub const CONSOLE_RETRIES: u32 = 2;
/// Readings one console request may ask for.
pub const MAX_CONSOLE_READINGS: usize = 1000;

/// What a person asks of the console.
#[derive(Debug, Clone, PartialEq)]
pub enum ConsoleAction {
    State,
    /// Named axes to physical degrees, in one safe move.
    Move(Vec<(String, f64)>),
    MoveGeometry(Geometry),
    Jog {
        axis: String,
        delta_deg: f64,
    },
    /// One axis, or every axis.
    Home(Option<String>),
    Filter(FilterChoice),
    Read {
        count: usize,
    },
}

impl ConsoleAction {
    /// True for the actions that move something (logged at info; the others at debug).
    fn moves(&self) -> bool {
        !matches!(self, ConsoleAction::State | ConsoleAction::Read { .. })
    }
}

impl From<ConsoleError> for ServiceError {
    fn from(e: ConsoleError) -> ServiceError {
        match e {
            ConsoleError::Refused { .. } => ServiceError::Conflict(e.to_string()),
            ConsoleError::Invalid(m) => ServiceError::Invalid(m),
            ConsoleError::Motion(m) => ServiceError::Internal(m),
        }
    }
}

/// The console's answer to a filter request (`POST /api/console/filter`): where the wheel is now.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct FilterMoved {
    pub position: u8,
}

fn to_json<T: Serialize>(v: T) -> Result<Value, ServiceError> {
    serde_json::to_value(v).map_err(|e| ServiceError::Internal(format!("console answer: {e}")))
}

impl Service {
    /// Do one console action for `who` (the token holder, or loopback) and answer its JSON (module doc).
    pub async fn console(&self, who: &str, action: ConsoleAction) -> Result<Value, ServiceError> {
        if let ConsoleAction::Read { count } = action
            && !(1..=MAX_CONSOLE_READINGS).contains(&count)
        {
            return Err(ServiceError::Invalid(format!(
                "count {count}: between 1 and {MAX_CONSOLE_READINGS} readings per request"
            )));
        }
        let service = self.clone();
        let who = who.to_string();
        let task = tokio::spawn(async move { service.console_now(&who, action).await });
        task.await
            .map_err(|e| ServiceError::Internal(format!("console task failed: {e}")))?
    }

    async fn console_now(&self, who: &str, action: ConsoleAction) -> Result<Value, ServiceError> {
        let _one_at_a_time = self.shared.console.lock().await;
        if action.moves() {
            tracing::info!(%who, ?action, "console request");
        } else {
            tracing::debug!(%who, ?action, "console request");
        }
        let lease = self.take_instrument(&format!("the console ({who})"))?;
        let Some(motion) = lease.motion(CONSOLE_RETRIES) else {
            return Err(ServiceError::Conflict(
                "this daemon has no instrument of its own".into(),
            ));
        };
        // The current calibration, the one campaigns submitted now are given.
        let correction = self
            .current_calibration()
            .and_then(|c| self.shared.runner.pose_correction(&c.toml));
        let mut console = Console::new(motion).with_correction(correction);
        let answer = match action {
            ConsoleAction::State => to_json(console.state().await),
            ConsoleAction::Move(targets) => to_json(console.move_axes(&targets).await?),
            ConsoleAction::MoveGeometry(g) => to_json(console.move_geometry(&g).await?),
            ConsoleAction::Jog { axis, delta_deg } => to_json(console.jog(&axis, delta_deg).await?),
            ConsoleAction::Home(axis) => {
                console.home(axis.as_deref()).await?;
                to_json(console.state().await)
            }
            ConsoleAction::Filter(choice) => {
                let position = console.filter(choice).await?;
                to_json(FilterMoved { position })
            }
            ConsoleAction::Read { count } => to_json(console.read(count).await?),
        };
        if let Err(e) = &answer {
            tracing::warn!(%who, "console request failed: {e}");
        }
        answer
    }
}
