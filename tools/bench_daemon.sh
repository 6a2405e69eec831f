#!/usr/bin/env bash
# Benchmarks tipforced on live udpm input inside a private network namespace (nothing leaves this
# machine): 1250-sample windows, spring model with k_n_per_m and h_m unknown, CPU backend.
#  1. at RATE windows/s (default 500) for DURATION s: receive->publish latency p50/p99/max,
#     windows/s solved, windows dropped;
#  2. the highest rate without drops (bisection between 0 and the first rate that drops).
# The stream is issue 9's live case: lines of WIDTH windows whose first is INITIAL_UNKNOWN (as an
# acquisition marks the pixel after its retrace), and every FALSE_EVERY windows a false
# continuation (marked CONTINUED, its trajectory started afresh). WIDTH=0 FALSE_EVERY=0: one
# continued trajectory, as before 2026-12-01.
# PATTERN=domains (the default): the windows of issue 9's 1 MHz line, as tipforce bench inverts
# it (1e-6 s, k in domains of 1 and 4 N/m, h 20-26 nm in 2 nm steps, NOISE 0.05 nm).
# PATTERN=smooth: the stream used before 2026-12-02 (k 1-4 N/m and h as sines of the pixel,
# every pixel changed by up to 30 %; ~1.27 MHz, NOISE 0.02 nm), about 3 x the solves per window.
# Usage: tools/bench_daemon.sh [BUILD_DIR]
#   (env: RATE=500 DURATION=4 MODES=8 QUEUE=64 SEARCH=1 WIDTH=64 FALSE_EVERY=100 PATTERN=domains
#    NOISE=5e-11 for domains, 2e-11 for smooth)
# BUILD_DIR must hold daemon/tipforced and tests/daemon/tfd_tool (default: build).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=${1:-${BUILD_DIR:-$root/build}}
build=$(cd "$build" && pwd)
if [ "${TFD_IN_NETNS:-0}" != 1 ]; then
  exec "$root/tests/daemon/netns_run.sh" "$0" "$build"
fi
tipforced=$build/daemon/tipforced
tool=$build/tests/daemon/tfd_tool
for b in "$tipforced" "$tool"; do
  [ -x "$b" ] || { echo "missing $b (build targets tipforced and tfd_tool)"; exit 1; }
done
RATE=${RATE:-500}
DURATION=${DURATION:-4}
MODES=${MODES:-8}
QUEUE=${QUEUE:-64}
SEARCH=${SEARCH:-1}
WIDTH=${WIDTH:-64}
FALSE_EVERY=${FALSE_EVERY:-100}
PATTERN=${PATTERN:-domains}
case "$PATTERN" in
  domains | smooth) ;;
  *) echo "bench_daemon.sh: PATTERN must be domains or smooth, not '$PATTERN'" >&2; exit 2 ;;
esac
if [ "$PATTERN" = domains ]; then NOISE=${NOISE:-5e-11}; else NOISE=${NOISE:-2e-11}; fi
url="udpm://239.255.76.67:7667?ttl=0"
work=$(mktemp -d /tmp/tipforced-bench.XXXXXX)
trap 'rm -rf "$work"' EXIT

cat > "$work/bench.toml" <<TOML
[daemon]
queue_capacity = $QUEUE
stats_period_s = 1.0
backend = "cpu"

[probe.tip]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
quality_factor = 100
modes = $MODES
model = "spring"
unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }
TOML

max_windows=$(( RATE * DURATION ))
echo "generating $max_windows windows of 1250 samples ($PATTERN pattern, noise $NOISE m, $MODES modes; lines of $WIDTH, UNKNOWN first; a false continuation every $FALSE_EVERY)..."
lines=()
[ "$WIDTH" -gt 0 ] && lines=(--width "$WIDTH" --line-starts-unknown)
"$tool" scan --config "$work/bench.toml" --windows "$max_windows" --samples 1250 "${lines[@]}" \
  --false-continuation-every "$FALSE_EVERY" --pattern "$PATTERN" --noise-m "$NOISE" --out "$work/scan.lcmlog" >/dev/null

# run RATE: prints "received done dropped p50_us p99_us max_us sent"
run() {
  local rate=$1 n=$(( $1 * DURATION ))
  [ "$n" -gt "$max_windows" ] && n=$max_windows
  rm -f "$work/out.lcmlog"
  "$tipforced" --config "$work/bench.toml" --input-url "$url" --output-url "file://$work/out.lcmlog?mode=w" \
    2>"$work/daemon.log" &
  local pid=$!
  sleep 0.5
  "$tool" pace --url "$url" --in "$work/scan.lcmlog" --rate "$rate" --count "$n" >"$work/pace.log"
  # Let the queue drain (at most QUEUE windows), then stop.
  sleep 2
  kill -TERM $pid
  wait $pid || true
  "$tool" summarize --in "$work/out.lcmlog" > "$work/summary.txt"
  local est lat stats
  est=$(grep '^estimates' "$work/summary.txt")
  stats=$(grep '^stats' "$work/summary.txt")
  local received done dropped p50 p99 max
  received=$(sed -E 's/.*received ([0-9]+).*/\1/' <<<"$stats")
  done=$(sed -E 's/.* done ([0-9]+).*/\1/' <<<"$stats")
  dropped=$(sed -E 's/.*dropped ([0-9]+).*/\1/' <<<"$stats")
  p50=$(sed -E 's/.*p50 ([0-9.]+).*/\1/' <<<"$est")
  p99=$(sed -E 's/.*p99 ([0-9.]+).*/\1/' <<<"$est")
  max=$(sed -E 's/.*max ([0-9.]+).*/\1/' <<<"$est")
  echo "$received $done $dropped $p50 $p99 $max $n"
}

echo "== $RATE windows/s for $DURATION s (queue $QUEUE) =="
read -r received done dropped p50 p99 max n < <(run "$RATE")
echo "sent $n, received $received, estimates $done, dropped $dropped"
echo "receive->publish latency: p50 $((${p50%.*}/1000)) ms, p99 $((${p99%.*}/1000)) ms, max $((${max%.*}/1000)) ms"
grep -h "final stats" "$work/daemon.log" || true
solved_per_s=$(awk -v d="$done" -v t="$DURATION" 'BEGIN{printf "%.1f", d/t}')
echo "solved: $done windows over a ${DURATION} s stream (~$solved_per_s windows/s sustained)"

[ "$SEARCH" = 1 ] || exit 0
echo "== highest rate without drops =="
lo=0; hi=$RATE
if [ "$dropped" = 0 ] && [ "$received" = "$n" ]; then
  echo "no drops at $RATE/s; raise RATE to search higher"; exit 0
fi
while [ $(( hi - lo )) -gt $(( hi / 10 + 1 )) ]; do
  mid=$(( (lo + hi) / 2 ))
  read -r received done dropped p50 p99 max n < <(run "$mid")
  if [ "$dropped" = 0 ] && [ "$received" = "$n" ]; then
    echo "  $mid/s: no drops (p99 $((${p99%.*}/1000)) ms)"; lo=$mid
  else
    echo "  $mid/s: $dropped dropped of $received"; hi=$mid
  fi
done
echo "highest rate without drops: about $lo windows/s (dropping at $hi/s)"
