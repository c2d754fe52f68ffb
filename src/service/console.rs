//! The web console: a few static files (`console/` at the top of the repository), built
//! into the binary so that it works on a network with no way out, served at `/console/`
//! (`/` redirects there). The page itself holds no data and needs no key: everything it
//! shows it fetches from the API with the key the user types, so the API's checks apply.
//!
//! Every answer carries a strict Content-Security-Policy: scripts and styles from this
//! server only (no inline script or style), requests to this server only, images from it
//! or from the page's own blobs (the uploaded photo), never framed.

use axum::extract::Path;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;
use axum::Router;

/// The console's files: name, content type, bytes.
const ASSETS: &[(&str, &str, &[u8])] = &[
    ("index.html", "text/html; charset=utf-8", include_bytes!("../../console/index.html")),
    ("console.css", "text/css; charset=utf-8", include_bytes!("../../console/console.css")),
    ("main.js", "text/javascript; charset=utf-8", include_bytes!("../../console/main.js")),
    ("api.js", "text/javascript; charset=utf-8", include_bytes!("../../console/api.js")),
    ("dom.js", "text/javascript; charset=utf-8", include_bytes!("../../console/dom.js")),
    ("objects.js", "text/javascript; charset=utf-8", include_bytes!("../../console/objects.js")),
    ("onboard.js", "text/javascript; charset=utf-8", include_bytes!("../../console/onboard.js")),
    ("photo.js", "text/javascript; charset=utf-8", include_bytes!("../../console/photo.js")),
    ("snippets.js", "text/javascript; charset=utf-8", include_bytes!("../../console/snippets.js")),
    ("service.js", "text/javascript; charset=utf-8", include_bytes!("../../console/service.js")),
    ("icon.svg", "image/svg+xml", include_bytes!("../../console/icon.svg")),
];

pub const CONTENT_SECURITY_POLICY: &str =
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// The console's routes (no state: the page talks to the API like any client).
pub fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new()
        .route("/", get(|| async { Redirect::temporary("/console/") }))
        .route("/console", get(|| async { Redirect::permanent("/console/") }))
        .route("/console/", get(|| async { asset("index.html") }))
        .route("/console/{file}", get(|Path(file): Path<String>| async move { asset(&file) }))
}

fn asset(name: &str) -> Response {
    let Some((_, content_type, bytes)) = ASSETS.iter().find(|(n, _, _)| *n == name) else {
        return super::error::ServiceError::new(super::error::ErrorKind::NotFound, format!("the console has no file {name:?}")).into_response();
    };
    let mut resp = (StatusCode::OK, *bytes).into_response();
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CONTENT_SECURITY_POLICY));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    // Small files, and a new server version must not meet an old cached script.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_script_the_page_imports_is_served() {
        // A module the page imports but the table lacks would only fail in a browser.
        let served: Vec<&str> = ASSETS.iter().map(|(n, _, _)| *n).collect();
        for (name, _, bytes) in ASSETS.iter().filter(|(n, _, _)| n.ends_with(".js") || n.ends_with(".html")) {
            let text = std::str::from_utf8(bytes).unwrap();
            for part in text.split(['"', '\'']).filter(|p| p.starts_with("./") && [".js", ".css", ".svg"].iter().any(|e| p.ends_with(e))) {
                assert!(served.contains(&&part[2..]), "{name} refers to {part}, which the console does not serve");
            }
        }
        // No inline script or style: the CSP would block them.
        let index = std::str::from_utf8(ASSETS[0].2).unwrap();
        assert!(!index.contains("<script>") && !index.contains("style="), "index.html has inline script or style");
    }
}
