"""Schemathesis hooks for `tests/it/conformance.rs` (issue 20): positive cases carry real files,
and respect the few rules of the API that JSON Schema cannot state.

Loaded with `SCHEMATHESIS_HOOKS=hooks` and `PYTHONPATH=tests/conformance`. Only cases generated in
the positive mode are touched: a negative case keeps every violation schemathesis put in it.

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
   - `camera.eye` ≠ `camera.target`: the eye is moved;
   - `slope_end_deg` ≥ `slope_start_deg`, `full_snow_quantile` ≥ `snowline_quantile`
     (snow-terrain, also against the `winter` preset's values when one is not given): swapped or
     raised;
   - edit pixels (`from`, `to`, `strokes[].pixels`) inside the view (`width` × `height`,
     default 960 × 540): taken modulo the size;
   - a `set` edit gives at least one of its fields: `kappa` is added;
   - a volume's `bounds` have min < max and sides not thinner than the documented bound: widened;
   - a JSON body names an uploaded asset of the operation's kind (a DEM, a mesh, a volume).
3. One filter (`filter_case`), on negative cases only: see its doc.
"""

import os
import struct
import zlib

import schemathesis
from schemathesis import GenerationMode

FILES = os.environ.get("PHENOMENA_ST_FILES", "")
MAX_PIXELS = int(os.environ.get("PHENOMENA_ST_MAX_PIXELS", "33177600"))

# The `winter` preset's values of the ordered pairs (engine `DescriptorParams::default`).
PRESET_PAIRS = {
    "slope_start_deg": 35.0,
    "slope_end_deg": 60.0,
    "snowline_quantile": 0.3,
    "full_snow_quantile": 0.7,
}
# The default view of a cloud scene edit.
EDIT_VIEW = (960, 540)
# Default output sizes per operation (for a case that gives one side only).
DEFAULT_SIZE = {
    "submitSnowTerrain": (900, 600),
    "submitSnowCover": (960, 640),
    "submitDust": (960, 640),
    "submitCloud": (960, 540),
    "renderCloudScene": (960, 540),
    "editCloudScene": EDIT_VIEW,
}
# Uploaded assets of each kind (`tests/it/conformance.rs`), for JSON bodies naming one.
ASSETS = {
    "submitSnowTerrain": os.environ.get("PHENOMENA_ST_DEM_ASSET"),
    "submitSnowCover": os.environ.get("PHENOMENA_ST_MESH_ASSET"),
    "submitDust": os.environ.get("PHENOMENA_ST_MESH_ASSET"),
    "submitCloud": os.environ.get("PHENOMENA_ST_VOLUME_ASSET"),
    "createCloudScene": os.environ.get("PHENOMENA_ST_VOLUME_ASSET"),
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


def _file(part):
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
    return meta is not None and meta.generation.mode == GenerationMode.POSITIVE


def _fit_pixels(obj, default):
    """`width` × `height` within MAX_PIXELS (the missing side at its default), lowering the
    height."""
    if not isinstance(obj, dict):
        return
    w, h = obj.get("width", default[0]), obj.get("height", default[1])
    if isinstance(w, int) and isinstance(h, int) and w * h > MAX_PIXELS:
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


def _order(obj, lo, hi):
    a = obj.get(lo, PRESET_PAIRS[lo])
    b = obj.get(hi, PRESET_PAIRS[hi])
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and b < a:
        if lo in obj and hi in obj:
            obj[lo], obj[hi] = b, a
        elif lo in obj:
            obj[hi] = a
        else:
            obj[lo] = b


def _terrain(params):
    if not isinstance(params, dict):
        return
    if params.get("preset", "winter") == "winter":
        _order(params, "slope_start_deg", "slope_end_deg")
        _order(params, "snowline_quantile", "full_snow_quantile")


def _inside(p, w, h):
    if isinstance(p, list) and len(p) == 2 and all(isinstance(v, int) for v in p):
        return [p[0] % w, p[1] % h]
    return p


def _edit(body):
    w = body.get("width", EDIT_VIEW[0])
    h = body.get("height", EDIT_VIEW[1])
    if not (isinstance(w, int) and isinstance(h, int)):
        return
    for k in ("from", "to"):
        if k in body:
            body[k] = _inside(body[k], w, h)
    for s in body.get("strokes", []) if isinstance(body.get("strokes"), list) else []:
        if isinstance(s, dict) and isinstance(s.get("pixels"), list):
            s["pixels"] = [_inside(p, w, h) for p in s["pixels"]]


SET_FIELDS = ("kappa", "sun_direction", "sun_azimuth_deg", "sun_color", "scattering", "albedo")


@schemathesis.hook
def filter_case(ctx, case):
    """A negative case of `POST /v1/assets` whose `file` part schemathesis turned into a number or
    boolean: on the wire it is that text, a valid (tiny) file the server cannot and should not
    tell from one (its refusals of what the schema excludes are asserted by
    `api::asset_uploads_refuse_what_the_schema_refuses`)."""
    op = ctx.operation.definition.raw.get("operationId", "") if ctx.operation else ""
    if op == "uploadAsset" and not _positive(case) and isinstance(case.body, dict):
        f = case.body.get("file")
        if f is not None and not isinstance(f, (str, bytes)):
            return False
    return True


@schemathesis.hook
def before_call(ctx, case, kwargs):
    """Applied to every case before it is sent (every phase, the coverage phase included)."""
    _repair(ctx, case)


def _repair(ctx, case):
    if not _positive(case):
        return case
    op = ctx.operation.definition.raw.get("operationId", "") if ctx.operation else ""
    body = case.body if isinstance(case.body, dict) else None
    if body is None:
        return case
    multipart = (case.media_type or "").startswith("multipart/")
    if multipart:
        for part in FILE_PARTS:
            if part in body:
                body[part] = _file(part)
    elif ASSETS.get(op) and "asset" in body:
        body["asset"] = ASSETS[op]
    if op.startswith("submit") or op == "createCloudScene":
        if not isinstance(body.get("params"), dict) and body.get("params") is None and op in DEFAULT_SIZE:
            body["params"] = {}
        params = body.get("params")
    else:
        params = body
    if op in DEFAULT_SIZE and op != "editCloudScene":
        _fit_pixels(params, DEFAULT_SIZE[op])
        _distinct_eye(params)
    if op in ("submitCloud", "createCloudScene"):
        _bounds(params)
    if op == "submitSnowTerrain":
        _terrain(params)
    if op == "editCloudScene":
        _fit_pixels(body, EDIT_VIEW)
        _distinct_eye(body)
        _edit(body)
        kind = (case.path_parameters or {}).get("kind")
        if kind == "set" and not any(k in body for k in SET_FIELDS):
            body["kappa"] = 1.0
    return case
