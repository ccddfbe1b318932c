#!/usr/bin/env bash
# Runs every fuzz target (or those named after the time) for SECONDS each (default 30) on seed
# corpora from fuzz/seeds.py. Needs cargo-fuzz (`cargo install cargo-fuzz`). The machine's Rust is
# stable, so nightly-only flags are unlocked with RUSTC_BOOTSTRAP=1 and the run uses no sanitizer
# (`-s none`): panics, hangs (-timeout) and allocations over -rss_limit_mb/-malloc_limit_mb are
# what it finds. Crashes land in fuzz/artifacts/<target>/; the script exits non-zero on any.
#   fuzz/run.sh 30                  # each target 30 s
#   fuzz/run.sh 3600 dem_geotiff    # one target for an hour
# FUZZ_RUNS=N caps each target at N executions and fixes libFuzzer's seed (-seed=1), so a run
# is repeatable: CI's regression run is `FUZZ_RUNS=20000 fuzz/run.sh 15` (whichever ends first).
set -euo pipefail
cd "$(dirname "$0")"
secs="${1:-30}"; shift || true
export RUSTC_BOOTSTRAP=1
targets=("$@")
[ ${#targets[@]} -gt 0 ] || mapfile -t targets < <(cargo fuzz list)
python3 seeds.py
cargo fuzz build -s none --release
mkdir -p logs
status=0
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t"
  extra=()
  [ -z "${FUZZ_RUNS:-}" ] || extra=(-runs="$FUZZ_RUNS" -seed=1)
  if cargo fuzz run -s none --release "$t" "corpus/$t" -- \
      -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 \
      -max_len=1048576 -print_final_stats=1 "${extra[@]}" >"logs/$t.log" 2>&1; then
    execs=$(grep -E '^stat::number_of_executed_units' "logs/$t.log" | awk '{print $2}')
    echo "$t: ${secs}s, ${execs:-?} executions, no crash"
  else
    echo "$t: FAILED (see fuzz/logs/$t.log and fuzz/artifacts/$t/)"; tail -30 "logs/$t.log"; status=1
  fi
done
exit $status
