//! `/v1/assets`: upload an input once, refer to it by SHA-256 afterwards.

use axum::extract::{FromRequest, Multipart, Path, Query, Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;

use super::submit::sanitize_filename;
use super::AppState;
use crate::error::ApiError;
use crate::store::assets::AssetRecord;
use crate::store::is_sha256_hex;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    /// File name (used for format detection by extension) for raw uploads.
    filename: Option<String>,
}

/// Longest `?filename=` accepted (a common file-system limit; names are metadata only).
const MAX_FILENAME_CHARS: usize = 255;

/// `POST /v1/assets`: the raw body (any content type but multipart), or a multipart body with one
/// `file` part. 201 with the record when new, 200 when the same bytes were uploaded before.
pub async fn upload(
    State(st): State<AppState>,
    q: Result<Query<UploadQuery>, axum::extract::rejection::QueryRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    if q.filename
        .as_ref()
        .is_some_and(|f| f.chars().count() > MAX_FILENAME_CHARS)
    {
        return Err(ApiError::bad_field(
            "filename",
            format!("longer than {MAX_FILENAME_CHARS} characters"),
        ));
    }
    let is_multipart = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.to_ascii_lowercase().starts_with("multipart/form-data"));
    let (bytes, filename) = if is_multipart {
        let mut mp = Multipart::from_request(req, &st)
            .await
            .map_err(|e| ApiError::bad_request(e.body_text()))?;
        let mut found = None;
        while let Some(field) = mp.next_field().await.map_err(|e| {
            if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                ApiError::PayloadTooLarge("request body too large".into())
            } else {
                ApiError::bad_request(format!("malformed multipart body: {}", e.body_text()))
            }
        })? {
            if field.name() != Some("file") {
                return Err(ApiError::bad_field(
                    field.name().unwrap_or("").to_string(),
                    "expected a single part named `file`",
                ));
            }
            let name = field.file_name().map(sanitize_filename);
            let b = field.bytes().await.map_err(|e| {
                if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                    ApiError::PayloadTooLarge("request body too large".into())
                } else {
                    ApiError::bad_request(e.body_text())
                }
            })?;
            found = Some((b, name.or(q.filename.as_deref().map(sanitize_filename))));
        }
        found.ok_or_else(|| ApiError::bad_field("file", "missing the `file` part"))?
    } else {
        let b = axum::body::to_bytes(req.into_body(), st.cfg.max_body_bytes)
            .await
            .map_err(|_| ApiError::PayloadTooLarge("request body too large".into()))?;
        (b, q.filename.as_deref().map(sanitize_filename))
    };
    if bytes.is_empty() {
        return Err(ApiError::bad_request("the upload is empty"));
    }
    let store = st.jobs.store().clone();
    let (rec, created) =
        tokio::task::spawn_blocking(move || store.put_asset(&bytes, filename.as_deref()))
            .await
            .map_err(ApiError::internal)??;
    let status = if created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    let view = AssetView::from(rec);
    let location = HeaderValue::from_str(&view.url).map_err(ApiError::internal)?;
    let mut resp = (status, Json(view)).into_response();
    resp.headers_mut().insert(header::LOCATION, location);
    Ok(resp)
}

/// An asset as the API shows it.
#[derive(Debug, serde::Serialize)]
pub struct AssetView {
    pub id: String,
    pub size: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub filename: Option<String>,
    pub created_at: String,
    pub url: String,
}

impl From<AssetRecord> for AssetView {
    fn from(r: AssetRecord) -> Self {
        AssetView {
            url: format!("/v1/assets/{}", r.id),
            id: r.id,
            size: r.size,
            filename: r.filename,
            created_at: r
                .created_at
                .to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
        }
    }
}

/// `GET /v1/assets/{id}`: the asset's metadata.
pub async fn get(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<AssetView>, ApiError> {
    if !is_sha256_hex(&id) {
        return Err(ApiError::NotFound(format!("no asset {id}")));
    }
    let store = st.jobs.store().clone();
    let rec = tokio::task::spawn_blocking(move || store.get_asset(&id))
        .await
        .map_err(ApiError::internal)?;
    rec.map(|r| Json(AssetView::from(r)))
        .ok_or_else(|| ApiError::NotFound("no such asset".into()))
}
