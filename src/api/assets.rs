//! `/v1/assets`: upload an input once, refer to it by SHA-256 afterwards.

use axum::extract::{FromRequest, Multipart, Query, Request, State};

use super::extract::ApiPath;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures_util::StreamExt;
use serde::Deserialize;

use super::submit::sanitize_filename;
use super::AppState;
use crate::error::ApiError;
use crate::store::assets::AssetRecord;
use crate::store::{is_sha256_hex, StoreError};

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
    let max = st.cfg.max_body_bytes as u64;
    let store = st.jobs.store().clone();
    // The bytes stream to the blob store as they arrive (hashed on the way), never held whole.
    let (sha, size, filename) = if is_multipart {
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
            let chunks = field.map(|r| {
                r.map_err(|e| {
                    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                        StoreError::TooLarge { max }
                    } else {
                        StoreError::Upload(e.body_text())
                    }
                })
            });
            let (sha, size) = store.put_blob_stream(chunks, max).await?;
            found = Some((
                sha,
                size,
                name.or(q.filename.as_deref().map(sanitize_filename)),
            ));
        }
        found.ok_or_else(|| ApiError::bad_field("file", "missing the `file` part"))?
    } else {
        let chunks = req
            .into_body()
            .into_data_stream()
            .map(|r| r.map_err(|e| StoreError::Upload(e.to_string())));
        let (sha, size) = store.put_blob_stream(chunks, max).await?;
        (sha, size, q.filename.as_deref().map(sanitize_filename))
    };
    if size == 0 {
        return Err(ApiError::bad_request("the upload is empty"));
    }
    let (rec, created) = store.record_asset(&sha, size, filename.as_deref()).await?;
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
    ApiPath(id): ApiPath<String>,
) -> Result<Json<AssetView>, ApiError> {
    if !is_sha256_hex(&id) {
        return Err(ApiError::NotFound(format!("no asset {id}")));
    }
    let rec = st.jobs.store().get_asset(&id).await;
    rec.map(|r| Json(AssetView::from(r)))
        .ok_or_else(|| ApiError::NotFound("no such asset".into()))
}
