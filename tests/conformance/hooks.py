"""Schemathesis hooks for `tests/it/conformance.rs` (issue 20): positive cases carry real files,
and respect the few rules of the API that OpenAPI 3.1 (JSON Schema 2020-12) cannot state.

Loaded with `SCHEMATHESIS_HOOKS=hooks` and `PYTHONPATH=tests/conformance` (both set by
`tests/it/conformance.rs`). Only cases generated in the positive mode are touched: a negative case
keeps every violation schemathesis put in it. Every repair below is for a rule JSON Schema has no
keyword for (a comparison between two values of the request, or with a deployment setting, or
with what exists on the server); everything a schema can say (ranges, exclusive or dependent
fields, per-mode edit bodies, tuple items) is said in `openapi.yaml` and not repaired here.

1. File parts. A multipart file part is bytes; `openapi.yaml` states which formats each part
   takes (`encoding.<part>.contentType`), and a schema cannot say "a DEM". The positive cases of
   the submit operations get a small valid file of the part's kind (`dem`: an ESRI ASCII grid,
   `mesh`: an OBJ, `volume`: a NumPy array, `ortho`: a PNG), read from the files
   `tests/it/conformance.rs` fetched from `GET /v1/examples/…` (`PHENOMENA_ST_FILES`) or made
   here (the PNG).
2. Rules across fields, each refused with 422 naming the field and documented in
   `openapi.yaml`; a positive case is repaired to respect them, the value schemathesis drew kept
   where the rule allows:
   - `width` × `height` at most the server's `max_output_pixels` (a deployment setting:
     `PHENOMENA_ST_MAX_PIXELS`): the height is lowered;
   - `camera.eye` ≠ `camera.target` (two arrays compared): the eye is moved;
   - `slope_end_deg` ≥ `slope_start_deg`, `full_snow_quantile` ≥ `snowline_quantile`
     (snow-terrain, also against the preset's values when one is not given), and in each run of
     a `sweep` over one of them: swapped, raised or capped;
   - dust `bends` < `fiber_length` (default 48): `bends` lowered; `shells` × `texture_size`² and
     `fibers` × (`fiber_length` + 1) within dust's memory budgets: `shells`, `fibers` lowered;
   - a raw volume's `dims` multiply to at most the voxel limit: the largest side halved;
   - snow-cover `snowfall` schedule hours strictly increasing: the pairs sorted by hour and
     repeated hours dropped;
   - edit pixels (`from`, `to`, `strokes[].pixels`) inside the view (`width` × `height`,
     default 960 × 540): taken modulo the size;
   - a volume's `bounds` have min < max and sides not thinner than the documented bound: widened;
   - a JSON body names an uploaded asset of the operation's kind (a DEM, a mesh, a volume):
     which ids exist is the server's state, not the schema's;
   - an OGC execute request's `inputs` are those of the process named in the path (its
     description's inputs and their schemas): see `_ogc_execute`.
3. One filter (`filter_case`), on negative cases only: see its doc.
4. Clean-up (`after_call`): the job an accepted request queued is canceled once its answer is
   in, so the checks do not wait behind thousands of renders (see its doc).
"""

import copy
import json
import os
import struct
import zlib
from urllib.parse import urljoin

import requests

import schemathesis
from schemathesis import GenerationMode

FILES = os.environ.get("PHENOMENA_ST_FILES", "")
MAX_PIXELS = int(os.environ.get("PHENOMENA_ST_MAX_PIXELS", "33177600"))

# Each snow-terrain preset's values of the ordered pairs (engine `DescriptorParams::default` and
# `DescriptorParams::paper`).
PRESET_PAIRS = {
    "winter": {
        "slope_start_deg": 35.0,
        "slope_end_deg": 60.0,
        "snowline_quantile": 0.3,
        "full_snow_quantile": 0.7,
    },
    "paper": {
        "slope_start_deg": 90.0,
        "slope_end_deg": 90.0,
        "snowline_quantile": 0.3,
        "full_snow_quantile": 1.0,
    },
}
PAIRS = (("slope_start_deg", "slope_end_deg"), ("snowline_quantile", "full_snow_quantile"))
# The cloud pipeline's default view (engine `cloud::params::DEFAULT_SIZE`, `openapi.yaml`'s
# `CloudParams.width`/`height` defaults): a scene's renders and edits use it when they give none.
EDIT_VIEW = (800, 600)
# Default output sizes per operation (for a case that gives one side only).
DEFAULT_SIZE = {
    "submitSnowTerrain": (900, 600),
    "submitSnowCover": (960, 640),
    "submitDust": (960, 640),
    "submitCloud": EDIT_VIEW,
    "renderCloudScene": EDIT_VIEW,
    "editCloudSceneSunColor": EDIT_VIEW,
    "editCloudSceneAmbient": EDIT_VIEW,
    "editCloudSceneSunDirection": EDIT_VIEW,
    "editCloudSceneSet": EDIT_VIEW,
}
EDIT_OPS = tuple(k for k in DEFAULT_SIZE if k.startswith("editCloudScene"))
# Uploaded assets of each kind (`tests/it/conformance.rs`), for JSON bodies naming one.
ASSETS = {
    "submitSnowTerrain": os.environ.get("PHENOMENA_ST_DEM_ASSET"),
    "submitSnowCover": os.environ.get("PHENOMENA_ST_MESH_ASSET"),
    "submitDust": os.environ.get("PHENOMENA_ST_MESH_ASSET"),
    "submitCloud": os.environ.get("PHENOMENA_ST_VOLUME_ASSET"),
    "createCloudScene": os.environ.get("PHENOMENA_ST_VOLUME_ASSET"),
    # Maps reproject: a DEM with an EPSG-coded CRS.
    "createMap": os.environ.get("PHENOMENA_ST_MAP_ASSET"),
}


def _read(name):
    with open(os.path.join(FILES, name), "rb") as f:
        return f.read()


def _png(width=4, height=4):
    """A small RGB PNG."""
    raw = b"".join(
        b"\x00" + bytes(v for x in range(width) for v in (x * 60, y * 60, 120)) for y in range(height)
    )

    def chunk(kind, data):
        c = struct.pack(">I", len(data)) + kind + data
        return c + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


_cache = {}


# The maps' DEM: georeferenced with an EPSG-coded CRS (maps are reprojected to web mercator).
MAP_DEM = os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "data", "dem", "kagwene_cameroon_elev_30m_utm32n.tif"
)


def _file(part, op=""):
    if op == "createMap" and part == "dem":
        with open(MAP_DEM, "rb") as f:
            return f.read()
    if part not in _cache:
        _cache[part] = {
            "dem": lambda: _read("dem.asc"),
            "mesh": lambda: _read("mesh.obj"),
            "volume": lambda: _read("volume.npy"),
            "ortho": _png,
            "file": lambda: _read("dem.asc"),
        }[part]()
    return _cache[part]


FILE_PARTS = ("dem", "mesh", "volume", "ortho")


def _positive(case):
    meta = getattr(case, "meta", None)
    # A case without metadata is judged by neither the positive nor the negative check
    # (both need it); it is sent repaired like a positive one.
    return meta is None or meta.generation.mode == GenerationMode.POSITIVE


def _fit_pixels(obj, default):
    """`width` × `height` within MAX_PIXELS (the missing side at its default), lowering the
    height."""
    if not isinstance(obj, dict):
        return
    w, h = _int(obj.get("width", default[0])), _int(obj.get("height", default[1]))
    if w is not None and h is not None and w * h > MAX_PIXELS:
        obj["width"] = w
        obj["height"] = max(16, MAX_PIXELS // w)
        if w * obj["height"] > MAX_PIXELS:
            obj["width"] = max(16, MAX_PIXELS // obj["height"])


def _bounds(obj):
    """A volume's `bounds`: each side at least 1 (min < max, not thin)."""
    b = obj.get("bounds") if isinstance(obj, dict) else None
    if isinstance(b, list) and len(b) == 2 and all(isinstance(c, list) and len(c) == 3 for c in b):
        lo, hi = b
        for i in range(3):
            if isinstance(lo[i], (int, float)) and isinstance(hi[i], (int, float)):
                a, c = min(lo[i], hi[i]), max(lo[i], hi[i])
                if c - a < max(1.0, 1e-5 * max(abs(a), abs(c))):
                    c = a + max(1.0, 1e-5 * abs(a)) if abs(a) < 1e8 else a
                    if c - a < 1.0:
                        a, c = -1.0, 1.0
                lo[i], hi[i] = a, c


def _distinct_eye(obj):
    cam = obj.get("camera") if isinstance(obj, dict) else None
    if isinstance(cam, dict):
        eye, target = cam.get("eye"), cam.get("target")
        if isinstance(eye, list) and eye == target:
            cam["eye"] = [eye[0] + 1.0] + list(eye[1:])


def _num(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _int(x):
    """`x` as an int when JSON Schema counts it as an integer (`980` and `980.0` alike: the
    server accepts both), else None."""
    if isinstance(x, bool):
        return None
    if isinstance(x, int):
        return x
    if isinstance(x, float) and x == x and abs(x) != float("inf") and x.is_integer():
        return int(x)
    return None


def _order(obj, lo, hi, preset):
    a = obj.get(lo, preset[lo])
    b = obj.get(hi, preset[hi])
    if _num(a) and _num(b) and b < a:
        if lo in obj and hi in obj:
            obj[lo], obj[hi] = b, a
        elif lo in obj:
            obj[hi] = a
        else:
            obj[lo] = b


def _terrain(params):
    """The ordered pairs, in the params and in every run of a `sweep` (each value replaces the
    swept parameter): a swept lower bound is capped at its partner, a swept upper bound raised to
    it."""
    if not isinstance(params, dict):
        return
    preset = PRESET_PAIRS.get(params.get("preset", "winter"))
    if preset is None:
        return
    for lo, hi in PAIRS:
        _order(params, lo, hi, preset)
    sweep = params.get("sweep")
    if not isinstance(sweep, dict) or not isinstance(sweep.get("values"), list):
        return
    name, values = sweep.get("param"), sweep["values"]
    for lo, hi in PAIRS:
        if name == lo:
            bound = params.get(hi, preset[hi])
            if _num(bound):
                sweep["values"] = [min(v, bound) if _num(v) else v for v in values]
        elif name == hi:
            bound = params.get(lo, preset[lo])
            if _num(bound):
                sweep["values"] = [max(v, bound) if _num(v) else v for v in values]


def _inside(p, w, h):
    if isinstance(p, list) and len(p) == 2 and all(_int(v) is not None for v in p):
        return [_int(p[0]) % w, _int(p[1]) % h]
    return p


def _edit(body):
    w = _int(body.get("width", EDIT_VIEW[0]))
    h = _int(body.get("height", EDIT_VIEW[1]))
    if w is None or h is None or w < 1 or h < 1:
        return
    for k in ("from", "to"):
        if k in body:
            body[k] = _inside(body[k], w, h)
    for s in body.get("strokes", []) if isinstance(body.get("strokes"), list) else []:
        if isinstance(s, dict) and isinstance(s.get("pixels"), list):
            s["pixels"] = [_inside(p, w, h) for p in s["pixels"]]


# Dust's memory budgets (engine `dust::params`): `shells` × `texture_size`² texels at most
# MAX_TEXELS, `fibers` × (`fiber_length` + 1) trail texels at most MAX_TRAIL.
MAX_TEXELS = 1 << 26
MAX_TRAIL = 1 << 25


def _dust(params):
    """`bends` < `fiber_length`; the texel and trail budgets (products of two fields)."""
    if not isinstance(params, dict):
        return
    length = _int(params.get("fiber_length", 48))
    bends = _int(params.get("bends", 2))
    if length is not None and bends is not None and bends >= length:
        params["bends"] = max(0, length - 1)
    shells, size = _int(params.get("shells", 32)), _int(params.get("texture_size", 512))
    if shells is not None and size is not None and shells * size * size > MAX_TEXELS:
        params["shells"] = max(1, MAX_TEXELS // (size * size))
    fibers = _int(params.get("fibers", 5000))
    if fibers is not None and length is not None and fibers * (length + 1) > MAX_TRAIL:
        params["fibers"] = MAX_TRAIL // (length + 1)


# The cloud pipelines' raw-volume `dims`: at most this many voxels in all (`max_input_cells`).
MAX_VOXELS = 1 << 26


def _dims(params):
    """A raw volume's `dims`: their product within the voxel limit (each side lowered in turn)."""
    d = params.get("dims") if isinstance(params, dict) else None
    if isinstance(d, list) and len(d) == 3 and all((_int(n) or 0) >= 1 for n in d):
        d = [_int(n) for n in d]
        while d[0] * d[1] * d[2] > MAX_VOXELS:
            k = d.index(max(d))
            d[k] = max(1, d[k] // 2)
        params["dims"] = d


def _snowfall(params):
    """A `snowfall` schedule's hours strictly increasing."""
    sched = params.get("snowfall") if isinstance(params, dict) else None
    if isinstance(sched, list) and all(isinstance(p, list) and len(p) == 2 for p in sched):
        out = []
        for p in sorted(sched, key=lambda p: p[0]):
            if not out or p[0] > out[-1][0]:
                out.append(p)
        params["snowfall"] = out


@schemathesis.hook
def filter_case(ctx, case):
    """A negative case of `POST /v1/assets` whose `file` part schemathesis turned into a number or
    boolean: on the wire it is that text, a valid (tiny) file the server cannot and should not
    tell from one (its refusals of what the schema excludes are asserted by
    `api::asset_uploads_refuse_what_the_schema_refuses`)."""
    op = _op(ctx, case)
    if op == "uploadAsset" and not _positive(case) and isinstance(case.body, dict):
        f = case.body.get("file")
        if f is not None and not isinstance(f, (str, bytes)):
            return False
    return True


def _pending_jobs(body):
    """The URLs of the unfinished jobs an accepted answer names: a job (`url`, with `events_url`),
    a cloud scene version (`job_url`), a scene (its `versions`), an OGC status (`jobID`)."""
    if not isinstance(body, dict):
        return []
    if isinstance(body.get("jobID"), str):
        return ["/ogc/jobs/" + body["jobID"]] if body.get("status") in ("accepted", "running") else []
    if isinstance(body.get("events_url"), str) and isinstance(body.get("url"), str):
        return [body["url"]] if body.get("status") in ("queued", "running") else []
    if isinstance(body.get("job_url"), str):
        return [body["job_url"]] if body.get("status") == "pending" else []
    versions = body.get("versions")
    if isinstance(versions, list):
        return [u for v in versions for u in _pending_jobs(v)]
    return []


@schemathesis.hook
def after_call(ctx, case, response):
    """Cancels the job an accepted request queued (`DELETE` on its URL), after the answer is
    received and whatever it is checked against is fixed. The contract under test is what the
    server accepts and answers, not the render: the jobs of the thousands of accepted cases would
    otherwise run one after another behind the checks (over 22 minutes of rendering at 140 % CPU
    in session 12). The answer itself is untouched; the cancel's own answer is not checked here
    (`cancelJob` is exercised as an operation of its own)."""
    if response.status_code not in (200, 201, 202) or response.request is None:
        return
    if (response.request.method or "").upper() != "POST":
        return
    try:
        body = json.loads(response.content)
    except ValueError:
        return
    for url in _pending_jobs(body):
        try:
            requests.delete(urljoin(response.request.url, url), timeout=10, headers=_auth(response))
        except requests.RequestException:
            pass


def _auth(response):
    a = response.request.headers.get("Authorization")
    return {"Authorization": a} if a else {}


@schemathesis.hook
def before_call(ctx, case, kwargs):
    """Applied to every case before it is sent (every phase, the coverage phase included)."""
    _repair(ctx, case, kwargs)


def _op(ctx, case):
    """The case's operationId (from the case itself: the hook context names no operation in
    every phase)."""
    operation = getattr(case, "operation", None) or getattr(ctx, "operation", None)
    return operation.definition.raw.get("operationId", "") if operation is not None else ""


def _multipart(body):
    """The parts of a multipart body for `requests` (`files=`): file parts as files, the rest
    (`params`) as JSON."""
    parts = []
    for name, value in body.items():
        if name in FILE_PARTS:
            parts.append((name, (name, value, "application/octet-stream")))
        elif isinstance(value, (bytes, str)):
            parts.append((name, (None, value)))
        else:
            parts.append((name, (None, json.dumps(value), "application/json")))
    return parts


def _body_positive(case):
    """Whether the case's body is schema-valid (its own component's mode; the case's overall mode
    when it has none). A body repaired for the rules across fields loses no schema violation, so
    a case negative through another component (a header, the query) stays negative."""
    meta = getattr(case, "meta", None)
    if meta is None:
        return True
    for location, info in (getattr(meta, "components", None) or {}).items():
        if getattr(location, "name", "") == "BODY":
            return info.mode == GenerationMode.POSITIVE
    return meta.generation.mode == GenerationMode.POSITIVE


# OGC API processes (`POST /ogc/processes/{processId}/execution`): the `/v1` operation whose
# parameters and rules they share, and the input file each takes.
OGC_PROCESSES = {
    "snow-terrain": ("submitSnowTerrain", "dem"),
    "snow-cover": ("submitSnowCover", "mesh"),
    "dust": ("submitDust", "mesh"),
    "cloud": ("submitCloud", "volume"),
}
BASE = os.environ.get("PHENOMENA_ST_BASE", "")
_descriptions = {}


def _process_inputs(pid):
    """The process description's inputs (`GET /ogc/processes/{pid}`), each with its schema."""
    if pid not in _descriptions:
        r = requests.get(BASE + "/ogc/processes/" + pid, timeout=30)
        _descriptions[pid] = r.json().get("inputs", {}) if r.status_code == 200 else {}
    return _descriptions[pid]


def _ogc_execute(case, body):
    """An execute request's `inputs` are the process's own (its description lists them with
    their schemas, which depend on the `processId` in the path: a rule across two components of
    the request that one body schema cannot state). A positive case keeps each generated input
    that the process has and whose value its schema accepts, names an uploaded asset of the
    process's kind as the input file, and then follows the `/v1` operation's rules."""
    pid = (case.path_parameters or {}).get("processId")
    if pid not in OGC_PROCESSES or not isinstance(body.get("inputs"), dict):
        return
    import jsonschema

    submit, part = OGC_PROCESSES[pid]
    described = _process_inputs(pid)
    inputs = {}
    for name, value in body["inputs"].items():
        schema = (described.get(name) or {}).get("schema")
        if name in FILE_PARTS or schema is None:
            continue
        try:
            jsonschema.Draft202012Validator(schema).validate(value)
        except (jsonschema.ValidationError, jsonschema.SchemaError):
            continue
        inputs[name] = value
    inputs[part] = {"href": "/v1/assets/" + (ASSETS.get(submit) or "")}
    _rules(submit, inputs)
    body["inputs"] = inputs


def _rules(op, params):
    """The rules across fields of a submit operation's (or scene's) parameters."""
    if op in DEFAULT_SIZE and op not in EDIT_OPS:
        _fit_pixels(params, DEFAULT_SIZE[op])
        _distinct_eye(params)
    if op in ("submitCloud", "createCloudScene"):
        _bounds(params)
        _dims(params)
    if op in ("submitSnowTerrain", "createMap"):
        _terrain(params)
    if op == "submitDust":
        _dust(params)
    if op == "submitSnowCover":
        _snowfall(params)


def _repair(ctx, case, kwargs):
    if not _body_positive(case):
        return case
    op = _op(ctx, case)
    if not isinstance(case.body, dict):
        return case
    if op == "ogcExecute":
        body = copy.deepcopy(case.body)
        _ogc_execute(case, body)
        case.body = body
        return case
    # A copy: schemathesis may build several cases on the same nested objects (a negative case
    # on a positive one's `params`), and a repair must reach this case only.
    body = copy.deepcopy(case.body)
    multipart = (case.media_type or "").startswith("multipart/")
    if multipart:
        # Sent as the request's own body (`files=`), the case left as generated: schemathesis
        # re-validates a case a hook edits, and a body holding bytes never validates (it cannot
        # check binary against a schema), so the edited positive case would count as negative.
        for part in FILE_PARTS:
            if part in body:
                body[part] = _file(part, op)
    else:
        case.body = body
    if not multipart and ASSETS.get(op) and "asset" in body:
        body["asset"] = ASSETS[op]
    if op.startswith("submit") or op in ("createCloudScene", "createMap"):
        if not isinstance(body.get("params"), dict) and body.get("params") is None and op in DEFAULT_SIZE:
            body["params"] = {}
        params = body.get("params")
    else:
        params = body
    _rules(op, params)
    if op in EDIT_OPS:
        _fit_pixels(body, EDIT_VIEW)
        _distinct_eye(body)
        _edit(body)
    if multipart:
        kwargs["files"] = _multipart(body)
    return case
