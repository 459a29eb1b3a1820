//! The console's routes: the instrument's state, safe moves, jog, homing, the wheel, meter readings and their
//! live stream ([`crate::service::ConsoleAction`]). Every answer is JSON; a refused request is 409 with the rule
//! it breaks and nothing moved, a malformed one 400.
//!
//! - `GET /api/console/state`
//! - `POST /api/console/move` `{"axes": {"detector": 40.0, ...}}` (physical degrees) or `{"geometry":
//!   [theta_i, phi_i, theta_o, phi_o]}` (degrees) -> the axes' read-back positions
//! - `POST /api/console/jog` `{"axis": "tilt", "delta_deg": 0.5}`
//! - `POST /api/console/home` `{}` (every axis) or `{"axis": "light"}` -> the state
//! - `POST /api/console/filter` `{"filter": "3"}` or `{"filter": "550nm"}` -> `{"position": N}`
//! - `GET /api/console/read?count=N` -> N readings
//! - `GET /api/console/readings?interval_ms=M` -> server-sent events, `reading` (one reading) or `unavailable`
//!   (`{"error": ...}`: the instrument is not the console's now, say a campaign runs), every M ms (at least
//!   [`MIN_STREAM_INTERVAL_MS`]), until the client leaves or the daemon shuts down

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

use super::{ApiError, AppState};
use crate::service::ConsoleAction;
use gonio_engine::console::parse_filter_choice;
use gonio_scheduler::kinematics::Geometry;

/// The live stream reads no faster than this (ms): a person watches it, and each reading takes the instrument.
pub const MIN_STREAM_INTERVAL_MS: u64 = 50;
/// The live stream's interval when the client names none (ms).
pub const DEFAULT_STREAM_INTERVAL_MS: u64 = 250;

/// Who sent a console request, for the log: with a token set every request carries it.
pub(super) fn who(state: &AppState) -> &'static str {
    if state.token.is_some() {
        "token holder"
    } else {
        "loopback"
    }
}

pub(super) fn parse_body<T: for<'de> Deserialize<'de>>(body: &Bytes, example: &str) -> Result<T, ApiError> {
    let body: &[u8] = if body.iter().all(u8::is_ascii_whitespace) {
        b"{}"
    } else {
        body
    };
    serde_json::from_slice(body).map_err(|e| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            format!("the request body: {e}; expected JSON like {example}"),
        )
    })
}

async fn run(state: &AppState, action: ConsoleAction) -> Result<Response, ApiError> {
    let answer = state.service.console(who(state), action).await?;
    Ok(axum::Json(answer).into_response())
}

pub(super) async fn console_state(State(state): State<AppState>) -> Result<Response, ApiError> {
    run(&state, ConsoleAction::State).await
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MoveBody {
    #[serde(default)]
    axes: Option<BTreeMap<String, f64>>,
    #[serde(default)]
    geometry: Option<[f64; 4]>,
}

pub(super) async fn console_move(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let example = r#"{"axes": {"detector": 40.0}} or {"geometry": [30, 0, 30, 180]}"#;
    let body: MoveBody = parse_body(&body, example)?;
    let action = match (body.axes, body.geometry) {
        (Some(axes), None) => ConsoleAction::Move(axes.into_iter().collect()),
        (None, Some([ti, pi, to, po])) => ConsoleAction::MoveGeometry(Geometry::new(ti, pi, to, po)),
        _ => {
            return Err(ApiError::new(
                StatusCode::BAD_REQUEST,
                format!("a move names either axes or a geometry, e.g. {example}"),
            ));
        }
    };
    run(&state, action).await
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JogBody {
    axis: String,
    delta_deg: f64,
}

pub(super) async fn console_jog(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let body: JogBody = parse_body(&body, r#"{"axis": "tilt", "delta_deg": 0.5}"#)?;
    run(
        &state,
        ConsoleAction::Jog {
            axis: body.axis,
            delta_deg: body.delta_deg,
        },
    )
    .await
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct HomeBody {
    #[serde(default)]
    axis: Option<String>,
}

pub(super) async fn console_home(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let body: HomeBody = parse_body(&body, r#"{} or {"axis": "light"}"#)?;
    run(&state, ConsoleAction::Home(body.axis)).await
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FilterBody {
    filter: serde_json::Value,
}

pub(super) async fn console_filter(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let body: FilterBody = parse_body(&body, r#"{"filter": "3"} or {"filter": "550nm"}"#)?;
    let text = match &body.filter {
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Number(n) => n.to_string(),
        other => {
            return Err(ApiError::new(
                StatusCode::BAD_REQUEST,
                format!("filter {other}: a wheel position or a band such as \"550nm\""),
            ));
        }
    };
    let choice =
        parse_filter_choice(&text).map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.to_string()))?;
    run(&state, ConsoleAction::Filter(choice)).await
}

#[derive(Debug, Deserialize)]
pub(super) struct ReadQuery {
    count: Option<usize>,
}

pub(super) async fn console_read(
    State(state): State<AppState>,
    Query(q): Query<ReadQuery>,
) -> Result<Response, ApiError> {
    run(
        &state,
        ConsoleAction::Read {
            count: q.count.unwrap_or(1),
        },
    )
    .await
}

#[derive(Debug, Deserialize)]
pub(super) struct StreamQuery {
    interval_ms: Option<u64>,
}

/// The stream's event for a reading it could not take.
fn unavailable(error: String) -> SseEvent {
    SseEvent::default()
        .event("unavailable")
        .data(serde_json::to_string(&super::wire::Unavailable { error }).unwrap_or_default())
}

/// The live readings (module doc). Each reading is one console action, so a move waits for it and a campaign
/// that starts meanwhile makes the stream say `unavailable` until the instrument is free again.
pub(super) async fn console_readings(
    State(state): State<AppState>,
    Query(q): Query<StreamQuery>,
) -> Result<Sse<impl futures_util::Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    let permit = state.event_stream_permit()?;
    let interval = Duration::from_millis(
        q.interval_ms
            .unwrap_or(DEFAULT_STREAM_INTERVAL_MS)
            .max(MIN_STREAM_INTERVAL_MS),
    );
    let who = who(&state);
    let start = (state.service.clone(), state.shutdown.clone(), permit, true);
    let stream =
        futures_util::stream::unfold(start, move |(service, mut shutdown, permit, first)| async move {
            if !first {
                tokio::select! {
                    _ = tokio::time::sleep(interval) => {}
                    _ = shutdown.recv() => return None,
                }
            }
            let read = tokio::select! {
                r = service.console(who, ConsoleAction::Read { count: 1 }) => r,
                _ = shutdown.recv() => return None,
            };
            let event = match read {
                Ok(serde_json::Value::Array(mut readings)) if !readings.is_empty() => SseEvent::default()
                    .event("reading")
                    .data(readings.swap_remove(0).to_string()),
                Ok(other) => unavailable(format!("unexpected answer {other}")),
                Err(e) => unavailable(e.to_string()),
            };
            Some((Ok(event), (service, shutdown, permit, false)))
        });
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
