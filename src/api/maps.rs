//! `/v1/maps` (issue 22): a DEM asset with snow-terrain parameters as a web map — the map
//! resource, its TileJSON 3.0.0 document and its WebMercatorQuad PNG tiles.

use axum::extract::{Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use phenomena_engine::snow_terrain::tiles::{Layer, MapError, MapInfo, Region, SourceKind};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use super::extract::ApiPath;
use super::submit::{read_body, reject_nulls, request_key, store_input};
use super::AppState;
use crate::error::ApiError;
use crate::maps::MapsError;
use crate::store::maps::MapRecord;

/// The pipeline whose parameters a map takes.
const PIPELINE: &str = "snow-terrain";

/// `Cache-Control` of tiles and TileJSON: a map id names its DEM and parameters, so what it
/// serves changes only with the renderer (a day's caching bounds that).
const CACHE_CONTROL: &str = "public, max-age=86400";

/// Attribution shown by map clients.
const ATTRIBUTION: &str = "Snow: phenomena, after Nakatani, Fujishiro and Ohno's surface descriptor; elevation: the uploaded DEM";

impl From<MapsError> for ApiError {
    fn from(e: MapsError) -> Self {
        match e {
            MapsError::Store(s) => s.into(),
            MapsError::Map(MapError::Param(p)) => ApiError::InvalidParameter(p),
            MapsError::Map(MapError::Input(i)) => ApiError::from_input(i, "dem"),
            MapsError::Map(MapError::Crs(c)) => ApiError::InvalidInput {
                detail: format!("dem: {c}"),
                field: Some("dem".into()),
            },
            MapsError::Map(MapError::Source(d)) => {
                tracing::error!(error = %d, "reading a map's DEM");
                ApiError::Unavailable("storage is unavailable; try again later".into())
            }
            e @ MapsError::AssetGone(_) => ApiError::Gone(e.to_string()),
            MapsError::Failed(d) => ApiError::internal(d),
        }
    }
}

/// A map as the API shows it.
#[derive(Debug, Serialize)]
pub struct MapView {
    pub id: String,
    pub asset: String,
    pub params: Value,
    #[serde(flatten)]
    pub info: MapInfo,
    pub layers: Vec<&'static str>,
    /// Tile URL template per layer (relative; `{z}`, `{x}`, `{y}`).
    pub tiles: serde_json::Map<String, Value>,
    pub tilejson_url: String,
    pub created_at: String,
    pub url: String,
}

impl From<MapRecord> for MapView {
    fn from(r: MapRecord) -> Self {
        let url = format!("/v1/maps/{}", r.id);
        MapView {
            layers: Layer::ALL.iter().map(|l| l.name()).collect(),
            tiles: Layer::ALL
                .iter()
                .map(|l| (l.name().to_string(), json!(tile_template("", &r.id, *l))))
                .collect(),
            tilejson_url: format!("{url}/tilejson.json"),
            id: r.id,
            asset: r.asset,
            params: r.params,
            info: r.info,
            created_at: r
                .created_at
                .to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
            url,
        }
    }
}

fn tile_template(base: &str, id: &str, layer: Layer) -> String {
    format!(
        "{base}/v1/maps/{id}/tiles/{}/{{z}}/{{x}}/{{y}}.png",
        layer.name()
    )
}

/// `POST /v1/maps`: JSON `{"asset": "<sha256>", "params": {…}}` (or multipart with a `params`
/// part and a `dem` part). 201 with the map when new, 200 when the same DEM and resolved
/// parameters made one before; `Location` names it either way.
pub async fn create(State(st): State<AppState>, req: Request) -> Result<Response, ApiError> {
    if !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let (raw, input) = read_body(&st, req, "dem").await?;
    reject_nulls(&raw, "")?;
    let canonical = st.maps.params(&raw)?;
    let asset = store_input(&st, input).await?;
    let id = request_key("maps", &asset.id, &canonical);
    let store = st.maps.store().clone();
    let (status, rec) = match store.get_map(&id).await? {
        Some(rec) => (StatusCode::OK, rec),
        None => {
            // The DEM is read within the process's memory budget, as a job's input check is: a
            // corrupt, unsupported or oversize file is a 4xx before anything is kept. A DEM read
            // whole reserves its bytes and the most its decode can allocate; a COG read by
            // ranges (its header tells, read first) what the map holds: its bounded overview,
            // shadow field and tile cache, whatever its cells.
            let worst = match st.maps.source_kind(&asset.id, &canonical).await? {
                SourceKind::Whole => asset
                    .size
                    .saturating_add(st.jobs.pipelines().decode_cost(PIPELINE, false)),
                SourceKind::Tiled { held_bytes } => held_bytes,
            };
            let _reservation = super::admission::reserve_worst(&st.memory, worst).await?;
            let src = st
                .maps
                .prepare(&id, &asset.id, asset.filename.clone(), canonical.clone())
                .await?;
            let rec = MapRecord {
                id: id.clone(),
                asset: asset.id.clone(),
                filename: asset.filename.clone(),
                params: canonical,
                info: src.info().clone(),
                created_at: chrono::Utc::now(),
            };
            store.put_map(&rec).await?;
            (StatusCode::CREATED, rec)
        }
    };
    store.touch_asset(&asset).await?;
    let view = MapView::from(rec);
    let location = HeaderValue::from_str(&view.url).map_err(ApiError::internal)?;
    let mut resp = (status, Json(view)).into_response();
    resp.headers_mut().insert(header::LOCATION, location);
    Ok(resp)
}

async fn record(st: &AppState, id: &str) -> Result<std::sync::Arc<MapRecord>, ApiError> {
    st.maps
        .record(id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("no map {id}")))
}

/// `GET /v1/maps/{id}`.
pub async fn get(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<MapView>, ApiError> {
    Ok(Json(MapView::from(MapRecord::clone(
        &*record(&st, &id).await?,
    ))))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TileJsonQuery {
    /// The layer the document describes (default `relief`).
    layer: Option<String>,
    /// 256 (default) or 512.
    tile_size: Option<u32>,
}

fn layer_named(name: &str) -> Result<Layer, ApiError> {
    Layer::parse(name).ok_or_else(|| {
        ApiError::NotFound(format!(
            "no layer {name:?}; layers: {}",
            Layer::ALL.map(|l| l.name()).join(", ")
        ))
    })
}

fn tile_size(given: Option<u32>) -> Result<u32, ApiError> {
    match given.unwrap_or(256) {
        s @ (256 | 512) => Ok(s),
        s => Err(ApiError::bad_field(
            "tile_size",
            format!("tile_size {s}: give 256 or 512"),
        )),
    }
}

/// `scheme://host` of the request, for absolute tile URLs (map clients resolve TileJSON's
/// `tiles` against nothing): `Host` (`X-Forwarded-Proto` for the scheme behind a proxy); empty
/// when there is no usable `Host`, leaving the URLs relative.
pub(super) fn base_url(headers: &HeaderMap) -> String {
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .filter(|h| {
            !h.is_empty()
                && h.bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b"-.:[]".contains(&b))
        });
    let proto = match headers
        .get("x-forwarded-proto")
        .and_then(|v| v.to_str().ok())
    {
        Some("https") => "https",
        _ => "http",
    };
    host.map_or_else(String::new, |h| format!("{proto}://{h}"))
}

/// `GET /v1/maps/{id}/tilejson.json?layer=…&tile_size=…`: TileJSON 3.0.0 of one layer.
pub async fn tilejson(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    q: Result<Query<TileJsonQuery>, axum::extract::rejection::QueryRejection>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let layer = match q.layer.as_deref() {
        Some(name) => Layer::parse(name).ok_or_else(|| {
            ApiError::bad_field(
                "layer",
                format!(
                    "no layer {name:?}; layers: {}",
                    Layer::ALL.map(|l| l.name()).join(", ")
                ),
            )
        })?,
        None => Layer::Relief,
    };
    let size = tile_size(q.tile_size)?;
    let rec = record(&st, &id).await?;
    let mut template = tile_template(&base_url(&headers), &rec.id, layer);
    if size != 256 {
        template.push_str(&format!("?tile_size={size}"));
    }
    let info = &rec.info;
    let mut doc = json!({
        "tilejson": "3.0.0",
        "name": format!("phenomena {} {}", layer.name(), &rec.id[..12]),
        "description": format!(
            "{} of the snow-terrain map {} ({}×{} cells, {})",
            layer.name(), rec.id, info.width, info.height, info.crs
        ),
        "version": "1.0.0",
        "attribution": ATTRIBUTION,
        "scheme": "xyz",
        "tiles": [template],
        "minzoom": info.minzoom,
        "maxzoom": info.maxzoom,
        "bounds": info.bounds,
        "center": info.center,
        "tileSize": size,
    });
    if let Some(enc) = layer.encoding() {
        doc["encoding"] = json!(enc);
    }
    let mut resp = Json(doc).into_response();
    resp.headers_mut().insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static(CACHE_CONTROL),
    );
    Ok(resp)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TileQuery {
    /// 256 (default) or 512.
    tile_size: Option<u32>,
}

/// `GET /v1/maps/{id}/tiles/{layer}/{z}/{x}/{y}.png?tile_size=…`: 200 PNG (`ETag`,
/// `Cache-Control`; 304 on a matching `If-None-Match`), 204 when no pixel of the tile falls on
/// the DEM, 404 for an unknown map or layer or a tile outside the tile matrix.
pub async fn tile(
    State(st): State<AppState>,
    ApiPath((id, layer, z, x, file)): ApiPath<(String, String, u8, u64, String)>,
    q: Result<Query<TileQuery>, axum::extract::rejection::QueryRejection>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let size = tile_size(q.tile_size)?;
    let layer = layer_named(&layer)?;
    let y: u64 = file
        .strip_suffix(".png")
        .and_then(|y| y.parse().ok())
        .ok_or_else(|| ApiError::NotFound(format!("no tile {file:?}: name it {{y}}.png")))?;
    if Region::tile(z, x, y, size).is_none() {
        return Err(ApiError::NotFound(format!(
            "no tile {z}/{x}/{y}: zoom 0–24 and x, y below 2^zoom"
        )));
    }
    let rec = record(&st, &id).await?;
    let cache = HeaderValue::from_static(CACHE_CONTROL);
    let Some((png, etag)) = st.maps.tile_tagged(&rec, layer, z, x, y, size).await? else {
        let mut resp = StatusCode::NO_CONTENT.into_response();
        resp.headers_mut().insert(header::CACHE_CONTROL, cache);
        return Ok(resp);
    };
    let etag_value = HeaderValue::from_str(&etag).map_err(ApiError::internal)?;
    let matches = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.split(',')
                .any(|t| t.trim() == "*" || t.trim().trim_start_matches("W/") == &*etag)
        });
    let mut resp = if matches {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        (
            [(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))],
            png,
        )
            .into_response()
    };
    resp.headers_mut().insert(header::ETAG, etag_value);
    resp.headers_mut().insert(header::CACHE_CONTROL, cache);
    Ok(resp)
}
