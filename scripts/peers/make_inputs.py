#!/usr/bin/env python3
"""Inputs of `scripts/peers.sh`, made from the real data in `../shared/data` (issue 19).

Writes into OUT (argument 1):

- `table5k.obj`: `mesh/inventor_table.glb` (SGI Open Inventor sample, 4,960 triangles; its Z-up
  content turned Y-up, the OBJ convention both Blender's and our OBJ readers use). Real.
- `bunny75k.obj`: `mesh/bunny00.ply` (Stanford bunny, hole-filled, 75,408 triangles; Y-up). Real;
  the nearest real mesh to the issue's "100 k" (none of 90–200 k is in the data).
- `bunny1m.obj` (unless `--quick`): bunny00 split twice by midpoint subdivision (every triangle
  into 4, then again: 1,206,528 triangles, the same surface). *Synthetic in its triangle count
  only*: no real 1 M-triangle mesh is available here.
- `dem4096.tif` + `dem4096.f32` (`--quick`: 1024²): `dem/colorado_front_range_srtmgl3_f32.tif`
  (SRTM GL3, 758², 3″) resampled by cubic convolution to 4096² with `gdal_translate` (cells
  ≈ 16.5 m instead of 3″ ≈ 92 × 70 m: *synthetic in its size*, the relief is the real one), as
  a float32 GeoTIFF (ours and `gdaldem` read it) and as raw float32 rows (`.f32`, for numpy,
  which has no GeoTIFF reader; `dem4096.json` gives its size and cell size in metres).
- `cloud128.npy` (`--quick`: 48³): the smoke plume of `volume/openvdb_smoke_density.nrrd`
  (OpenVDB sample, 111×222×112) resampled trilinearly to 128³ plus a haze of 5 % of its peak,
  so that every voxel of the box is cloud (ρ ≥ 1 % of the maximum): the issue's "cloud filling
  its 128³ box". Synthetic haze over real density.

Idempotent: a file already there is kept.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def write_obj(path: Path, mesh: trimesh.Trimesh):
    """Plain `v`/`f` OBJ (no normals, no UVs), written with numpy: fast and the same for both."""
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w") as f:
        f.write(f"# {len(mesh.faces)} triangles\n")
        np.savetxt(f, mesh.vertices, fmt="v %.7g %.7g %.7g")
        np.savetxt(f, mesh.faces + 1, fmt="f %d %d %d")
    tmp.rename(path)


def meshes(out: Path, quick: bool):
    table = out / "table5k.obj"
    if not table.exists():
        m = trimesh.load(DATA / "mesh" / "inventor_table.glb", force="mesh")
        v = m.vertices
        # Z-up content → Y-up: (x, y, z) → (x, z, −y).
        m = trimesh.Trimesh(np.c_[v[:, 0], v[:, 2], -v[:, 1]], m.faces, process=False)
        write_obj(table, m)
    bunny = out / "bunny75k.obj"
    big = out / "bunny1m.obj"
    if not bunny.exists() or (not quick and not big.exists()):
        m = trimesh.load(DATA / "mesh" / "bunny00.ply", force="mesh", process=False)
        if not bunny.exists():
            write_obj(bunny, m)
        if not quick and not big.exists():
            v, f = m.vertices, m.faces
            for _ in range(2):
                v, f = trimesh.remesh.subdivide(v, f)
            write_obj(big, trimesh.Trimesh(v, f, process=False))


def dem(out: Path, quick: bool):
    n = 1024 if quick else 4096
    tif = out / f"dem{n}.tif"
    raw = out / f"dem{n}.f32"
    if not tif.exists():
        subprocess.run(
            ["gdal_translate", "-q", "-ot", "Float32", "-outsize", str(n), str(n), "-r", "cubic",
             "-co", "TILED=NO", str(DATA / "dem" / "colorado_front_range_srtmgl3_f32.tif"),
             str(tif)],
            check=True,
        )
    if not raw.exists():
        subprocess.run(["gdal_translate", "-q", "-of", "ENVI", str(tif), str(raw)], check=True)
        info = json.loads(subprocess.run(["gdalinfo", "-json", str(tif)], check=True,
                                         capture_output=True, text=True).stdout)
        gt = info["geoTransform"]
        lat = gt[3] + gt[5] * n / 2
        # Degrees to metres at the DEM's middle latitude (as our reader does for geographic CRSs).
        dx = abs(gt[1]) * 111_320.0 * np.cos(np.radians(lat))
        dy = abs(gt[5]) * 110_574.0
        (out / f"dem{n}.json").write_text(json.dumps({"width": n, "height": n, "dx": dx, "dy": dy}))


def nrrd_f32(path: Path):
    data = path.read_bytes()
    head, _, body = data.partition(b"\n\n")
    sizes = None
    for line in head.decode().splitlines():
        if line.startswith("sizes:"):
            sizes = [int(s) for s in line.split(":")[1].split()]
    return np.frombuffer(body, dtype="<f4").reshape(sizes[::-1])  # [z][y][x]


def cloud(out: Path, quick: bool):
    n = 48 if quick else 128
    path = out / f"cloud{n}.npy"
    if path.exists():
        return
    from scipy.ndimage import map_coordinates

    src = nrrd_f32(DATA / "volume" / "openvdb_smoke_density.nrrd")
    idx = np.meshgrid(*[np.linspace(0, s - 1, n) for s in src.shape], indexing="ij")
    d = map_coordinates(src, idx, order=1).astype(np.float32)
    d = d / d.max()
    d = (0.05 + d) / 1.05
    np.save(path, np.ascontiguousarray(d, dtype=np.float32))


def main():
    out = Path(sys.argv[1])
    quick = "--quick" in sys.argv
    out.mkdir(parents=True, exist_ok=True)
    meshes(out, quick)
    dem(out, quick)
    cloud(out, quick)


if __name__ == "__main__":
    main()
