#!/usr/bin/python3
"""Derived OpenVDB fog volumes from held-out NRRDs, with Debian's python3-openvdb (pyopenvdb).

Run with Debian's /usr/bin/python3 (python3-openvdb + python3-numpy):  make_vdb.py OUT/volume
Each grid: FloatGrid named `density`, class FOG_VOLUME, background 0, voxels whose value is 0
left inactive (copyFromArray, tolerance 0), voxel size = the NRRD spacing (uniform only), no
other change of values than the stated normalisation.  README lines are appended by fetch.sh.
"""
import gzip, sys
import numpy as np
import pyopenvdb as vdb

D = sys.argv[1]
T = {"uint8": "u1", "int16": "i2", "uint16": "u2", "float": "f4"}


def read_nrrd(p):
    b = open(p, "rb").read()
    i = b.index(b"\n\n")
    h = dict(l.split(": ", 1) for l in b[:i].decode().splitlines()[1:] if ": " in l)
    d = b[i + 2:]
    if h["encoding"] == "gzip":
        d = gzip.decompress(d)
    e = ">" if h.get("endian") == "big" else "<"
    sz = [int(v) for v in h["sizes"].split()]
    a = np.frombuffer(d, e + T[h["type"]]).reshape(sz[::-1]).transpose(2, 1, 0)  # -> [x, y, z]
    sp = [float(v) for v in h["spacings"].split()]
    return a, sp


for src, dst, scale, what in [
    ("volpack_brainsmall.nrrd", "volpack_brainsmall_fog.vdb", 1 / 255.0, "value/255"),
    ("frog_body_mask_u8.nrrd", "frog_body_mask_fog.vdb", 1 / 255.0, "mask/255 (0 or 1)"),
    ("inia19_macaque_t1.nrrd", "inia19_macaque_t1_fog.vdb", None, "value/max"),
]:
    a, sp = read_nrrd(f"{D}/{src}")
    a = a.astype(np.float32)
    if scale is None:
        scale = 1.0 / float(a.max())
    a = np.ascontiguousarray(a * np.float32(scale))
    g = vdb.FloatGrid(background=0.0)
    g.copyFromArray(a, tolerance=0.0)
    g.name = "density"
    g.gridClass = vdb.GridClass.FOG_VOLUME
    if len(set(sp)) == 1:
        g.transform = vdb.createLinearTransform(voxelSize=sp[0])
    else:
        g.transform = vdb.createLinearTransform(np.diag(sp + [1.0]).tolist())
    vdb.write(f"{D}/{dst}", grids=[g])
    print(f"{dst}\t{src}\t{what}\t{g.activeVoxelCount()} active voxels, bbox {g.evalActiveVoxelBoundingBox()}")
