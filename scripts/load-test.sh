#!/usr/bin/env bash
# Server-overhead benchmark (BENCHMARKS.md, "Server overhead"): requests/s and p50/p99 latency of
#   1. GET /v1/jobs/{id} on a finished job, and
#   2. a cached submit: POST /v1/snow-terrain {"asset": "<sha256>", "params": {}} whose identical
#      request already finished, so it is answered from the result cache (no decode, no new job),
#   3. the same cached submit as multipart (params + dem upload), for comparison,
#   4. a warm (cached) map tile (issue 22): GET /v1/maps/{id}/tiles/relief/{z}/{x}/{y}.png of
#      the map of the server's georeferenced example DEM (/v1/examples/dem.tif), the tile at
#      the map's centre at its maxzoom, fetched once before the run so every request is a
#      cache read (ETag computed, 200 with the PNG; no If-None-Match),
# each with CONNECTIONS concurrent clients (default 16) for DURATION (default 10s), against a
# --release build listening on 127.0.0.1 only (port chosen by the OS), with a throw-away data dir.
#
# Usage: scripts/load-test.sh            (from anywhere; builds first)
#   env: DURATION=10s CONNECTIONS=16 THREADS=2 DEM=../shared/data/dem/maunga_whau_volcano.asc
#        PHENOMENA_LOG=info (the server's log filter; try `warn` to measure logging overhead)
#        CARGO_TARGET_DIR (where the release binary is built; default ./target)
#        BIN=path/to/phenomena (skip the build and run that binary, e.g. the test profile's
#            target/debug/phenomena; say which in the figures)
#        ONLY=map (only the map tile run; default: all four)
# Needs curl; installs wrk from Debian (apt-get) when it is missing.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
DURATION="${DURATION:-10s}"
CONNECTIONS="${CONNECTIONS:-16}"
THREADS="${THREADS:-2}"
DEM="${DEM:-$ROOT/../shared/data/dem/maunga_whau_volcano.asc}"
TARGET_DIR="${CARGO_TARGET_DIR:-$ROOT/target}"
export PHENOMENA_LOG="${PHENOMENA_LOG:-info}"

if ! command -v wrk >/dev/null 2>&1; then
    echo "== installing wrk (Debian package)" >&2
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq wrk >/dev/null
fi
command -v curl >/dev/null || { echo "curl is required" >&2; exit 1; }
[ -f "$DEM" ] || { echo "no DEM at $DEM (set DEM=...)" >&2; exit 1; }

if [ -z "${BIN:-}" ]; then
    echo "== building (cargo build --release)" >&2
    cargo build --release --quiet
    BIN="$TARGET_DIR/release/phenomena"
fi
ONLY="${ONLY:-}"
echo "== binary $BIN" >&2

WORK="$(mktemp -d)"
SERVER_PID=""
cleanup() {
    if [ -n "$SERVER_PID" ]; then
        kill "$SERVER_PID" 2>/dev/null || true
        wait "$SERVER_PID" 2>/dev/null || true
    fi
    rm -rf "$WORK"
}
trap cleanup EXIT

# Port 0: the OS picks a free port; the server logs the address it got.
"$BIN" serve --bind 127.0.0.1:0 --data-dir "$WORK/data" --log-format json >"$WORK/server.log" 2>&1 &
SERVER_PID=$!
ADDR=""
for _ in $(seq 1 100); do
    ADDR="$(grep -o '"addr":"127\.0\.0\.1:[0-9]*"' "$WORK/server.log" | head -n1 | cut -d'"' -f4 || true)"
    [ -n "$ADDR" ] && break
    kill -0 "$SERVER_PID" 2>/dev/null || { cat "$WORK/server.log" >&2; exit 1; }
    sleep 0.1
done
[ -n "$ADDR" ] || { echo "server did not start" >&2; cat "$WORK/server.log" >&2; exit 1; }
BASE="http://$ADDR"
echo "== server on $BASE (log filter $PHENOMENA_LOG)" >&2

# One finished job: upload the DEM as an asset, submit it by asset id and wait for the result.
ASSET="$(curl -fsS --data-binary @"$DEM" "$BASE/v1/assets?filename=$(basename "$DEM")" \
    | grep -o '"id":"[0-9a-f]\{64\}"' | cut -d'"' -f4)"
printf '{"asset": "%s", "params": {}}' "$ASSET" >"$WORK/submit.json"
JOB_JSON="$(curl -fsS -H 'Prefer: wait=60' -H 'Content-Type: application/json' \
    --data-binary @"$WORK/submit.json" "$BASE/v1/snow-terrain")"
JOB="$(printf '%s' "$JOB_JSON" | grep -o '"id":"[0-9a-f]\{32\}"' | head -n1 | cut -d'"' -f4)"
STATUS="$(printf '%s' "$JOB_JSON" | grep -o '"status":"[a-z]*"' | head -n1 | cut -d'"' -f4)"
[ "$STATUS" = "succeeded" ] || { echo "job $JOB is $STATUS, not succeeded" >&2; exit 1; }
echo "== finished job $JOB (asset $ASSET)" >&2

# The same request as multipart, byte for byte as curl -F would send it, for the third run.
BOUNDARY="phenomena-load-test-boundary"
{
    printf -- '--%s\r\nContent-Disposition: form-data; name="params"\r\n\r\n{}\r\n' "$BOUNDARY"
    printf -- '--%s\r\nContent-Disposition: form-data; name="dem"; filename="%s"\r\n' "$BOUNDARY" "$(basename "$DEM")"
    printf 'Content-Type: application/octet-stream\r\n\r\n'
    cat "$DEM"
    printf '\r\n--%s--\r\n' "$BOUNDARY"
} >"$WORK/submit.multipart"

# Sanity: both cached forms answer 200 with the same finished job.
for form in json multipart; do
    if [ "$form" = json ]; then ct="application/json"; body="$WORK/submit.json"
    else ct="multipart/form-data; boundary=$BOUNDARY"; body="$WORK/submit.multipart"; fi
    got="$(curl -fsS -o "$WORK/resp.json" -w '%{http_code}' -H "Content-Type: $ct" \
        --data-binary @"$body" "$BASE/v1/snow-terrain")"
    grep -q "\"id\":\"$JOB\"" "$WORK/resp.json" && [ "$got" = 200 ] \
        || { echo "cached $form submit answered $got: $(cat "$WORK/resp.json")" >&2; exit 1; }
done

run() { # name, then wrk arguments
    local name="$1"; shift
    echo
    echo "== $name: wrk -t$THREADS -c$CONNECTIONS -d$DURATION --latency $*"
    wrk -t"$THREADS" -c"$CONNECTIONS" -d"$DURATION" --latency -s "$ROOT/scripts/wrk-bench.lua" "$@" \
        | tee "$WORK/wrk.out"
    RESULTS+=("$(printf '%-34s %s' "$name" "$(grep '^RESULT' "$WORK/wrk.out" | cut -d' ' -f2-)")")
}
RESULTS=()
if [ "$ONLY" != map ]; then
    run "GET /v1/jobs/{id}" "$BASE/v1/jobs/$JOB"
    WRK_BODY_FILE="$WORK/submit.json" WRK_CONTENT_TYPE="application/json" \
        run "POST cached submit (JSON asset)" "$BASE/v1/snow-terrain"
    WRK_BODY_FILE="$WORK/submit.multipart" WRK_CONTENT_TYPE="multipart/form-data; boundary=$BOUNDARY" \
        run "POST cached submit (multipart)" "$BASE/v1/snow-terrain"
fi

# A map of the example DEM and its centre tile at maxzoom, computed once (cold) before the run.
curl -fsS -o "$WORK/dem.tif" "$BASE/v1/examples/dem.tif"
MAP_ASSET="$(curl -fsS --data-binary @"$WORK/dem.tif" "$BASE/v1/assets?filename=dem.tif" \
    | grep -o '"id":"[0-9a-f]\{64\}"' | cut -d'"' -f4)"
printf '{"asset": "%s", "params": {}}' "$MAP_ASSET" >"$WORK/map.json"
curl -fsS -H 'Content-Type: application/json' --data-binary @"$WORK/map.json" "$BASE/v1/maps" \
    >"$WORK/map.out"
MAP="$(grep -o '"id":"[0-9a-f]\{64\}"' "$WORK/map.out" | head -n1 | cut -d'"' -f4)"
# "center":[lon,lat,zoom] and "maxzoom":z → the XYZ tile holding the centre at maxzoom.
CENTER="$(grep -o '"center":\[[^]]*\]' "$WORK/map.out" | sed 's/.*\[\(.*\)\]/\1/')"
MAXZOOM="$(grep -o '"maxzoom":[0-9]*' "$WORK/map.out" | cut -d: -f2)"
TILE="$(printf '%s' "$CENTER" | awk -F, -v z="$MAXZOOM" '{
    pi = atan2(0, -1); n = 2 ^ z; lat = $2 * pi / 180;
    x = int(($1 + 180) / 360 * n);
    y = int((1 - log(sin(lat) / cos(lat) + 1 / cos(lat)) / pi) / 2 * n);
    printf "%d/%d/%d", z, x, y }')"
TILE_URL="$BASE/v1/maps/$MAP/tiles/relief/$TILE.png"
COLD="$(curl -fsS -o "$WORK/tile.png" -w '%{http_code} %{time_total}' "$TILE_URL")"
WARM="$(curl -fsS -o /dev/null -w '%{http_code} %{time_total}' "$TILE_URL")"
[ "${COLD%% *}" = 200 ] && [ "${WARM%% *}" = 200 ] \
    || { echo "tile $TILE_URL answered $COLD then $WARM" >&2; exit 1; }
echo "== map $MAP, tile relief/$TILE: $(wc -c <"$WORK/tile.png") bytes; cold ${COLD#* } s, then ${WARM#* } s" >&2
run "GET warm map tile (relief, 256 px)" "$TILE_URL"

# The jobs list must still hold exactly one job: every cached submit reused it.
JOBS="$(curl -fsS "$BASE/v1/jobs?limit=100" | grep -o '"events_url"' | wc -l)"
echo
echo "== summary ($CONNECTIONS connections, $DURATION each, $(nproc) CPUs shared by server and wrk; jobs created: $JOBS)"
printf '%s\n' "${RESULTS[@]}"
