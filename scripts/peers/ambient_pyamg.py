#!/usr/bin/env python3
"""Ambient propagation with pyamg's Ruge–Stüben AMG: the peer of our multigrid `propagate`
(`engine/src/cloud/multigrid.rs`; SPEC §3.2; issue 19, "ambient propagation, a cloud filling its
128³ box").

    python3 scripts/peers/ambient_pyamg.py VOLUME.npy [TIMES.json]

The same system as ours, built here from the volume (float32 .npy, [z][y][x]):
- guide Y = the sun transmittance exp(−κ ∫ρ), κ chosen so that the median optical depth of the
  columns is 4 (our automatic κ's rule); the sun straight overhead here (ours: the default sun
  at 150°/35°, marched on the grid), which changes the weights' pattern, not the system's size
  or kind;
- LLW affinities exactly as `multigrid/llw.rs`: c_r = max(0.6·var_r, min_s (Y_r−Y_s)²/ln 100,
  2·10⁻⁶) over the voxel and its face neighbours, a_rs = exp(−(Y_r−Y_s)²/½(c_r+c_s));
- unknowns: every voxel but the pins (the whole box is cloud: ρ ≥ 1 % of the maximum
  everywhere), pins = two painted blobs (our benchmark's `cumulus_pins`: warm at (0.35, 0.3,
  0.45), r² < 0.004; cool at (0.65, 0.4, 0.55), r² < 0.003, in box units) as Dirichlet values;
- the graph Laplacian Σ_s a_rs (U_r − U_s) = 0 with the pins moved to the right-hand side
  (symmetric positive definite), three channels sharing one hierarchy, each solved to a relative
  residual of 10⁻⁶ (ours: the same tolerance, `SolveOptions::default()`).
Solver: `pyamg.ruge_stuben_solver` (classical AMG, default strength and splitting), then
`ml.solve(b, tol=1e-6, accel="cg")` per channel.

Timed in-process: `system` (guide → weights → CSR matrix), `setup` (the AMG hierarchy), `solve`
(3 channels); `propagate` = system + setup + solve is the figure compared with ours (whose
`propagate` builds the weights, the hierarchy and solves).
"""

import json
import sys
import time

import numpy as np
import pyamg
import scipy.sparse as sp


def guide_of(rho: np.ndarray) -> np.ndarray:
    """Sun transmittance from straight above (axis 1 = y, up), κ for a median column depth 4."""
    n = rho.shape[1]
    col = rho.sum(axis=1) / n
    lit = col[col > 0.01 * col.max()]
    kappa = 4.0 / float(np.median(lit))
    depth = np.cumsum(rho[:, ::-1, :], axis=1)[:, ::-1, :] / n - rho / (2 * n)
    return np.exp(-kappa * depth).astype(np.float32)


def llw_weights(y: np.ndarray):
    """Affinities of the +x, +y, +z edges (arrays one shorter along their axis)."""
    ln100 = np.float32(np.log(100.0))
    s, s2 = y.copy(), y * y
    cnt = np.ones_like(y)
    mind2 = np.full_like(y, np.inf)
    for ax in range(3):
        for sh in (1, -1):
            nb = np.roll(y, sh, axis=ax)
            valid = np.ones_like(y, dtype=bool)
            idx = [slice(None)] * 3
            idx[ax] = 0 if sh == 1 else -1
            valid[tuple(idx)] = False
            s += np.where(valid, nb, 0)
            s2 += np.where(valid, nb * nb, 0)
            cnt += valid
            mind2 = np.minimum(mind2, np.where(valid, (nb - y) ** 2, np.inf))
    mean = s / cnt
    var = np.maximum(s2 / cnt - mean * mean, 0)
    c = np.maximum(np.maximum(0.6 * var, np.where(np.isfinite(mind2), mind2 / ln100, 0)), 2e-6)
    out = []
    for ax in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[ax], b[ax] = slice(0, -1), slice(1, None)
        d = y[tuple(b)] - y[tuple(a)]
        out.append(np.exp(-d * d / (0.5 * (c[tuple(a)] + c[tuple(b)]))))
    return out


def pins_of(shape):
    nz, ny, nx = shape
    z, yy, x = np.meshgrid(np.arange(nz) / nz, np.arange(ny) / ny, np.arange(nx) / nx,
                           indexing="ij")
    d1 = (x - 0.35) ** 2 + (yy - 0.3) ** 2 + (z - 0.45) ** 2
    d2 = (x - 0.65) ** 2 + (yy - 0.4) ** 2 + (z - 0.55) ** 2
    color = np.zeros(shape + (3,), dtype=np.float64)
    warm, cool = d1 < 0.004, (d1 >= 0.004) & (d2 < 0.003)
    color[warm] = [0.9, 0.5, 0.3]
    color[cool] = [0.2, 0.3, 0.8]
    return warm | cool, color


def system(rho: np.ndarray):
    y = guide_of(rho)
    w = llw_weights(y)
    shape = rho.shape
    n = rho.size
    pinned, color = pins_of(shape)
    idx = np.arange(n).reshape(shape)
    rows, cols, vals = [], [], []
    for ax in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[ax], b[ax] = slice(0, -1), slice(1, None)
        i, j, v = idx[tuple(a)].ravel(), idx[tuple(b)].ravel(), w[ax].ravel().astype(np.float64)
        rows += [i, j]
        cols += [j, i]
        vals += [v, v]
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    full = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    deg = np.asarray(full.sum(axis=1)).ravel()
    free = ~pinned.ravel()
    fi = np.flatnonzero(free)
    a_ff = full[fi][:, fi]
    a_fp = full[fi][:, np.flatnonzero(~free)]
    lap = (sp.diags(deg[fi]) - a_ff).tocsr()
    b = a_fp @ color.reshape(n, 3)[~free]
    return lap, b


def main():
    rho = np.load(sys.argv[1]).astype(np.float32)
    times = {}
    t = time.perf_counter()
    lap, b = system(rho)
    times["system"] = time.perf_counter() - t
    t = time.perf_counter()
    ml = pyamg.ruge_stuben_solver(lap)
    times["setup"] = time.perf_counter() - t
    t = time.perf_counter()
    iters = []
    for ch in range(3):
        res = []
        x = ml.solve(b[:, ch], tol=1e-6, accel="cg", residuals=res)
        rel = np.linalg.norm(b[:, ch] - lap @ x) / np.linalg.norm(b[:, ch])
        iters.append(len(res) - 1)
        assert rel <= 1e-5, rel
    times["solve"] = time.perf_counter() - t
    times["propagate"] = times["system"] + times["setup"] + times["solve"]
    times["unknowns"] = int(lap.shape[0])
    times["levels"] = len(ml.levels)
    times["iterations"] = iters
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in times.items()}))
    if len(sys.argv) > 2:
        json.dump(times, open(sys.argv[2], "w"))


if __name__ == "__main__":
    main()
