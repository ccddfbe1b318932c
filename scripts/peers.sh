#!/usr/bin/env bash
# The peers, side by side (issue 19): installs the tools a user already has for each job of ours,
# makes the inputs from the real data in ../shared/data, and prints for each row of the issue's
# table the time of ours, of the peer and the ratio peer ÷ ours, from interleaved whole-process
# runs (A B A B …: ours, peer, ours, peer; the ratio is taken pair by pair, so a drift of the
# machine's speed hits both sides of a pair alike; scripts/peers/abtime.py).
#
#   scripts/peers.sh                      # the full table (22 min at load 3–11 on 2026-12-05,
#                                         # 5 runs, the clouds row ≈ 4 min of it)
#   PEERS_QUICK=1 scripts/peers.sh        # small inputs, 3 runs: checks that every row works
#   PEERS_ONLY=snow,descriptor scripts/peers.sh
#
# Environment:
#   PHENOMENA_BIN  our binary (default target/release/phenomena; build it with
#                  `cargo build --release`; the script never builds)
#   PEERS_DIR      work directory: venv, inputs, outputs, results (default target/peers)
#   PEERS_QUICK    1: small inputs (5 k and 75 k triangles, a 1024² DEM, a 48³ cloud), 3 runs
#   PEERS_RUNS     counted pairs per row (default 5; quick 3), after one warm-up run of each
#   PEERS_ONLY     comma-separated rows: snow, probability, descriptor, hillshade, ambient, clouds
#
# Installs (idempotent: each is skipped when already there; measured on this 2-core machine,
# 2026-12-03, while other builds ran):
#   apt   blender gdal-bin   45 s, +350 MB on disk (Debian 12: Blender 3.4.1 with the "Real
#                            Snow" 1.3 add-on in blender-data, GDAL 3.6.2)
#   apt   libllvm19          ~15 s, +110 MB (Mitsuba's LLVM back end; without it Mitsuba runs
#                            its much slower scalar variant)
#   pip   numpy scipy trimesh embreex pyamg mitsuba (pinned below) into $PEERS_DIR/venv:
#                            23 s, 523 MB (mitsuba + drjit ≈ 200 MB of it)
#   inputs                   6 s, 190 MB in $PEERS_DIR/in (scripts/peers/make_inputs.py says
#                            what each is and which are synthetic)
#
# Rows (the peer programs state in their headers what they compute and how it matches ours):
#   snow         `phenomena render snow-cover` defaults vs Blender's Real Snow add-on
#                (scripts/peers/real_snow.py), 5 k / 75 k / 1.2 M triangles
#   probability  our probability stage with K = 64 (report.json) vs trimesh + Embree
#                per-vertex rays (scripts/peers/probability_embree.py), 75 k / 1.2 M triangles
#   descriptor   `snow-terrain` preset paper, outputs ["snow_cover.tif"], 4096² vs numpy
#                (scripts/peers/descriptor_numpy.py)
#   hillshade    the same run of ours vs `gdaldem hillshade` (a one-pass stencil: the floor)
#   ambient      our ambient edit through the server (scripts/peers/ambient_ours.py) vs pyamg
#                Ruge–Stüben on the full 128³ grid (scripts/peers/ambient_pyamg.py)
#   clouds       scripts/mitsuba/compare_multiple.py (single scattering): Mitsuba 3's time at
#                our error, extrapolated from its spp ladder (not interleaved; its own method)
#
# Output: one block per row on stdout, a summary table at the end, every run's figures in
# $PEERS_DIR/results-<date>.jsonl and the commands' stderr in $PEERS_DIR/<row>.{a,b}.log.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=${PHENOMENA_BIN:-$ROOT/target/release/phenomena}
DIR=${PEERS_DIR:-$ROOT/target/peers}
QUICK=${PEERS_QUICK:-0}
if [ "$QUICK" = 1 ]; then RUNS=${PEERS_RUNS:-3}; IN=$DIR/in-quick; else RUNS=${PEERS_RUNS:-5}; IN=$DIR/in; fi
ONLY=${PEERS_ONLY:-snow,probability,descriptor,hillshade,ambient,clouds}
VENV=$DIR/venv
PY=$VENV/bin/python
OUT=$DIR/out
RESULTS=$DIR/results-$(date -u +%Y%m%dT%H%M%SZ).jsonl
PIP_PACKAGES="numpy==2.4.6 scipy==1.17.1 trimesh==5.2.0 embreex==4.4.0.post1 pyamg==5.4.1 mitsuba==3.9.1 drjit==1.5.0"

want() { [[ ",$ONLY," == *",$1,"* ]]; }
say() { printf '%s\n' "$*" >&2; }

[ -x "$BIN" ] || { say "no binary at $BIN: cargo build --release, or set PHENOMENA_BIN"; exit 2; }

# ---- installs ---------------------------------------------------------------------------------
missing=()
command -v blender >/dev/null || missing+=(blender)
command -v gdaldem >/dev/null || missing+=(gdal-bin)
dpkg -s libllvm19 >/dev/null 2>&1 || missing+=(libllvm19)
if [ ${#missing[@]} -gt 0 ]; then
  say "installing ${missing[*]} (apt)"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
fi
[ -f /usr/share/blender/scripts/addons/real_snow.py ] \
  || { say "Blender has no Real Snow add-on (expected in blender-data)"; exit 2; }
if ! "$PY" -c 'import numpy, scipy, trimesh, embreex, pyamg, mitsuba' 2>/dev/null; then
  say "installing the Python peers into $VENV (pip)"
  python3 -m venv "$VENV"
  "$PY" -m pip install -q --upgrade pip
  # shellcheck disable=SC2086
  "$PY" -m pip install -q $PIP_PACKAGES
fi

# ---- inputs -----------------------------------------------------------------------------------
mkdir -p "$OUT"
if [ "$QUICK" = 1 ]; then "$PY" "$ROOT/scripts/peers/make_inputs.py" "$IN" --quick
else "$PY" "$ROOT/scripts/peers/make_inputs.py" "$IN"; fi

say "machine: $(nproc) cores, $(uname -r); load average $(cut -d' ' -f1-3 /proc/loadavg)"
say "ours: $BIN ($("$BIN" --version)); $RUNS interleaved pairs per row; results in $RESULTS"

# Interleaved pairs: A = ours, B = the peer.
ab() { "$PY" "$ROOT/scripts/peers/abtime.py" --runs "$RUNS" --results "$RESULTS" "$@"; }
# The peers' Python without the OpenBLAS pins some machines set (they slow a current numpy).
PEER_PY="env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE $PY"
# Our report.json's stage timings, as "stage ms, …".
stages() {
  python3 - "$1" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
total = r.get("total_ms") or sum(t["ms"] for t in r["timings"])
print("   ours' stages (last run, report.json): " + ", ".join(
    f"{t['stage']} {t['ms']:.0f} ms" for t in r["timings"]) + f"; total {total:.0f} ms")
EOF
}
stage_expr() { echo "$1/report.json::sum(t['ms'] for t in r['timings'] if t['stage'] == '$2') / 1e3"; }

BLENDER="blender -b --factory-startup --python-exit-code 1 --python $ROOT/scripts/peers/real_snow.py --"

if want snow; then
  meshes="table5k bunny75k"; [ "$QUICK" = 1 ] || meshes="$meshes bunny1m"
  for m in $meshes; do
    o=$OUT/snow_$m
    ab --label "snow_$m" \
      --a "$BIN render snow-cover --input $IN/$m.obj --out $o --quiet" \
      --b "$BLENDER $IN/$m.obj $OUT/blender_$m.obj"
    stages "$o/report.json"
  done
fi

if want probability; then
  meshes="bunny75k"; [ "$QUICK" = 1 ] || meshes="$meshes bunny1m"
  for m in $meshes; do
    o=$OUT/prob_$m
    # Ours: the whole pipeline with K = 64, no snowfall (one step stabilised once), a 64×64 render,
    # so that little but the probability is left in the whole process; the stage is the
    # probability. (snowfall=0: since the converged stabilisation, one step that drops the whole
    # 12 h of snow at once and is stabilised once still took 3 s of routing on the 75 k bunny.)
    ab --label "probability_k64_$m" \
      --a "$BIN render snow-cover --input $IN/$m.obj --set directions=64 --set snowfall=0 --set steps=1 --set max_stabilize_iterations=1 --set width=64 --set height=64 --out $o --quiet" \
      --b "$PEER_PY $ROOT/scripts/peers/probability_embree.py $IN/$m.obj 64 $OUT/embree_$m.json" \
      --a-stage "$(stage_expr "$o" probability)" \
      --b-stage "$OUT/embree_$m.json::r['probability']"
    stages "$o/report.json"
  done
fi

if [ "$QUICK" = 1 ]; then dem=dem1024; else dem=dem4096; fi
OURS_DESCRIPTOR="$BIN render snow-terrain --input $IN/$dem.tif --set preset=paper --set 'outputs=[\"snow_cover.tif\"]' --out $OUT/descriptor --quiet"
if want descriptor; then
  ab --label "descriptor_${dem}_numpy" \
    --a "$OURS_DESCRIPTOR" \
    --b "$PEER_PY $ROOT/scripts/peers/descriptor_numpy.py $IN/$dem.f32 $IN/$dem.json $OUT/numpy_snow.f32 $OUT/numpy_descriptor.json"
  stages "$OUT/descriptor/report.json"
fi

if want hillshade; then
  ab --label "descriptor_${dem}_gdaldem" \
    --a "$OURS_DESCRIPTOR" \
    --b "gdaldem hillshade -q $IN/$dem.tif $OUT/hillshade.tif"
fi

if want ambient; then
  if [ "$QUICK" = 1 ]; then vol=cloud48; else vol=cloud128; fi
  ab --label "ambient_$vol" \
    --a "python3 $ROOT/scripts/peers/ambient_ours.py $BIN $IN/$vol.npy $OUT/ambient_ours.json" \
    --b "$PEER_PY $ROOT/scripts/peers/ambient_pyamg.py $IN/$vol.npy $OUT/ambient_pyamg.json" \
    --a-stage "$OUT/ambient_ours.json::r['edit']" \
    --b-stage "$OUT/ambient_pyamg.json::r['propagate']"
fi

if want clouds; then
  if [ "$QUICK" = 1 ]; then cargs="--size 32 --width 64 --height 48 --ref-spp 256"; else cargs="--ref-spp 4096"; fi
  say "== clouds: Mitsuba 3 single scattering at our error (scripts/mitsuba/compare_multiple.py $cargs)"
  # A result left by an earlier run (the quick one's cumulus32 sorts first) must not be read.
  rm -f "$OUT"/mitsuba/result_cumulus*.json
  # shellcheck disable=SC2086
  $PEER_PY "$ROOT/scripts/mitsuba/compare_multiple.py" --modes single --binary "$BIN" \
    --out "$OUT/mitsuba" $cargs > "$OUT/mitsuba.log" 2>&1 || { say "   compare_multiple.py failed: $OUT/mitsuba.log"; }
  res=$(ls "$OUT"/mitsuba/result_cumulus*.json 2>/dev/null | head -1 || true)
  if [ -n "$res" ]; then
    python3 - "$res" "$RESULTS" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))["single"]
print(f"   ours {r['ours_seconds_cli']:.3f} s (whole CLI run), error {r['rel_rmse']:.4f}; Mitsuba "
      f"needs ≈ {r['mitsuba_spp_at_equal_error']:.0f} spp = {r['mitsuba_seconds_at_equal_error']:.1f} s "
      f"for it: ratio {r['time_ratio_at_equal_error']:.0f}×")
with open(sys.argv[2], "a") as f:
    f.write(json.dumps({"label": "clouds_mitsuba_single", "mitsuba": r}) + "\n")
EOF
  fi
fi

# ---- summary ----------------------------------------------------------------------------------
python3 - "$RESULTS" <<'EOF'
import json, sys
print("\n| row | ours (median) | peer (median) | peer ÷ ours, whole process | stage: ours / peer / ratio | load |")
print("|---|---:|---:|---:|---|---|")
for line in open(sys.argv[1]):
    r = json.loads(line)
    if "a_wall" not in r:
        m = r["mitsuba"]
        print(f"| {r['label']} | {m['ours_seconds_cli']:.2f} s | {m['mitsuba_seconds_at_equal_error']:.1f} s (extrapolated) | {m['time_ratio_at_equal_error']:.0f}× | — | — |")
        continue
    q = lambda m: f"{m['median']:.2f}" if m else "—"
    st = "—"
    if r.get("ratio_stage"):
        st = f"{q(r['a_stage'])} s / {q(r['b_stage'])} s / {r['ratio_stage']['median']:.2f}×"
    rw = r["ratio_wall"]
    print(f"| {r['label']} | {q(r['a_wall'])} s | {q(r['b_wall'])} s | {rw['median']:.2f}× [{rw['min']:.2f}–{rw['max']:.2f}] | {st} | {r['load_before']:.1f} → {r['load_after']:.1f} |")
EOF
