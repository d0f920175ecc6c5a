//! The service routes: the page, its script, the OpenAPI document and liveness.

use axum::extract::State;
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};
use axum::Json;

use super::Shared;
use crate::daemon::openapi::{self, Health};

/// The web page (embedded; no build step).
pub(super) const INDEX_HTML: &str = include_str!("../web/index.html");
/// The page's script.
pub(super) const APP_JS: &str = include_str!("../web/app.js");

/// The web page (embedded; no build step).
#[utoipa::path(get, path = "/", tag = "service",
    responses((status = 200, description = "The web page", content_type = "text/html", body = String)))]
pub(super) async fn index() -> Html<&'static str> {
    Html(INDEX_HTML)
}

/// The page's script.
#[utoipa::path(get, path = "/app.js", tag = "service",
    responses((status = 200, description = "The page's script", content_type = "text/javascript", body = String)))]
pub(super) async fn app_js() -> Response {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        APP_JS,
    )
        .into_response()
}

/// This document, generated from the handlers and their types.
#[utoipa::path(get, path = "/openapi.json", tag = "service",
    responses((status = 200, description = "The OpenAPI 3.1 description of this API", content_type = "application/json", body = Object)))]
pub(super) async fn openapi_json() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        openapi::document(),
    )
        .into_response()
}

/// Liveness, and what holds the arm.
#[utoipa::path(get, path = "/healthz", tag = "service",
    responses((status = 200, description = "The daemon answers", body = Health)))]
pub(super) async fn healthz(State(d): State<Shared>) -> Json<Health> {
    Json(Health {
        status: "ok".into(),
        busy: d.busy().map(|b| b.name().to_string()),
    })
}
