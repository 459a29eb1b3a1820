//! The status page's routes on the daemon's real router: the page and its assets are served with their content
//! types and security headers, without the token (they hold no data), while every API route the page uses keeps
//! the token rule. The page itself is tested in a real browser by `tests/browser/run.sh`.

use crate::common;

use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use common::{App, Setup};
use gonio_daemon::api::ApiConfig;
use gonio_daemon::status_page::{ASSETS, CONTENT_SECURITY_POLICY, INDEX_HTML};
use http_body_util::BodyExt;
use tower::ServiceExt;

const TOKEN: &str = "s3cret-t0ken";

/// The daemon's router (no queue task: these tests run no campaign).
async fn app(token: Option<&str>) -> App {
    let setup = Setup {
        config: ApiConfig {
            token: token.map(str::to_string),
            ..ApiConfig::default()
        },
        queue: false,
        ..Setup::default()
    };
    common::app_with(tempfile::tempdir().expect("tempdir"), setup).await
}

struct Answer {
    status: StatusCode,
    headers: axum::http::HeaderMap,
    body: Vec<u8>,
}

impl App {
    async fn page_request(&self, method: &str, path: &str, token: Option<&str>) -> Answer {
        let mut r = Request::builder().method(method).uri(path);
        if let Some(t) = token {
            r = r.header(header::AUTHORIZATION, format!("Bearer {t}"));
        }
        let response = tokio::time::timeout(
            Duration::from_secs(30),
            self.router
                .clone()
                .oneshot(r.body(Body::empty()).expect("request")),
        )
        .await
        .expect("answer in time")
        .expect("infallible");
        let status = response.status();
        let headers = response.headers().clone();
        // The event stream never ends: read only the head of it.
        let is_stream = headers
            .get(header::CONTENT_TYPE)
            .is_some_and(|v| v.as_bytes().starts_with(b"text/event-stream"));
        let body = if is_stream {
            Vec::new()
        } else {
            response
                .into_body()
                .collect()
                .await
                .expect("body")
                .to_bytes()
                .to_vec()
        };
        Answer {
            status,
            headers,
            body,
        }
    }
}

fn header_of(answer: &Answer, name: header::HeaderName) -> &str {
    answer
        .headers
        .get(&name)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_else(|| panic!("no {name} header"))
}

#[tokio::test]
async fn the_page_is_served_at_the_root_as_html_with_a_strict_policy() {
    let app = app(None).await;
    let page = app.page_request("GET", "/", None).await;
    assert_eq!(page.status, StatusCode::OK);
    assert_eq!(header_of(&page, header::CONTENT_TYPE), "text/html; charset=utf-8");
    let html = String::from_utf8(page.body.clone()).expect("UTF-8");
    assert_eq!(html, INDEX_HTML);
    assert!(html.starts_with("<!doctype html>"), "{html}");
    assert!(
        html.contains(r#"<script src="/assets/status.js" defer></script>"#),
        "{html}"
    );
    let csp = header_of(&page, header::CONTENT_SECURITY_POLICY);
    assert_eq!(csp, CONTENT_SECURITY_POLICY);
    for directive in [
        "default-src 'none'",
        "script-src 'self'",
        "connect-src 'self'",
        "frame-ancestors 'none'",
    ] {
        assert!(csp.contains(directive), "{csp} lacks {directive}");
    }
    assert!(!csp.contains("unsafe-inline"), "{csp}");
    assert_eq!(header_of(&page, header::X_CONTENT_TYPE_OPTIONS), "nosniff");
    assert_eq!(header_of(&page, header::CACHE_CONTROL), "no-cache");

    // HEAD answers like GET, without a body; other methods are refused.
    let head = app.page_request("HEAD", "/", None).await;
    assert_eq!(head.status, StatusCode::OK);
    assert!(head.body.is_empty());
    let post = app.page_request("POST", "/", None).await;
    assert_eq!(post.status, StatusCode::METHOD_NOT_ALLOWED);
}

#[tokio::test]
async fn every_asset_is_served_byte_for_byte_with_its_content_type() {
    let app = app(None).await;
    let expected_types = [
        ("/", "text/html"),
        ("/assets/status.js", "text/javascript"),
        ("/assets/console.js", "text/javascript"),
        ("/assets/align.js", "text/javascript"),
        ("/assets/status.css", "text/css"),
        ("/assets/favicon.svg", "image/svg+xml"),
    ];
    assert_eq!(ASSETS.len(), expected_types.len());
    for ((path, content_type, body), (want_path, want_type)) in ASSETS.iter().zip(expected_types) {
        assert_eq!(*path, want_path);
        let answer = app.page_request("GET", path, None).await;
        assert_eq!(answer.status, StatusCode::OK, "{path}");
        assert_eq!(header_of(&answer, header::CONTENT_TYPE), *content_type);
        assert!(content_type.starts_with(want_type), "{path}: {content_type}");
        assert_eq!(answer.body, body.as_bytes(), "{path}");
    }
    // The script is the one the page loads, and it talks to the API routes that exist.
    let js = String::from_utf8(app.page_request("GET", "/assets/status.js", None).await.body).expect("UTF-8");
    for used in [
        "'/api/events'",
        "'/api/campaigns'",
        "'/points.csv'",
        "'/report.html'",
        "Authorization",
    ] {
        assert!(js.contains(used), "status.js does not use {used}");
    }
    // The alignment card's script talks to the alignment's and the calibrations' routes.
    let js = String::from_utf8(app.page_request("GET", "/assets/align.js", None).await.body).expect("UTF-8");
    for used in ["'/api/align'", "'/api/align/confirm'", "'/api/calibrations'"] {
        assert!(js.contains(used), "align.js does not use {used}");
    }
    for (path, body) in [("/api/align", "{}"), ("/api/calibrations", "[]")] {
        let answer = app.page_request("GET", path, None).await;
        assert_eq!(answer.status, StatusCode::OK, "{path}");
        let v: serde_json::Value = serde_json::from_slice(&answer.body).expect("JSON");
        assert_eq!(v.is_array(), body == "[]", "{path}: {v}");
    }
    // Other paths under /assets are not files: the API's 404.
    let missing = app.page_request("GET", "/assets/other.js", None).await;
    assert_eq!(missing.status, StatusCode::NOT_FOUND);
    let error: serde_json::Value = serde_json::from_slice(&missing.body).expect("JSON error");
    assert!(
        error["error"]
            .as_str()
            .is_some_and(|e| e.contains("/assets/other.js")),
        "{error}"
    );
}

#[tokio::test]
async fn with_a_token_the_page_loads_without_it_but_the_api_it_calls_needs_it() {
    let app = app(Some(TOKEN)).await;
    // The page and its assets: no token needed, none leaked.
    for (path, _, body) in ASSETS {
        let answer = app.page_request("GET", path, None).await;
        assert_eq!(answer.status, StatusCode::OK, "{path}");
        assert_eq!(answer.body, body.as_bytes());
        assert!(!String::from_utf8_lossy(&answer.body).contains(TOKEN));
    }
    // What the page fetches: refused without the token or with a wrong one...
    for path in [
        "/api/campaigns",
        "/api/events",
        "/api/campaigns/1/points.csv",
        "/api/campaigns/1/report.html",
    ] {
        for given in [None, Some("wrong"), Some("")] {
            let answer = app.page_request("GET", path, given).await;
            assert_eq!(answer.status, StatusCode::UNAUTHORIZED, "{path} with {given:?}");
            assert_eq!(header_of(&answer, header::WWW_AUTHENTICATE), "Bearer");
        }
    }
    let pause = app.page_request("POST", "/api/campaigns/1/pause", None).await;
    assert_eq!(pause.status, StatusCode::UNAUTHORIZED);
    // ...and a token in the query string is not one: the page sends the header, so the token never ends up in
    // URLs, logs or history.
    let query = app
        .page_request("GET", &format!("/api/events?token={TOKEN}"), None)
        .await;
    assert_eq!(query.status, StatusCode::UNAUTHORIZED);
    // Paths that are not the page's stay behind the token, even under /assets.
    for path in ["/assets/other.js", "/favicon.ico", "/index.html"] {
        let answer = app.page_request("GET", path, None).await;
        assert_eq!(answer.status, StatusCode::UNAUTHORIZED, "{path}");
        let answer = app.page_request("GET", path, Some(TOKEN)).await;
        assert_eq!(answer.status, StatusCode::NOT_FOUND, "{path}");
    }

    // With the header, as the page sends it: the list, and the event stream as server-sent events.
    let list = app.page_request("GET", "/api/campaigns", Some(TOKEN)).await;
    assert_eq!(list.status, StatusCode::OK);
    assert_eq!(list.body, b"[]");
    let events = app.page_request("GET", "/api/events", Some(TOKEN)).await;
    assert_eq!(events.status, StatusCode::OK);
    assert!(header_of(&events, header::CONTENT_TYPE).starts_with("text/event-stream"));
}
