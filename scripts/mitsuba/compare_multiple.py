#!/usr/bin/env python3
"""Multiple scattering against Mitsuba 3 (issue 24's "done when").

Renders one volume with our `cloud` pipeline (`phenomena render cloud`, `scattering: multiple`,
its linear layers from `layers.bin`) and with Mitsuba 3's volumetric path tracer (`volpath`,
`max_depth = -1`) on the same volume, box, camera, sun, albedo and Henyey–Greenstein phase, and
reports the relative RMSE after an exposure fit, Mitsuba's own noise, and the time ratio at
equal error.

Usage (from the repository root; needs a release build of `phenomena`):

    cargo build --release
    python3 scripts/mitsuba/compare_multiple.py --volume cumulus --out target/mitsuba
    python3 scripts/mitsuba/compare_multiple.py \
        --volume ../shared/data/volume/openvdb_smoke_density.nrrd --out target/mitsuba
    python3 scripts/mitsuba/compare_multiple.py \
        --volume ../shared/data/volume/bunny_fog_density.vdb --ref-spp 1024 --out target/mitsuba

A `.vdb` volume is read with Debian's `python3-openvdb` (`apt-get install python3-openvdb`).

The first run makes a virtual environment in `target/mitsuba-venv` and installs `mitsuba` and
`numpy` from PyPI there. Mitsuba's reference (`--ref-spp`, default 512) is rendered once and
kept in the output directory (`ref_<name>.npy`); delete it to render it again.

Matching the two models:
- Ours integrates σ_t·g·(α·I_l·Φ·T_sun + α·I_l·J) with Φ normalised to 1 for isotropic
  scattering, so I_l is the sun's irradiance E over 4π. Mitsuba's `directional` emitter is given
  `irradiance = 4π` (I_l = 1); the exposure fit removes any remaining constant.
- σ_t = κ·ρ: Mitsuba's `heterogeneous` medium with a `gridvolume` of ρ and `scale = κ`, inside a
  `cube` with a `null` BSDF spanning the volume's box; the grid's voxel centres sit at
  (i + ½)/n of the box on both sides.
- Ambient 0, no background: both images are the cloud's own radiance over black.

Error measure: s = argmin ‖s·ours − ref‖ over the pixels where either image has light; relative
RMSE = RMS(s·ours − ref) / mean(ref) over those pixels. Mitsuba's noise at the reference's spp is
the same measure between two references with different seeds, divided by √2.
"""

import argparse
import json
import math
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def ensure_venv():
    """Re-executes this script inside target/mitsuba-venv with mitsuba and numpy installed."""
    venv = ROOT / "target" / "mitsuba-venv"
    py = venv / "bin" / "python"
    if Path(sys.executable).resolve() == py.resolve() if py.exists() else False:
        return
    try:
        import mitsuba  # noqa: F401
        import numpy  # noqa: F401

        return
    except ImportError:
        pass
    if not py.exists():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(py), "-m", "pip", "install", "-q", "mitsuba", "numpy"], check=True)
    os.execv(str(py), [str(py)] + sys.argv)


def llvm_library():
    """Dr.Jit's LLVM back end needs a libLLVM newer than Debian 12's default 14/15 (their
    instruction selection fails on `fminimum`): `apt-get install libllvm19`. Returns the
    newest libLLVM-NN.so found with NN ≥ 16, or None (then the scalar variant is used)."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    found = []
    for d in ["/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib"]:
        for f in Path(d).glob("libLLVM-*.so") if Path(d).exists() else []:
            ver = f.name[len("libLLVM-"):-len(".so")].split(".")[0]
            if ver.isdigit() and int(ver) >= 16:
                found.append((int(ver), str(f)))
    return max(found)[1] if found else None


ensure_venv()
if llvm_library():
    os.environ["DRJIT_LIBLLVM_PATH"] = llvm_library()

import numpy as np  # noqa: E402


def cumulus(n):
    """A procedural cumulus: overlapping spheres with fBm-perturbed edges and a flat base (the
    shape of `cloud::procedural::cumulus`, computed here in numpy)."""
    p = (np.arange(n, dtype=np.float64) + 0.5) / n
    z, y, x = np.meshgrid(p, p, p, indexing="ij")
    rng = np.random.default_rng(7)
    lattice = rng.random((64, 64, 64))

    def noise(q):
        i = np.floor(q).astype(int)
        f = q - i
        f = f * f * (3 - 2 * f)
        s = 0
        for c in range(8):
            a, b, e = c & 1, (c >> 1) & 1, (c >> 2) & 1
            w = (f[0] if a else 1 - f[0]) * (f[1] if b else 1 - f[1]) * (f[2] if e else 1 - f[2])
            s = s + w * lattice[(i[0] + a) % 64, (i[1] + b) % 64, (i[2] + e) % 64]
        return s

    fbm = 0
    amp, fr = 0.5, 6.0
    for _ in range(4):
        fbm = fbm + amp * noise(np.stack([x * fr, y * fr, z * fr]))
        amp *= 0.5
        fr *= 2
    field = -np.inf
    for (cx, cy, cz), r in [((0.5, 0.35, 0.5), 0.22), ((0.33, 0.3, 0.45), 0.16),
                            ((0.67, 0.3, 0.55), 0.17), ((0.48, 0.52, 0.5), 0.16)]:
        d = np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2)
        field = np.maximum(field, 1 - d / r)
    dens = np.clip(field * 2.5 + (fbm - 0.5) * 1.2, 0, 1)
    dens[y < 0.2] = 0
    return dens.astype(np.float32)  # (z, y, x)


def read_nrrd(path):
    """Raw or gzip float32 NRRD, x fastest → (z, y, x)."""
    import gzip

    data = Path(path).read_bytes()
    head, body = data.split(b"\n\n", 1)
    fields = dict(
        line.split(": ", 1) for line in head.decode().splitlines()[1:] if ": " in line
    )
    sizes = [int(s) for s in fields["sizes"].split()]
    if fields.get("encoding") == "gzip":
        body = gzip.decompress(body)
    assert fields["type"] == "float", fields["type"]
    arr = np.frombuffer(body, dtype="<f4").reshape(sizes[2], sizes[1], sizes[0])
    return np.maximum(arr, 0).astype(np.float32)


def read_vdb(path, out):
    """The first grid of an OpenVDB file, its active bounding box → (z, y, x), through Debian's
    `python3-openvdb` (the system interpreter's `pyopenvdb`; it is not on PyPI), run as a
    subprocess because this script runs in the venv. The grid is cut to the active voxels'
    bounding box and written as `.npy`, which both renderers then read."""
    npy = Path(out) / (Path(path).stem + "_vdb_zyx.npy")
    code = (
        "import sys, numpy as np, pyopenvdb as vdb\n"
        "g = vdb.read(sys.argv[1], vdb.readAllGridMetadata(sys.argv[1])[0].name)\n"
        "lo, hi = g.evalActiveVoxelBoundingBox()\n"
        "a = np.zeros(tuple(h - l + 1 for l, h in zip(lo, hi)), dtype=np.float32)\n"
        "g.copyToArray(a, ijk=lo)\n"
        "np.save(sys.argv[2], np.ascontiguousarray(a.transpose(2, 1, 0)))\n"
    )
    subprocess.run(["/usr/bin/python3", "-c", code, str(path), str(npy)], check=True)
    return np.maximum(np.load(npy), 0).astype(np.float32)


def write_npy(path, arr):
    np.save(path, arr)


def default_bounds(dims_xyz):
    """SPEC §3's default box: the unit cube scaled to the grid's aspect, base at Y = 0."""
    m = max(dims_xyz)
    ext = [d / m for d in dims_xyz]
    lo = [-ext[0] / 2, 0.0, -ext[2] / 2]
    hi = [ext[0] / 2, ext[1], ext[2] / 2]
    return lo, hi


def read_layers(path):
    """`layers.bin` (PHLAY1/PHLAY2) → per pixel Ī, M, α as (h, w) arrays."""
    b = Path(path).read_bytes()
    magic = b[:8]
    ms = magic == b"PHLAY2\0\0"
    assert ms or magic == b"PHLAY1\0\0", magic
    n = struct.unpack_from("<I", b, 8)[0]
    at = 12 + n
    w, h = struct.unpack_from("<II", b, at)
    at += 8
    spans = [struct.unpack_from("<II", b, at + 8 * y) for y in range(h)]
    at += 8 * h
    rec = 6 if ms else 5
    direct = np.zeros((h, w))
    multiple = np.zeros((h, w))
    alpha = np.zeros((h, w))
    for y, (x0, x1) in enumerate(spans):
        k = x1 - x0
        v = np.frombuffer(b, dtype="<f4", count=rec * k, offset=at).reshape(k, rec)
        at += 4 * rec * k
        direct[y, x0:x1] = v[:, 0]
        if ms:
            multiple[y, x0:x1] = v[:, 1]
        alpha[y, x0:x1] = v[:, -1]
    return direct, multiple, alpha


def render_ours(binary, vol_path, params, out_dir):
    out_dir.mkdir(parents=True, exist_ok=True)
    pfile = out_dir / "params.json"
    pfile.write_text(json.dumps(params))
    t0 = time.perf_counter()
    subprocess.run([str(binary), "render", "cloud", "--input", str(vol_path), "--params",
                    str(pfile), "--out", str(out_dir), "--quiet"], check=True)
    t = time.perf_counter() - t0
    d, m, a = read_layers(out_dir / "layers.bin")
    return d + m, d, a, t


def mitsuba_scene(mi, dens_zyx, lo, hi, kappa, albedo, g, sun, eye, target, fov, w, h, spp,
                  max_depth, seed):
    from mitsuba import ScalarTransform4f as T

    size = [hi[k] - lo[k] for k in range(3)]
    centre = [(hi[k] + lo[k]) / 2 for k in range(3)]
    grid = {
        "type": "gridvolume",
        "data": mi.TensorXf(dens_zyx[..., None]),
        "to_world": T().translate(lo).scale(size),
        "filter_type": "trilinear",
    }
    medium = {
        "type": "heterogeneous",
        "sigma_t": grid,
        "scale": kappa,
        "albedo": albedo,
        "phase": {"type": "hg", "g": g},
    }
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": max_depth},
        "sensor": {
            "type": "perspective",
            "fov": fov,
            "fov_axis": "y",
            "to_world": T().look_at(origin=eye, target=target, up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                     "pixel_format": "luminance" if "mono" in mi.variant() else "rgb"},
        },
        "sun": {
            "type": "directional",
            "direction": [-s for s in sun],
            "irradiance": {"type": "rgb", "value": [4 * math.pi] * 3},
        },
        "box": {
            "type": "cube",
            "to_world": T().translate(centre).scale([s / 2 for s in size]),
            "bsdf": {"type": "null"},
            "interior": medium,
        },
    }


def render_mitsuba(mi, scene_args, spp, seed, max_depth):
    """`spp` samples per pixel in passes of at most `PASS_SPP` (the LLVM variant traces all of a
    pass's paths as one wavefront: memory grows with width × height × spp), each pass with its
    own seed, averaged. Returns the (h, w) luminance/grey image and the seconds of rendering
    (scene loading excluded)."""
    args = dict(scene_args)
    scene = mi.load_dict(mitsuba_scene(mi, **args, spp=spp, max_depth=max_depth, seed=seed))
    total = None
    done = 0
    t = 0.0
    k = 0
    while done < spp:
        n = min(PASS_SPP, spp - done)
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, spp=n, seed=seed * 100_003 + k))
        t += time.perf_counter() - t0
        img = img.mean(axis=2) if img.ndim == 3 else img
        total = img * n if total is None else total + img * n
        done += n
        k += 1
    return total / spp, t


PASS_SPP = 64


def ref_tag(name, mode, kappa, a):
    """The cache name of a Mitsuba reference: everything it depends on."""
    return (f"{name}_{mode}_k{kappa:.6g}_a{a.albedo:g}_g{a.g:g}_{a.width}x{a.height}"
            f"_{a.ref_spp}spp")


def reference(mi, a, out, name, mode, kappa, scene_args):
    """Mitsuba's reference at `--ref-spp`, rendered once and cached in `out` (with its time)."""
    tag = ref_tag(name, mode, kappa, a)
    ref_path = out / f"ref_{tag}.npy"
    if ref_path.exists():
        return np.load(ref_path), json.loads((out / f"ref_{tag}.json").read_text())["seconds"]
    depth = 2 if mode == "single" else -1
    ref, t_ref = render_mitsuba(mi, scene_args, a.ref_spp, 1, depth)
    np.save(ref_path, ref)
    (out / f"ref_{tag}.json").write_text(json.dumps({"seconds": t_ref, "variant": mi.variant()}))
    return ref, t_ref


def rel_rmse(ours, ref, mask):
    o, r = ours[mask], ref[mask]
    s = float((o * r).sum() / max((o * o).sum(), 1e-30))
    return float(np.sqrt(((s * o - r) ** 2).mean()) / max(r.mean(), 1e-30)), s


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--volume", default="cumulus", help="'cumulus' or a .nrrd/.npy path")
    ap.add_argument("--size", type=int, default=64, help="cumulus grid size")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--kappa", type=float, default=None, help="default: our choice from the volume")
    ap.add_argument("--albedo", type=float, default=1.0)
    ap.add_argument("--g", type=float, default=0.0)
    ap.add_argument("--ref-spp", type=int, default=4096)
    # llvm_ad_mono: vectorised and grey (the comparison is grey: sun and albedo are white); it
    # needs libLLVM ≥ 16 (see `llvm_library`), else scalar_rgb.
    ap.add_argument("--variant", default="llvm_ad_mono" if llvm_library() else "scalar_rgb")
    ap.add_argument("--modes", default="single,multiple",
                    help="which comparisons to run: single (max_depth 2), multiple (-1)")
    ap.add_argument("--reference-only", action="store_true",
                    help="render and cache the multiple-scattering reference only (needs --kappa)")
    ap.add_argument("--out", default="target/mitsuba")
    ap.add_argument("--binary", default=str(ROOT / "target" / "release" / "phenomena"))
    a = ap.parse_args()

    import mitsuba as mi

    try:
        mi.set_variant(a.variant)
    except Exception:  # no LLVM on this machine
        mi.set_variant("scalar_rgb")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.volume == "cumulus":
        name = f"cumulus{a.size}"
        dens = cumulus(a.size)
    elif a.volume.endswith(".nrrd"):
        name = Path(a.volume).stem
        dens = read_nrrd(a.volume)
    elif a.volume.endswith(".vdb"):
        name = Path(a.volume).stem
        dens = read_vdb(a.volume, out)
    else:
        name = Path(a.volume).stem
        dens = np.load(a.volume).astype(np.float32)
    vol_path = out / f"{name}.npy"
    write_npy(vol_path, dens)
    dims = [dens.shape[2], dens.shape[1], dens.shape[0]]
    lo, hi = default_bounds(dims)
    centre = [(lo[k] + hi[k]) / 2 for k in range(3)]
    # The default orbit's direction (azimuth 200°, elevation 12°), framing the box.
    az, el = math.radians(200), math.radians(12)
    radius = 1.6 * max(hi[k] - lo[k] for k in range(3))
    eye = [centre[0] + radius * math.cos(el) * math.sin(az), centre[1] + radius * math.sin(el),
           centre[2] - radius * math.cos(el) * math.cos(az)]
    fov = 40.0
    sun_az, sun_el = math.radians(150), math.radians(35)
    sun = [math.cos(sun_el) * math.sin(sun_az), math.sin(sun_el), -math.cos(sun_el) * math.cos(sun_az)]
    params = {
        "width": a.width, "height": a.height,
        "camera": {"eye": eye, "target": centre, "fov_deg": fov},
        "sun_direction": sun, "sun_color": [1, 1, 1], "ambient": [0, 0, 0],
        "albedo": a.albedo, "anisotropy": a.g, "layers": ["linear"],
    }
    if a.kappa is not None:
        params["kappa"] = a.kappa

    def args_for(kappa):
        return dict(dens_zyx=dens, lo=lo, hi=hi, kappa=kappa, albedo=a.albedo, g=a.g, sun=sun,
                    eye=eye, target=centre, fov=fov, w=a.width, h=a.height)

    if a.reference_only:
        if a.kappa is None:
            sys.exit("--reference-only needs --kappa")
        ref, t_ref = reference(mi, a, out, name, "multiple", a.kappa, args_for(a.kappa))
        print(json.dumps({"reference": ref_tag(name, "multiple", a.kappa, a), "seconds": t_ref,
                          "variant": mi.variant()}))
        return
    results = {"volume": name, "dims": dims, "width": a.width, "height": a.height,
               "variant": mi.variant()}
    for mode in a.modes.split(","):
        p = dict(params, scattering=mode)
        ours, direct, alpha, t_ours = render_ours(a.binary, vol_path, p, out / f"ours_{name}_{mode}")
        # Time the render again (the first run pays for page-ins).
        ours, direct, alpha, t_ours = render_ours(a.binary, vol_path, p, out / f"ours_{name}_{mode}")
        state = json.loads((out / f"ours_{name}_{mode}" / "state.json").read_text())
        kappa = state["kappa"]
        scene_args = args_for(kappa)
        depth = 2 if mode == "single" else -1
        ref, t_ref = reference(mi, a, out, name, mode, kappa, scene_args)
        mask = (alpha > 0.01) | (ref > 1e-3 * ref.max())
        err, scale = rel_rmse(ours, ref, mask)
        # Mitsuba's own noise at the reference's spp, and its error at fewer samples (vs the
        # reference) to find the spp (and time) at which it matches our error.
        second, _ = render_mitsuba(mi, scene_args, a.ref_spp // 4, 2, depth)
        noise4, _ = rel_rmse(second, ref, mask)
        ladder = []
        for spp in [1, 4, 16, 64]:
            img, t = render_mitsuba(mi, scene_args, spp, 3 + spp, depth)
            e, _ = rel_rmse(img, ref, mask)
            ladder.append((spp, e, t))
        # Error ∝ spp^(−½): the spp at which Mitsuba's error equals ours, from the ladder's
        # best-fitting constant; its time from the measured time per sample.
        c = np.median([e * math.sqrt(spp) for spp, e, _ in ladder])
        spp_eq = (c / err) ** 2 if err > 0 else float("inf")
        t_per_spp = np.median([t / spp for spp, _, t in ladder if spp >= 4])
        t_eq = spp_eq * t_per_spp
        res = {
            "kappa": kappa, "rel_rmse": err, "exposure": scale,
            "mitsuba_noise_at_ref_spp": noise4 / 2 / math.sqrt(1 + 1 / 4),
            "ladder": [{"spp": s, "rel_rmse": e, "seconds": t} for s, e, t in ladder],
            "ours_seconds_cli": t_ours, "ref_seconds": t_ref, "ref_spp": a.ref_spp,
            "mitsuba_spp_at_equal_error": spp_eq, "mitsuba_seconds_at_equal_error": t_eq,
            "time_ratio_at_equal_error": t_eq / t_ours,
        }
        results[mode] = res
        np.save(out / f"ours_{name}_{mode}.npy", ours)
        for tag, img in [("ours", scale * ours), ("ref", ref)]:
            save_png(out / f"{tag}_{name}_{mode}.png", img, ref.max())
        print(json.dumps({mode: res}, indent=1), flush=True)
    (out / f"result_{name}.json").write_text(json.dumps(results, indent=1))


def save_png(path, img, peak):
    """A grey 8-bit PNG of a linear image scaled by `peak`, sRGB-encoded (for eyes only)."""
    import zlib

    v = np.clip(img / max(peak, 1e-30), 0, 1)
    v = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    b = (v * 255 + 0.5).astype(np.uint8)
    h, w = b.shape
    raw = b"".join(b"\0" + b[y].tobytes() for y in range(h))

    def chunk(t, d):
        c = struct.pack(">I", len(d)) + t + d
        return c + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    Path(path).write_bytes(png)


if __name__ == "__main__":
    main()
