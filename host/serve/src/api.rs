//! The HTTP/JSON API: routes, their checks and the OpenAPI document.
//!
//! Every request must name this service in `Host` (127.0.0.1, localhost or [::1] at its
//! port) and, when a browser sends one, come from its own `Origin`: a page elsewhere
//! cannot drive the rig, nor can a DNS name rebound to 127.0.0.1. Requests that change
//! the rig carry the token (`Authorization: Bearer …`), which the service writes 0600
//! into its state directory. Bad requests get a 4xx naming what is wrong, and change
//! nothing.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use axum::extract::{DefaultBodyLimit, Path as UrlPath, Request, State as Extract};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::Stream;
use serde::Serialize;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::StreamExt;
use utoipa::{OpenApi, ToSchema};

use crate::jobs::{AcquireRequest, JobRequest};
use crate::store::{Job, JobState};
use crate::worker::{CancelError, Event, Handle, Shared};

/// The largest request body, bytes: a job request is a few hundred.
pub const MAX_BODY: usize = 64 * 1024;

/// The token requests that change the rig must carry.
pub struct Token {
    value: String,
    /// Where it is written (0600).
    pub path: PathBuf,
}

impl Token {
    /// A new random token, written 0600 to `path` (a previous one is replaced).
    pub fn create(path: &Path) -> Result<Self> {
        use rand::Rng;
        use std::io::Write;
        use std::os::unix::fs::OpenOptionsExt;
        let bytes: [u8; 24] = rand::thread_rng().gen();
        let value: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let _ = std::fs::remove_file(path);
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(path)
            .with_context(|| format!("writing the token to {}", path.display()))?;
        file.write_all(value.as_bytes())?;
        Ok(Self {
            value,
            path: path.to_path_buf(),
        })
    }

    fn accepts(&self, headers: &HeaderMap) -> bool {
        headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .is_some_and(|t| constant_time_eq(t.trim().as_bytes(), self.value.as_bytes()))
    }
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// What every route sees.
#[derive(Clone)]
pub struct State {
    /// The database, the events, the running job.
    pub shared: Arc<Shared>,
    /// The way to the worker.
    pub worker: Handle,
    /// The token.
    pub token: Arc<Token>,
    /// Where the service listens.
    pub address: SocketAddr,
}

/// An error as the API answers it: a status and a message naming what is wrong.
#[derive(Debug, Serialize, ToSchema)]
pub struct ApiError {
    /// What is wrong, naming the field, header or job.
    pub error: String,
    #[serde(skip)]
    status: StatusCode,
}

impl ApiError {
    fn new(status: StatusCode, error: impl Into<String>) -> Self {
        Self {
            error: error.into(),
            status,
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.status, Json(self)).into_response()
    }
}

/// The API's OpenAPI document.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "fpm acquisition service",
        description = "The rig's jobs over HTTP/JSON on 127.0.0.1; see docs/service.md."
    ),
    paths(status, list_jobs, submit, get_job, cancel, events),
    components(schemas(
        Status,
        Submitted,
        Job,
        JobState,
        JobRequest,
        AcquireRequest,
        ApiError,
        Event
    ))
)]
pub struct ApiDoc;

/// The routes.
pub fn router(state: State) -> Router {
    Router::new()
        .route("/api/status", get(status))
        .route("/api/jobs", get(list_jobs).post(submit))
        .route("/api/jobs/{id}", get(get_job))
        .route("/api/jobs/{id}/cancel", post(cancel))
        .route("/api/events", get(events))
        .route("/openapi.json", get(openapi))
        .layer(middleware::from_fn_with_state(state.clone(), guard))
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .with_state(state)
}

/// Host and Origin must be this service's; requests that are not reads need the token.
async fn guard(Extract(state): Extract<State>, request: Request, next: Next) -> Response {
    let port = state.address.port();
    let ours = |authority: &str| {
        [
            format!("127.0.0.1:{port}"),
            format!("localhost:{port}"),
            format!("[::1]:{port}"),
            state.address.to_string(),
        ]
        .iter()
        .any(|a| a == authority)
    };
    let headers = request.headers();
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
    if !host.is_some_and(ours) {
        return ApiError::new(
            StatusCode::FORBIDDEN,
            format!(
                "Host {host:?}: this service answers only to 127.0.0.1:{port} or localhost:{port}"
            ),
        )
        .into_response();
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let from_us = origin
            .to_str()
            .ok()
            .and_then(|o| o.strip_prefix("http://"))
            .is_some_and(ours);
        if !from_us {
            return ApiError::new(
                StatusCode::FORBIDDEN,
                format!("Origin {origin:?}: requests from other sites are refused"),
            )
            .into_response();
        }
    }
    let reads = request.method() == axum::http::Method::GET;
    if !reads && !state.token.accepts(headers) {
        return ApiError::new(
            StatusCode::UNAUTHORIZED,
            format!(
                "Authorization: this request changes the rig and needs `Bearer <token>` (the token is in {})",
                state.token.path.display()
            ),
        )
        .into_response();
    }
    next.run(request).await
}

/// The service and its rig.
#[derive(Debug, Serialize, ToSchema)]
pub struct Status {
    /// The service's version.
    pub version: String,
    /// The rig, in words.
    pub rig: String,
    /// The running job, if any.
    pub running: Option<i64>,
    /// Its progress.
    #[schema(value_type = Option<Object>)]
    pub progress: Option<fpm_acquire::Progress>,
}

#[utoipa::path(get, path = "/api/status", responses((status = 200, body = Status)))]
async fn status(Extract(state): Extract<State>) -> Json<Status> {
    let current = state.shared.current();
    Json(Status {
        version: env!("CARGO_PKG_VERSION").into(),
        rig: state.shared.rig.clone(),
        running: current.map(|c| c.0),
        progress: current.and_then(|c| c.1),
    })
}

#[utoipa::path(get, path = "/api/jobs", responses((status = 200, body = [Job])))]
async fn list_jobs(Extract(state): Extract<State>) -> Result<Json<Vec<Job>>, ApiError> {
    state
        .shared
        .store
        .list()
        .map(Json)
        .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")))
}

/// A queued job.
#[derive(Debug, Serialize, ToSchema)]
pub struct Submitted {
    /// Its id.
    pub id: i64,
}

#[utoipa::path(post, path = "/api/jobs", request_body = JobRequest,
    responses((status = 202, body = Submitted), (status = 400, body = ApiError), (status = 401, body = ApiError)),
    security(("token" = [])))]
async fn submit(
    Extract(state): Extract<State>,
    body: Result<axum::body::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<(StatusCode, Json<Submitted>), ApiError> {
    let body = body.map_err(|e| ApiError::new(e.status(), e.body_text()))?;
    let request =
        JobRequest::parse(&body).map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e))?;
    // Checked now, not when the rig gets to it: a bad value is said to the one who sent it.
    match &request {
        JobRequest::Acquire(a) => {
            a.plan(&state.shared.camera)
                .map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, format!("{e:#}")))?;
        }
    }
    let id = state
        .worker
        .submit(&request)
        .map_err(|e| ApiError::new(StatusCode::SERVICE_UNAVAILABLE, format!("{e:#}")))?;
    Ok((StatusCode::ACCEPTED, Json(Submitted { id })))
}

#[utoipa::path(get, path = "/api/jobs/{id}", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 200, body = Job), (status = 404, body = ApiError)))]
async fn get_job(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<Json<Job>, ApiError> {
    let UrlPath(id) = id.map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?;
    match state.shared.store.get(id) {
        Ok(Some(job)) => Ok(Json(job)),
        Ok(None) => Err(ApiError::new(StatusCode::NOT_FOUND, format!("no job {id}"))),
        Err(e) => Err(ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("{e:#}"),
        )),
    }
}

#[utoipa::path(post, path = "/api/jobs/{id}/cancel", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 202, description = "Cancelling: a running job stops within its next step"),
        (status = 404, body = ApiError), (status = 409, body = ApiError)),
    security(("token" = [])))]
async fn cancel(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<StatusCode, ApiError> {
    let UrlPath(id) = id.map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?;
    match state.worker.cancel(id) {
        Ok(()) => Ok(StatusCode::ACCEPTED),
        Err(e @ CancelError::Unknown(_)) => {
            Err(ApiError::new(StatusCode::NOT_FOUND, e.to_string()))
        }
        Err(e @ CancelError::Ended(..)) => Err(ApiError::new(StatusCode::CONFLICT, e.to_string())),
        Err(e) => Err(ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            e.to_string(),
        )),
    }
}

#[utoipa::path(get, path = "/api/events",
    responses((status = 200, description = "Server-sent events, each a JSON Event", content_type = "text/event-stream")))]
async fn events(
    Extract(state): Extract<State>,
) -> Sse<impl Stream<Item = Result<SseEvent, Infallible>>> {
    let stream = BroadcastStream::new(state.shared.events.subscribe()).map(|e| {
        Ok(match e {
            Ok(event) => SseEvent::default()
                .json_data(&event)
                .unwrap_or_else(|_| SseEvent::default().comment("unserialisable event")),
            Err(tokio_stream::wrappers::errors::BroadcastStreamRecvError::Lagged(n)) => {
                SseEvent::default().event("lagged").data(n.to_string())
            }
        })
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

async fn openapi() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        ApiDoc::openapi().to_pretty_json().unwrap_or_default(),
    )
}
