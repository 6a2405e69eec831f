#!/usr/bin/env bash
# Issue 10's soak and overload measurements of tipforced on live udpm, inside a private network
# namespace (nothing leaves the machine; only 239.255.76.67 with TTL 0). Not part of CI.
#   soak:     N windows (default 100,000) paced at RATE windows/s (default 250), estimates published on
#             udpm (so the daemon watches its own echoes all along); RSS sampled every SAMPLE_S s.
#   overload: N windows (default 3,000) at RATE (default 2,500/s, about 10x what 2 cores solve),
#             a garbage message after every GARBAGE_EVERY-th window (default 50); the invariant
#             estimates + dropped + garbage = received is checked on the final stats.
# Usage: tools/soak_daemon.sh soak|overload [BUILD_DIR]   (env: N RATE SAMPLES MODES QUEUE SAMPLE_S)
# Prints the final stats line, the RSS samples, and the estimates recorded by lcm-logger.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
mode=${1:?soak or overload}
build=${2:-$root/build}
build=$(cd "$build" && pwd)
if [ "${TFD_IN_NETNS:-0}" != 1 ]; then
  exec "$root/tests/daemon/netns_run.sh" "$0" "$mode" "$build"
fi
tipforced=$build/daemon/tipforced
tool=$build/tests/daemon/tfd_tool
command -v lcm-logger >/dev/null || { echo "lcm-logger not found (liblcm-bin)"; exit 1; }
if [ "$mode" = soak ]; then
  N=${N:-100000}; RATE=${RATE:-250}; GARBAGE_EVERY=${GARBAGE_EVERY:-0}
else
  N=${N:-3000}; RATE=${RATE:-2500}; GARBAGE_EVERY=${GARBAGE_EVERY:-50}
fi
SAMPLES=${SAMPLES:-400}; MODES=${MODES:-3}; QUEUE=${QUEUE:-64}; SAMPLE_S=${SAMPLE_S:-10}
url="udpm://239.255.76.67:7667?ttl=0"
work=${WORK:-$(mktemp -d /tmp/tipforced-soak.XXXXXX)}
mkdir -p "$work"
cat > "$work/soak.toml" <<TOML
[daemon]
queue_capacity = $QUEUE
stats_period_s = 5.0
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
[probe.tip.inversion]
swarm_size = 24
max_generations = 25
warm_swarm_size = 12
warm_max_generations = 6
lm_max_iterations = 15
TOML
scan_windows=$N
[ "$scan_windows" -gt 100000 ] && scan_windows=100000
if [ ! -s "$work/scan.lcmlog" ]; then
  echo "generating $scan_windows windows of $SAMPLES samples ($MODES modes)..."
  "$tool" scan --config "$work/soak.toml" --windows "$scan_windows" --samples "$SAMPLES" --out "$work/scan.lcmlog" >/dev/null
fi
rm -f "$work/rec.lcmlog"
# A large receive buffer: datagrams the kernel drops before LCM reads them are invisible to
# tipforced's counters (the daemon's README says so); the test is of tipforced, not of the kernel.
in_url="$url&recv_buf_size=8388608"
lcm-logger -f --lcm-url="$in_url" --channel='TIPFORCE_(ESTIMATE|STATS)' "$work/rec.lcmlog" >"$work/logger.txt" 2>&1 &
logger=$!
"$tipforced" --config "$work/soak.toml" --input-url "$in_url" --output-url "$url" 2>"$work/daemon.log" &
pid=$!
sleep 1
: > "$work/rss.txt"
(
  t0=$(date +%s)
  while kill -0 $pid 2>/dev/null; do
    echo "$(( $(date +%s) - t0 )) $(awk '/VmRSS/ {print $2}' /proc/$pid/status 2>/dev/null)" >> "$work/rss.txt"
    sleep "$SAMPLE_S"
  done
) &
sampler=$!
"$tool" pace --url "$url" --in "$work/scan.lcmlog" --rate "$RATE" --count "$N" --garbage-every "$GARBAGE_EVERY" \
  | tee "$work/pace.txt"
# Let the queue drain, then stop as systemd does.
sleep 3
kill -TERM $pid
wait $pid && rc=0 || rc=$?
sleep 1
kill -INT $logger; wait $logger || true
kill $sampler 2>/dev/null || true
echo "tipforced exit $rc"
grep -h "final stats\|stopped" "$work/daemon.log" | tail -2
"$tool" summarize --in "$work/rec.lcmlog"
echo "RSS (s kB), first, middle and last samples:"
n_rss=$(wc -l < "$work/rss.txt")
sed -n "1p;$(( (n_rss + 1) / 2 ))p;${n_rss}p" "$work/rss.txt"
echo "RSS max/min over $n_rss samples: $(awk 'NR==1{mx=$2;mn=$2} {if($2>mx)mx=$2; if($2<mn)mn=$2} END{print mx" / "mn}' "$work/rss.txt") kB"
echo "work files: $work"
