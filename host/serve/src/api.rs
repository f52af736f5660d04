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

use crate::board::Board;
pub use crate::error::ApiError;
use crate::error::ErrorBody;
use crate::jobs::{
    AcquireRequest, CalibrateRequest, DpcRequest, JobRequest, ReconstructRequest, ResumeRequest,
    ScanRequest, SequenceRequest,
};
use crate::store::{Job, JobState};
use crate::worker::{resumable_request, Event, Handle, Shared};

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

    /// The token itself (for the page's address `fpm serve` prints).
    pub fn value(&self) -> &str {
        &self.value
    }

    /// Whether the request carries the token: `Authorization: Bearer …`, or `token=…`
    /// in its query (what a browser's `<img>` and `EventSource` can send; the page
    /// takes it from the address `fpm serve` prints, as Jupyter's does).
    fn accepts(&self, headers: &HeaderMap, query: Option<&str>) -> bool {
        let ours = |t: &str| constant_time_eq(t.trim().as_bytes(), self.value.as_bytes());
        let in_header = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .is_some_and(ours);
        in_header
            || query.is_some_and(|q| {
                q.split('&')
                    .filter_map(|kv| kv.strip_prefix("token="))
                    .any(ours)
            })
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
    /// It listens beyond loopback (`--public`): every request needs the token.
    pub public: bool,
    /// Set when the service stops (the event streams then end).
    pub stopping: tokio::sync::watch::Receiver<bool>,
}

/// The API's OpenAPI document.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "fpm acquisition service",
        description = "The rig's jobs over HTTP/JSON on 127.0.0.1; see docs/service.md."
    ),
    paths(
        status,
        list_jobs,
        submit,
        get_job,
        cancel,
        pause,
        resume,
        events,
        snapshot,
        camera_frame,
        job_file
    ),
    components(schemas(
        Status,
        Board,
        Submitted,
        Resumed,
        Job,
        JobState,
        JobRequest,
        AcquireRequest,
        CalibrateRequest,
        ReconstructRequest,
        SequenceRequest,
        ResumeRequest,
        DpcRequest,
        ScanRequest,
        ErrorBody,
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
        .route("/api/jobs/{id}/pause", post(pause))
        .route("/api/jobs/{id}/resume", post(resume))
        .route("/api/jobs/{id}/snapshot/{part}", get(snapshot))
        .route("/api/jobs/{id}/files/{*path}", get(job_file))
        .route("/api/camera/frame", get(camera_frame))
        .route("/api/events", get(events))
        .route("/openapi.json", get(openapi))
        .route("/", get(page))
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
        return ApiError::Forbidden(format!(
            "Host {host:?}: this service answers only to 127.0.0.1:{port} or localhost:{port}"
        ))
        .into_response();
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let from_us = origin
            .to_str()
            .ok()
            .and_then(|o| o.strip_prefix("http://"))
            .is_some_and(ours);
        if !from_us {
            return ApiError::Forbidden(format!(
                "Origin {origin:?}: requests from other sites are refused"
            ))
            .into_response();
        }
    }
    let reads = request.method() == axum::http::Method::GET;
    if (state.public || !reads) && !state.token.accepts(headers, request.uri().query()) {
        let why = if reads {
            "this service listens beyond loopback (--public): every request"
        } else {
            "this request changes the rig and"
        };
        return ApiError::Unauthorized(format!(
            "Authorization: {why} needs `Bearer <token>` (the token is in {})",
            state.token.path.display()
        ))
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
    /// Its capture's time left, s (while it captures).
    pub eta_s: Option<f64>,
    /// Where jobs sent without `out` write.
    pub runs: String,
    /// The iceoryx2 service on which local viewers read the snapshots in place
    /// (`fpm_frames::SnapshotSubscriber`; header `fpm::SnapshotHeader/1`).
    pub snapshot_service: String,
    /// The LED controller as last found: `ready` with its versions, `mismatch` (jobs
    /// that drive the rig are refused, `error` says what to do), `unreachable` or
    /// `unchecked`.
    pub controller: Board,
}

#[utoipa::path(get, path = "/api/status", responses((status = 200, body = Status)))]
async fn status(Extract(state): Extract<State>) -> Json<Status> {
    let current = state.shared.current();
    Json(Status {
        version: env!("CARGO_PKG_VERSION").into(),
        rig: state.shared.rig.clone(),
        running: current.map(|c| c.0),
        progress: current.and_then(|c| c.1),
        eta_s: current.and_then(|c| c.2),
        runs: state.shared.runs.display().to_string(),
        snapshot_service: state.shared.snapshot_service.clone(),
        controller: state.shared.board(),
    })
}

#[utoipa::path(get, path = "/api/jobs", responses((status = 200, body = [Job])))]
async fn list_jobs(Extract(state): Extract<State>) -> Result<Json<Vec<Job>>, ApiError> {
    state
        .shared
        .store
        .list()
        .map(Json)
        .map_err(ApiError::internal)
}

/// A queued job.
#[derive(Debug, Serialize, ToSchema)]
pub struct Submitted {
    /// Its id.
    pub id: i64,
}

#[utoipa::path(post, path = "/api/jobs", request_body = JobRequest,
    responses((status = 202, body = Submitted), (status = 400, body = ErrorBody), (status = 401, body = ErrorBody),
        (status = 409, body = ErrorBody, description = "The job drives the rig and the LED controller speaks another protocol version (the error says what to do)")),
    security(("token" = [])))]
async fn submit(
    Extract(state): Extract<State>,
    body: Result<axum::body::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<(StatusCode, Json<Submitted>), ApiError> {
    let mut request = JobRequest::parse(&body?).map_err(ApiError::BadRequest)?;
    if request.drives_rig() {
        refuse_on_wrong_firmware(&state).await?;
    }
    request.place(&state.shared.runs);
    // Checked now, not when the rig gets to it: a bad value is said to the one who sent it.
    match &mut request {
        JobRequest::Resume(r) => r.out = Some(resumable(&state, r.job)?),
        other => other
            .check(&state.shared.camera)
            .map_err(ApiError::invalid)?,
    }
    let id = state
        .worker
        .submit(&request)
        .map_err(ApiError::unavailable)?;
    Ok((StatusCode::ACCEPTED, Json(Submitted { id })))
}

#[utoipa::path(get, path = "/api/jobs/{id}", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 200, body = Job), (status = 404, body = ErrorBody)))]
async fn get_job(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<Json<Job>, ApiError> {
    let UrlPath(id) = id?;
    Ok(Json(stored_job(&state, id)?))
}

#[utoipa::path(post, path = "/api/jobs/{id}/cancel", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 202, description = "Cancelling: a running job stops within its next step"),
        (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)),
    security(("token" = [])))]
async fn cancel(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<StatusCode, ApiError> {
    let UrlPath(id) = id?;
    state.worker.cancel(id)?;
    Ok(StatusCode::ACCEPTED)
}

/// How long a job's request waits for the worker's look at an unchecked board (the
/// handshake's own timeout is 2 s).
const UNCHECKED_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// A 409 when the controller speaks another protocol version, after looking at it
/// again (a board flashed since the last look is taken).
async fn refuse_on_wrong_firmware(state: &State) -> Result<(), ApiError> {
    // Looked at again where it was wrong (it may have been flashed since), and where
    // it was not looked at yet (a job sent as the service starts, before its worker
    // has): the job is refused now rather than queued to fail.
    let (Board::Mismatch { port, .. } | Board::Unchecked { port }) = state.shared.board() else {
        return Ok(());
    };
    let (tx, rx) = tokio::sync::oneshot::channel();
    let shared = state.shared.clone();
    // Opening a serial port and its handshake block: off the runtime's threads.
    std::thread::spawn(move || tx.send(shared.check_board(&port)));
    let mut board = rx.await.map_err(ApiError::internal)?;
    // Still unchecked: the worker is looking at the board right now (its first look,
    // or a job opening it), and says what it found within the handshake's timeout.
    let waited = std::time::Instant::now();
    while matches!(board, Board::Unchecked { .. }) && waited.elapsed() < UNCHECKED_WAIT {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        board = state.shared.board();
    }
    match board.refusal() {
        Some(why) => Err(ApiError::Conflict(why.to_owned())),
        None => Ok(()),
    }
}

/// Where job `id`'s frames are, if it can be completed by a resume job: it is an
/// acquisition or a scan (or a resume of one) that ended part-way.
fn resumable(state: &State, id: i64) -> Result<PathBuf, ApiError> {
    let job = stored_job(state, id)?;
    resumable_request(&state.shared.store, id)?;
    match job.state {
        JobState::Interrupted | JobState::Cancelled | JobState::Failed => Ok(PathBuf::from(job.out)),
        JobState::Done => Err(ApiError::Conflict(format!(
            "job {id}: done, every LED has its frame; nothing to resume"
        ))),
        JobState::Queued | JobState::Running => Err(ApiError::Conflict(format!(
            "job {id}: {:?}, not ended; pause and resume a running job with /api/jobs/{id}/pause and /resume",
            job.state
        ))),
    }
}

/// Job `id` as stored: 404 when there is none.
fn stored_job(state: &State, id: i64) -> Result<Job, ApiError> {
    state
        .shared
        .store
        .get(id)
        .map_err(ApiError::internal)?
        .ok_or_else(|| ApiError::NotFound(format!("no job {id}")))
}

#[utoipa::path(post, path = "/api/jobs/{id}/pause", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 202, description = "Pausing: the rig holds before its next LED (the capture's sequence is cut at the LED it is on; those it did not reach wait)"),
        (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)),
    security(("token" = [])))]
async fn pause(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<StatusCode, ApiError> {
    let UrlPath(id) = id?;
    state.worker.pause(id)?;
    Ok(StatusCode::ACCEPTED)
}

/// What a resume did.
#[derive(Debug, Serialize, ToSchema)]
pub struct Resumed {
    /// The job that goes on: the paused one itself, or the new `resume` job queued to
    /// complete one that ended part-way.
    pub id: i64,
    /// Whether `id` is a new job.
    pub queued: bool,
}

#[utoipa::path(post, path = "/api/jobs/{id}/resume", params(("id" = i64, Path, description = "The job's id")),
    responses((status = 202, body = Resumed, description = "A paused job goes on; a job that ended part-way (interrupted, cancelled, failed) is completed by a new resume job, which lights only the LEDs its frames lack"),
        (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)),
    security(("token" = [])))]
async fn resume(
    Extract(state): Extract<State>,
    id: Result<UrlPath<i64>, axum::extract::rejection::PathRejection>,
) -> Result<(StatusCode, Json<Resumed>), ApiError> {
    let UrlPath(id) = id?;
    if state.worker.is_paused(id) {
        state.worker.resume_running(id)?;
        return Ok((StatusCode::ACCEPTED, Json(Resumed { id, queued: false })));
    }
    let out = resumable(&state, id)?;
    let request = JobRequest::Resume(ResumeRequest {
        job: id,
        out: Some(out),
    });
    let new = state
        .worker
        .submit(&request)
        .map_err(ApiError::unavailable)?;
    Ok((
        StatusCode::ACCEPTED,
        Json(Resumed {
            id: new,
            queued: true,
        }),
    ))
}

#[utoipa::path(get, path = "/api/events",
    responses((status = 200, description = "Server-sent events, each a JSON Event with `at_s`, when the service published it (Unix seconds); a slow client is sent `event: lagged` with how many it missed", content_type = "text/event-stream")))]
async fn events(
    Extract(state): Extract<State>,
) -> Sse<impl Stream<Item = Result<SseEvent, Infallible>>> {
    let mut stopping = state.stopping.clone();
    let stopped = async move {
        let _ = stopping.wait_for(|&s| s).await;
    };
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
    Sse::new(futures_util::StreamExt::take_until(
        stream,
        Box::pin(stopped),
    ))
    .keep_alive(KeepAlive::default())
}

async fn openapi() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        ApiDoc::openapi().to_pretty_json().unwrap_or_default(),
    )
}

/// How a live image is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    /// 8-bit grey PNG for people (the object's with a scale bar; the phase ±π with a
    /// colour bar).
    Png,
    /// Little-endian float32, row-major, its shape in `X-Fpm-Shape: rows,cols`.
    F32,
    /// Little-endian uint16 counts, row-major (a camera frame), shape as for f32.
    U16,
}

/// `?format=`.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Format {
    #[serde(default)]
    format: Option<ImageFormat>,
    /// The token may ride in the query (see the guard); nothing else may.
    #[serde(default, rename = "token")]
    _token: Option<String>,
    /// A page's cache-buster.
    #[serde(default, rename = "seq")]
    _seq: Option<u64>,
}

/// An image response: the bytes, their type, and what they are in `X-Fpm-*` headers.
fn image(bytes: Vec<u8>, content_type: &'static str, meta: &[(&'static str, String)]) -> Response {
    let mut response = (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, "no-store"),
        ],
        bytes,
    )
        .into_response();
    for (name, value) in meta {
        if let Ok(v) = axum::http::HeaderValue::from_str(value) {
            response.headers_mut().insert(*name, v);
        }
    }
    response
}

/// A PNG encoded off the async threads.
async fn encoded(
    encode: impl FnOnce() -> anyhow::Result<Vec<u8>> + Send + 'static,
) -> Result<Vec<u8>, ApiError> {
    tokio::task::spawn_blocking(encode)
        .await
        .map_err(ApiError::internal)?
        .map_err(ApiError::internal)
}

fn le_bytes<T: Copy, const N: usize>(a: &ndarray::Array2<T>, to: fn(T) -> [u8; N]) -> Vec<u8> {
    a.iter().flat_map(|&v| to(v)).collect()
}

#[utoipa::path(get, path = "/api/jobs/{id}/snapshot/{part}",
    params(("id" = i64, Path, description = "The job's id"),
        ("part" = String, Path, description = "amplitude or phase"),
        ("format" = Option<ImageFormat>, Query, description = "png (default) or f32")),
    responses((status = 200, description = "The job's newest snapshot; X-Fpm-Shape (rows,cols), X-Fpm-Pixel-Um, X-Fpm-Frames, X-Fpm-Of, X-Fpm-Seq, X-Fpm-Finished",
            content_type = "image/png"),
        (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn snapshot(
    Extract(state): Extract<State>,
    path: Result<UrlPath<(i64, String)>, axum::extract::rejection::PathRejection>,
    query: Result<axum::extract::Query<Format>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let UrlPath((id, part)) = path?;
    let format = query?.0.format;
    let phase = match part.as_str() {
        "amplitude" => false,
        "phase" => true,
        other => {
            return Err(ApiError::BadRequest(format!(
                "part \"{other}\": give amplitude or phase"
            )))
        }
    };
    let s = state.shared.live.snapshot(id).ok_or_else(|| {
        ApiError::NotFound(format!(
            "job {id} has no snapshot (yet, or no longer in memory: its images are in its output directory)"
        ))
    })?;
    let (rows, cols) = s.amplitude.dim();
    let meta = [
        ("x-fpm-shape", format!("{rows},{cols}")),
        ("x-fpm-pixel-um", s.pixel_um.to_string()),
        ("x-fpm-frames", s.frames.to_string()),
        ("x-fpm-of", s.of.to_string()),
        ("x-fpm-seq", s.seq.to_string()),
        ("x-fpm-finished", s.finished.to_string()),
    ];
    let image_of = if phase { &s.phase } else { &s.amplitude };
    match format.unwrap_or(ImageFormat::Png) {
        ImageFormat::F32 => Ok(image(
            le_bytes(image_of, f32::to_le_bytes),
            "application/octet-stream",
            &meta,
        )),
        ImageFormat::Png => {
            let s = s.clone();
            let png = encoded(move || match phase {
                true => fpm_report::preview::phase_png_bytes(&s.phase, s.pixel_um),
                false => fpm_report::preview::amplitude_png_bytes(&s.amplitude, s.pixel_um),
            })
            .await?;
            Ok(image(png, "image/png", &meta))
        }
        ImageFormat::U16 => Err(ApiError::BadRequest(
            "format u16: a snapshot is float; give png or f32".into(),
        )),
    }
}

#[utoipa::path(get, path = "/api/camera/frame",
    params(("format" = Option<ImageFormat>, Query, description = "png (default) or u16")),
    responses((status = 200, description = "The newest camera frame kept (a few a second while a job runs); X-Fpm-Shape, X-Fpm-Led (row,col), X-Fpm-Exposure-Us, X-Fpm-Job, X-Fpm-Seq",
            content_type = "image/png"),
        (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn camera_frame(
    Extract(state): Extract<State>,
    query: Result<axum::extract::Query<Format>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let format = query?.0.format;
    let f = state.shared.live.frame().ok_or_else(|| {
        ApiError::NotFound("no camera frame yet: one is kept while a job captures".into())
    })?;
    let (rows, cols) = f.pixels.dim();
    let meta = [
        ("x-fpm-shape", format!("{rows},{cols}")),
        ("x-fpm-led", format!("{},{}", f.led[0], f.led[1])),
        ("x-fpm-exposure-us", f.exposure_us.to_string()),
        ("x-fpm-job", f.job.to_string()),
        ("x-fpm-seq", f.seq.to_string()),
    ];
    match format.unwrap_or(ImageFormat::Png) {
        ImageFormat::U16 => Ok(image(
            le_bytes(&f.pixels, u16::to_le_bytes),
            "application/octet-stream",
            &meta,
        )),
        ImageFormat::Png => {
            let png =
                encoded(move || fpm_report::preview::counts_png_bytes(&f.pixels.view())).await?;
            Ok(image(png, "image/png", &meta))
        }
        ImageFormat::F32 => Err(ApiError::BadRequest(
            "format f32: a camera frame is counts; give png or u16".into(),
        )),
    }
}

#[utoipa::path(get, path = "/api/jobs/{id}/files/{path}",
    params(("id" = i64, Path, description = "The job's id"),
        ("path" = String, Path, description = "A file in the job's output directory, e.g. acquisition.html")),
    responses((status = 200, description = "The file"), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn job_file(
    Extract(state): Extract<State>,
    path: Result<UrlPath<(i64, String)>, axum::extract::rejection::PathRejection>,
) -> Result<Response, ApiError> {
    let UrlPath((id, relative)) = path?;
    let job = stored_job(&state, id)?;
    // Only plain names below the job's directory: no `..`, no absolute paths, no links
    // out of it.
    let rel = Path::new(&relative);
    if !rel
        .components()
        .all(|c| matches!(c, std::path::Component::Normal(_)))
    {
        return Err(ApiError::BadRequest(format!(
            "path {relative:?}: give a file inside the job's output directory"
        )));
    }
    let root = Path::new(&job.out);
    let not_found = || ApiError::NotFound(format!("job {id} has no file {relative:?} (yet)"));
    let (Ok(root), Ok(file)) = (root.canonicalize(), root.join(rel).canonicalize()) else {
        return Err(not_found());
    };
    if !file.starts_with(&root) || !file.is_file() {
        return Err(not_found());
    }
    let bytes = tokio::fs::read(&file).await.map_err(|_| not_found())?;
    let content_type = match file.extension().and_then(|e| e.to_str()) {
        Some("html") => "text/html; charset=utf-8",
        Some("png") => "image/png",
        Some("json") => "application/json",
        Some("tif" | "tiff") => "image/tiff",
        Some("toml" | "txt" | "csv" | "md") => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    };
    Ok(([(header::CONTENT_TYPE, content_type)], bytes).into_response())
}

/// The page: rig status, jobs, the live reconstruction (assets embedded in the binary).
async fn page() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        include_str!("../assets/index.html"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_answers_are_documented_as_the_api_error_schema() {
        let doc = serde_json::to_value(ApiDoc::openapi()).unwrap();
        let schema = &doc["components"]["schemas"]["ApiError"];
        assert!(schema["properties"]["error"].is_object(), "{schema}");
        let not_found = &doc["paths"]["/api/jobs/{id}"]["get"]["responses"]["404"];
        let reference = not_found["content"]["application/json"]["schema"]["$ref"].as_str();
        assert_eq!(
            reference,
            Some("#/components/schemas/ApiError"),
            "{not_found}"
        );
    }
}
