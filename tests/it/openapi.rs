//! `openapi.yaml` is the truth about the API: every route it lists is served, every route served is
//! in it, and real responses validate against its schemas (status codes and content types
//! included).

use serde_json::{json, Value};

use crate::common::{data, Server};

pub(crate) fn spec() -> Value {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml")).unwrap();
    serde_yaml::from_str(&text).unwrap()
}

/// Follows a local `$ref` (`#/components/...`).
fn deref<'a>(spec: &'a Value, v: &'a Value) -> &'a Value {
    match v.get("$ref").and_then(Value::as_str) {
        Some(r) => {
            let ptr = r.strip_prefix('#').unwrap();
            deref(
                spec,
                spec.pointer(ptr)
                    .unwrap_or_else(|| panic!("dangling $ref {r}")),
            )
        }
        None => v,
    }
}

/// (method, path) of every operation in the spec.
fn spec_routes(spec: &Value) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for (path, item) in spec["paths"].as_object().unwrap() {
        for (method, _) in item.as_object().unwrap() {
            if ["get", "post", "put", "delete", "patch"].contains(&method.as_str()) {
                out.push((method.clone(), path.clone()));
            }
        }
    }
    out.sort();
    out
}

/// Validates a response against the schema the spec declares for it.
fn check(spec: &Value, method: &str, path: &str, status: u16, ctype: &str, body: &Value) {
    let op = &spec["paths"][path][method];
    assert!(op.is_object(), "{method} {path} is not in the spec");
    let resp = op["responses"].get(status.to_string()).unwrap_or_else(|| {
        panic!("{method} {path} answered {status}, which the spec does not list")
    });
    let resp = deref(spec, resp);
    let media = ctype.split(';').next().unwrap().trim();
    let content = resp["content"].get(media).unwrap_or_else(|| {
        panic!("{method} {path} {status}: content type {media} not in the spec")
    });
    let schema = deref(spec, &content["schema"]).clone();
    // Resolve `$ref`s against the whole document: validate with the spec as the root schema.
    let mut root = spec.clone();
    root.as_object_mut()
        .unwrap()
        .insert("$ref".into(), json!("#/$defs/__target"));
    root.as_object_mut()
        .unwrap()
        .insert("$defs".into(), json!({ "__target": schema }));
    let validator = jsonschema::validator_for(&root).unwrap();
    let errors: Vec<String> = validator
        .iter_errors(body)
        .map(|e| format!("{} at {}", e, e.instance_path))
        .collect();
    assert!(
        errors.is_empty(),
        "{method} {path} {status} violates the spec: {errors:?}\n{body}"
    );
}

/// Reads a JSON response and validates it against the spec; returns the body.
pub(crate) async fn checked(spec: &Value, method: &str, path: &str, r: reqwest::Response) -> Value {
    let ct = r.headers()["content-type"].to_str().unwrap().to_string();
    let status = r.status().as_u16();
    let body: Value = r.json().await.unwrap();
    check(spec, method, path, status, &ct, &body);
    body
}

#[tokio::test]
async fn spec_routes_equal_served_routes() {
    let spec = spec();
    let mut served: Vec<(String, String)> = phenomena::api::ROUTES
        .iter()
        .map(|(m, p)| (m.to_string(), p.to_string()))
        .collect();
    for kind in phenomena_engine::registry::PipelineKind::public() {
        served.push(("post".into(), format!("/v1/{}", kind.name())));
    }
    served.sort();
    assert_eq!(spec_routes(&spec), served);

    // And the router really serves each of them (no fallback 404 "no route", no 405).
    let s = Server::start(|_| {}).await;
    for (method, path) in spec_routes(&spec) {
        let concrete = path
            .replace("{id}", &"0".repeat(32))
            .replace("{name}", "render.png")
            .replace("{kind}", "sun-color");
        let req = s
            .client
            .request(method.to_uppercase().parse().unwrap(), s.url(&concrete));
        let resp = req.send().await.unwrap();
        let status = resp.status().as_u16();
        assert_ne!(status, 405, "{method} {path}");
        let text = resp.text().await.unwrap();
        assert!(
            !text.contains("no route for"),
            "{method} {path} is not routed: {text}"
        );
    }
}

#[tokio::test]
async fn responses_match_the_spec() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let dem = std::fs::read(data("dem/maunga_whau_volcano.asc")).unwrap();
    let get = |path: &str| s.client.get(s.url(path)).send();

    checked(&spec, "get", "/healthz", get("/healthz").await.unwrap()).await;
    checked(&spec, "get", "/readyz", get("/readyz").await.unwrap()).await;

    // Assets.
    let r = s
        .client
        .post(s.url("/v1/assets?filename=volcano.asc"))
        .body(dem.clone())
        .send()
        .await
        .unwrap();
    let asset = checked(&spec, "post", "/v1/assets", r).await;
    let r = get(asset["url"].as_str().unwrap()).await.unwrap();
    checked(&spec, "get", "/v1/assets/{id}", r).await;
    let r = get(&format!("/v1/assets/{}", "a".repeat(64)))
        .await
        .unwrap();
    checked(&spec, "get", "/v1/assets/{id}", r).await;

    // A real snow-terrain job, small.
    let params = json!({"width": 64, "height": 48, "mesh_max_vertices": 1000});
    let r = s
        .submit(
            "snow-terrain",
            "dem",
            params.clone(),
            dem.clone(),
            "volcano.asc",
        )
        .await;
    let job = checked(&spec, "post", "/v1/snow-terrain", r).await;
    let id = job["id"].as_str().unwrap().to_string();
    let done = s.wait_done(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    check(
        &spec,
        "get",
        "/v1/jobs/{id}",
        200,
        "application/json",
        &done,
    );
    let r = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": asset["id"], "params": params}))
        .send()
        .await
        .unwrap();
    let reused = checked(&spec, "post", "/v1/snow-terrain", r).await;
    assert_eq!(
        reused["id"],
        json!(id),
        "the JSON form reuses the multipart job's result"
    );

    checked(
        &spec,
        "get",
        "/v1/jobs",
        get("/v1/jobs?limit=5").await.unwrap(),
    )
    .await;
    let r = s
        .client
        .delete(s.url(&format!("/v1/jobs/{id}")))
        .send()
        .await
        .unwrap();
    checked(&spec, "delete", "/v1/jobs/{id}", r).await;

    // Every output is downloadable with a media type the spec lists.
    for o in done["outputs"].as_array().unwrap() {
        let r = get(o["url"].as_str().unwrap()).await.unwrap();
        assert_eq!(r.status().as_u16(), 200);
        let ct = r.headers()["content-type"].to_str().unwrap().to_string();
        assert_eq!(ct, o["media_type"].as_str().unwrap());
        let op =
            &spec["paths"]["/v1/jobs/{id}/outputs/{name}"]["get"]["responses"]["200"]["content"];
        assert!(
            op.get(&ct).is_some(),
            "output media type {ct} is not in the spec"
        );
    }

    // Errors: out-of-range parameter, corrupt DEM, unsupported format, bad query, unknown job.
    let r = s
        .submit(
            "snow-terrain",
            "dem",
            json!({"probe_radius": -1}),
            dem.clone(),
            "v.asc",
        )
        .await;
    assert_eq!(r.status().as_u16(), 422);
    let p = checked(&spec, "post", "/v1/snow-terrain", r).await;
    assert_eq!(p["field"], "probe_radius");
    let r = s
        .submit(
            "snow-terrain",
            "dem",
            json!({}),
            b"ncols 3\nnrows 3\n".to_vec(),
            "v.asc",
        )
        .await;
    assert_eq!(r.status().as_u16(), 422);
    checked(&spec, "post", "/v1/snow-terrain", r).await;
    let r = s
        .submit(
            "snow-terrain",
            "dem",
            json!({}),
            b"GIF89a not a dem".to_vec(),
            "v.gif",
        )
        .await;
    assert_eq!(r.status().as_u16(), 415);
    checked(&spec, "post", "/v1/snow-terrain", r).await;
    checked(
        &spec,
        "get",
        "/v1/jobs",
        get("/v1/jobs?limit=1000").await.unwrap(),
    )
    .await;
    let r = get(&format!("/v1/jobs/{}", "1".repeat(32))).await.unwrap();
    checked(&spec, "get", "/v1/jobs/{id}", r).await;
}

#[test]
fn every_parameter_is_documented_with_its_default() {
    // For each pipeline: the resolved defaults the engine reports equal the spec's `default`s,
    // and every parameter the engine accepts is in the spec (and vice versa).
    use phenomena_engine::params::Limits;
    use phenomena_engine::registry::{PipelineKind, PipelineParams};
    let spec = spec();
    for (kind, schema) in [
        (PipelineKind::SnowTerrain, "SnowTerrainParams"),
        (PipelineKind::SnowCover, "SnowCoverParams"),
        (PipelineKind::Cloud, "CloudParams"),
        (PipelineKind::Dust, "DustParams"),
    ] {
        let props = spec["components"]["schemas"][schema]["properties"]
            .as_object()
            .unwrap();
        let p = PipelineParams::parse(kind, &json!({}), &Limits::default())
            .unwrap()
            .canonical();
        for (name, value) in p.as_object().unwrap() {
            let prop = props
                .get(name)
                .unwrap_or_else(|| panic!("{schema}.{name} is not in openapi.yaml"));
            assert!(
                prop.get("description").is_some(),
                "{schema}.{name} has no description"
            );
            if name == "camera" {
                continue;
            }
            match prop.get("default") {
                Some(d) => match (d.as_f64(), value.as_f64()) {
                    (Some(a), Some(b)) => assert!(
                        (a - b).abs() <= 1e-6 * a.abs().max(1.0),
                        "{schema}.{name}: spec default {d}, engine {value}"
                    ),
                    _ => assert_eq!(d, value, "{schema}.{name}"),
                },
                None => assert!(
                    value.is_null(),
                    "{schema}.{name}: the engine's default {value} is not documented"
                ),
            }
        }
        // Accepted on the wire but resolved into other fields (`sweep` is a separate output;
        // the sun's angles become `sun_direction`), or absent from the resolved defaults
        // (`kappa_auto` exists only beside a κ chosen from the volume: the defaults leave κ
        // unchosen until a volume is decoded; so do `density_floor` and its `density_floor_auto`,
        // left out of the resolved parameters until a volume is decoded; so is the cloud's
        // `sun_direction` left open, chosen from the volume's shape, and its `sun_auto`).
        let wire_only = [
            "sweep",
            "sun_azimuth_deg",
            "sun_elevation_deg",
            "kappa_auto",
            "sun_direction",
            "sun_auto",
            "density_floor",
            "density_floor_auto",
        ];
        for name in props.keys() {
            if !wire_only.contains(&name.as_str()) {
                assert!(
                    p.get(name).is_some(),
                    "{schema}.{name} is in openapi.yaml but not accepted"
                );
            }
        }
    }
}
