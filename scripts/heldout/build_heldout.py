#!/usr/bin/env python3
"""Build /work/heldout/{mesh,volume,dem} from unpacked registry packages.

Called by fetch.sh:  build_heldout.py SRC OUT [mesh|volume|dem ...]
SRC holds x/<debian-package>/ (dpkg-deb -x), w/<wheel-name>/ (unzipped wheels),
pyflwdir-<v>/ (sdist), npm/<pkg>-<v>.tgz.  Every step is deterministic; existing
outputs are overwritten.  Each conversion is described in the README lines below.
"""
import base64, gzip, io, json, math, os, re, shutil, sys, tarfile, zipfile, zlib
import numpy as np
import warnings
warnings.filterwarnings("ignore")  # rdata warns about every R class it has no constructor for

SRC, OUT = sys.argv[1], sys.argv[2]
PARTS = sys.argv[3:] or ["mesh", "volume", "dem"]
X = os.path.join(SRC, "x")
W = os.path.join(SRC, "w")
ASSIMP = f"{X}/assimp-testmodels/usr/share/assimp/models"
OCCT = f"{X}/occt-misc/usr/share/opencascade/data/stl"
SCAD = f"{X}/openscad-testing-data/usr/share/openscad/testdata"
SH3D = f"{X}/sweethome3d-furniture/usr/share/sweethome3d/furniture"
PYMESHLAB = f"{W}/pymeshlab/pymeshlab-2025.7.post1.data/purelib/pymeshlab/tests/sample_meshes"
PYVISTA = f"{W}/pyvista/pyvista/examples"
MRICRON = f"{X}/mricron-data/usr/share/mricron/templates"

V = {  # versions, must match fetch.sh
    "assimp-testmodels": "5.2.5~ds0-1", "occt-misc": "7.6.3+dfsg1-7",
    "openscad-testing-data": "2021.01-6", "libcgal-demo": "5.5.1-2",
    "sweethome3d-furniture": "1.8-1", "mricron-data": "1.2.20211006+dfsg-4",
    "libvolpack1-dev": "1.0b3-9", "ferret-datasets": "7.6.0-5",
    "r-cran-spatstat.data": "3.0-0-1", "r-cran-fields": "14.1-1",
    "pymeshlab": "2025.7.post1", "pyvista": "0.49.2", "matplotlib": "3.11.2",
    "lidar": "0.8.4", "nibabel": "5.4.2", "dipy": "1.12.1", "pydicom-data": "1.0.0",
    "pyflwdir": "0.5.12", "nilearn": "0.14.1", "teapot": "1.0.0", "bunny": "1.0.1", "trimesh": "5.2.0",
}
rows = {"mesh": [], "volume": [], "dem": []}


def row(kind, name, source, path, licence, conversion="none (unmodified copy)"):
    rows[kind].append(f"| `{name}` | {source} | `{path}` | {licence} | {conversion} |")


def ensure(d):
    os.makedirs(d, exist_ok=True)
    return d


def copy(src, dst):
    if not os.path.isfile(src):
        sys.exit(f"build_heldout: missing source file {src}")
    shutil.copyfile(src, dst)


# ----------------------------------------------------------------------------- meshes
def meshes():
    import trimesh
    M = ensure(os.path.join(OUT, "mesh"))
    deb = lambda p: f"Debian `{p}` {V[p]}"
    A = deb("assimp-testmodels")
    # assimp-testmodels
    copy(f"{ASSIMP}/PLY/Wuson.ply", f"{M}/assimp_wuson.ply")
    row("mesh", "assimp_wuson.ply", A, "/usr/share/assimp/models/PLY/Wuson.ply", "BSD-3-Clause (assimp)")
    d = ensure(f"{M}/assimp_spider")
    for f in ["spider.obj", "spider.mtl", "SpiderTex.jpg", "drkwood2.jpg", "engineflare1.jpg",
              "wal67ar_small.jpg", "wal69ar_small.jpg"]:
        copy(f"{ASSIMP}/OBJ/{f}", f"{d}/{f}")
    row("mesh", "assimp_spider/ (spider.obj, .mtl, 5 JPEGs)", A, "/usr/share/assimp/models/OBJ/spider.{obj,mtl} + JPEGs beside", "BSD-3-Clause (assimp)")
    copy(f"{ASSIMP}/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb", f"{M}/khronos_boxtextured.glb")
    row("mesh", "khronos_boxtextured.glb", A, "/usr/share/assimp/models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb", "CC-BY-4.0 (Khronos glTF sample models, (c) Cesium)")
    copy(f"{ASSIMP}/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb", f"{M}/khronos_2cylinderengine.glb")
    row("mesh", "khronos_2cylinderengine.glb", A, "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb", "CC-BY-4.0 (Khronos glTF sample models, (c) Cesium)")
    # KIT FZK-Haus IFC -> GLB with Debian assimp-utils (the project reads no IFC)
    import subprocess
    assimp = shutil.which("assimp")
    if not assimp:
        sys.exit("build_heldout: `assimp` (Debian assimp-utils) not on PATH")
    subprocess.run([assimp, "export", f"{ASSIMP}/IFC/AC14-FZK-Haus.ifc", f"{M}/fzk_haus.glb", "-fglb2"], check=True,
                   stdout=subprocess.DEVNULL)
    row("mesh", "fzk_haus.glb", A, "/usr/share/assimp/models/IFC/AC14-FZK-Haus.ifc (+ AC14-FZK-Haus.source.txt)",
        "KIT/IAI: \"used with permission and fine to redistribute\", attribution KIT/IAI requested",
        "IFC → GLB 2.0 with Debian `assimp-utils` 5.2.5~ds0-1+b1: `assimp export AC14-FZK-Haus.ifc fzk_haus.glb -fglb2` (200 meshes, 32,588 triangles, material colours)")
    # OCCT CAD / scan STLs
    for n in ["motor", "propeller", "video_part", "bearing", "head", "shape"]:
        copy(f"{OCCT}/{n}.stl", f"{M}/occt_{n}.stl")
        row("mesh", f"occt_{n}.stl", deb("occt-misc"), f"/usr/share/opencascade/data/stl/{n}.stl", "LGPL-2.1 with OCCT exception (Open CASCADE sample data)")
    copy(f"{SCAD}/stl/adns2610_dev_circuit_inv.stl", f"{M}/openscad_adns2610_dev_circuit_inv.stl")
    row("mesh", "openscad_adns2610_dev_circuit_inv.stl", deb("openscad-testing-data"), "/usr/share/openscad/testdata/stl/adns2610_dev_circuit_inv.stl", "GPL-2+ (OpenSCAD test data)")
    # CGAL data (OFF -> binary PLY, the project reads no OFF)
    cg = f"{X}/libcgal-demo/usr/share/doc/libcgal-dev/data.tar.gz"
    with tarfile.open(cg) as t:
        for off, name in [("bunny00.off", "bunny00.ply"), ("armadillo.off", "cgal_armadillo.ply"),
                          ("refined_elephant.off", "cgal_refined_elephant.ply"),
                          ("fandisk.off", "cgal_fandisk.ply"), ("ChineseDragon-10kv.off", "cgal_chinese_dragon_10kv.ply"),
                          ("blade.off", "cgal_blade.ply"), ("femur.off", "cgal_femur.ply"),
                          ("camel.off", "cgal_camel.ply"), ("turbine.off", "cgal_turbine.ply")]:
            data = t.extractfile(f"data/meshes/{off}").read()
            m = trimesh.load(io.BytesIO(data), file_type="off", process=False)
            m.export(f"{M}/{name}", file_type="ply", encoding="binary")
            row("mesh", name, deb("libcgal-demo"), f"/usr/share/doc/libcgal-dev/data.tar.gz → data/meshes/{off}",
                "CGAL data (GPL-3+/LGPL-3+ package; models from their authors, e.g. Stanford 3D Scanning Repository for bunny/armadillo)",
                f"OFF → binary little-endian PLY with trimesh {V['trimesh']} (process=False: vertices kept in order, polygons fan-triangulated); {len(m.vertices)} v / {len(m.faces)} tris")
        open(f"{M}/cgal_pig.stl", "wb").write(t.extractfile("data/meshes/pig.stl").read())
        row("mesh", "cgal_pig.stl", deb("libcgal-demo"), "/usr/share/doc/libcgal-dev/data.tar.gz → data/meshes/pig.stl", "CGAL data (GPL-3+/LGPL-3+)")
    # Sweet Home 3D furniture (OBJ + MTL + textures, one folder each)
    for arch, top, lic, names in [
        ("BlendSwap-CC-0.sh3f", "blendswap-cc-0", "CC0-1.0 (Blend Swap, creator named in the folder's licence file)",
         ["table", "bookcase", "childHut", "deer", "rock2", "bench", "oakChair", "shippingContainer",
          "woodToy", "cartoon_biplane", "peterbilt"]),
        ("BlendSwap-CC-BY.sh3f", "blendswap-cc-by", "CC-BY (Blend Swap, creator named in the folder's licence file)",
         ["rowboat", "piano"])]:
        with zipfile.ZipFile(f"{SH3D}/{arch}") as z:
            for n in names:
                d = ensure(f"{M}/sh3d_{n}")
                members = [i for i in z.namelist() if i.startswith(f"{top}/{n}/") and not i.endswith("/")]
                if not members:
                    sys.exit(f"build_heldout: {n} not in {arch}")
                for i in members:
                    base = os.path.basename(i)
                    if base.endswith("LICENSE.html"):
                        base = "LICENSE.html"
                    open(f"{d}/{base}", "wb").write(z.read(i))
                row("mesh", f"sh3d_{n}/ ({n}.obj + mtl + textures + licence)", deb("sweethome3d-furniture"),
                    f"/usr/share/sweethome3d/furniture/{arch} (zip) → {top}/{n}/", lic,
                    "none (files copied; a licence named `NNNNN - LICENSE.html` renamed LICENSE.html)")
    # pymeshlab sample meshes
    pm = f"PyPI `pymeshlab` {V['pymeshlab']} wheel (cp311 manylinux)"
    pmp = "pymeshlab/tests/sample_meshes/"
    d = ensure(f"{M}/bunny10k_textured")
    for f in ["bunny10k_textured.obj", "bunny10k_textured.mtl", "TextureDouble_A.png"]:
        copy(f"{PYMESHLAB}/{f}", f"{d}/{f}")
    row("mesh", "bunny10k_textured/ (obj, mtl, TextureDouble_A.png)", pm, pmp + "bunny10k_textured.{obj,mtl}, TextureDouble_A.png", "GPL-3.0 (pymeshlab package; test data)")
    scene = trimesh.load(f"{d}/bunny10k_textured.obj", process=False)
    g = scene if isinstance(scene, trimesh.Trimesh) else trimesh.util.concatenate(list(scene.geometry.values()))
    tri = len(g.faces)
    scene.export(f"{M}/bunny10k_textured.glb", file_type="glb")
    chk = trimesh.load(f"{M}/bunny10k_textured.glb", process=False)
    chk = chk if isinstance(chk, trimesh.Trimesh) else trimesh.util.concatenate(list(chk.geometry.values()))
    if len(chk.faces) != tri or tri != 9999:
        sys.exit(f"build_heldout: bunny10k GLB has {len(chk.faces)} triangles (OBJ {tri}), expected 9999")
    row("mesh", "bunny10k_textured.glb", pm, pmp + "bunny10k_textured.obj + .mtl + TextureDouble_A.png", "GPL-3.0 (pymeshlab package; test data)",
        f"OBJ+MTL+PNG → GLB with trimesh {V['trimesh']} (`trimesh.load(obj, process=False).export(glb)`): 9,999 triangles (no decimation), UVs kept, the PNG embedded as baseColorTexture; vertices split at UV seams by trimesh")
    for f, name in [("cow.obj", "pymeshlab_cow.obj"), ("bone.ply", "pymeshlab_bone_vcolor.ply"),
                    ("airplane.obj", "pymeshlab_airplane.obj"), ("colored_airplane.ply", "pymeshlab_colored_airplane.ply"),
                    ("rangemaps/face000.ply", "pymeshlab_face000_rangemap.ply"), ("bunny.obj", "pymeshlab_bunny.obj")]:
        copy(f"{PYMESHLAB}/{f}", f"{M}/{name}")
        row("mesh", name, pm, pmp + f, "GPL-3.0 (pymeshlab package; test data)")
    for f in ["ant.ply", "airplane.ply", "nut.ply"]:
        copy(f"{PYVISTA}/{f}", f"{M}/pyvista_{f}")
        row("mesh", f"pyvista_{f}", f"PyPI `pyvista` {V['pyvista']} wheel", f"pyvista/examples/{f}", "MIT (pyvista)")
    # npm JSON meshes -> OBJ
    for pkg, js, name, lic in [("bunny", "index.js", "bunny_npm.obj", "public domain (Stanford bunny; npm package MIT)"),
                               ("teapot", "teapot.js", "teapot_npm.obj", "public domain (Utah teapot; npm package MIT)")]:
        with tarfile.open(f"{SRC}/npm/{pkg}-{V[pkg]}.tgz") as t:
            txt = t.extractfile(f"package/{js}").read().decode()
        pos = json.loads(re.search(r"positions\s*=\s*(\[.*?\]\])", txt, re.S).group(1))
        cells = json.loads(re.search(r"cells\s*=\s*(\[.*?\]\])", txt, re.S).group(1))
        with open(f"{M}/{name}", "w") as o:
            o.write(f"# {pkg}@{V[pkg]} (npm) package/{js}, converted to OBJ\n")
            for p in pos:
                o.write("v %r %r %r\n" % tuple(p))
            for c in cells:
                o.write("f " + " ".join(str(i + 1) for i in c) + "\n")
        row("mesh", name, f"npm `{pkg}` {V[pkg]}", f"package/{js}", lic,
            f"JS arrays `positions`/`cells` → OBJ `v`/`f` lines (1-based), values unchanged; {len(pos)} v / {len(cells)} faces")


# ----------------------------------------------------------------------------- volumes
def write_nrrd(path, arr_xyz_fortran, spacings=(1, 1, 1), gzip_enc=True, content=""):
    """arr indexed [x, y, z]; written x fastest."""
    a = np.asarray(arr_xyz_fortran)
    tmap = {"u1": "uint8", "i1": "int8", "u2": "uint16", "i2": "int16", "u4": "uint32", "i4": "int32",
            "f4": "float", "f8": "double"}
    t = tmap[a.dtype.kind + str(a.dtype.itemsize)]
    endian = "big" if a.dtype.byteorder == ">" else "little"
    data = a.ravel(order="F").tobytes()
    hdr = ["NRRD0004", f"# {content}" if content else None, f"type: {t}", "dimension: 3",
           "sizes: %d %d %d" % a.shape, "spacings: %s %s %s" % tuple(repr(float(s)) for s in spacings),
           f"encoding: {'gzip' if gzip_enc else 'raw'}"]
    if a.dtype.itemsize > 1:
        hdr.append(f"endian: {endian}")
    with open(path, "wb") as f:
        f.write(("\n".join(h for h in hdr if h is not None) + "\n\n").encode())
        f.write(gzip.compress(data, 6, mtime=0) if gzip_enc else data)


def read_vti(path):
    """VTK XML ImageData with one UInt8/Int64 array, zlib-compressed, inline base64 or appended."""
    txt = open(path, "rb").read()
    head = txt[: txt.find(b"<AppendedData")] if b"<AppendedData" in txt else txt
    ext = [int(v) for v in re.search(rb'WholeExtent="([^"]+)"', txt).group(1).split()]
    spacing = [float(v) for v in re.search(rb'Spacing="([^"]+)"', txt).group(1).split()]
    m = re.search(rb'<DataArray type="(\w+)"[^>]*format="(\w+)"[^>]*>', head)
    dtype = {b"UInt8": np.uint8, b"Int64": np.int64}[m.group(1)]
    cell = b"<CellData" in head[: m.start()] and head.rfind(b"<CellData", 0, m.start()) > head.rfind(b"</CellData", 0, m.start())
    if m.group(2) == b"binary":
        body = head[m.end(): head.find(b"</DataArray>", m.end())].strip()
        n = np.frombuffer(base64.b64decode(body[:16]), "<u4")[0]
        hl = ((3 + n) * 4 + 2) // 3 * 4
        hdr = np.frombuffer(base64.b64decode(body[:hl]), "<u4")
        raw = base64.b64decode(body[hl:])
    else:
        off = int(re.search(rb'offset="\s*(\d+)', m.group(0)).group(1))
        ad = txt.find(b"<AppendedData")
        enc = re.search(rb'encoding="(\w+)"', txt[ad:ad + 100]).group(1)
        start = txt.find(b"_", ad) + 1 + off
        if enc == b"base64":  # one array only: header and blocks base64-encoded separately
            body = txt[start:txt.find(b"</AppendedData", start)].strip()
            n = np.frombuffer(base64.b64decode(body[:16]), "<u4")[0]
            hl = ((3 + n) * 4 + 2) // 3 * 4
            hdr = np.frombuffer(base64.b64decode(body[:hl]), "<u4")
            raw = base64.b64decode(body[hl:])
        else:
            n = np.frombuffer(txt[start:start + 4], "<u4")[0]
            hdr = np.frombuffer(txt[start:start + 4 * (3 + n)], "<u4")
            raw = txt[start + 4 * (3 + n):]
    n = hdr[0]
    sizes = hdr[3:3 + n]
    out, p = [], 0
    for s in sizes:
        out.append(zlib.decompress(raw[p:p + s]))
        p += s
    a = np.frombuffer(b"".join(out), dtype)
    dims = [ext[1] - ext[0] + 1, ext[3] - ext[2] + 1, ext[5] - ext[4] + 1]
    if cell:
        dims = [d - 1 for d in dims]
    return a.reshape(dims, order="F"), spacing


def volumes():
    import nibabel as nib
    Vd = ensure(os.path.join(OUT, "volume"))
    # pyvista frog
    lab, sp = read_vti(f"{PYVISTA}/frog_tissues.vti")
    assert lab.shape == (500, 470, 136), lab.shape
    pv = f"PyPI `pyvista` {V['pyvista']} wheel"
    write_nrrd(f"{Vd}/frog_body_mask_u8.nrrd", np.where(lab > 0, 255, 0).astype(np.uint8), sp, content="frog body mask: all tissue labels > 0 -> 255")
    row("volume", "frog_body_mask_u8.nrrd", pv, "pyvista/examples/frog_tissues.vti", "MIT (pyvista); data Whole Frog Project (LBL)",
        "VTI (zlib, base64) decoded in Python; mask = label > 0 → 255 else 0; 500×470×136 uint8, spacings 1 1 1.5, gzip NRRD")
    write_nrrd(f"{Vd}/frog_tissue_labels_u8.nrrd", lab.astype(np.uint8), sp, content="frog tissue labels 0..29")
    row("volume", "frog_tissue_labels_u8.nrrd", pv, "pyvista/examples/frog_tissues.vti", "MIT (pyvista); data Whole Frog Project (LBL)",
        "VTI decoded; tissue labels 0–29 unchanged; 500×470×136 uint8, gzip NRRD")
    ch, sp = read_vti(f"{PYVISTA}/channels.vti")
    write_nrrd(f"{Vd}/pyvista_channels_facies_u8.nrrd", ch.astype(np.uint8), sp, content="channels facies 0..4")
    row("volume", "pyvista_channels_facies_u8.nrrd", pv, "pyvista/examples/channels.vti", "MIT (pyvista)",
        f"VTI (appended base64, zlib) decoded; cell array `facies` int64 0–4 → uint8 (values unchanged); {'×'.join(map(str, ch.shape))}, gzip NRRD")
    # NIfTI volumes
    def nii(src, name, srcdesc, path, lic, mask=False):
        img = nib.load(src)
        a = np.asarray(img.dataobj.get_unscaled())
        while a.ndim > 3:
            a = a[..., 0]
        zooms = img.header.get_zooms()[:3]
        slope, inter = img.dataobj.slope, img.dataobj.inter
        if mask:
            a = np.where(a > 0, 255, 0).astype(np.uint8)
            conv = f"NIfTI → NRRD with nibabel: mask = value > 0 → 255; {'×'.join(map(str, a.shape))} uint8, gzip"
        else:
            conv = (f"NIfTI → NRRD with nibabel: stored values and type unchanged ({a.dtype.str}), x fastest; {'×'.join(map(str, a.shape))}"
                    + ("" if (slope in (1.0, None) and inter in (0.0, None)) else f"; NIfTI scl_slope {slope} / scl_inter {inter} not applied"))
        write_nrrd(f"{Vd}/{name}", a, zooms, gzip_enc=a.nbytes > 200000)
        row("volume", name, srcdesc, path, lic, conv + f"; spacings {tuple(round(float(z), 4) for z in zooms)}")
    mri = f"Debian `mricron-data` {V['mricron-data']}"
    nii(f"{MRICRON}/ch2bet.nii.gz", "colin27_brain_mask_u8.nrrd", mri, "/usr/share/mricron/templates/ch2bet.nii.gz", "BSD-3-Clause (MRIcron)", mask=True)
    nii(f"{MRICRON}/ch2.nii.gz", "colin27_t1_head.nrrd", mri, "/usr/share/mricron/templates/ch2.nii.gz", "BSD-3-Clause (MRIcron)")
    nii(f"{MRICRON}/inia19-t1-brain.nii.gz", "inia19_macaque_t1.nrrd", mri, "/usr/share/mricron/templates/inia19-t1-brain.nii.gz", "BSD-3-Clause (MRIcron; INIA19 template)")
    nii(f"{MRICRON}/aal.nii.gz", "aal_labels.nrrd", mri, "/usr/share/mricron/templates/aal.nii.gz", "BSD-3-Clause (MRIcron; AAL atlas)")
    nii(f"{W}/nibabel/nibabel/tests/data/anatomical.nii", "nibabel_anatomical_i16be.nrrd", f"PyPI `nibabel` {V['nibabel']} wheel",
        "nibabel/tests/data/anatomical.nii", "MIT (nibabel)")
    nii(f"{W}/dipy/dipy/data/files/aniso_vox.nii.gz", "dipy_aniso_vox_t1_i16.nrrd", f"PyPI `dipy` {V['dipy']} wheel (cp311)",
        "dipy/data/files/aniso_vox.nii.gz", "BSD-3-Clause (dipy)")
    nl = f"{W}/nilearn/nilearn/datasets/data"
    for f, name in [("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz", "mni152_2009a_t1.nrrd"),
                    ("mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz", "mni152_2009a_gm_probability.nrrd")]:
        nii(f"{nl}/{f}", name, f"PyPI `nilearn` {V['nilearn']} wheel", f"nilearn/datasets/data/{f}",
            "BSD-3-Clause (nilearn); MNI ICBM152 2009a template (c) McConnell Brain Imaging Centre, redistribution permitted with its notice")
    # VolPack brainsmall.den
    p = f"{X}/libvolpack1-dev/usr/share/doc/libvolpack1-dev/examples/brainsmall.den"
    b = open(p, "rb").read()
    for e in "<>":
        if np.frombuffer(b[:2], e + "i2")[0] == 0x0001 or True:
            sh = np.frombuffer(b[:58], e + "i2")
            ln = sh[25:28]
            if all(0 < v < 4096 for v in ln) and 62 + int(np.prod(ln)) == len(b):
                break
    else:
        sys.exit("build_heldout: brainsmall.den header not understood")
    vol = np.frombuffer(b[62:], np.uint8).reshape(tuple(int(v) for v in ln), order="F")
    write_nrrd(f"{Vd}/volpack_brainsmall.nrrd", vol, (1, 1, 1))
    row("volume", "volpack_brainsmall.nrrd", f"Debian `libvolpack1-dev` {V['libvolpack1-dev']}",
        "/usr/share/doc/libvolpack1-dev/examples/brainsmall.den", "BSD-3-Clause (Stanford VolPack); data UNC SoftLab",
        f"VolPack .den (62-byte header, map_len {tuple(int(v) for v in ln)}) → NRRD, uint8 values unchanged, x fastest, gzip")
    # pydicom-data enhanced MR
    import pydicom
    ds = pydicom.dcmread(f"{W}/pydicom_data/data_store/data/emri_small.dcm")
    a = ds.pixel_array  # frames, rows, cols
    a = np.ascontiguousarray(np.transpose(a, (2, 1, 0))).astype("<u2")
    write_nrrd(f"{Vd}/pydicom_emri_small_u16.nrrd", a, (1, 1, 1), gzip_enc=False)
    row("volume", "pydicom_emri_small_u16.nrrd", f"PyPI `pydicom-data` {V['pydicom-data']}", "data_store/data/emri_small.dcm", "MIT (pydicom-data)",
        f"multi-frame DICOM → NRRD with pydicom: pixel values unchanged, (frame,row,col) → x=col fastest; {'×'.join(map(str, a.shape))} uint16 raw; spacings set 1 1 1")

    # derived OpenVDB fog volumes, written afterwards by make_vdb.py (Debian python3-openvdb 10.0.1-2)
    for dst, src, what in [("volpack_brainsmall_fog.vdb", "volpack_brainsmall.nrrd", "value/255"),
                           ("frog_body_mask_fog.vdb", "frog_body_mask_u8.nrrd", "mask/255 (0 or 1)"),
                           ("inia19_macaque_t1_fog.vdb", "inia19_macaque_t1.nrrd", "value/max")]:
        r = next(x for x in rows["volume"] if f"`{src}`" in x).split(" | ")
        row("volume", dst, r[1], r[2].strip("`"), r[3],
            f"*derived* from `{src}` by `make_vdb.py` with Debian `python3-openvdb` 10.0.1-2 (OpenVDB 10.0.1): FloatGrid `density`, class fog volume, "
            f"density = {what}, zero voxels inactive, voxel size = NRRD spacing, Tree_float_5_4_3, file compression blosc + active values (library default); "
            "no real smoke/cloud VDB exists in the reachable registries (see ../INDEX.md)")

# ----------------------------------------------------------------------------- DEMs
def write_geotiff(path, z, west, north, dx, dy, epsg=None, geographic=True, nodata=None, desc=""):
    import tifffile
    z = np.asarray(z, np.float32)
    tags = [(33550, "d", 3, (dx, dy, 0.0), False), (33922, "d", 6, (0.0, 0.0, 0.0, west, north, 0.0), False)]
    if epsg:
        keys = [1, 1, 0, 3, 1024, 0, 1, 2 if geographic else 1, 1025, 0, 1, 1,
                2048 if geographic else 3072, 0, 1, epsg]
        tags.append((34735, "H", len(keys), keys, False))
    if nodata is not None:
        tags.append((42113, "s", 0, str(nodata), False))
    tifffile.imwrite(path, z, photometric="minisblack", compression="zlib", extratags=tags, description=None,
                     metadata=None)


def stats(z, nodata=None):
    v = z[np.isfinite(z)] if nodata is None else z[z != nodata]
    return f"min {v.min():.6g} / max {v.max():.6g} / mean {v.mean():.6g}"


def read_rdb(rdx, rdb, name):
    import rdata
    import bz2, lzma
    idx = rdata.conversion.convert(rdata.parser.parse_file(rdx))
    off, ln = [int(v) for v in idx["variables"][name]]
    blob = open(rdb, "rb").read()[off:off + ln]
    t = blob[4:5]  # R lazy-load entry: 4-byte length, then zlib data or a type byte (2 bzip2, X xz, Z zlib, 0 none)
    data = {b"2": lambda: bz2.decompress(blob[5:]), b"X": lambda: lzma.decompress(blob[5:]),
            b"Z": lambda: zlib.decompress(blob[5:]), b"0": lambda: blob[5:]}.get(t, lambda: zlib.decompress(blob[4:]))()
    cmap = dict(rdata.conversion.DEFAULT_CLASS_MAP)
    cmap["factor"] = lambda obj, attrs: obj  # spatstat factor images (not used) break the default factor constructor
    return rdata.conversion.convert(rdata.parser.parse_data(data), constructor_dict=cmap)


def dems():
    import tifffile
    D = ensure(os.path.join(OUT, "dem"))
    # matplotlib topobathy -> Web Mercator
    mpl = f"PyPI `matplotlib` {V['matplotlib']} wheel (cp311)"
    d = np.load(f"{W}/matplotlib/matplotlib/mpl-data/sample_data/topobathy.npz")
    topo, lon, lat = d["topo"].astype(np.float32), d["longitude"].astype(float) - 360.0, d["latitude"].astype(float)
    R = 6378137.0
    y = R * np.log(np.tan(np.pi / 4 + np.radians(lat) / 2))
    x = R * np.radians(lon)
    cy, cx = np.diff(y).mean(), np.diff(x).mean()
    dev = max(np.abs(np.diff(y) - cy).max(), np.abs(np.diff(x) - cx).max()) / cy
    if dev > 0.01:
        sys.exit(f"build_heldout: topobathy latitudes not uniform in Mercator (dev {dev})")
    if lat[0] < lat[-1]:
        topo, y = topo[::-1], y[::-1]
    write_geotiff(f"{D}/salish_sea_topobathy_mercator.tif", topo, x[0] - cx / 2, y[0] + cy / 2, cx, cy, 3857, geographic=False)
    row("dem", "salish_sea_topobathy_mercator.tif", mpl, "matplotlib/mpl-data/sample_data/topobathy.npz", "matplotlib licence (PSF-style)",
        f"npz → GeoTIFF float32 EPSG:3857 (lat/lon cell centres are uniform in Mercator y within {dev:.2%} of a cell), rows north first; topography **and bathymetry**; {topo.shape[1]}×{topo.shape[0]}, cell {cx:.1f} m (Mercator); {stats(topo)}")
    # pyflwdir Rhine, lidar Minnesota: GeoTIFFs copied
    copy(f"{W}/pyflwdir-{V['pyflwdir']}/examples/rhine_elv0.tif", f"{D}/rhine_basin_elv_30s.tif")
    row("dem", "rhine_basin_elv_30s.tif", f"PyPI `pyflwdir` {V['pyflwdir']} sdist", f"pyflwdir-{V['pyflwdir']}/examples/rhine_elv0.tif", "MIT (Deltares)",
        "none; GeoTIFF EPSG:4326, 30″ (~0.9 km), nodata −9999 outside the basin (Europe)")
    copy(f"{W}/lidar/lidar/data/dem.tif", f"{D}/minnesota_lidar_dem_1m_utm15n.tif")
    row("dem", "minnesota_lidar_dem_1m_utm15n.tif", f"PyPI `lidar` {V['lidar']} wheel", "lidar/data/dem.tif", "MIT (lidar)",
        "none; LiDAR bare-earth GeoTIFF, EPSG:26915, 1 m (North America)")
    copy(f"{W}/lidar/lidar/data/dsm.tif", f"{D}/minnesota_lidar_dsm_1m_utm15n.tif")
    row("dem", "minnesota_lidar_dsm_1m_utm15n.tif", f"PyPI `lidar` {V['lidar']} wheel", "lidar/data/dsm.tif", "MIT (lidar)",
        "none; LiDAR surface model (with sinks) GeoTIFF, 1 m")
    # ferret etopo5 crops
    from scipy.io import netcdf_file
    fe = f"Debian `ferret-datasets` {V['ferret-datasets']}"
    nc = netcdf_file(f"{X}/ferret-datasets/usr/share/ferret-vis/data/etopo5.cdf", "r", mmap=False)
    var = [k for k, v in nc.variables.items() if v.data.ndim == 2][0]
    yname, xname = nc.variables[var].dimensions
    E = np.asarray(nc.variables[var].data, np.float32)
    la, lo = np.asarray(nc.variables[yname].data, float), np.asarray(nc.variables[xname].data, float)
    step = 5.0 / 60
    for name, (w, e, s, n), what in [
            ("central_andes_aconcagua_etopo5.tif", (-70.5, -64.5, -36, -24), "Central Andes, Chile/Argentina (South America)"),
            ("himalaya_everest_etopo5.tif", (80, 92, 26, 34), "Central Himalaya / Tibet (Asia)"),
            ("new_zealand_south_island_etopo5.tif", (166, 175, -47, -40), "South Island of New Zealand with surrounding sea floor (Oceania, topography and bathymetry)"),
            ("east_african_rift_kilimanjaro_etopo5.tif", (34, 40, -6, 0), "Kilimanjaro / Mt Kenya side of the East African Rift (Africa)")]:
        lon360 = np.mod(np.round(lo * 12) / 12, 360)  # float32 axis values snapped to the 5' grid
        lats_all = np.round(la * 12) / 12
        ws, es = np.mod(w, 360), np.mod(e, 360)
        ci = np.where((lon360 >= ws - 1e-9) & (lon360 < es - 1e-9))[0]  # half-open: w <= lon < e
        ri = np.where((lats_all >= s - 1e-9) & (lats_all < n - 1e-9))[0]  # s <= lat < n
        z = E[np.ix_(ri, ci)]
        lats = lats_all[ri]
        if lats[0] < lats[-1]:
            z, lats = z[::-1], lats[::-1]
        west = (lon360[ci[0]] + 180) % 360 - 180 - step / 2
        write_geotiff(f"{D}/{name}", z, west, lats[0] + step / 2, step, step, 4326)
        row("dem", name, fe, f"/usr/share/ferret-vis/data/etopo5.cdf (variable `{var}`)", "public domain (NOAA NGDC ETOPO5)",
            f"crop of cell centres {w} ≤ lon < {e}, {s} ≤ lat < {n} → GeoTIFF float32 EPSG:4326, 5′ (~9 km), rows north first; {what}; {z.shape[1]}×{z.shape[0]}; {stats(z)}")
    nc.close()
    # r-cran-fields PRISMelevation and RMelevation (.rda)
    import rdata
    fl = f"Debian `r-cran-fields` {V['r-cran-fields']}"
    for obj, name, what in [("PRISMelevation", "conus_prism_elevation_2_5min.tif", "PRISM elevation, conterminous USA"),
                            ("RMelevation", "rocky_mountains_prism_elevation_2_5min.tif", "PRISM elevation, US Rocky Mountains subset")]:
        r = rdata.conversion.convert(rdata.parser.parse_file(f"{X}/r-cran-fields/usr/lib/R/site-library/fields/data/{obj}.rda"))[obj]
        xs, ys, z = np.asarray(r["x"], float), np.asarray(r["y"], float), np.asarray(r["z"], float)
        # fields image list: z[i, j] at (x[i], y[j]); -> rows = y descending
        z = z.T[::-1].astype(np.float32)
        dx, dy = np.diff(xs).mean(), np.diff(ys).mean()
        nd = -9999.0
        z = np.where(np.isfinite(z), z, nd).astype(np.float32)
        write_geotiff(f"{D}/{name}", z, xs[0] - dx / 2, ys[-1] + dy / 2, dx, dy, 4326, nodata=nd)
        row("dem", name, fl, f"/usr/lib/R/site-library/fields/data/{obj}.rda", "GPL-2+ (fields); PRISM data (Oregon State Univ.)",
            f"R image list (x, y, z[x,y]) read with PyPI rdata → GeoTIFF float32 EPSG:4326, cell {dx:.6f}°×{dy:.6f}°, rows north first, NA → −9999 nodata; {what}; {z.shape[1]}×{z.shape[0]}; {stats(z, nd)}")
    # spatstat.data: bei.extra$elev (5 m, Panama), gorillas.extra$elevation (30 m, Cameroon)
    sd = f"{X}/r-cran-spatstat.data/usr/lib/R/site-library/spatstat.data/data"
    sp = f"Debian `r-cran-spatstat.data` {V['r-cran-spatstat.data']}"
    bei = read_rdb(f"{sd}/Rdata.rdx", f"{sd}/Rdata.rdb", "bei.extra")
    im = bei["elev"]
    z = np.asarray(im["v"], float)[::-1].astype(np.float32)  # im$v rows run south->north
    xr, yr = np.asarray(im["xrange"], float), np.asarray(im["yrange"], float)
    cell = float(np.asarray(im["xstep"]).ravel()[0])
    with open(f"{D}/barro_colorado_bei_elev_5m.asc", "w") as o:
        o.write(f"ncols {z.shape[1]}\nnrows {z.shape[0]}\nxllcorner {float(xr[0])!r}\nyllcorner {float(yr[0])!r}\ncellsize {float(cell)!r}\nNODATA_value -9999\n")
        for rw in z:
            o.write(" ".join(f"{v:.4g}" for v in rw) + "\n")
    row("dem", "barro_colorado_bei_elev_5m.asc", sp, "/usr/lib/R/site-library/spatstat.data/data/Rdata.rdb, object `bei.extra$elev`", "GPL-2+ (spatstat.data)",
        f"lazy-load DB entry (zlib) parsed with PyPI rdata → ESRI ASCII grid, local metres (no CRS), 5 m, rows flipped north first; Barro Colorado Island, Panama (Central America); {z.shape[1]}×{z.shape[0]}; {stats(z)}")
    gor = read_rdb(f"{sd}/Rdata.rdx", f"{sd}/Rdata.rdb", "gorillas.extra")
    im = gor["elevation"]
    z = np.asarray(im["v"], float)[::-1]
    z[z == -2147483648] = np.nan  # R integer NA
    nd = -9999.0
    z = np.where(np.isfinite(z), z, nd).astype(np.float32)
    xr, yr = np.asarray(im["xrange"], float), np.asarray(im["yrange"], float)
    dx, dy = float(np.asarray(im["xstep"]).ravel()[0]), float(np.asarray(im["ystep"]).ravel()[0])
    write_geotiff(f"{D}/kagwene_cameroon_elev_30m_utm32n.tif", z, xr[0], yr[1], dx, dy, 32632, geographic=False, nodata=nd)
    row("dem", "kagwene_cameroon_elev_30m_utm32n.tif", sp, "/usr/lib/R/site-library/spatstat.data/data/Rdata.rdb, object `gorillas.extra$elevation`", "GPL-2+ (spatstat.data); data WCS Takamanda-Mone Landscape Project",
        f"lazy-load DB entry parsed with PyPI rdata → GeoTIFF float32 EPSG:32632 (CRS from the help page), cell {dx:.4f} m, rows flipped north first, NA → −9999; Kagwene Gorilla Sanctuary, Cameroon (Africa); {z.shape[1]}×{z.shape[0]}; {stats(z, nd)}")


def write_readmes():
    titles = {"mesh": "Held-out meshes", "volume": "Held-out volumes", "dem": "Held-out DEMs"}
    for k, rs in rows.items():
        if not rs:
            continue
        with open(os.path.join(OUT, k, "README.md"), "w") as o:
            o.write(f"# {titles[k]}\n\nNot committed; re-created by `/work/heldout/fetch.sh` from package registries only. "
                    "One line per file: file, source package + version, path inside the package, licence, conversion.\n\n")
            o.write("| file | source (registry, package, version) | path in package | licence | conversion |\n|---|---|---|---|---|\n")
            o.write("\n".join(rs) + "\n")


if __name__ == "__main__":
    for p in PARTS:
        {"mesh": meshes, "volume": volumes, "dem": dems}[p]()
    write_readmes()
    print("build_heldout: done", {k: len(v) for k, v in rows.items()})
