#!/usr/bin/env bash
# Runs each libFuzzer target for FUZZ_SECONDS (default 30) from its seed corpus in fuzz/corpus/, or,
# with FUZZ_RUNS=N, for N inputs each (the issue 10 note's 1,000,000-input runs; no time limit).
# New inputs go to a scratch directory (the seeds in the repository are not changed); a crash,
# leak, timeout or out-of-memory input is kept in BUILD_DIR/fuzz-artifacts/ and fails the run.
# Usage: fuzz/run_fuzzers.sh [BUILD_DIR]   (a build configured with -DTIPFORCE_FUZZ=ON, clang)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build-fuzz}
seconds=${FUZZ_SECONDS:-30}
runs_limit=${FUZZ_RUNS:-}
if [ -n "$runs_limit" ]; then budget=(-runs="$runs_limit"); else budget=(-max_total_time="$seconds"); fi
work=$(mktemp -d /tmp/tipforce-fuzz.XXXXXX)
trap 'rm -rf "$work"' EXIT
mkdir -p "$build/fuzz-artifacts"
for target in fuzz_window_decode fuzz_config fuzz_log_reader; do
  mkdir -p "$work/$target"
  # -rss_limit_mb and -timeout turn a runaway allocation or a hang into a failure; -max_len lets
  # inputs grow past the small seeds (a window with hundreds of samples, a log of several events).
  start=$(date +%s)
  if ! "$build/fuzz/$target" "${budget[@]}" -rss_limit_mb=2048 -timeout=10 -max_len=65536 \
       -print_final_stats=1 -artifact_prefix="$build/fuzz-artifacts/$target-" \
       "$work/$target" "fuzz/corpus/$target" >"$work/$target.log" 2>&1; then
    tail -n 40 "$work/$target.log"
    echo "fuzz: $target FAILED (input kept in $build/fuzz-artifacts/)"
    exit 1
  fi
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$work/$target.log" | grep -o '[0-9]*$' || echo '?')
  rss=$(grep -o 'stat::peak_rss_mb: *[0-9]*' "$work/$target.log" | grep -o '[0-9]*$' || echo '?')
  echo "fuzz: $target: $runs inputs in $(( $(date +%s) - start )) s (peak RSS $rss MB), no crash, leak or hang"
done
