#!/usr/bin/env python3
"""Snow probability with trimesh + Embree per-vertex rays: the peer of our `probability` stage
(`phenomena render snow-cover --set directions=64`, report.json → timings → probability; issue 19).

    python3 scripts/peers/probability_embree.py MESH.obj [K] [TIMES.json]

The same quantity as ours (SPEC §2 step 2, `engine/src/snow_cover/probability.rs`): K snowfall
directions drawn around straight down from a 2-D normal distribution of angular offsets
(standard deviation 10° per axis, clamped at 85° from vertical, seeded), and per surface point
P = the share of the directions from which the point is lit, i.e. not shadowed by the scene.
Here the points are the mesh's vertices (offset by 10⁻⁴ of the diagonal along the vertex normal)
and each (vertex, direction) is one ray towards the sky tested with Embree (`embreex`, through
trimesh's `RayMeshIntersector.intersects_any`, batched over all rays). Ours tests the cells of
its layered snow maps (default 512² per layer) against K rasterised shadow maps instead.

Timed: reading the OBJ (trimesh), building Embree's BVH, the rays, the mean per vertex; the
figure compared with ours is `rays` + `bvh` (the in-process probability), the whole process is
timed from outside.
"""

import json
import sys
import time

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector


def directions(k: int, spread_deg: float = 10.0, seed: int = 0) -> np.ndarray:
    """K unit vectors along which the snow travels (Y up), around straight down."""
    rng = np.random.default_rng(seed)
    a = np.radians(rng.normal(0.0, spread_deg, size=(k, 2)))
    tilt = np.minimum(np.hypot(a[:, 0], a[:, 1]), np.radians(85.0))
    az = np.arctan2(a[:, 1], a[:, 0])
    return np.c_[np.sin(tilt) * np.cos(az), -np.cos(tilt), np.sin(tilt) * np.sin(az)]


def main():
    path = sys.argv[1]
    k = int(sys.argv[2]) if len(sys.argv) > 2 else 64
    times = {}
    t0 = time.perf_counter()
    mesh = trimesh.load(path, force="mesh", process=False)
    times["read"] = time.perf_counter() - t0
    t = time.perf_counter()
    rmi = RayMeshIntersector(mesh)
    rmi.intersects_any(np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]]))  # builds the BVH
    times["bvh"] = time.perf_counter() - t
    t = time.perf_counter()
    eps = 1e-4 * float(np.linalg.norm(mesh.extents))
    origins = mesh.vertices + eps * mesh.vertex_normals
    n = len(origins)
    lit = np.zeros(n, dtype=np.int32)
    for d in directions(k):
        hit = rmi.intersects_any(origins, np.broadcast_to(-d, (n, 3)))
        lit += ~hit
    p = lit / k
    times["rays"] = time.perf_counter() - t
    times["probability"] = times["bvh"] + times["rays"]
    times["total"] = time.perf_counter() - t0
    times["vertices"] = n
    times["rays_per_s"] = n * k / times["rays"]
    times["mean_p"] = float(p.mean())
    print(json.dumps({a: (round(b, 4) if isinstance(b, float) else b) for a, b in times.items()}))
    if len(sys.argv) > 3:
        json.dump(times, open(sys.argv[3], "w"))


if __name__ == "__main__":
    main()
