//! The route handlers: submitting, listing, showing and acting on campaigns, their points as CSV, the
//! emergency stop, the event stream, and the JSON answers for unknown routes and methods.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::{Path, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use serde_json::json;
use tokio::sync::broadcast;

use super::{ApiError, AppState, ORIGIN_HEADER, connections};
use gonio_engine::store::CampaignId;

fn parse_id(raw: &str) -> Result<CampaignId, ApiError> {
    raw.parse::<i64>().map(CampaignId).map_err(|_| {
        ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no campaign with id {raw:?}: ids are integers"),
        )
    })
}

pub(super) async fn submit(State(state): State<AppState>, request: Request) -> Result<Response, ApiError> {
    let limit = state.body_limit_bytes;
    let too_large = || {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the campaign file is over {limit} bytes"),
        )
    };
    // Refuse early on the announced length; `to_bytes` also stops a chunked body at the limit.
    let announced = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if announced.is_some_and(|n| n > limit as u64) {
        return Err(too_large());
    }
    let origin = request.headers().clone();
    // While the body arrives the daemon only waits for the client: its connection may be closed under pressure
    // (see `connections`), and the whole body must come within the deadline.
    let waiting = request
        .extensions()
        .get::<connections::ConnTag>()
        .map(connections::ConnTag::waiting_for_client);
    let read_timeout = state.body_read_timeout;
    let read = tokio::time::timeout(read_timeout, axum::body::to_bytes(request.into_body(), limit))
        .await
        .map_err(|_| {
            ApiError::new(
                StatusCode::REQUEST_TIMEOUT,
                format!(
                    "the campaign file did not arrive within {} s",
                    read_timeout.as_secs_f64()
                ),
            )
        })?;
    drop(waiting);
    let bytes = read.map_err(|e| {
        if std::error::Error::source(&e).is_some_and(|s| s.is::<http_body_util::LengthLimitError>())
            || e.to_string().contains("length limit")
        {
            too_large()
        } else {
            ApiError::new(
                StatusCode::BAD_REQUEST,
                format!("cannot read the request body: {e}"),
            )
        }
    })?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            format!("the campaign file is not UTF-8 text: {e}"),
        )
    })?;
    // The client may name its file, so that messages say "demo.toml:12"; only a plain, short name is taken.
    let origin = origin
        .get(ORIGIN_HEADER)
        .and_then(|v| v.to_str().ok())
        .filter(|v| !v.is_empty() && v.len() <= 256 && !v.chars().any(char::is_control))
        .unwrap_or("submitted campaign")
        .to_string();
    let service = state.service.clone();
    let text = text.to_string();
    // Validation plans the campaign (pure computation, possibly a few milliseconds): off the async threads.
    let id = tokio::task::spawn_blocking(move || service.submit(&text, &origin))
        .await
        .map_err(|e| {
            ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("validation task failed: {e}"),
            )
        })??;
    let mut response = (StatusCode::CREATED, axum::Json(super::wire::Submitted { id })).into_response();
    if let Ok(location) = HeaderValue::from_str(&format!("/api/campaigns/{id}")) {
        response.headers_mut().insert(header::LOCATION, location);
    }
    Ok(response)
}

pub(super) async fn list(State(state): State<AppState>) -> Result<Response, ApiError> {
    Ok(axum::Json(state.service.campaigns()?).into_response())
}

pub(super) async fn show(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    Ok(axum::Json(state.service.campaign(parse_id(&id)?)?).into_response())
}

pub(super) async fn action(
    State(state): State<AppState>,
    Path((id, action)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let id = parse_id(&id)?;
    let service = &state.service;
    let view = match action.as_str() {
        "pause" => service.pause(id)?,
        "resume" => service.resume(id)?,
        "abort" => service.abort(id)?,
        "confirm" => service.confirm(id)?,
        other => {
            return Err(ApiError::new(
                StatusCode::NOT_FOUND,
                format!("unknown action {other:?}: expected pause, resume, abort or confirm"),
            ));
        }
    };
    Ok(axum::Json(view).into_response())
}

pub(super) async fn points_csv(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = parse_id(&id)?;
    let service = state.service.clone();
    let csv = tokio::task::spawn_blocking(move || service.points_csv(id))
        .await
        .map_err(|e| {
            ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("export task failed: {e}"),
            )
        })??;
    Ok(([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], csv).into_response())
}

pub(super) async fn report_html(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = parse_id(&id)?;
    let service = state.service.clone();
    let page = tokio::task::spawn_blocking(move || service.report_html(id))
        .await
        .map_err(|e| {
            ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("report task failed: {e}"),
            )
        })??;
    Ok(([(header::CONTENT_TYPE, "text/html; charset=utf-8")], page).into_response())
}

pub(super) async fn estop(State(state): State<AppState>) -> Result<Response, ApiError> {
    state.service.estop()?;
    Ok(axum::Json(json!({ "estop": true })).into_response())
}

pub(super) async fn method_not_allowed(request: Request) -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        format!("{} is not allowed on {}", request.method(), request.uri().path()),
    )
}

pub(super) async fn not_found(request: Request) -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        format!("no route {} {}", request.method(), request.uri().path()),
    )
}

/// The event stream: every event as `event: <type>` and `data: <json>`, until the client leaves or the daemon
/// shuts down. A client too slow to keep up gets a `lagged` event saying how many it missed.
pub(super) async fn events(
    State(state): State<AppState>,
) -> Result<Sse<impl futures_util::Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    // Each stream holds a connection as long as its client listens: bounded, so that streams cannot take every
    // connection.
    let permit = state.event_stream_permit()?;
    let rx = state.service.subscribe();
    let start = (rx, state.shutdown, permit);
    let stream = futures_util::stream::unfold(start, |(mut rx, mut shutdown, permit)| async move {
        let received = tokio::select! {
            r = rx.recv() => r,
            _ = shutdown.recv() => return None,
        };
        let event = match received {
            Ok(event) => {
                let data = serde_json::to_value(&event)
                    .unwrap_or_else(|e| json!({ "type": "error", "error": e.to_string() }));
                let kind = data
                    .get("type")
                    .and_then(|t| t.as_str())
                    .unwrap_or("event")
                    .to_string();
                SseEvent::default().event(kind).data(data.to_string())
            }
            Err(broadcast::error::RecvError::Lagged(missed)) => SseEvent::default().event("lagged").data(
                serde_json::to_string(&super::wire::StreamNotice::Lagged { missed }).unwrap_or_default(),
            ),
            Err(broadcast::error::RecvError::Closed) => return None,
        };
        Some((Ok(event), (rx, shutdown, permit)))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
