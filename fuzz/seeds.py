#!/usr/bin/env python3
"""Seed corpora for the fuzz targets: small real files from ../../shared/data (when present)
plus tiny files of every format written here (no third-party modules). Idempotent; writes
fuzz/corpus/<target>/. Run by fuzz/run.sh."""
import gzip, json, os, shutil, struct, zlib

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data")
CORPUS = os.path.join(HERE, "corpus")


def put(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def copy(target, rel):
    p = os.path.join(DATA, rel)
    if os.path.exists(p):
        with open(p, "rb") as f:
            put(target, os.path.basename(rel), f.read())


def npy(shape, values):
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (%s), }" % (
        ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else ""))
    pad = 64 - (10 + len(header) + 1) % 64
    header = header + " " * pad + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + struct.pack(
        "<%df" % len(values), *values)


def png16(w, h):
    raw = b"".join(b"\0" + b"".join(struct.pack(">H", (x * 977 + y * 131) % 65536) for x in range(w))
                   for y in range(h))
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


grid = [float((x - 4) ** 2 + (y - 4) ** 2) for y in range(8) for x in range(8)]
vol = [max(0.0, 1.0 - ((x - 2) ** 2 + (y - 2) ** 2 + (z - 2) ** 2) / 4.0)
       for z in range(5) for y in range(5) for x in range(5)]

# DEMs
copy("dem_geotiff", "dem/luxembourg_elev.tif")
copy("dem_geotiff", "dem/olinda_dem_utm25s.tif")
copy("dem_asc", "dem/maunga_whau_volcano.asc")
put("dem_asc", "tiny.asc", b"ncols 4\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n"
    b"1 2 3 4\n5 6 -9999 8\n9 10 11 12\n")
put("dem_hgt", "short.hgt", struct.pack(">64h", *range(64)))
put("dem_png", "tiny16.png", png16(8, 8))
put("dem_npy", "tiny.npy", npy((8, 8), grid))

# Meshes
copy("mesh_gltf", "mesh/inventor_table.glb")
copy("mesh_obj", "mesh/teapot_npm.obj")
put("mesh_obj", "tet.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
tet = [((0, 0, 0), (1, 0, 0), (0, 1, 0)), ((0, 0, 0), (1, 0, 0), (0, 0, 1)),
       ((0, 0, 0), (0, 1, 0), (0, 0, 1)), ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
put("mesh_stl", "tet_binary.stl", b"\0" * 80 + struct.pack("<I", len(tet)) + b"".join(
    struct.pack("<12fH", 0, 0, 0, *a, *b, *c, 0) for a, b, c in tet))
put("mesh_stl", "tet_ascii.stl", ("solid t\n" + "".join(
    "facet normal 0 0 0\nouter loop\n" + "".join("vertex %g %g %g\n" % v for v in t) + "endloop\nendfacet\n"
    for t in tet) + "endsolid t\n").encode())
verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
faces = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]
head = "ply\nformat %s 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n" \
       "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
put("mesh_ply", "tet_ascii.ply", (head % "ascii" + "".join("%g %g %g\n" % v for v in verts)
                                  + "".join("3 %d %d %d\n" % f for f in faces)).encode())
put("mesh_ply", "tet_binary.ply", (head % "binary_little_endian").encode()
    + b"".join(struct.pack("<3f", *v) for v in verts) + b"".join(struct.pack("<B3i", 3, *f) for f in faces))

# Volumes
copy("volume_vdb", "volume/bunny_fog_density.vdb")
put("volume_npy", "ball.npy", npy((5, 5, 5), vol))
raw = struct.pack("<%df" % len(vol), *vol)
nh = "NRRD0004\ntype: float\ndimension: 3\nsizes: 5 5 5\nendian: little\nencoding: %s\n\n"
put("volume_nrrd", "ball_raw.nrrd", (nh % "raw").encode() + raw)
put("volume_nrrd", "ball_gzip.nrrd", (nh % "gzip").encode() + gzip.compress(raw))
put("volume_raw", "ball.raw", bytes([4, 4, 4]) + raw)  # dims byte % 64 + 1 = 5

# Params and whole requests
for i, p in enumerate([{}, {"width": 64, "height": 48, "camera": {"azimuth_deg": 10}},
                       {"camera": {"eye": [1, 2, 3], "target": [0, 0, 0]}, "sweep": {"param": "b", "values": [0, 1]}},
                       {"kappa": 50, "sun_color": [1, 1, 1], "layers": ["direct"]},
                       {"resolution": 64, "directions": 4, "wind": {"azimuth_deg": 90, "tilt_deg": 10}}]):
    put("params_json", "p%d.json" % i, json.dumps(p).encode())
asc = open(os.path.join(CORPUS, "dem_asc", "tiny.asc"), "rb").read()
put("multipart", "form.txt", b"--fuzzboundary\r\nContent-Disposition: form-data; name=\"params\"\r\n"
    b"Content-Type: application/json\r\n\r\n{\"width\": 64}\r\n--fuzzboundary\r\n"
    b"Content-Disposition: form-data; name=\"dem\"; filename=\"x.asc\"\r\n\r\n" + asc
    + b"\r\n--fuzzboundary--\r\n")
put("multipart", "json.txt", json.dumps({"asset": "0" * 64, "params": {"width": 64}}).encode())
