//! `ApiError`: every failure the API reports, as an RFC 9457 `application/problem+json` response
//! with a stable `type` URI per kind. 5xx bodies are generic; their detail goes to the log.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use phenomena_engine::{InputError, ParamError};
use serde::Serialize;

/// Base of the problem `type` URIs (documented in openapi.yaml; they need not resolve).
pub const PROBLEM_BASE: &str = "https://phenomena.dev/problems/";

/// An API failure.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    #[error("{detail}")]
    BadRequest {
        detail: String,
        field: Option<String>,
    },
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    MethodNotAllowed(String),
    /// No or a wrong bearer token on a `/v1` route while tokens are configured.
    #[error("{0}")]
    Unauthorized(String),
    #[error("{0}")]
    Conflict(String),
    /// The client stopped sending the request body (`body_read_timeout_secs`).
    #[error("{0}")]
    RequestTimeout(String),
    #[error("{0}")]
    PayloadTooLarge(String),
    #[error("{0}")]
    UnsupportedMediaType(String),
    #[error("{0}")]
    InvalidParameter(ParamError),
    #[error("{detail}")]
    InvalidInput {
        detail: String,
        field: Option<String>,
    },
    #[error("{detail}")]
    QueueFull { detail: String, retry_after: u64 },
    /// The process's decode budget stayed in use (see `api::admission`).
    #[error("{detail}")]
    Overloaded { detail: String, retry_after: u64 },
    #[error("{0}")]
    Unavailable(String),
    /// Something internal failed; the message is logged, never sent.
    #[error("{0}")]
    Internal(String),
}

#[derive(Serialize)]
struct Problem<'a> {
    #[serde(rename = "type")]
    kind: String,
    title: &'a str,
    status: u16,
    detail: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    field: Option<String>,
}

impl ApiError {
    pub fn bad_request(detail: impl Into<String>) -> Self {
        ApiError::BadRequest {
            detail: detail.into(),
            field: None,
        }
    }

    pub fn bad_field(field: impl Into<String>, detail: impl Into<String>) -> Self {
        ApiError::BadRequest {
            detail: detail.into(),
            field: Some(field.into()),
        }
    }

    pub fn internal(e: impl std::fmt::Display) -> Self {
        ApiError::Internal(e.to_string())
    }

    /// Maps a decoder failure of the input part named `part` to its status code.
    pub fn from_input(e: InputError, part: &str) -> Self {
        match e {
            InputError::UnsupportedFormat(d) => {
                ApiError::UnsupportedMediaType(format!("{part}: unsupported format: {d}"))
            }
            InputError::TooLarge { .. } => ApiError::PayloadTooLarge(format!("{part}: {e}")),
            InputError::Param(p) => ApiError::InvalidParameter(p),
            other => ApiError::InvalidInput {
                detail: format!("{part}: {other}"),
                field: Some(part.to_string()),
            },
        }
    }

    fn parts(&self) -> (StatusCode, &'static str, &'static str) {
        match self {
            ApiError::BadRequest { .. } => (StatusCode::BAD_REQUEST, "bad-request", "Bad request"),
            ApiError::NotFound(_) => (StatusCode::NOT_FOUND, "not-found", "Not found"),
            ApiError::MethodNotAllowed(_) => (
                StatusCode::METHOD_NOT_ALLOWED,
                "method-not-allowed",
                "Method not allowed",
            ),
            ApiError::Conflict(_) => (StatusCode::CONFLICT, "conflict", "Conflict"),
            ApiError::RequestTimeout(_) => (
                StatusCode::REQUEST_TIMEOUT,
                "request-timeout",
                "Request timeout",
            ),
            ApiError::Unauthorized(_) => (StatusCode::UNAUTHORIZED, "unauthorized", "Unauthorized"),
            ApiError::PayloadTooLarge(_) => (
                StatusCode::PAYLOAD_TOO_LARGE,
                "too-large",
                "Payload too large",
            ),
            ApiError::UnsupportedMediaType(_) => (
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported-format",
                "Unsupported format",
            ),
            ApiError::InvalidParameter(_) => (
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid-parameter",
                "Invalid parameter",
            ),
            ApiError::InvalidInput { .. } => (
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid-input",
                "Invalid input",
            ),
            ApiError::QueueFull { .. } => {
                (StatusCode::TOO_MANY_REQUESTS, "queue-full", "Queue full")
            }
            ApiError::Overloaded { .. } => {
                (StatusCode::TOO_MANY_REQUESTS, "overloaded", "Overloaded")
            }
            ApiError::Unavailable(_) => (
                StatusCode::SERVICE_UNAVAILABLE,
                "unavailable",
                "Service unavailable",
            ),
            ApiError::Internal(_) => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "internal",
                "Internal server error",
            ),
        }
    }
}

impl From<ParamError> for ApiError {
    fn from(e: ParamError) -> Self {
        ApiError::InvalidParameter(e)
    }
}

impl From<crate::store::StoreError> for ApiError {
    fn from(e: crate::store::StoreError) -> Self {
        match e {
            crate::store::StoreError::TooLarge { .. } => {
                ApiError::PayloadTooLarge("request body too large".into())
            }
            crate::store::StoreError::Upload(detail) => {
                ApiError::bad_request(format!("the upload failed: {detail}"))
            }
            e => {
                tracing::error!(error = %e, "store failure");
                ApiError::Unavailable("storage is unavailable; try again later".into())
            }
        }
    }
}

impl From<crate::jobs::JobsError> for ApiError {
    fn from(e: crate::jobs::JobsError) -> Self {
        match e {
            crate::jobs::JobsError::Store(e) => e.into(),
            crate::jobs::JobsError::Backend(msg) => {
                tracing::error!(error = %msg, "job backend failure");
                ApiError::Unavailable("the job system is unavailable; try again later".into())
            }
        }
    }
}

impl From<crate::clouds::SceneError> for ApiError {
    fn from(e: crate::clouds::SceneError) -> Self {
        match e {
            crate::clouds::SceneError::NotFound(d) => {
                ApiError::NotFound(format!("no cloud scene {d}"))
            }
            crate::clouds::SceneError::Store(s) => s.into(),
            crate::clouds::SceneError::Backend(msg) => {
                tracing::error!(error = %msg, "scene store failure");
                ApiError::Unavailable("the scene store is unavailable; try again later".into())
            }
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, kind, title) = self.parts();
        let (detail, field) = match &self {
            ApiError::Internal(msg) => {
                tracing::error!(error = %msg, "internal error");
                ("the server failed to handle the request".to_string(), None)
            }
            ApiError::BadRequest { detail, field } | ApiError::InvalidInput { detail, field } => {
                (detail.clone(), field.clone())
            }
            ApiError::InvalidParameter(p) => (p.to_string(), Some(p.field.clone())),
            other => (other.to_string(), None),
        };
        let body = Problem {
            kind: format!("{PROBLEM_BASE}{kind}"),
            title,
            status: status.as_u16(),
            detail,
            field,
        };
        let mut resp = (status, axum::Json(body)).into_response();
        resp.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/problem+json"),
        );
        if let ApiError::QueueFull { retry_after, .. } | ApiError::Overloaded { retry_after, .. } =
            &self
        {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(*retry_after));
        }
        if matches!(self, ApiError::Unauthorized(_)) {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"phenomena\""),
            );
        }
        if matches!(self, ApiError::Unavailable(_)) {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(5u64));
        }
        resp
    }
}
