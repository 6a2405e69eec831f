#!/usr/bin/env bash
# Issue 12, acceptance 4: windows/s of a multi-line stream answered by one tipforced, and by two
# shards (by line) on the same host, each with one CPU thread. Live udpm inside a private network
# namespace (TTL 0; nothing leaves the machine). The acquisition sends the whole stream faster
# than it is solved, into queues that hold all of it (no drops), so the figure is what the
# daemons sustain: estimates / (first window received .. last estimate published).
# Usage: tools/bench_shards.sh [BUILD_DIR]   (env: LINES=40 WIDTH=10 SAMPLES=1250 MODES=3)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=${1:-$root/build}
build=$(cd "$build" && pwd)
if [ "${TFD_IN_NETNS:-0}" != 1 ]; then
  exec "$root/tests/daemon/netns_run.sh" "$0" "$build"
fi
tipforced=$build/daemon/tipforced
tool=$build/tests/daemon/tfd_tool
LINES=${LINES:-40}; WIDTH=${WIDTH:-10}; SAMPLES=${SAMPLES:-1250}; MODES=${MODES:-3}
n=$(( LINES * WIDTH ))
url="udpm://239.255.76.67:7667?ttl=0"
in_url="$url&recv_buf_size=8388608"
work=$(mktemp -d /tmp/tipforced-shards.XXXXXX)
trap '[ -n "${KEEP:-}" ] || rm -rf "$work"' EXIT
config() {  # config THREADS SHARD_LINE
  cat <<TOML
[daemon]
queue_capacity = $n
stats_period_s = 1.0
backend = "cpu"
cpu_threads = $1
$2
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
# The whole stream arrives at once and waits in the queue: with a latency budget counted from
# receipt, every window past the first second would be cut short (NOT_CONVERGED) rather than solved.
[probe.tip.inversion]
deadline_ms = 0
TOML
}
config 0 "" > "$work/one.toml"
config 1 "" > "$work/one1.toml"
config 1 'shard = { count = 2, by = "line" }' > "$work/shard.toml"
echo "generating $n windows ($LINES lines of $WIDTH) of $SAMPLES samples, $MODES modes..."
"$tool" scan --config "$work/one.toml" --windows "$n" --samples "$SAMPLES" --out "$work/scan.lcmlog" >/dev/null

run() {  # run NAME CONFIG [SHARDS]
  local name=$1 cfg=$2 shards=${3:-0} pids=()
  rm -f "$work/rec.lcmlog"
  lcm-logger -f --lcm-url="$in_url" --channel=TIPFORCE_ESTIMATE "$work/rec.lcmlog" >/dev/null 2>&1 &
  local logger=$!
  if [ "$shards" = 0 ]; then
    "$tipforced" --config "$cfg" --input-url "$in_url" --output-url "$url" 2>"$work/$name.log" &
    pids+=($!)
  else
    for i in $(seq 0 $(( shards - 1 ))); do
      "$tipforced" --config "$cfg" --shard-index "$i" --input-url "$in_url" --output-url "$url" 2>"$work/$name.$i.log" &
      pids+=($!)
    done
  fi
  sleep 1
  "$tool" pace --url "$url" --in "$work/scan.lcmlog" --rate 2000 >/dev/null
  # Until every window is answered, or nothing more comes for 10 s (lcm-logger writes in bursts;
  # the figure comes from the estimates' own time stamps, not from this wait), or 10 minutes.
  local t=0 got=0 before=-1 still=0
  while [ $t -lt ${WAIT_S:-600} ]; do
    sleep 1; t=$((t + 1))
    got=$("$tool" summarize --in "$work/rec.lcmlog" 2>/dev/null | awk '/^estimates/ {print $2}')
    got=${got:-0}
    [ "$got" -ge "$n" ] && break
    if [ "$got" = "$before" ]; then still=$((still + 1)); else still=0; fi
    [ $still -ge 10 ] && break
    before=$got
  done
  # CPU time each daemon got (user + system), to tell a slow daemon from a starved one.
  local cpu=""
  for p in "${pids[@]}"; do
    cpu+=" $(awk -v hz="$(getconf CLK_TCK)" '{printf "%.1f", ($14 + $15) / hz}' /proc/$p/stat) s"
  done
  kill -TERM "${pids[@]}"; wait "${pids[@]}" || true
  kill -INT $logger; wait $logger || true
  echo "== $name (CPU time per daemon:$cpu)"
  "$tool" summarize --in "$work/rec.lcmlog" | grep -E '^(estimates|throughput)'
  # The work: forward solves per window, overall and for the first window of each line.
  "$tool" summarize --in "$work/rec.lcmlog" --print | awk -v w="$WIDTH" '
    / solves=/ { split($0, a, "solves="); split(a[2], b, " "); s += b[1]; n++; if ($1 % w == 0) { f += b[1]; m++ } }
    END { if (n) printf "   forward solves per window %.0f; first window of a line %.0f\n", s / n, m ? f / m : 0 }'
  grep -h "tipforced stopped" "$work/$name"*.log | sed 's/^.*tipforced stopped: /   /'
}
uptime
[ -n "${ONLY_SHARDS:-}" ] || run "one daemon, cpu_threads = 0 (both cores)" "$work/one.toml"
[ -n "${ONLY_SHARDS:-}" ] || run "one daemon, cpu_threads = 1" "$work/one1.toml"
run "two shards by line, cpu_threads = 1 each" "$work/shard.toml" 2
uptime
