//! The API's description: the OpenAPI root (title, security scheme, tags) and the bodies the
//! handlers of [`super::api`] exchange that are not stored types. The paths come from each
//! handler's `#[utoipa::path]`, and the router registers every route from that same
//! annotation (`utoipa_axum::routes!`), so the served document and the served routes are one
//! list. `GET /openapi.json` serves [`document`].

use std::sync::OnceLock;

use serde::Serialize;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi, ToSchema};

use super::store::{CalibrationRecord, CheckRecord, State};
use crate::interop::ExportFormat;
use crate::run::ResultFile;

/// The document's root; paths and schemas are added by the router.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "easyhec daemon",
        version = "1",
        description = "Markerless eye-to-hand calibration as a service: one cell, one calibration \
            at a time. Routes that act (POST) always need `Authorization: Bearer TOKEN` \
            ([daemon] token or EASYHEC_TOKEN). Routes that read (GET under /api/v1, and \
            /metrics) need it only when [daemon] protect_reads = true: their security lists \
            both no requirement and the bearer token. /, /app.js, /openapi.json and /healthz \
            are always open. Every error is JSON {\"error\": \"…\"} on one line. A connection \
            over [daemon] max_connections is answered 503 and closed."
    ),
    modifiers(&BearerToken),
    tags(
        (name = "calibrations", description = "Start, follow, cancel and activate calibrations."),
        (name = "checks", description = "Bump checks of the active calibration."),
        (name = "service", description = "The page, health, metrics and this document.")
    )
)]
pub struct ApiRoot;

/// Adds the `bearer` scheme the paths' `security` entries name.
struct BearerToken;

impl Modify for BearerToken {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// The generated document as JSON, built once (it is the same for the process's life).
pub fn document() -> &'static str {
    static JSON: OnceLock<String> = OnceLock::new();
    JSON.get_or_init(|| {
        let mut openapi = super::api::routes().into_openapi();
        list_export_content_types(&mut openapi);
        openapi
            .to_json()
            .unwrap_or_else(|e| format!("{{\"error\": \"openapi: {e}\"}}"))
    })
}

/// The download route's path in the document.
pub const EXPORT_PATH: &str = "/api/v1/calibrations/{id}/export/{format}";

/// Gives the download route's 200 answer one content type per export format, read from
/// [`ExportFormat`]: the route's annotation cannot call code, and a list written there by
/// hand would drift from the formats.
fn list_export_content_types(openapi: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::{schema::Type, ContentBuilder, ObjectBuilder, RefOr};
    let Some(get) = openapi
        .paths
        .paths
        .get_mut(EXPORT_PATH)
        .and_then(|p| p.get.as_mut())
    else {
        return;
    };
    let Some(RefOr::T(ok)) = get.responses.responses.get_mut("200") else {
        return;
    };
    for format in ExportFormat::ALL {
        let text = ObjectBuilder::new().schema_type(Type::String).build();
        ok.content.insert(
            format.content_type().to_string(),
            RefOr::T(ContentBuilder::new().schema(Some(text)).build()),
        );
    }
}

/// Every error body.
#[derive(Serialize, ToSchema)]
pub struct ErrorBody {
    /// What went wrong, on one line.
    pub error: String,
    /// On a 409 for a busy arm: the running calibration's id, `check` or `preview`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub running: Option<String>,
}

impl ErrorBody {
    /// An error with no `running` field.
    pub fn new(error: String) -> Self {
        ErrorBody {
            error,
            running: None,
        }
    }
}

/// `GET /healthz`.
#[derive(Serialize, ToSchema)]
pub struct Health {
    /// Always `ok` while the daemon answers.
    pub status: String,
    /// What holds the arm: a calibration id, `check`, `preview`, or null.
    pub busy: Option<String>,
}

/// `POST /api/v1/calibrations` accepted.
#[derive(Serialize, ToSchema)]
pub struct Started {
    /// The new calibration's id (also in the `Location` header).
    pub id: String,
}

/// `GET /api/v1/calibrations`.
#[derive(Serialize, ToSchema)]
pub struct History {
    /// Every calibration on record, newest first.
    pub calibrations: Vec<CalibrationRecord>,
    /// The active calibration's id, if any.
    pub active: Option<String>,
}

/// `POST /api/v1/calibrations/{id}/cancel` accepted.
#[derive(Serialize, ToSchema)]
pub struct Cancelling {
    /// The calibration.
    pub id: String,
    /// Its state when the cancel was accepted.
    pub state: State,
    /// Always true: the run stops at its next check of the flag, the arm first.
    pub cancelling: bool,
}

/// `GET /api/v1/calibration`: the active calibration and its last bump check.
#[derive(Serialize, ToSchema)]
pub struct ActiveCalibration {
    /// Its id.
    pub id: String,
    /// When it became active (RFC 3339).
    pub activated_at: String,
    /// Whether a bump check found it no longer fits.
    pub stale: bool,
    /// When it was first found stale.
    pub stale_since: Option<String>,
    /// The latest bump check of this calibration.
    pub last_check: Option<CheckRecord>,
    /// The result (`easyhec-result/1`).
    pub result: ResultFile,
}

/// One camera of `GET /api/v1/cameras`.
#[derive(Serialize, ToSchema)]
pub struct CameraState {
    /// The camera's name in the config (`camera` for a single `[camera]` table).
    pub camera: String,
    /// Its active calibration and last bump check, if one is active.
    pub active: Option<ActiveCalibration>,
}

/// `GET /api/v1/cameras`: every camera of the cell, in config order.
#[derive(Serialize, ToSchema)]
pub struct Cameras {
    /// Whether the config lists `[[camera]]` tables: each camera then has its own active
    /// calibration, and view overlays take `?camera=NAME`.
    pub listed: bool,
    /// One entry per camera.
    pub cameras: Vec<CameraState>,
}

/// `GET /api/v1/checks`.
#[derive(Serialize, ToSchema)]
pub struct Checks {
    /// The last 50 bump checks, newest first.
    pub checks: Vec<CheckRecord>,
}

/// A PNG image's bytes (`type: string, format: binary`).
pub struct Png;

impl utoipa::PartialSchema for Png {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{KnownFormat, ObjectBuilder, SchemaFormat, Type};
        ObjectBuilder::new()
            .schema_type(Type::String)
            .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)))
            .into()
    }
}

impl ToSchema for Png {}
