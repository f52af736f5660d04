//! The API's errors: one enum whose variant decides the HTTP status, so that a handler
//! says what went wrong with `?` and no caller matches on wording. The body is always
//! `{"error": "…"}`, its text naming the field, header, job or file.

use axum::extract::rejection::{BytesRejection, PathRejection, QueryRejection};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use utoipa::ToSchema;

use crate::worker::{CancelError, SteerError};

/// An error as the API answers it.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The request is malformed, or a value in it is out of range or unknown (400).
    #[error("{0}")]
    BadRequest(String),
    /// The request changes the rig (or the service listens beyond loopback) and lacks
    /// the token (401).
    #[error("{0}")]
    Unauthorized(String),
    /// `Host` or `Origin` is not this service's (403).
    #[error("{0}")]
    Forbidden(String),
    /// No such job, file, snapshot or frame (404).
    #[error("{0}")]
    NotFound(String),
    /// The job is in a state the request does not apply to (409).
    #[error("{0}")]
    Conflict(String),
    /// The body, path or query could not be read: the status and text axum gives.
    #[error("{1}")]
    Rejected(StatusCode, String),
    /// The worker takes no jobs now (503; the service is stopping).
    #[error("{0}")]
    Unavailable(String),
    /// The service's own failure: its database, an image encoder (500).
    #[error("{0}")]
    Internal(String),
}

impl ApiError {
    /// The service's own failure, with its chain of causes.
    pub fn internal(e: impl Into<anyhow::Error>) -> Self {
        Self::Internal(format!("{:#}", e.into()))
    }

    /// The worker would not take the job (it is stopping), with the chain of causes.
    pub fn unavailable(e: anyhow::Error) -> Self {
        Self::Unavailable(format!("{e:#}"))
    }

    /// A request value that fails its check, with the check's chain of causes.
    pub fn invalid(e: anyhow::Error) -> Self {
        Self::BadRequest(format!("{e:#}"))
    }

    /// The HTTP status this error is answered with.
    pub fn status(&self) -> StatusCode {
        match self {
            Self::BadRequest(_) => StatusCode::BAD_REQUEST,
            Self::Unauthorized(_) => StatusCode::UNAUTHORIZED,
            Self::Forbidden(_) => StatusCode::FORBIDDEN,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::Conflict(_) => StatusCode::CONFLICT,
            Self::Rejected(status, _) => *status,
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}

/// The body of every error answer (named `ApiError` in the OpenAPI document, as it
/// always was).
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = ApiError)]
pub struct ErrorBody {
    /// What is wrong, naming the field, header or job.
    pub error: String,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let body = ErrorBody {
            error: self.to_string(),
        };
        (status, Json(body)).into_response()
    }
}

impl From<SteerError> for ApiError {
    fn from(e: SteerError) -> Self {
        match e {
            SteerError::Unknown(_) => Self::NotFound(e.to_string()),
            SteerError::Conflict(_) => Self::Conflict(e.to_string()),
            SteerError::Store(_) => Self::Internal(e.to_string()),
        }
    }
}

impl From<CancelError> for ApiError {
    fn from(e: CancelError) -> Self {
        match e {
            CancelError::Unknown(_) => Self::NotFound(e.to_string()),
            CancelError::Ended(..) | CancelError::Unstoppable(_) => Self::Conflict(e.to_string()),
            CancelError::Store(_) => Self::Internal(e.to_string()),
        }
    }
}

/// Axum's rejections keep their own status and text.
macro_rules! rejected {
    ($($rejection:ty),*) => {$(
        impl From<$rejection> for ApiError {
            fn from(e: $rejection) -> Self {
                Self::Rejected(e.status(), e.body_text())
            }
        }
    )*};
}

rejected!(BytesRejection, PathRejection, QueryRejection);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_error_is_answered_with_its_status_and_text() {
        let cases = [
            (ApiError::BadRequest("step_ms 0".into()), 400),
            (ApiError::Unauthorized("token".into()), 401),
            (ApiError::Forbidden("Host".into()), 403),
            (ApiError::NotFound("no job 3".into()), 404),
            (ApiError::Conflict("ended".into()), 409),
            (
                ApiError::Rejected(StatusCode::PAYLOAD_TOO_LARGE, "big".into()),
                413,
            ),
            (ApiError::Unavailable("stopping".into()), 503),
            (ApiError::internal(anyhow::anyhow!("disk full")), 500),
            (SteerError::Unknown(7).into(), 404),
            (SteerError::Conflict("paused".into()).into(), 409),
            (CancelError::Unstoppable(2).into(), 409),
        ];
        for (error, status) in cases {
            let text = error.to_string();
            let response = error.into_response();
            assert_eq!(response.status().as_u16(), status, "{text}");
            assert!(!text.is_empty());
        }
    }
}
