//! The HTTP/JSON control API of `gonio daemon` (axum), and the server loop that serves it.
//!
//! Routes (all JSON; errors are `{"error": "..."}` with 400, 401, 403, 404, 405, 408, 409, 413, 421, 503 or
//! 500):
//! - `POST /api/campaigns` (campaign TOML body) -> 201 `{"id": N}`
//! - `GET /api/campaigns`, `GET /api/campaigns/{id}` -> state, points done/total, ETA, last error, operator message
//! - `POST /api/campaigns/{id}/pause|resume|abort|confirm` -> 200 with the campaign (409 when its state does not
//!   allow it)
//! - `GET /api/campaigns/{id}/points.csv` -> `text/csv`, the columns of `gonio run`
//! - `POST /api/estop` -> 200
//! - `GET /api/events` -> server-sent events, one per engine event, `data` the JSON of
//!   [`Event`](crate::control::Event) with its `type`
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

mod connections;
mod origin;

pub use connections::ConnectionLimits;
pub use origin::HostPolicy;

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
/// Time a client has to send a request body (a campaign file).
pub const BODY_READ_TIMEOUT: Duration = Duration::from_secs(20);
/// A response write blocked this long (the client stopped reading) ends the connection.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(20);
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
        .route("/api/campaigns/{id}/{action}", post(action))
        .route("/api/estop", post(estop))
        .layer(middleware::from_fn_with_state(state.clone(), request_deadline));
    // The event stream lives as long as the client listens: no request timeout on it.
    Router::new()
        .route("/api/events", get(events))
        .merge(timed)
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

async fn method_not_allowed(request: Request) -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        format!("{} is not allowed on {}", request.method(), request.uri().path()),
    )
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
) -> Result<Sse<impl futures_util::Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    // Each stream holds a connection as long as its client listens: bounded, so that streams cannot take every
    // connection.
    let permit = Arc::clone(&state.event_streams)
        .try_acquire_owned()
        .map_err(|_| {
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "{} event streams are open, the most this daemon serves: close one and retry",
                    state.max_event_streams
                ),
            )
        })?;
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
            Err(broadcast::error::RecvError::Lagged(missed)) => SseEvent::default()
                .event("lagged")
                .data(json!({ "type": "lagged", "missed": missed }).to_string()),
            Err(broadcast::error::RecvError::Closed) => return None,
        };
        Some((Ok(event), (rx, shutdown, permit)))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}

/// Serve `app` on `listener` until `shutdown` with the default [`ConnectionLimits`] (see [`serve_with`]).
pub async fn serve(listener: TcpListener, app: Router, shutdown: Shutdown, complete: mpsc::Sender<()>) {
    serve_with(listener, app, ConnectionLimits::default(), shutdown, complete).await;
}

/// Serve `app` on `listener` until `shutdown`, then let open connections finish (bounded). `_complete` is
/// dropped when every connection has ended. Connections are bounded and policed as [`connections`] says.
pub async fn serve_with(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    mut shutdown: Shutdown,
    complete: mpsc::Sender<()>,
) {
    let slots = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let registry = Arc::new(connections::Registry::default());
    loop {
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
        let permit = match Arc::clone(&slots).try_acquire_owned() {
            Ok(p) => p,
            Err(_) => {
                // Full: close the oldest connection that is not being served, else wait for one to end.
                if registry.evict_oldest_idle() {
                    tracing::warn!(%peer, open = registry.len(), "connection limit reached: closing the oldest idle connection");
                } else {
                    tracing::warn!(%peer, open = registry.len(), "connection limit reached: every connection is busy, waiting");
                }
                tokio::select! {
                    p = Arc::clone(&slots).acquire_owned() => match p { Ok(p) => p, Err(_) => break },
                    _ = shutdown.recv() => break,
                }
            }
        };
        let entry = registry.open();
        let mut conn_shutdown = shutdown.clone();
        let complete = complete.clone();
        let app = app.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let _complete = complete;
            serve_connection(stream, peer, app, entry, limits, &mut conn_shutdown).await;
        });
    }
    tracing::info!("no longer accepting connections");
}

/// One connection: HTTP/1.1 with the header deadline, the write deadline, eviction, and the requests marked
/// busy while they are served.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    app: Router,
    entry: connections::Entry,
    limits: ConnectionLimits,
    shutdown: &mut Shutdown,
) {
    use http_body_util::BodyExt;
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;

    let conn = Arc::clone(entry.conn());
    let inner = TowerToHyperService::new(app);
    let tracked = Arc::clone(&conn);
    let service = hyper::service::service_fn(move |mut request: hyper::Request<hyper::body::Incoming>| {
        let busy = connections::Busy::new(&tracked);
        request
            .extensions_mut()
            .insert(connections::ConnTag(Arc::clone(&tracked)));
        let response = hyper::service::Service::call(&inner, request);
        async move {
            let response = response.await?;
            // The request counts as served until its response body is sent (event streams: until they end).
            Ok::<_, Infallible>(response.map(|body| {
                axum::body::Body::new(body.map_frame(move |frame| {
                    let _ = &busy;
                    frame
                }))
            }))
        }
    });
    let io = TokioIo::new(connections::WriteDeadline::new(stream, limits.write_timeout));
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout);
    let http = builder.serve_connection(io, service);
    let mut http = std::pin::pin!(http);
    tokio::select! {
        r = http.as_mut() => {
            if let Err(e) = r { tracing::debug!(%peer, "connection ended: {e}"); }
        }
        _ = conn.evicted() => {
            tracing::debug!(%peer, "connection closed to admit a new client");
        }
        _ = shutdown.recv() => {
            http.as_mut().graceful_shutdown();
            let _ = tokio::time::timeout(CONNECTION_DRAIN, http).await;
        }
    }
    drop(entry);
}

/// Run the daemon on a bound listener: the campaign queue and the API, until `signal` completes; then stop the
/// running campaign at a safe point and wait for every task to finish. A listener that breaks the token rule
/// ([`check_listen`]) is refused: nothing is served.
pub async fn run_daemon(
    listener: TcpListener,
    service: Service,
    config: &ApiConfig,
    signal: impl std::future::Future<Output = ()>,
) {
    match listener.local_addr() {
        Ok(addr) => {
            if let Err(e) = check_listen(addr, config.token.as_deref()) {
                tracing::error!("{e}");
                return;
            }
        }
        Err(e) => {
            tracing::error!("cannot read the listening address: {e}");
            return;
        }
    }
    let trigger = crate::service::ShutdownTrigger::new();
    let (complete_tx, mut complete_rx) = mpsc::channel::<()>(1);
    let queue = {
        let service = service.clone();
        let shutdown = trigger.subscribe();
        let complete = complete_tx.clone();
        tokio::spawn(async move { service.run_queue(shutdown, complete).await })
    };
    let mut config = config.clone();
    if config.listen_addr.is_none() {
        config.listen_addr = listener.local_addr().ok();
    }
    let app = router(service, &config, trigger.subscribe());
    let server = tokio::spawn(serve_with(
        listener,
        app,
        config.connection_limits(),
        trigger.subscribe(),
        complete_tx.clone(),
    ));
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
