//! `GET /v1/jobs/{id}/stac.json` (issue 22): a finished snow-terrain job as a STAC 1.0.0 Item
//! with the projection (v2.0.0), raster (v1.1.0) and web-map-links (v1.2.0) extensions.
//!
//! Everything georeferenced is read from the job's own `snow_cover.tif`
//! (`snow_terrain::catalog::footprint`): the footprint and bbox in WGS 84 (the grid's outline
//! reprojected with proj4rs, eight points a side), `proj:code`, `proj:shape`, `proj:transform`
//! and `proj:bbox` in the raster's CRS, and the band's data type, nodata and statistics. Tiles
//! are linked when a web map (`/v1/maps`) of the same DEM and parameters exists; otherwise a
//! link says how to make one (`POST /v1/maps` with the body given). `datetime` is when the job
//! finished: the DEM's acquisition time is not known to the service. Every `href` is absolute
//! (`scheme://host` from the request's `Host`, `X-Forwarded-Proto` behind a proxy, as TileJSON's
//! tile URLs are): STAC wants an absolute `self` link, and a catalog tool that copies the Item
//! elsewhere resolves nothing against the server. Without a usable `Host` they stay relative.

use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use phenomena_engine::snow_terrain::catalog::{self, FootprintError, RasterFootprint};
use phenomena_engine::snow_terrain::tiles::Layer;
use serde_json::{json, Value};

use super::extract::ApiPath;
use super::submit::{blocking_err, request_key};
use super::AppState;
use crate::error::ApiError;
use crate::jobs::record::is_job_id;
use crate::jobs::{JobRecord, Status};

/// The pipeline whose results have STAC Items.
const PIPELINE: &str = "snow-terrain";
/// The georeferenced output an Item describes.
const COG: &str = "snow_cover.tif";

const STAC_EXTENSIONS: [&str; 3] = [
    "https://stac-extensions.github.io/projection/v2.0.0/schema.json",
    "https://stac-extensions.github.io/raster/v1.1.0/schema.json",
    "https://stac-extensions.github.io/web-map-links/v1.2.0/schema.json",
];

/// Whether a job has a STAC Item: a successful snow-terrain job that wrote `snow_cover.tif`.
pub fn describes(rec: &JobRecord) -> bool {
    rec.pipeline == PIPELINE
        && rec.status == Status::Succeeded
        && rec.outputs.iter().any(|o| o.name == COG)
}

/// STAC asset roles and titles of the snow-terrain outputs besides the COG.
fn role(name: &str) -> (&'static str, &'static str) {
    match name {
        "render.png" => (
            "overview",
            "The snowy terrain in perspective (not georeferenced)",
        ),
        "descriptor.png" => (
            "visual",
            "The descriptor t as grey, snow white (the DEM's grid, not georeferenced)",
        ),
        "terrain.glb" => ("data", "The terrain mesh with snow vertex colours (glTF)"),
        "report.json" => ("metadata", "Resolved parameters, input statistics, timings"),
        "sweep.png" => ("overview", "Contact sheet of the parameter sweep"),
        _ => ("data", "An output of the job"),
    }
}

/// `GET /v1/jobs/{id}/stac.json`.
pub async fn item(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: axum::http::HeaderMap,
) -> Result<Response, ApiError> {
    let found = if is_job_id(&id) {
        st.jobs.get(&id).await?
    } else {
        None
    };
    let rec = found.ok_or_else(|| ApiError::NotFound(format!("no job {id}")))?;
    if rec.pipeline != PIPELINE {
        return Err(ApiError::NotFound(format!(
            "job {id} is a {} job; STAC Items describe snow-terrain results",
            rec.pipeline
        )));
    }
    if rec.status != Status::Succeeded {
        return Err(ApiError::Conflict(format!(
            "job {id} is {}; its STAC Item appears when it succeeds",
            rec.status.as_str()
        )));
    }
    let cog = rec
        .outputs
        .iter()
        .find(|o| o.name == COG)
        .ok_or_else(|| {
            ApiError::NotFound(format!(
                "job {id} has no {COG} (its `outputs` parameter left it out): nothing georeferenced to describe"
            ))
        })?;
    // The COG is decoded within the memory budget, as a DEM is for a map.
    let cost = st.jobs.pipelines().decode_cost(PIPELINE, false);
    let reservation =
        super::admission::reserve_worst(&st.memory, cog.size.saturating_add(cost)).await?;
    let bytes = st.jobs.store().read_blob(&cog.sha256).await?;
    let limits = st.cfg.limits();
    let fp = tokio::task::spawn_blocking(move || {
        let _reservation = reservation;
        catalog::footprint(&bytes, &limits)
    })
    .await
    .map_err(blocking_err)?
    .map_err(|e| match e {
        // The job wrote this file: failing to read it back is the server's fault.
        FootprintError::Input(i) => ApiError::internal(format!("{COG} of job {id}: {i}")),
        // A DEM without an EPSG code or georeferencing makes a COG that cannot be placed.
        FootprintError::Crs(c) => ApiError::Conflict(format!(
            "job {id}: the DEM cannot be placed on the Earth, so it has no STAC Item: {c}"
        )),
    })?;
    let map_links = map_links(&st, &rec).await?;
    let mut item = item_json(&rec, &fp, map_links);
    absolute_hrefs(&mut item, &super::maps::base_url(&headers));
    let mut resp = Json(item).into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/geo+json"),
    );
    Ok(resp)
}

/// Links to the web map of the job's DEM and parameters: its TileJSON and XYZ templates when
/// it exists, else how to create it. A job with an orthophoto has no map of its own (maps take
/// no orthophoto).
async fn map_links(st: &AppState, rec: &JobRecord) -> Result<Vec<Value>, ApiError> {
    if !rec.input.aux.is_empty() {
        return Ok(Vec::new());
    }
    // The job's resolved parameters as a request: a `null` there is a field left to its
    // default, which a request spells by leaving it out.
    let params = without_nulls(&rec.params);
    let canonical = st.maps.params(&params)?;
    let map_id = request_key("maps", &rec.input.asset, &canonical);
    if st.maps.store().get_map(&map_id).await?.is_some() {
        let base = format!("/v1/maps/{map_id}");
        let mut links = vec![json!({
            "rel": "tilejson",
            "href": format!("{base}/tilejson.json"),
            "type": "application/json",
            "title": "TileJSON of the web map of this DEM and parameters",
        })];
        for layer in [Layer::Snow, Layer::Relief] {
            links.push(json!({
                "rel": "xyz",
                "href": format!("{base}/tiles/{}/{{z}}/{{x}}/{{y}}.png", layer.name()),
                "type": "image/png",
                "title": format!("`{}` tiles (WebMercatorQuad)", layer.name()),
            }));
        }
        Ok(links)
    } else {
        Ok(vec![json!({
            "rel": "related",
            "href": "/v1/maps",
            "type": "application/json",
            "method": "POST",
            "body": {"asset": rec.input.asset, "params": params},
            "title": "No web map of this DEM and parameters yet: POST this body to /v1/maps to make one (tiles, TileJSON)",
        })])
    }
}

/// Prefixes `base` (`scheme://host`) to every server-relative `href` of the Item: its links'
/// and its assets'.
fn absolute_hrefs(item: &mut Value, base: &str) {
    let Some(obj) = item.as_object_mut() else {
        return;
    };
    for (key, v) in obj.iter_mut() {
        let holders: Vec<&mut Value> = match (key.as_str(), v) {
            ("links", Value::Array(links)) => links.iter_mut().collect(),
            ("assets", Value::Object(assets)) => assets.values_mut().collect(),
            _ => continue,
        };
        for h in holders.into_iter().filter_map(|x| x.get_mut("href")) {
            if let Some(rel) = h.as_str().filter(|h| h.starts_with('/')) {
                *h = Value::String(format!("{base}{rel}"));
            }
        }
    }
}

/// `v` with every `null` member of its objects left out, at any depth.
fn without_nulls(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(
            m.iter()
                .filter(|(_, x)| !x.is_null())
                .map(|(k, x)| (k.clone(), without_nulls(x)))
                .collect(),
        ),
        Value::Array(a) => Value::Array(a.iter().map(without_nulls).collect()),
        other => other.clone(),
    }
}

/// An output's asset key: its name without the extension (`snow_cover`, `render`).
fn asset_key(name: &str) -> &str {
    name.split_once('.').map_or(name, |(stem, _)| stem)
}

fn ts(t: chrono::DateTime<chrono::Utc>) -> String {
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// The Item.
fn item_json(rec: &JobRecord, fp: &RasterFootprint, map_links: Vec<Value>) -> Value {
    let t = fp.geotransform;
    let ring: Vec<[f64; 2]> = fp.outline.iter().map(|&(x, y)| [x, y]).collect();
    let finished = rec.finished_at.unwrap_or(rec.created_at);
    let job_url = format!("/v1/jobs/{}", rec.id);
    let nodata = match fp.nodata {
        Some(v) if v.is_nan() => json!("nan"),
        Some(v) => json!(v),
        None => Value::Null,
    };
    let mut band = json!({
        "data_type": "float32",
        "sampling": "area",
        "description": "Snow cover s = 1 − t (0 bare, 1 snow)",
    });
    if let Some(b) = band.as_object_mut() {
        if !nodata.is_null() {
            b.insert("nodata".into(), nodata);
        }
        if let Some(s) = fp.stats {
            b.insert(
                "statistics".into(),
                json!({
                    "minimum": s.minimum,
                    "maximum": s.maximum,
                    "mean": s.mean,
                    "stddev": s.stddev,
                    "valid_percent": s.valid_percent,
                }),
            );
        }
    }
    let mut assets = serde_json::Map::new();
    for o in &rec.outputs {
        let href = format!("{job_url}/outputs/{}", o.name);
        let a = if o.name == COG {
            json!({
                "href": href,
                "type": "image/tiff; application=geotiff; profile=cloud-optimized",
                "title": "Snow cover (float32 Cloud-Optimized GeoTIFF)",
                "roles": ["data"],
                "raster:bands": [band.clone()],
            })
        } else {
            let (role, title) = role(&o.name);
            json!({"href": href, "type": o.media_type, "title": title, "roles": [role]})
        };
        assets.insert(asset_key(&o.name).to_string(), a);
    }
    let mut links = vec![
        json!({"rel": "self", "href": format!("{job_url}/stac.json"), "type": "application/geo+json"}),
        json!({"rel": "related", "href": job_url, "type": "application/json", "title": "The job"}),
        json!({"rel": "related", "href": format!("/ogc/jobs/{}", rec.id), "type": "application/json", "title": "The job as OGC API – Processes statusInfo"}),
        json!({"rel": "derived_from", "href": format!("/v1/assets/{}", rec.input.asset), "type": "application/json", "title": "The DEM (asset record)"}),
    ];
    links.extend(map_links);
    json!({
        "type": "Feature",
        "stac_version": "1.0.0",
        "stac_extensions": STAC_EXTENSIONS,
        "id": rec.id,
        "geometry": {"type": "Polygon", "coordinates": [ring]},
        "bbox": fp.bbox,
        "properties": {
            "datetime": ts(finished),
            "created": ts(finished),
            "title": "Snow cover on the DEM (snow-terrain)",
            "description": "Nakatani, Fujishiro and Ohno's surface descriptor on the uploaded DEM (SPEC §1): snow cover s = 1 − t.",
            "proj:code": fp.epsg.map(|c| format!("EPSG:{c}")),
            "proj:shape": [fp.height, fp.width],
            "proj:transform": [t[1], t[2], t[0], t[4], t[5], t[3], 0.0, 0.0, 1.0],
            "proj:bbox": fp.crs_bbox,
        },
        "links": links,
        "assets": assets,
    })
}
