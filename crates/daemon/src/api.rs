//! The HTTP/JSON control API of `gonio daemon` (axum), and the server loop that serves it.
//!
//! Routes (all JSON; errors are `{"error": "..."}` with 400, 401, 403, 404, 405, 408, 409, 413, 421, 503 or
//! 500):
//! - `POST /api/campaigns` (campaign TOML body) -> 201 `{"id": N}`
//! - `GET /api/campaigns`, `GET /api/campaigns/{id}` -> state, points done/total, ETA, last error, operator message
//! - `POST /api/campaigns/{id}/pause|resume|abort|confirm` -> 200 with the campaign (409 when its state does not
//!   allow it)
//! - `GET /api/campaigns/{id}/points.csv` -> `text/csv`, the columns of `gonio run`
//! - `GET /api/campaigns/{id}/report.html` -> `text/html`, the campaign's measurement report as `gonio report`
//!   writes it (every model fitted: seconds)
//! - `POST /api/estop` -> 200
//! - `GET /api/events` -> server-sent events, one per engine event, `data` the JSON of
//!   [`Event`](gonio_engine::control::Event) with its `type`
//! - `/api/console/...`: the console (state, move, jog, home, filter, read, a live reading stream), see
//!   [`console`]
//! - `/api/align`, `/api/align/confirm|abort`, `/api/calibrations`, `/api/calibrations/{id}` (the TOML file),
//!   `/api/calibrations/{id}/report.json`: the alignment action and the stored calibrations, see [`align`]
//! - `GET /` and `/assets/*`: the live status page ([`crate::status_page`]), the only routes without the token
//!
//! Safety of the service itself:
//! - The token rule: the daemon listens on loopback by default; listening on any other address needs a token
//!   ([`check_listen`] refuses to start without one), and when a token is set every request must carry it as
//!   `Authorization: Bearer <token>`, compared in constant time ([`constant_time_eq`]), before any body is read.
//! - Browsers: a request naming a `Host` that is not the daemon's (DNS rebinding) is refused with 421, a POST
//!   from a web page of another origin (CSRF) with 403; the status page, the CLI and curl pass ([`origin`]).
//! - Request bodies are limited ([`ApiConfig::body_limit_bytes`], 413 beyond, announced or streamed) and must
//!   arrive within [`ApiConfig::body_read_timeout`] (408); requests other than the event stream time out;
//!   headers must arrive within [`ApiConfig::header_read_timeout`]; at most [`ApiConfig::max_event_streams`]
//!   event streams are open (503 beyond); the number of open connections is bounded, and when it is reached the
//!   oldest connection that is not being served (idle, or a client still trickling its headers or body) is
//!   closed to admit the newcomer; a client that stops reading is dropped after [`ApiConfig::write_timeout`]
//!   (see [`connections`]). So a slow or hostile client can neither take the daemon down nor lock others out.

//!
//! Parts: this file holds the configuration, the token rule, the router and its middleware; `handlers` the
//! routes; `console` and `align` theirs; `server` the accept loop and the daemon's life; `connections` and `origin` the policing above.

mod align;
mod connections;
mod console;
mod handlers;
mod origin;
mod server;
pub mod wire;

pub use connections::ConnectionLimits;
pub use origin::HostPolicy;
pub use server::{run_daemon, serve, serve_with};

use align::{align_action, align_start, align_status, calibration, calibration_report, calibrations};
use console::{
    console_filter, console_home, console_jog, console_move, console_read, console_readings, console_state,
};
use handlers::{
    action, estop, events, list, method_not_allowed, not_found, points_csv, report_html, show, submit,
};

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::{Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use tokio::sync::Semaphore;

use crate::service::{Service, ServiceError, Shutdown};

/// Where the daemon listens unless told otherwise.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
/// Largest accepted request body (a campaign file): 1 MiB.
pub const DEFAULT_BODY_LIMIT_BYTES: usize = 1 << 20;
/// Time a request (other than the event stream) may take, body upload included.
pub const DEFAULT_REQUEST_TIMEOUT: Duration = Duration::from_secs(30);
/// Time a client has to send its request headers.
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);
/// Time a client has to send a request body (a campaign file).
pub const BODY_READ_TIMEOUT: Duration = Duration::from_secs(20);
/// A response write blocked this long (the client stopped reading) ends the connection.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(20);
/// Time a console move, jog or homing may take before its request answers 408 (the motion goes on).
pub const CONSOLE_MOTION_TIMEOUT: Duration = Duration::from_secs(600);
/// Event streams open at most (each holds a connection for as long as its client listens).
pub const MAX_EVENT_STREAMS: usize = 64;
/// Request header naming the submitted file, used in validation messages.
pub const ORIGIN_HEADER: &str = "x-gonio-origin";
/// Open connections at most; past it the oldest idle connection is closed to admit a new client (or the new
/// client waits while every connection is serving a request).
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
    /// Time a client has to send its request headers.
    pub header_read_timeout: Duration,
    /// Time a client has to send a request body.
    pub body_read_timeout: Duration,
    /// A response write blocked this long ends the connection.
    pub write_timeout: Duration,
    /// Open connections at most.
    pub max_connections: usize,
    /// Open event streams at most (fewer than `max_connections`, so that they cannot take every connection).
    pub max_event_streams: usize,
    /// Host names the daemon answers to besides localhost and its addresses (see [`origin`]): requests naming
    /// any other `Host` are refused (DNS rebinding).
    pub allowed_hosts: Vec<String>,
    /// The address listened on, for the `Host` check; [`run_daemon`] sets it from its listener.
    pub listen_addr: Option<SocketAddr>,
}

impl ApiConfig {
    /// The server loop's part of the configuration.
    pub fn connection_limits(&self) -> ConnectionLimits {
        ConnectionLimits {
            max_connections: self.max_connections.max(1),
            header_read_timeout: self.header_read_timeout,
            write_timeout: self.write_timeout,
        }
    }
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ApiConfig::default().connection_limits()
    }
}

impl std::fmt::Debug for ApiConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never print the token.
        f.debug_struct("ApiConfig")
            .field("token", &self.token.as_ref().map(|_| "<set>"))
            .field("body_limit_bytes", &self.body_limit_bytes)
            .field("request_timeout", &self.request_timeout)
            .field("header_read_timeout", &self.header_read_timeout)
            .field("body_read_timeout", &self.body_read_timeout)
            .field("write_timeout", &self.write_timeout)
            .field("max_connections", &self.max_connections)
            .field("max_event_streams", &self.max_event_streams)
            .field("allowed_hosts", &self.allowed_hosts)
            .field("listen_addr", &self.listen_addr)
            .finish()
    }
}

impl Default for ApiConfig {
    fn default() -> Self {
        ApiConfig {
            token: None,
            body_limit_bytes: DEFAULT_BODY_LIMIT_BYTES,
            request_timeout: DEFAULT_REQUEST_TIMEOUT,
            header_read_timeout: HEADER_READ_TIMEOUT,
            body_read_timeout: BODY_READ_TIMEOUT,
            write_timeout: WRITE_TIMEOUT,
            max_connections: MAX_CONNECTIONS,
            max_event_streams: MAX_EVENT_STREAMS,
            allowed_hosts: Vec::new(),
            listen_addr: None,
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

/// Compare a given token with the expected one in time that depends only on the lengths, never on the
/// contents: every byte of `expected` is compared (against zero past the end of `given`), with `subtle`'s
/// branch-free comparisons, and the length check is folded in at the end. The length of a token is not a secret
/// worth hiding (a good token is long and random).
pub fn constant_time_eq(given: &[u8], expected: &[u8]) -> bool {
    use subtle::{Choice, ConstantTimeEq};
    let mut equal = Choice::from(1u8);
    for (i, e) in expected.iter().enumerate() {
        let g = given.get(i).copied().unwrap_or(0);
        equal &= g.ct_eq(e);
    }
    equal &= (given.len() as u64).ct_eq(&(expected.len() as u64));
    equal.into()
}

#[derive(Clone)]
struct AppState {
    service: Service,
    token: Option<Arc<str>>,
    body_limit_bytes: usize,
    body_read_timeout: Duration,
    request_timeout: Duration,
    /// One permit per open event stream.
    event_streams: Arc<Semaphore>,
    max_event_streams: usize,
    shutdown: Shutdown,
}

impl AppState {
    /// One of the bounded event-stream permits (the events, the console's readings): each stream holds a
    /// connection for as long as its client listens, so streams cannot take every connection. 503 beyond.
    fn event_stream_permit(&self) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
        Arc::clone(&self.event_streams).try_acquire_owned().map_err(|_| {
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "{} event streams are open, the most this daemon serves: close one and retry",
                    self.max_event_streams
                ),
            )
        })
    }
}

/// The API's routes with their middleware (token check, timeouts).
pub fn router(service: Service, config: &ApiConfig, shutdown: Shutdown) -> Router {
    let state = AppState {
        service,
        token: config.token.as_deref().map(Arc::from),
        body_limit_bytes: config.body_limit_bytes,
        body_read_timeout: config.body_read_timeout,
        request_timeout: config.request_timeout,
        event_streams: Arc::new(Semaphore::new(config.max_event_streams)),
        max_event_streams: config.max_event_streams,
        shutdown,
    };
    let timed = Router::new()
        .route("/api/campaigns", post(submit).get(list))
        .route("/api/campaigns/{id}", get(show))
        .route("/api/campaigns/{id}/points.csv", get(points_csv))
        .route("/api/campaigns/{id}/report.html", get(report_html))
        .route("/api/campaigns/{id}/{action}", post(action))
        .route("/api/estop", post(estop))
        .route("/api/console/state", get(console_state))
        .route("/api/console/filter", post(console_filter))
        .route("/api/console/read", get(console_read))
        .route("/api/align", post(align_start).get(align_status))
        .route("/api/align/{action}", post(align_action))
        .route("/api/calibrations", get(calibrations))
        .route("/api/calibrations/{id}", get(calibration))
        .route("/api/calibrations/{id}/report.json", get(calibration_report))
        .layer(middleware::from_fn_with_state(state.clone(), request_deadline));
    // A console move or homing takes as long as the instrument needs (every device wait has its own deadline).
    let motion = Router::new()
        .route("/api/console/move", post(console_move))
        .route("/api/console/jog", post(console_jog))
        .route("/api/console/home", post(console_home))
        .layer(middleware::from_fn_with_state(state.clone(), motion_deadline));
    // The event stream lives as long as the client listens: no request timeout on it.
    Router::new()
        .route("/api/events", get(events))
        .route("/api/console/readings", get(console_readings))
        .merge(timed)
        .merge(motion)
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(middleware::from_fn_with_state(state.clone(), require_token))
        .with_state(state)
        // The status page's embedded files hold no data: outside the token check (the page sends the token).
        .merge(crate::status_page::router())
        // A wrong method on the status page's routes answers JSON too (the API's own routes have theirs, behind
        // the token check, which this does not replace).
        .method_not_allowed_fallback(method_not_allowed)
        // Outermost, on every route: foreign Host names (DNS rebinding) and cross-site state changes (CSRF).
        .layer(middleware::from_fn_with_state(
            Arc::new(HostPolicy::new(&config.allowed_hosts, config.listen_addr)),
            origin::check,
        ))
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
        (self.status, axum::Json(wire::ErrorBody { error: self.message })).into_response()
    }
}

impl From<ServiceError> for ApiError {
    fn from(e: ServiceError) -> Self {
        let status = match &e {
            ServiceError::NotFound(_) | ServiceError::NoCalibration(_) => StatusCode::NOT_FOUND,
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
        .and_then(|v| bearer_token(v.as_bytes()))
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

/// The token of an `Authorization: Bearer <token>` value (the scheme name is case-insensitive, RFC 9110).
fn bearer_token(value: &[u8]) -> Option<&[u8]> {
    let (scheme, token) = value.split_at_checked(7)?;
    scheme.eq_ignore_ascii_case(b"bearer ").then_some(token)
}

/// Console motion requests end within [`CONSOLE_MOTION_TIMEOUT`], with a JSON 408 past it (the move itself
/// completes: it runs in its own task).
async fn motion_deadline(request: Request, next: Next) -> Response {
    match tokio::time::timeout(CONSOLE_MOTION_TIMEOUT, next.run(request)).await {
        Ok(response) => response,
        Err(_) => ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the console move took longer than {} s; it goes on: ask for the state",
                CONSOLE_MOTION_TIMEOUT.as_secs_f64()
            ),
        )
        .into_response(),
    }
}

/// Requests (other than the event stream) end within the request timeout, with a JSON 408 past it.
async fn request_deadline(State(state): State<AppState>, request: Request, next: Next) -> Response {
    match tokio::time::timeout(state.request_timeout, next.run(request)).await {
        Ok(response) => response,
        Err(_) => ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request took longer than {} s",
                state.request_timeout.as_secs_f64()
            ),
        )
        .into_response(),
    }
}

#[cfg(test)]
mod tests;
