//! Host and Origin checks: a web page in the operator's browser must not drive the instrument.
//!
//! On loopback the daemon may run without a token, and a browser reaches loopback too: any page it shows could
//! send requests to the daemon. Two checks close that, before the token check and for every route:
//! - DNS rebinding: a page at `http://evil.example:7878` whose name is made to resolve to 127.0.0.1 talks to the
//!   daemon as its own origin, so the browser lets it read the answers. Its requests name that host in `Host`:
//!   a request whose `Host` is not one of the daemon's own names is refused (421 Misdirected Request). Its own
//!   names: `localhost` (and `*.localhost`, which browsers resolve to loopback themselves), the loopback
//!   addresses (127.0.0.0/8, `[::1]`), the address it listens on (any address when it listens on all of them:
//!   an address cannot be rebound), and the names configured in [`ApiConfig::allowed_hosts`](super::ApiConfig).
//!   A request without `Host` (not HTTP/1.1, never a browser) passes.
//! - Cross-site requests (CSRF): a page elsewhere can still make the browser send a POST to the daemon, blind.
//!   Browsers name the page's origin in `Origin` on every POST, PUT, PATCH and DELETE: such a request whose
//!   `Origin` is not the daemon's own origin (`http://` + its `Host`, as the status page has) is refused (403).
//!   Without `Origin` (the CLI, curl, scripts) it passes.
//!
//! The status page is same-origin (it fetches the API from where it was loaded), so it is unaffected.

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::ApiError;

/// Which `Host` names are the daemon's own.
#[derive(Debug, Clone)]
pub struct HostPolicy {
    /// Configured names, lower case, without a trailing dot.
    names: Vec<String>,
    /// The address listened on, when known.
    bound: Option<IpAddr>,
}

impl HostPolicy {
    pub fn new(allowed_hosts: &[String], bound: Option<SocketAddr>) -> HostPolicy {
        HostPolicy {
            names: allowed_hosts.iter().map(|n| normalise(n)).collect(),
            bound: bound.map(|a| a.ip()),
        }
    }

    /// True when `host` (a name or address, without port; brackets allowed around IPv6) is one of the daemon's.
    pub fn allows(&self, host: &str) -> bool {
        let host = normalise(host);
        if host == "localhost" || host.ends_with(".localhost") {
            return true;
        }
        let literal = host
            .strip_prefix('[')
            .and_then(|h| h.strip_suffix(']'))
            .unwrap_or(&host);
        if let Ok(ip) = literal.parse::<IpAddr>() {
            return ip.is_loopback()
                || ip.to_canonical().is_loopback()
                || self.bound.is_some_and(|b| b == ip || b.is_unspecified());
        }
        self.names.contains(&host)
    }

    /// The names this daemon answers to, for messages.
    fn describe(&self) -> String {
        let mut list = vec!["localhost".to_string(), "127.0.0.1".into(), "[::1]".into()];
        match self.bound {
            Some(b) if b.is_unspecified() => list.push("any address of this machine".into()),
            Some(b) if !b.is_loopback() => list.push(b.to_string()),
            _ => {}
        }
        list.extend(self.names.iter().cloned());
        list.join(", ")
    }
}

fn normalise(host: &str) -> String {
    host.trim().trim_end_matches('.').to_ascii_lowercase()
}

/// `host[:port]` (RFC 9110 `Host`): the host (IPv6 with its brackets) and the port if any. None when malformed.
fn split_authority(value: &str) -> Option<(&str, Option<u16>)> {
    let value = value.trim();
    if value.is_empty() || value.contains(['/', '@', ' ', '?', '#']) {
        return None;
    }
    if value.starts_with('[') {
        let end = value.find(']')?;
        let (host, rest) = value.split_at(end + 1);
        return match rest {
            "" => Some((host, None)),
            _ => Some((host, Some(rest.strip_prefix(':')?.parse().ok()?))),
        };
    }
    match value.split_once(':') {
        None => Some((value, None)),
        Some((host, port)) if !host.is_empty() => Some((host, Some(port.parse().ok()?))),
        Some(_) => None,
    }
}

/// `scheme://host[:port]` of an `Origin` header, with the scheme's default port made explicit.
fn parse_origin(value: &str) -> Option<(String, String, u16)> {
    let (scheme, rest) = value.split_once("://")?;
    let scheme = scheme.to_ascii_lowercase();
    let default = match scheme.as_str() {
        "http" => 80,
        "https" => 443,
        _ => return None,
    };
    let (host, port) = split_authority(rest)?;
    Some((scheme, normalise(host), port.unwrap_or(default)))
}

/// Requests that change state: the ones a cross-site page could send blind.
fn changes_state(method: &Method) -> bool {
    !matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS)
}

/// The middleware: refuse foreign `Host`s and, on state-changing requests, foreign `Origin`s.
pub(super) async fn check(State(policy): State<Arc<HostPolicy>>, request: Request, next: Next) -> Response {
    let host_value = match request.headers().get(header::HOST) {
        Some(v) => Some(v.to_str().unwrap_or("").to_string()),
        None => request.uri().authority().map(|a| a.as_str().to_string()),
    };
    let host = match host_value.as_deref().map(|v| (v, split_authority(v))) {
        None => None,
        Some((_, Some((h, port)))) if policy.allows(h) => Some((normalise(h), port)),
        Some((raw, _)) => {
            tracing::warn!(host = raw, path = %request.uri().path(), "request for a foreign host refused");
            return ApiError::new(
                StatusCode::MISDIRECTED_REQUEST,
                format!(
                    "request refused: Host {raw:?} is not a name of this daemon ({}). A web page under another \
                     name (DNS rebinding) must not reach the instrument; to reach the daemon under another name, \
                     start it with `gonio daemon --allow-host NAME`",
                    policy.describe()
                ),
            )
            .into_response();
        }
    };
    if changes_state(request.method())
        && let Some(origin) = request.headers().get(header::ORIGIN)
    {
        let raw = origin.to_str().unwrap_or("<not text>").to_string();
        // The daemon's own origin: plain HTTP at the host and port the request names.
        let own = match (&host, parse_origin(&raw)) {
            (Some((h, port)), Some((scheme, oh, oport))) => {
                scheme == "http" && *h == oh && port.unwrap_or(80) == oport
            }
            _ => false,
        };
        if !own {
            tracing::warn!(origin = %raw, method = %request.method(), path = %request.uri().path(), "cross-origin request refused");
            return ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "request refused: {} {} comes from a web page at {raw:?}, not from this daemon's own page; \
                     only the status page, the gonio CLI and clients that send no Origin may change the state",
                    request.method(),
                    request.uri().path()
                ),
            )
            .into_response();
        }
    }
    next.run(request).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_values_split_into_host_and_port() {
        assert_eq!(split_authority("127.0.0.1:7878"), Some(("127.0.0.1", Some(7878))));
        assert_eq!(split_authority("localhost"), Some(("localhost", None)));
        assert_eq!(split_authority("[::1]:80"), Some(("[::1]", Some(80))));
        assert_eq!(split_authority("[::1]"), Some(("[::1]", None)));
        assert_eq!(split_authority("[::1]x"), None);
        assert_eq!(split_authority("host:port"), None);
        assert_eq!(split_authority(":80"), None);
        assert_eq!(split_authority(""), None);
        assert_eq!(split_authority("a@127.0.0.1"), None);
        assert_eq!(split_authority("127.0.0.1:99999"), None);
    }

    #[test]
    fn own_names_loopback_and_the_bound_address_are_allowed() {
        let loopback = HostPolicy::new(&[], Some("127.0.0.1:7878".parse().expect("addr")));
        for ok in [
            "localhost",
            "LocalHost.",
            "app.localhost",
            "127.0.0.1",
            "127.1.2.3",
            "[::1]",
            "::1",
        ] {
            assert!(loopback.allows(ok), "{ok}");
        }
        for refused in [
            "evil.example",
            "localhost.evil.example",
            "192.168.1.5",
            "[fe80::1]",
            "10.0.0.1",
            "",
        ] {
            assert!(!loopback.allows(refused), "{refused}");
        }
        let configured = HostPolicy::new(&["Lab-PC.local".into()], None);
        assert!(configured.allows("lab-pc.local"));
        assert!(!configured.allows("lab-pc.local.evil.example"));
        let lan = HostPolicy::new(&[], Some("192.168.1.5:7878".parse().expect("addr")));
        assert!(lan.allows("192.168.1.5") && !lan.allows("192.168.1.6") && !lan.allows("lab-pc"));
        let all = HostPolicy::new(&[], Some("0.0.0.0:7878".parse().expect("addr")));
        assert!(all.allows("192.168.1.6") && all.allows("[2001:db8::1]") && !all.allows("lab-pc"));
    }

    #[test]
    fn origins_parse_with_default_ports() {
        assert_eq!(
            parse_origin("http://127.0.0.1:7878"),
            Some(("http".into(), "127.0.0.1".into(), 7878))
        );
        assert_eq!(
            parse_origin("HTTP://LocalHost"),
            Some(("http".into(), "localhost".into(), 80))
        );
        assert_eq!(
            parse_origin("https://[::1]"),
            Some(("https".into(), "[::1]".into(), 443))
        );
        assert_eq!(parse_origin("null"), None);
        assert_eq!(parse_origin("file://"), None);
        assert_eq!(parse_origin("http://evil.example/path"), None);
    }
}
