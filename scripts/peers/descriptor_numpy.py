#!/usr/bin/env python3
"""The snow-terrain descriptor in numpy: the peer of `phenomena render snow-terrain --set
preset=paper --set 'outputs=["snow_cover.tif"]'` (issue 19, "numpy TSA").

    python3 scripts/peers/descriptor_numpy.py DEM.f32 DEM.json OUT.f32 [TIMES.json]

The same work as ours, stage by stage (SPEC §1, the `paper` preset; `engine/src/snow_terrain`):
1. smooth the heights with the L1 diamond 1 ≤ |di| + |dj| ≤ 3, 5 passes, each cell ← (own +
   mean of the neighbours inside the grid) / 2 (`smooth.rs`);
2. Tangent Sphere Accessibility with the 8 neighbours (window 1, `tsa.rs`): unit normals by
   central differences (second-order one-sided at the border, `np.gradient(edge_order=2)`), per
   neighbour P the sphere-through-P bound |P−X|²/2N·(P−X) and the tangent-plane bound (Eq. 3)
   kept when its touching point lies in P's cell and P's normal is central; min, clamped at
   100 km;
3. Eq. 4 with the probe radius 5000 m, b = 0 (`transfer.rs`);
4. the altitude term t ← 1 − (1 − t)·a(h), a = ((h − 0)/(h_max − 0))² clamped to [0, 1]
   (`altitude.rs`, snowline 0 m, band to the summit, exponent 2);
5. one more smoothing pass of t with the same diamond;
then writes snow s = 1 − t as raw float32. Vectorised numpy, float32, one core (numpy's
element-wise operations are single-threaded), every (X, P) pair evaluated from both sides.

Not done here, done by ours (so the comparison favours this peer): the sun correction (step 6),
the statistics and report, and the deflate-compressed GeoTIFF with the georeferencing (numpy
has no GeoTIFF writer; this writes raw rows). The input is raw float32 rows (`gdal_translate -of
ENVI` of the same GeoTIFF ours reads): numpy has no GeoTIFF reader either.

Checked (2026-12-03, the 1024² input): with ours' sun term off (`--set sun_spread_deg=0`) this
map differs from our `snow_cover.tif` by 0.0005 on average, by more than 0.01 in 0.08 % of the
cells (float evaluation order, amplified by TSA).
"""

import json
import sys
import time

import numpy as np


def shifted(a: np.ndarray, di: int, dj: int, pad: int) -> np.ndarray:
    """a[r + di, c + dj] from the zero-padded `a` (padding `pad`)."""
    h, w = a.shape[0] - 2 * pad, a.shape[1] - 2 * pad
    return a[pad + di: pad + di + h, pad + dj: pad + dj + w]


def smooth(z: np.ndarray, n: int, passes: int) -> np.ndarray:
    offsets = [(di, dj) for di in range(-n, n + 1) for dj in range(-n, n + 1)
               if 1 <= abs(di) + abs(dj) <= n]
    ones = np.pad(np.ones_like(z), n)
    count = np.zeros_like(z)
    for di, dj in offsets:
        count += shifted(ones, di, dj, n)
    for _ in range(passes):
        zp = np.pad(z, n)
        s = np.zeros_like(z)
        for di, dj in offsets:
            s += shifted(zp, di, dj, n)
        z = (z + s / count) * np.float32(0.5)
    return z


def tsa(z: np.ndarray, dx: float, dy: float, tsa_max: float) -> np.ndarray:
    gz, gx = np.gradient(z, np.float32(dy), np.float32(dx), edge_order=2)
    inv = 1.0 / np.sqrt(gx * gx + 1.0 + gz * gz)
    nx, ny, nz = -gx * inv, inv, -gz * inv
    h, w = z.shape
    central = np.zeros_like(z)
    central[1:-1, 1:-1] = 1.0
    pad = lambda a: np.pad(a, 1)  # noqa: E731
    zp, nxp, nyp, nzp, cp = pad(z), pad(nx), pad(ny), pad(nz), pad(central)
    inside = pad(np.ones_like(z))
    out = np.full_like(z, np.inf)
    hdx, hdz = np.float32(dx / 2), np.float32(dy / 2)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            ox, oz = np.float32(dj * dx), np.float32(di * dy)
            ph = shifted(zp, di, dj, 1)
            mx, my, mz = (shifted(a, di, dj, 1) for a in (nxp, nyp, nzp))
            dh = ph - z
            d2 = ox * ox + oz * oz + dh * dh
            q = nx * ox + ny * dh + nz * oz
            num = -(mx * ox + my * dh + mz * oz)
            den = 1.0 - (nx * mx + ny * my + nz * mz)
            with np.errstate(divide="ignore", invalid="ignore"):
                tp = np.where(q > 0, d2 / (2 * q), np.inf)
                t = num / den
                ex = t * (nx - mx) - ox
                ez = t * (nz - mz) - oz
            ok = ((shifted(cp, di, dj, 1) > 0.75) & (num > 0) & (den > 1e-6)
                  & (np.abs(ex) <= hdx) & (np.abs(ez) <= hdz))
            b = np.minimum(np.where(ok, t, np.inf), tp)
            b = np.where(shifted(inside, di, dj, 1) > 0, b, np.inf)
            np.minimum(out, b, out=out)
    return np.minimum(out, np.float32(tsa_max))


def main():
    src, meta, dst = sys.argv[1], sys.argv[2], sys.argv[3]
    times = {}
    t0 = time.perf_counter()
    m = json.load(open(meta))
    z = np.fromfile(src, dtype="<f4").reshape(m["height"], m["width"])
    heights = z
    t = time.perf_counter()
    zs = smooth(z, 3, 5)
    times["smooth"] = time.perf_counter() - t
    t = time.perf_counter()
    a = tsa(zs, m["dx"], m["dy"], 1.0e5)
    times["tsa"] = time.perf_counter() - t
    t = time.perf_counter()
    r = np.float32(5000.0)
    g = np.where(a >= r, np.float32(1.0), a / r)
    hmax = float(heights.max())
    alt = np.clip(heights / np.float32(hmax), 0, 1) ** 2
    g = 1.0 - (1.0 - g) * alt
    g = smooth(g.astype(np.float32), 3, 1)
    s = (1.0 - g).astype("<f4")
    times["transfer_altitude_smooth"] = time.perf_counter() - t
    s.tofile(dst)
    times["total"] = time.perf_counter() - t0
    print(json.dumps({k: round(v, 4) for k, v in times.items()}))
    if len(sys.argv) > 4:
        json.dump(times, open(sys.argv[4], "w"))


if __name__ == "__main__":
    main()
