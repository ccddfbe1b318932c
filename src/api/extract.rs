//! Extractors whose rejections are problem+json like every other error: axum's own answer
//! `text/plain` (an invalid percent-escape in a path segment, say).

use axum::extract::{FromRequestParts, Path};
use axum::http::request::Parts;
use serde::de::DeserializeOwned;

use crate::error::ApiError;

/// [`axum::extract::Path`] rejecting with `400` problem+json (an invalid percent-escape, a
/// segment that is not UTF-8).
#[derive(Debug)]
pub struct ApiPath<T>(pub T);

impl<S, T> FromRequestParts<S> for ApiPath<T>
where
    T: DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        match Path::<T>::from_request_parts(parts, state).await {
            Ok(Path(t)) => Ok(ApiPath(t)),
            Err(e) => Err(ApiError::bad_request(format!(
                "the path {:?} cannot be read: {}",
                parts.uri.path(),
                e.body_text()
            ))),
        }
    }
}
