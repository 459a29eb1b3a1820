//! The live status page at `/`: the current campaign, its state, progress and ETA, the last readings and a
//! polar plot that fills in as points arrive, with pause/resume/abort/confirm buttons; and the console panel
//! (the axes' positions, jog buttons, homing, the filter wheel, a live trace of the meter, a big emergency
//! stop), its controls disabled with the reason while a campaign owns the instrument.
//!
//! The alignment card (align.js) starts the daemon's alignment, follows it and shows the current calibration.
//!
//! Routes: `GET /` (the page), `GET /assets/status.js`, `GET /assets/console.js`, `GET /assets/align.js`,
//! `GET /assets/status.css`, `GET /assets/favicon.svg`.
//! The assets are hand-written files embedded in the binary (`include_str!`): no build step, no network; the
//! page works offline.
//!
//! The page holds no data, so it is served without the token; everything it shows comes from the JSON API,
//! which keeps the token rule (see [`crate::api`]). With a token, open the page as `http://HOST:PORT/#token=...`:
//! the fragment never leaves the browser; the script keeps the token in the tab's `sessionStorage`, removes it
//! from the address bar and sends it as `Authorization: Bearer` on every request. The event stream is read with
//! `fetch` and a server-sent-events parser rather than `EventSource`, because `EventSource` cannot send that
//! header and a token in a query string would end up in logs and browser history.
//!
//! The page's Content-Security-Policy allows only its own origin: no inline script or style, no third-party
//! resources, no framing.

use axum::Router;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

/// The page.
pub const INDEX_HTML: &str = include_str!("../assets/index.html");
/// Its script (fetches the API, parses the event stream, draws the plot).
pub const STATUS_JS: &str = include_str!("../assets/status.js");
/// The console panel's script (positions, jog, homing, the wheel, a live trace, the emergency stop).
pub const CONSOLE_JS: &str = include_str!("../assets/console.js");
/// The alignment card's script (start an alignment, follow it, confirm an operator step, the current calibration).
pub const ALIGN_JS: &str = include_str!("../assets/align.js");
/// Its style sheet.
pub const STATUS_CSS: &str = include_str!("../assets/status.css");
/// Its icon (without one, browsers ask for `/favicon.ico`, which the token rule may refuse).
pub const FAVICON_SVG: &str = include_str!("../assets/favicon.svg");

/// Paths of the page's files, with their content types.
pub const ASSETS: [(&str, &str, &str); 6] = [
    ("/", "text/html; charset=utf-8", INDEX_HTML),
    ("/assets/status.js", "text/javascript; charset=utf-8", STATUS_JS),
    ("/assets/console.js", "text/javascript; charset=utf-8", CONSOLE_JS),
    ("/assets/align.js", "text/javascript; charset=utf-8", ALIGN_JS),
    ("/assets/status.css", "text/css; charset=utf-8", STATUS_CSS),
    ("/assets/favicon.svg", "image/svg+xml", FAVICON_SVG),
];

/// Only this origin's scripts, styles, images and connections; nothing inline, no frames, no forms posted.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
     img-src 'self'; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// The page's routes, outside the token check (they serve only the embedded files).
pub fn router() -> Router {
    let mut router = Router::new();
    for (path, content_type, body) in ASSETS {
        router = router.route(path, get(move || async move { asset(content_type, body) }));
    }
    router
}

fn asset(content_type: &'static str, body: &'static str) -> Response {
    let mut response = body.into_response();
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    // The files change with the binary: always revalidate, so an upgraded daemon never runs an old script.
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    headers.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_uses_its_own_assets_and_nothing_remote_or_inline() {
        for (path, _, _) in &ASSETS[1..] {
            assert!(
                INDEX_HTML.contains(&format!("\"{path}\"")),
                "index.html does not reference {path}"
            );
        }
        // The CSP forbids inline script and style: the page must not need them.
        assert!(!INDEX_HTML.contains(" style="), "inline style in index.html");
        assert!(!INDEX_HTML.contains("<style"), "inline style sheet in index.html");
        assert_eq!(
            INDEX_HTML.matches("<script").count(),
            INDEX_HTML.matches("<script src=").count(),
            "inline script in index.html"
        );
        // Nothing from elsewhere: the page must work offline and under the CSP. The SVG namespace is a name,
        // not a resource.
        for text in [
            INDEX_HTML,
            STATUS_JS,
            CONSOLE_JS,
            ALIGN_JS,
            STATUS_CSS,
            FAVICON_SVG,
        ] {
            let text = text.replace("http://www.w3.org/2000/svg", "");
            for remote in ["http:", "https:", "//cdn", "@import"] {
                assert!(!text.contains(remote), "an asset refers to {remote}");
            }
        }
    }
}
