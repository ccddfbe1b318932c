//! `ApiError`: every failure the API reports, as an RFC 9457 `application/problem+json` response
//! with a stable `type` URI per kind. 5xx bodies are generic; their detail goes to the log.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use phenomena_engine::Refusal;
use phenomena_engine::{InputError, ParamError};
use serde::Serialize;

/// Base of the problem `type` URIs (documented in openapi.yaml; they need not resolve).
const PROBLEM_BASE: &str = "https://phenomena.dev/problems/";

/// Base of the OGC API – Processes exception `type` URIs (OGC 18-062r2 §7.5.2).
const OGC_EXCEPTION_BASE: &str = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/";

/// What went wrong, as the API names it: every problem `type` URI and title the service reports,
/// in HTTP responses and in failed jobs' `error`, comes from here and nowhere else.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Problem {
    BadRequest,
    NotFound,
    MethodNotAllowed,
    Unauthorized,
    Conflict,
    RequestTimeout,
    TooLarge,
    UnsupportedFormat,
    InvalidParameter,
    InvalidInput,
    QueueFull,
    Overloaded,
    Unavailable,
    Internal,
    /// A job's run: the pipeline cannot produce what was asked (a cloud edit dragged from
    /// empty sky).
    Unprocessable,
    /// A cloud edit's stroke that misses the cloud.
    StrokeMissesCloud,
    /// A cloud edit's stroke on cloud that no sunlight reaches.
    StrokeNotLit,
    /// A job's input could not be read from the store.
    InputMissing,
    /// A job's outputs could not be stored.
    Storage,
    /// A job ran longer than the time limit.
    TimeLimit,
    /// A job none of whose `max_attempts` attempts reached an end (a panic, a dead worker).
    Poisoned,
    /// A job canceled (a cloud scene version whose edit job was canceled).
    Canceled,
    /// OGC API – Processes: no process of that id (OGC 18-062r2 §7.10, `no-such-process`).
    NoSuchProcess,
    /// OGC API – Processes: no job of that id (§7.12, `no-such-job`).
    NoSuchJob,
    /// OGC API – Processes: the job has no results yet (§7.13, `result-not-ready`).
    ResultNotReady,
}

impl Problem {
    /// The last part of the `type` URI.
    fn slug(self) -> &'static str {
        match self {
            Problem::BadRequest => "bad-request",
            Problem::NotFound => "not-found",
            Problem::MethodNotAllowed => "method-not-allowed",
            Problem::Unauthorized => "unauthorized",
            Problem::Conflict => "conflict",
            Problem::RequestTimeout => "request-timeout",
            Problem::TooLarge => "too-large",
            Problem::UnsupportedFormat => "unsupported-format",
            Problem::InvalidParameter => "invalid-parameter",
            Problem::InvalidInput => "invalid-input",
            Problem::QueueFull => "queue-full",
            Problem::Overloaded => "overloaded",
            Problem::Unavailable => "unavailable",
            Problem::Internal => "internal",
            Problem::Unprocessable => "unprocessable",
            Problem::StrokeMissesCloud => "stroke-misses-cloud",
            Problem::StrokeNotLit => "stroke-not-lit",
            Problem::InputMissing => "input-missing",
            Problem::Storage => "storage",
            Problem::TimeLimit => "time-limit",
            Problem::Poisoned => "poisoned",
            Problem::Canceled => "canceled",
            Problem::NoSuchProcess => "no-such-process",
            Problem::NoSuchJob => "no-such-job",
            Problem::ResultNotReady => "result-not-ready",
        }
    }

    /// The problem's `type` URI: the OGC API – Processes exceptions keep the standard's own URIs
    /// (OGC 18-062r2 §7.5.2, Table 7), the rest are under [`PROBLEM_BASE`].
    pub fn type_uri(self) -> String {
        match self {
            Problem::NoSuchProcess | Problem::NoSuchJob | Problem::ResultNotReady => {
                format!("{OGC_EXCEPTION_BASE}{}", self.slug())
            }
            _ => format!("{PROBLEM_BASE}{}", self.slug()),
        }
    }

    /// The kind whose [`Problem::type_uri`] is `uri` (a failed job's recorded `error.type`).
    pub fn from_type_uri(uri: &str) -> Option<Problem> {
        Self::ALL.iter().copied().find(|p| p.type_uri() == uri)
    }

    /// Every kind.
    pub const ALL: &'static [Problem] = &[
        Problem::BadRequest,
        Problem::NotFound,
        Problem::MethodNotAllowed,
        Problem::Unauthorized,
        Problem::Conflict,
        Problem::RequestTimeout,
        Problem::TooLarge,
        Problem::UnsupportedFormat,
        Problem::InvalidParameter,
        Problem::InvalidInput,
        Problem::QueueFull,
        Problem::Overloaded,
        Problem::Unavailable,
        Problem::Internal,
        Problem::Unprocessable,
        Problem::StrokeMissesCloud,
        Problem::StrokeNotLit,
        Problem::InputMissing,
        Problem::Storage,
        Problem::TimeLimit,
        Problem::Poisoned,
        Problem::Canceled,
        Problem::NoSuchProcess,
        Problem::NoSuchJob,
        Problem::ResultNotReady,
    ];

    /// The problem's title. A failed job's title (a job-run problem) differs from the HTTP
    /// response's for the same kind where the job system words it its own way.
    pub fn title(self) -> &'static str {
        match self {
            Problem::BadRequest => "Bad request",
            Problem::NotFound => "Not found",
            Problem::MethodNotAllowed => "Method not allowed",
            Problem::Unauthorized => "Unauthorized",
            Problem::Conflict => "Conflict",
            Problem::RequestTimeout => "Request timeout",
            Problem::TooLarge => "Payload too large",
            Problem::UnsupportedFormat => "Unsupported format",
            Problem::InvalidParameter => "Invalid parameter",
            Problem::InvalidInput => "Invalid input",
            Problem::QueueFull => "Queue full",
            Problem::Overloaded => "Overloaded",
            Problem::Unavailable => "Service unavailable",
            Problem::Internal => "Internal server error",
            Problem::Unprocessable => "Cannot be done",
            Problem::StrokeMissesCloud => "The stroke misses the cloud",
            Problem::StrokeNotLit => "Nothing under the stroke is sunlit",
            Problem::InputMissing => "Input unavailable",
            Problem::Storage => "Storage unavailable",
            Problem::TimeLimit => "Time limit exceeded",
            Problem::Poisoned => "Job poisoned",
            Problem::Canceled => "Canceled",
            Problem::NoSuchProcess => "No such process",
            Problem::NoSuchJob => "No such job",
            Problem::ResultNotReady => "Result not ready",
        }
    }

    /// The title of the problem in a failed job's `error`: the job system says "Internal error"
    /// where an HTTP response says "Internal server error".
    pub fn job_title(self) -> &'static str {
        match self {
            Problem::Internal => "Internal error",
            other => other.title(),
        }
    }
}

/// The problem kind of a refusal by the engine.
impl From<Refusal> for Problem {
    fn from(r: Refusal) -> Self {
        match r {
            Refusal::Unprocessable => Problem::Unprocessable,
            Refusal::StrokeMissesCloud => Problem::StrokeMissesCloud,
            Refusal::StrokeNotLit => Problem::StrokeNotLit,
        }
    }
}

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
    /// 410: what the request names existed and is gone for good (a map whose DEM asset expired).
    #[error("{0}")]
    Gone(String),
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
    /// OGC API – Processes `no-such-process` (404).
    #[error("{0}")]
    NoSuchProcess(String),
    /// OGC API – Processes `no-such-job` (404).
    #[error("{0}")]
    NoSuchJob(String),
    /// OGC API – Processes `result-not-ready` (404).
    #[error("{0}")]
    ResultNotReady(String),
    /// The results of a failed job (OGC 18-062r2 `/req/core/job-results-failed`): the job's own
    /// recorded problem, with a status code reflecting it.
    #[error("{}", error.detail)]
    JobFailed {
        status: StatusCode,
        error: crate::jobs::JobError,
    },
}

#[derive(Serialize)]
struct ProblemBody<'a> {
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

    /// The status code and the problem kind.
    fn parts(&self) -> (StatusCode, Problem) {
        match self {
            ApiError::BadRequest { .. } => (StatusCode::BAD_REQUEST, Problem::BadRequest),
            ApiError::NotFound(_) => (StatusCode::NOT_FOUND, Problem::NotFound),
            ApiError::Gone(_) => (StatusCode::GONE, Problem::InputMissing),
            ApiError::MethodNotAllowed(_) => {
                (StatusCode::METHOD_NOT_ALLOWED, Problem::MethodNotAllowed)
            }
            ApiError::Conflict(_) => (StatusCode::CONFLICT, Problem::Conflict),
            ApiError::RequestTimeout(_) => (StatusCode::REQUEST_TIMEOUT, Problem::RequestTimeout),
            ApiError::Unauthorized(_) => (StatusCode::UNAUTHORIZED, Problem::Unauthorized),
            ApiError::PayloadTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, Problem::TooLarge),
            ApiError::UnsupportedMediaType(_) => (
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                Problem::UnsupportedFormat,
            ),
            ApiError::InvalidParameter(_) => {
                (StatusCode::UNPROCESSABLE_ENTITY, Problem::InvalidParameter)
            }
            ApiError::InvalidInput { .. } => {
                (StatusCode::UNPROCESSABLE_ENTITY, Problem::InvalidInput)
            }
            ApiError::QueueFull { .. } => (StatusCode::TOO_MANY_REQUESTS, Problem::QueueFull),
            ApiError::Overloaded { .. } => (StatusCode::TOO_MANY_REQUESTS, Problem::Overloaded),
            ApiError::Unavailable(_) => (StatusCode::SERVICE_UNAVAILABLE, Problem::Unavailable),
            ApiError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, Problem::Internal),
            ApiError::NoSuchProcess(_) => (StatusCode::NOT_FOUND, Problem::NoSuchProcess),
            ApiError::NoSuchJob(_) => (StatusCode::NOT_FOUND, Problem::NoSuchJob),
            ApiError::ResultNotReady(_) => (StatusCode::NOT_FOUND, Problem::ResultNotReady),
            ApiError::JobFailed { status, error } => (
                *status,
                Problem::from_type_uri(&error.kind).unwrap_or(Problem::Internal),
            ),
        }
    }
}

impl From<ParamError> for ApiError {
    fn from(e: ParamError) -> Self {
        ApiError::InvalidParameter(e)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, problem) = self.parts();
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
        let (kind, title) = match &self {
            // The job's own record: its type URI and title as the job system wrote them.
            ApiError::JobFailed { error, .. } => (error.kind.clone(), error.title.as_str()),
            _ => (problem.type_uri(), problem.title()),
        };
        let body = ProblemBody {
            kind,
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
