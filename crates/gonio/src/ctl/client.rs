//! The HTTP/1.1 client of `gonio ctl` on hyper: one connection per request, a deadline on every call, the
//! server's `{"error": ...}` message as the command's error, and server-sent event streams read block by block.

use std::time::Duration;

use http_body_util::{BodyExt, Full};
use hyper::body::{Bytes, Incoming};
use hyper::{Method, Request, Response, StatusCode, header};
use hyper_util::rt::TokioIo;
use serde_json::Value;

use crate::CliError;

/// Deadline to connect to the daemon.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Deadline for a whole request/response, by default.
pub(super) const CALL_TIMEOUT: Duration = Duration::from_secs(60);

pub(super) fn server_error(status: StatusCode, body: &Bytes) -> CliError {
    let message = serde_json::from_slice::<gonio_daemon::api::wire::ErrorBody>(body)
        .map(|b| b.error)
        .unwrap_or_else(|_| String::from_utf8_lossy(body).trim().to_string());
    if message.is_empty() {
        CliError::input(format!("the daemon answered {status}"))
    } else {
        CliError::input(format!("the daemon answered {status}: {message}"))
    }
}

pub(super) async fn collect(response: Response<Incoming>) -> Result<Bytes, CliError> {
    response
        .into_body()
        .collect()
        .await
        .map(|c| c.to_bytes())
        .map_err(|e| CliError::input(format!("cannot read the daemon's reply: {e}")))
}

/// The daemon's address and token.
#[derive(Debug)]
pub(super) struct Client {
    /// `host:port`.
    pub(super) authority: String,
    token: Option<String>,
}

impl Client {
    pub(super) fn new(url: &str, token: Option<String>) -> Result<Client, CliError> {
        let rest = url.strip_prefix("http://").ok_or_else(|| {
            CliError::input(format!(
                "--url {url:?}: expected http://HOST:PORT (the daemon speaks plain HTTP)"
            ))
        })?;
        let authority = rest.trim_end_matches('/');
        if authority.is_empty() || authority.contains('/') {
            return Err(CliError::input(format!(
                "--url {url:?}: expected http://HOST:PORT with no path"
            )));
        }
        let authority = if authority
            .rsplit_once(':')
            .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
        {
            authority.to_string()
        } else {
            format!("{authority}:80")
        };
        Ok(Client { authority, token })
    }

    /// Send one request on a new connection and return the response head (the body still streaming).
    pub(super) async fn send(
        &self,
        method: Method,
        path: &str,
        body: Option<(Vec<u8>, &str, String)>,
    ) -> Result<Response<Incoming>, CliError> {
        let unreachable =
            |e: std::io::Error| CliError::io(format!("cannot reach the daemon at {}", self.authority), e);
        let stream = tokio::time::timeout(CONNECT_TIMEOUT, tokio::net::TcpStream::connect(&self.authority))
            .await
            .map_err(|_| {
                unreachable(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "connect timed out",
                ))
            })?
            .map_err(unreachable)?;
        let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .map_err(|e| CliError::input(format!("HTTP handshake with {} failed: {e}", self.authority)))?;
        tokio::spawn(async move {
            if let Err(e) = conn.await {
                tracing::debug!("connection to the daemon ended: {e}");
            }
        });
        let mut request = Request::builder()
            .method(method)
            .uri(path)
            .header(header::HOST, &self.authority);
        if let Some(token) = &self.token {
            request = request.header(header::AUTHORIZATION, format!("Bearer {token}"));
        }
        let payload = match body {
            Some((bytes, content_type, origin)) => {
                request = request.header(header::CONTENT_TYPE, content_type);
                if origin.len() <= 256 && !origin.chars().any(char::is_control) {
                    request = request.header(gonio_daemon::api::ORIGIN_HEADER, origin);
                }
                Bytes::from(bytes)
            }
            None => Bytes::new(),
        };
        let request = request
            .body(Full::new(payload))
            .map_err(|e| CliError::input(format!("cannot build the request for {path}: {e}")))?;
        sender
            .send_request(request)
            .await
            .map_err(|e| CliError::input(format!("request {path} to {} failed: {e}", self.authority)))
    }

    /// A whole call within [`CALL_TIMEOUT`]: status checked, body returned.
    async fn call(
        &self,
        method: Method,
        path: &str,
        body: Option<(Vec<u8>, &str, String)>,
    ) -> Result<Bytes, CliError> {
        self.call_within(method, path, body, CALL_TIMEOUT).await
    }

    /// A whole call within `deadline`: status checked, body returned.
    pub(super) async fn call_within(
        &self,
        method: Method,
        path: &str,
        body: Option<(Vec<u8>, &str, String)>,
        deadline: Duration,
    ) -> Result<Bytes, CliError> {
        let exchange = async {
            let response = self.send(method, path, body).await?;
            let status = response.status();
            let bytes = collect(response).await?;
            if status.is_success() {
                Ok(bytes)
            } else {
                Err(server_error(status, &bytes))
            }
        };
        tokio::time::timeout(deadline, exchange).await.map_err(|_| {
            CliError::input(format!(
                "no answer from {} within {} s",
                self.authority,
                deadline.as_secs()
            ))
        })?
    }

    pub(super) async fn json(
        &self,
        method: Method,
        path: &str,
        body: Option<(Vec<u8>, &str, String)>,
    ) -> Result<Value, CliError> {
        let bytes = self.call(method, path, body).await?;
        serde_json::from_slice(&bytes)
            .map_err(|e| CliError::input(format!("the daemon's reply to {path} is not JSON: {e}")))
    }

    /// The reply as the API's type for it (gonio_daemon::api::wire): a reply that does not fit is an error
    /// that shows it, never a default.
    pub(super) async fn typed<T: serde::de::DeserializeOwned>(
        &self,
        method: Method,
        path: &str,
        body: Option<(Vec<u8>, &str, String)>,
    ) -> Result<T, CliError> {
        let value = self.json(method, path, body).await?;
        serde_json::from_value(value.clone()).map_err(|e| {
            CliError::input(format!(
                "unexpected reply from the daemon to {path} ({e}): {value}"
            ))
        })
    }

    pub(super) async fn text(&self, path: &str) -> Result<String, CliError> {
        let bytes = self.call(Method::GET, path, None).await?;
        String::from_utf8(bytes.to_vec())
            .map_err(|e| CliError::input(format!("the reply to {path} is not UTF-8: {e}")))
    }
}

/// The JSON in an SSE block's `data:` lines (none for comments and keep-alives).
pub(super) fn parse_sse_data(block: &str) -> Option<Value> {
    let data: Vec<&str> = block
        .lines()
        .filter_map(|l| l.strip_prefix("data:"))
        .map(|d| d.strip_prefix(' ').unwrap_or(d))
        .collect();
    if data.is_empty() {
        return None;
    }
    serde_json::from_str(&data.join("\n")).ok()
}
