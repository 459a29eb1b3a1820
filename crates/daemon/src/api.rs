//! The HTTP/JSON control API of `gonio daemon` (axum), and the server loop that serves it.
//!
//! Routes (all JSON; errors are `{"error": "..."}` with 400, 401, 404, 409, 413 or 500):
//! - `POST /api/campaigns` (campaign TOML body) -> 201 `{"id": N}`
//! - `GET /api/campaigns`, `GET /api/campaigns/{id}` -> state, points done/total, ETA, last error, operator message
//! - `POST /api/campaigns/{id}/pause|resume|abort|confirm` -> 200 with the campaign (409 when its state does not
//!   allow it)
//! - `GET /api/campaigns/{id}/points.csv` -> `text/csv`, the columns of `gonio run`
//! - `POST /api/estop` -> 200
//! - `GET /api/events` -> server-sent events, one per engine event, `data` the JSON of
//!   [`Event`](crate::control::Event) with its `type`
//!
//! Safety of the service itself:
//! - The token rule: the daemon listens on loopback by default; listening on any other address needs a token
//!   ([`check_listen`] refuses to start without one), and when a token is set every request must carry it as
//!   `Authorization: Bearer <token>`, compared in constant time.
//! - Request bodies are limited ([`ApiConfig::body_limit_bytes`], 413 beyond), requests other than the event
//!   stream time out, headers must arrive within [`HEADER_READ_TIMEOUT`], and the number of open connections is
//!   bounded, so a slow or hostile client cannot take the daemon down.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::json;
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, broadcast, mpsc};
use tower_http::timeout::TimeoutLayer;

use crate::service::{Service, ServiceError, Shutdown};
use crate::store::CampaignId;

/// Where the daemon listens unless told otherwise.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
/// Largest accepted request body (a campaign file): 1 MiB.
pub const DEFAULT_BODY_LIMIT_BYTES: usize = 1 << 20;
/// Time a request (other than the event stream) may take, body upload included.
pub const DEFAULT_REQUEST_TIMEOUT: Duration = Duration::from_secs(30);
/// Time a client has to send its request headers.
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);
/// Request header naming the submitted file, used in validation messages.
pub const ORIGIN_HEADER: &str = "x-gonio-origin";
/// Open connections at most; further clients wait in the kernel's backlog.
pub const MAX_CONNECTIONS: usize = 256;
/// Time a connection is given to finish at shutdown.
const CONNECTION_DRAIN: Duration = Duration::from_secs(5);

/// Configuration of the HTTP layer.
#[derive(Clone)]
pub struct ApiConfig {
    /// When set, every request must carry `Authorization: Bearer <token>`.
    pub token: Option<String>,
    pub body_limit_bytes: usize,
    pub request_timeout: Duration,
}

impl std::fmt::Debug for ApiConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never print the token.
        f.debug_struct("ApiConfig")
            .field("token", &self.token.as_ref().map(|_| "<set>"))
            .field("body_limit_bytes", &self.body_limit_bytes)
            .field("request_timeout", &self.request_timeout)
            .finish()
    }
}

impl Default for ApiConfig {
    fn default() -> Self {
        ApiConfig {
            token: None,
            body_limit_bytes: DEFAULT_BODY_LIMIT_BYTES,
            request_timeout: DEFAULT_REQUEST_TIMEOUT,
        }
    }
}

/// Why the daemon refuses to listen.
#[derive(Debug, thiserror::Error)]
pub enum ListenError {
    #[error(
        "refusing to listen on {0} without a token: any address other than loopback (127.0.0.1, ::1) lets other \
         machines drive the instrument; give one with --token or the GONIO_TOKEN environment variable"
    )]
    TokenRequired(SocketAddr),
    #[error("the token is empty: give a non-empty --token or GONIO_TOKEN")]
    EmptyToken,
}

/// The token rule: loopback needs no token, any other address does; a given token must not be empty.
pub fn check_listen(addr: SocketAddr, token: Option<&str>) -> Result<(), ListenError> {
    match token {
        Some("") => Err(ListenError::EmptyToken),
        Some(_) => Ok(()),
        None if addr.ip().is_loopback() => Ok(()),
        None => Err(ListenError::TokenRequired(addr)),
    }
}

/// Compare two byte strings in time that depends only on their lengths, not on where they differ.
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    use subtle::ConstantTimeEq;
    // `ct_eq` on slices of different lengths returns false at once; the length of a token is not a secret
    // worth hiding (a good token is long and random).
    a.ct_eq(b).into()
}

#[derive(Clone)]
struct AppState {
    service: Service,
    token: Option<Arc<str>>,
    body_limit_bytes: usize,
    shutdown: Shutdown,
}

/// The API's routes with their middleware (token check, timeouts).
pub fn router(service: Service, config: &ApiConfig, shutdown: Shutdown) -> Router {
    let state = AppState {
        service,
        token: config.token.as_deref().map(Arc::from),
        body_limit_bytes: config.body_limit_bytes,
        shutdown,
    };
    let timed = Router::new()
        .route("/api/campaigns", post(submit).get(list))
        .route("/api/campaigns/{id}", get(show))
        .route("/api/campaigns/{id}/points.csv", get(points_csv))
        .route("/api/campaigns/{id}/{action}", post(action))
        .route("/api/estop", post(estop))
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            config.request_timeout,
        ));
    // The event stream lives as long as the client listens: no request timeout on it.
    Router::new()
        .route("/api/events", get(events))
        .merge(timed)
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(state.clone(), require_token))
        .with_state(state)
}

/// An error as the API returns it: a status and `{"error": "..."}`.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
}

impl ApiError {
    fn new(status: StatusCode, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            message: message.into(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.status, axum::Json(json!({ "error": self.message }))).into_response()
    }
}

impl From<ServiceError> for ApiError {
    fn from(e: ServiceError) -> Self {
        let status = match &e {
            ServiceError::NotFound(_) => StatusCode::NOT_FOUND,
            ServiceError::Invalid(_) => StatusCode::BAD_REQUEST,
            ServiceError::Conflict(_) => StatusCode::CONFLICT,
            ServiceError::Store(_) | ServiceError::Internal(_) => {
                tracing::error!("request failed: {e}");
                StatusCode::INTERNAL_SERVER_ERROR
            }
        };
        ApiError::new(status, e.to_string())
    }
}

async fn require_token(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let Some(expected) = &state.token else {
        return next.run(request).await;
    };
    let given = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.as_bytes().strip_prefix(b"Bearer "))
        .unwrap_or_default();
    if constant_time_eq(given, expected.as_bytes()) {
        return next.run(request).await;
    }
    tracing::warn!(path = %request.uri().path(), "request without a valid token refused");
    let mut response = ApiError::new(
        StatusCode::UNAUTHORIZED,
        "missing or wrong token: send 'Authorization: Bearer <token>'",
    )
    .into_response();
    response
        .headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    response
}

fn parse_id(raw: &str) -> Result<CampaignId, ApiError> {
    raw.parse::<i64>().map(CampaignId).map_err(|_| {
        ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no campaign with id {raw:?}: ids are integers"),
        )
    })
}

async fn submit(State(state): State<AppState>, request: Request) -> Result<Response, ApiError> {
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
    let bytes = axum::body::to_bytes(request.into_body(), limit)
        .await
        .map_err(|e| {
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
    let mut response = (StatusCode::CREATED, axum::Json(json!({ "id": id }))).into_response();
    if let Ok(location) = HeaderValue::from_str(&format!("/api/campaigns/{id}")) {
        response.headers_mut().insert(header::LOCATION, location);
    }
    Ok(response)
}

async fn list(State(state): State<AppState>) -> Result<Response, ApiError> {
    Ok(axum::Json(state.service.campaigns()?).into_response())
}

async fn show(State(state): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    Ok(axum::Json(state.service.campaign(parse_id(&id)?)?).into_response())
}

async fn action(
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

async fn points_csv(State(state): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
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

async fn estop(State(state): State<AppState>) -> Result<Response, ApiError> {
    state.service.estop()?;
    Ok(axum::Json(json!({ "estop": true })).into_response())
}

async fn not_found(request: Request) -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        format!("no route {} {}", request.method(), request.uri().path()),
    )
}

/// The event stream: every event as `event: <type>` and `data: <json>`, until the client leaves or the daemon
/// shuts down. A client too slow to keep up gets a `lagged` event saying how many it missed.
async fn events(
    State(state): State<AppState>,
) -> Sse<impl futures_util::Stream<Item = Result<SseEvent, Infallible>>> {
    let rx = state.service.subscribe();
    let stream = futures_util::stream::unfold((rx, state.shutdown), |(mut rx, mut shutdown)| async move {
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
            Err(broadcast::error::RecvError::Lagged(missed)) => SseEvent::default()
                .event("lagged")
                .data(json!({ "type": "lagged", "missed": missed }).to_string()),
            Err(broadcast::error::RecvError::Closed) => return None,
        };
        Some((Ok(event), (rx, shutdown)))
    });
    Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
}

/// Serve `app` on `listener` until `shutdown`, then let open connections finish (bounded). `_complete` is
/// dropped when every connection has ended.
pub async fn serve(listener: TcpListener, app: Router, mut shutdown: Shutdown, complete: mpsc::Sender<()>) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;

    let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    loop {
        let permit = tokio::select! {
            p = slots.clone().acquire_owned() => match p { Ok(p) => p, Err(_) => break },
            _ = shutdown.recv() => break,
        };
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: back off instead of spinning.
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = shutdown.recv() => break,
        };
        let service = TowerToHyperService::new(app.clone());
        let mut conn_shutdown = shutdown.clone();
        let complete = complete.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let _complete = complete;
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_READ_TIMEOUT);
            let conn = builder.serve_connection(TokioIo::new(stream), service);
            let mut conn = std::pin::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r { tracing::debug!(%peer, "connection ended: {e}"); }
                }
                _ = conn_shutdown.recv() => {
                    conn.as_mut().graceful_shutdown();
                    let _ = tokio::time::timeout(CONNECTION_DRAIN, conn).await;
                }
            }
        });
    }
    tracing::info!("no longer accepting connections");
}

/// Run the daemon on a bound listener: the campaign queue and the API, until `signal` completes; then stop the
/// running campaign at a safe point and wait for every task to finish.
pub async fn run_daemon(
    listener: TcpListener,
    service: Service,
    config: &ApiConfig,
    signal: impl std::future::Future<Output = ()>,
) {
    let trigger = crate::service::ShutdownTrigger::new();
    let (complete_tx, mut complete_rx) = mpsc::channel::<()>(1);
    let queue = {
        let service = service.clone();
        let shutdown = trigger.subscribe();
        let complete = complete_tx.clone();
        tokio::spawn(async move { service.run_queue(shutdown, complete).await })
    };
    let app = router(service, config, trigger.subscribe());
    let server = tokio::spawn(serve(listener, app, trigger.subscribe(), complete_tx.clone()));
    drop(complete_tx);
    signal.await;
    tracing::info!("shutting down");
    trigger.trigger();
    // Every task holds a completion sender: recv() returns None once all are gone.
    let _ = complete_rx.recv().await;
    let _ = queue.await;
    let _ = server.await;
    tracing::info!("shutdown complete");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_time_eq_matches_plain_equality() {
        let cases: [(&[u8], &[u8]); 6] = [
            (b"", b""),
            (b"secret", b"secret"),
            (b"secret", b"secreT"),
            (b"secret", b"Secret"),
            (b"secret", b"secret!"),
            (b"s", b""),
        ];
        for (a, b) in cases {
            assert_eq!(constant_time_eq(a, b), a == b, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn token_rule() {
        let loopback: SocketAddr = "127.0.0.1:7878".parse().expect("addr");
        let loopback6: SocketAddr = "[::1]:7878".parse().expect("addr");
        let any: SocketAddr = "0.0.0.0:7878".parse().expect("addr");
        let lan: SocketAddr = "192.0.2.10:7878".parse().expect("addr");
        assert!(check_listen(loopback, None).is_ok());
        assert!(check_listen(loopback6, None).is_ok());
        assert!(matches!(
            check_listen(any, None),
            Err(ListenError::TokenRequired(_))
        ));
        assert!(matches!(
            check_listen(lan, None),
            Err(ListenError::TokenRequired(_))
        ));
        assert!(check_listen(any, Some("t0k3n")).is_ok());
        assert!(matches!(
            check_listen(any, Some("")),
            Err(ListenError::EmptyToken)
        ));
        let message = check_listen(any, None).expect_err("refused").to_string();
        assert!(
            message.contains("0.0.0.0:7878") && message.contains("--token"),
            "{message}"
        );
    }
}
