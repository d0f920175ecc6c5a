//! The layers every request passes: the access log, JSON errors and the token check.

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::{Json, Router};

use super::{is_json, one_line, Shared, BODY_LIMIT};
use crate::daemon::openapi::ErrorBody;

/// The access log: one `info` record per request, target `easyhec::access`, in a span that
/// carries the method and path (never the query or headers: a `?token=` stays out of logs),
/// with the final status (after [`json_errors`]) and the time to the response head. Events
/// logged while a handler runs carry the same span.
pub(super) fn with_access_log(router: Router) -> Router {
    router.layer(
    tower_http::trace::TraceLayer::new_for_http()
        .make_span_with(|req: &Request| {
            tracing::info_span!("http", method = %req.method(), path = %req.uri().path())
        })
        .on_request(())
        .on_response(
            |resp: &Response, latency: std::time::Duration, _: &tracing::Span| {
                tracing::info!(
                    target: "easyhec::access",
                    status = resp.status().as_u16(),
                    ms = (latency.as_secs_f64() * 1e4).round() / 10.0,
                    "access"
                );
            },
        )
        .on_body_chunk(())
        .on_eos(())
        .on_failure(()),
    )
}

/// Every error as `{"error": …}` on one line, the framework's too (405, 413, a path that
/// does not decode come from axum as plain text or nothing), and a declared body over
/// [`BODY_LIMIT`] refused at once: waiting for 100 GB that never come would hold the
/// connection until the idle timeout.
pub(super) async fn json_errors(req: Request, next: Next) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if let Some(n) = declared.filter(|n| *n > BODY_LIMIT as u64) {
        let m = format!("request body: Content-Length {n} is over the {BODY_LIMIT}-byte limit");
        return (StatusCode::PAYLOAD_TOO_LARGE, Json(ErrorBody::new(m))).into_response();
    }
    let (method, path) = (req.method().clone(), req.uri().path().to_string());
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) || is_json(resp.headers()) {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let text = String::from_utf8_lossy(&text).trim().to_string();
    let m = match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            format!("method {method} is not allowed on {path}: see /openapi.json")
        }
        StatusCode::PAYLOAD_TOO_LARGE => format!("request body: over the {BODY_LIMIT}-byte limit"),
        _ if text.is_empty() => status.to_string(),
        _ => text,
    };
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    let body = serde_json::to_string(&ErrorBody::new(one_line(&m))).unwrap_or_default();
    Response::from_parts(parts, Body::from(body))
}

/// The token check of the guarded routes: reads pass without it unless `protect_reads`.
pub(super) async fn auth(State(d): State<Shared>, req: Request, next: Next) -> Response {
    let read_only = matches!(
        *req.method(),
        axum::http::Method::GET | axum::http::Method::HEAD
    );
    if read_only && !d.settings().protect_reads {
        return next.run(req).await;
    }
    auth_always(State(d), req, next).await
}

/// The token check, whatever the method.
pub(super) async fn auth_always(State(d): State<Shared>, req: Request, next: Next) -> Response {
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(bearer_token);
    match given {
        Some(t) if d.token_matches(t) => next.run(req).await,
        _ => {
            let mut r = (
                StatusCode::UNAUTHORIZED,
                Json(ErrorBody::new(
                    "missing or wrong token: send `Authorization: Bearer TOKEN` with the daemon's token ([daemon] token or EASYHEC_TOKEN)".into(),
                )),
            )
                .into_response();
            r.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"easyhec\""),
            );
            r
        }
    }
}

/// The token of an `Authorization` value of exactly the documented form: the scheme
/// `Bearer` (any case, RFC 7235), one space, and the token with nothing around it.
pub(super) fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, token) = value.split_at_checked(7)?;
    let plain = !token.is_empty() && !token.chars().any(|c| c.is_whitespace() || c.is_control());
    (scheme.eq_ignore_ascii_case("Bearer ") && plain).then_some(token)
}
