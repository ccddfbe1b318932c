#!/usr/bin/env bash
# Byte-identity check for refactors: renders every pipeline on real data with the CLI and writes the
# SHA-256 of every output file into a manifest, so two builds can be compared output by output.
#
# Usage:
#   scripts/checksums.sh BINARY OUT_DIR          render all cases with BINARY (`phenomena`) into
#                                                OUT_DIR/<case>/ and write OUT_DIR/manifest.txt
#   scripts/checksums.sh --compare A.txt B.txt   diff two manifests; exit 1 when they differ
#
# The manifest has one line per output, `<sha256>  <case>/<file>`, sorted. `report.json` and
# `state.json` carry per-stage timings (wall-clock milliseconds), which differ from run to run:
# they are hashed with every key named `timings`, `timings_ms`, `ms` or `total_ms` removed (jq), so their
# numbers and structure still count. Everything else is hashed as written.
#
# scripts/checksums/baseline-457487d.txt is the manifest of main at 457487d (release build);
# baseline-1d1b8cf.txt that of main at 1d1b8cf (identical to it: the terrain work between them
# left every output unchanged).
#
# Cases: snow-terrain (default; `paper` preset; an orthophoto; a sea DEM; a sweep sheet),
# snow-cover (glTF, OBJ, textured glTF), cloud (single and `scattering: multiple`, with layers),
# dust (OBJ, OBJ with MTL and texture). Inputs come from ../shared/data (beside the clone) and
# tests/data; sizes are small so the whole run takes a few minutes with a release build.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
SHARED="${SHARED_DATA:-$ROOT/../shared/data}"
TESTS="$ROOT/tests/data"

if [ "${1:-}" = "--compare" ]; then
    if [ $# -ne 3 ]; then
        echo "usage: $0 --compare A.txt B.txt" >&2
        exit 2
    fi
    if diff -u "$2" "$3"; then
        echo "identical: $(wc -l <"$2") outputs"
        exit 0
    fi
    echo "DIFFERENT (lines above: - $2, + $3)" >&2
    exit 1
fi

if [ $# -ne 2 ]; then
    echo "usage: $0 BINARY OUT_DIR | $0 --compare A.txt B.txt" >&2
    exit 2
fi
BIN="$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"
OUT="$2"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
command -v jq >/dev/null || { echo "jq is required" >&2; exit 2; }

# case name, pipeline, input, then CLI options.
run() {
    local name="$1" pipeline="$2" input="$3"
    shift 3
    rm -rf "${OUT:?}/$name"
    local t0=$SECONDS
    "$BIN" render "$pipeline" --input "$input" --out "$OUT/$name" --quiet "$@"
    echo "$name: $((SECONDS - t0)) s" >&2
}

run st-volcano snow-terrain "$SHARED/dem/maunga_whau_volcano.asc" \
    --set width=320 --set height=200
run st-tanzawa snow-terrain "$SHARED/dem/tanzawa_sagami_aster_gdem2.tif" \
    --set width=360 --set height=240
run st-tanzawa-paper snow-terrain "$SHARED/dem/tanzawa_sagami_aster_gdem2.tif" \
    --set width=360 --set height=240 --set preset=paper
run st-olinda-ortho snow-terrain "$SHARED/dem/olinda_dem_utm25s.tif" \
    --ortho "$TESTS/ortho/olinda_l7_rgb_utm25s.tif" --set width=320 --set height=200
run st-salish-sea snow-terrain "$TESTS/dem/salish_sea_topobathy_mercator.tif" \
    --set width=320 --set height=200 --set 'sea_color=#204060' --set 'rock_color=#705040'
run st-volcano-sweep snow-terrain "$SHARED/dem/maunga_whau_volcano.asc" \
    --set width=160 --set height=100 \
    --set 'sweep={"param":"probe_radius","values":[100,300]}'
run sc-table snow-cover "$SHARED/mesh/inventor_table.glb" \
    --set up_axis=z --set width=320 --set height=240
run sc-teapot snow-cover "$SHARED/mesh/teapot_npm.obj" \
    --set width=320 --set height=240
run sc-box-textured snow-cover "$TESTS/mesh/box_textured.glb" \
    --set width=240 --set height=180
run cloud-skull cloud "$SHARED/volume/cgal_skull_ct_64.nrrd" \
    --set width=200 --set height=150 --set layers=true --set 'background=#6f8fb8'
run cloud-brain cloud "$TESTS/volume/colin27_brain_mask_2x.nrrd" \
    --set width=160 --set height=120
run cloud-skull-multiple cloud "$SHARED/volume/cgal_skull_ct_64.nrrd" \
    --set width=200 --set height=150 --set scattering=multiple --set layers=true \
    --set 'sun_color=[0.6,0.58,0.55]'
run dust-teapot dust "$SHARED/mesh/teapot_npm.obj" \
    --set width=320 --set height=240
run dust-bench dust "$TESTS/mesh/bench/bench.obj" \
    --set width=320 --set height=240

# Hash every output; the JSON files without their timings.
manifest="$OUT/manifest.txt"
(
    cd "$OUT"
    find . -mindepth 2 -type f | sed 's|^\./||' | LC_ALL=C sort | while read -r f; do
        case "$f" in
        *.json)
            sum=$(jq -S 'walk(if type == "object" then del(.timings, .timings_ms, .ms, .total_ms) else . end)' "$f" |
                sha256sum | cut -d' ' -f1)
            ;;
        *) sum=$(sha256sum "$f" | cut -d' ' -f1) ;;
        esac
        echo "$sum  $f"
    done
) >"$manifest"
echo "$(wc -l <"$manifest") outputs -> $manifest" >&2
