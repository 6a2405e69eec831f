#!/usr/bin/env bash
# The demo: set up, build, simulate a 64 x 64 scan of a soft cell on a stiff substrate, invert it
# through tipforced (file mode: the same code path as live), draw the maps, and report accuracy
# and speed; then the same cell recorded at 1 MHz (1250 samples per pixel), inverted and reported
# the same way. Everything lands in out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
build=${TIPFORCE_BUILD_DIR:-build}
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release > "$build.configure.log" 2>&1 || { cat "$build.configure.log"; exit 1; }
cmake --build "$build" -j"$(nproc)" --target tipforce tipforced
out=$PWD/out/demo
rm -rf "$out" && mkdir -p "$out"
config=tools/demo/demo.toml
# invert_and_map SCAN SUFFIX: simulate SCAN with the reference integrator into cell$SUFFIX.lcmlog,
# invert it through tipforced (file:// input at full speed, every estimate recorded, timed), and
# draw maps$SUFFIX/ (PNG + Gwyddion .gsf + CSV) with the accuracy against the truth.
invert_and_map() {
  local scan=$1 sfx=$2 start end
  "$build"/tools/tipforce simulate --config "$config" --probe afm1 --scan "$scan" --out "$out/cell$sfx.lcmlog"
  start=$(date +%s.%N)
  "$build"/daemon/tipforced --config "$config" --backend auto --log-level warn \
    --input-url "file://$out/cell$sfx.lcmlog?speed=0" --output-url "file://$out/estimates$sfx.lcmlog?mode=w"
  end=$(date +%s.%N)
  awk -v s="$start" -v e="$end" 'BEGIN { printf "tipforced: 4096 windows in %.1f s: %.0f windows/s\n", e - s, 4096 / (e - s) }'
  # tipforced does not pass the scan's scan_geometry_t on: --scan-log takes it from the windows.
  "$build"/tools/tipforce map --in "$out/estimates$sfx.lcmlog" --out "$out/maps$sfx" \
    --truth "$out/cell$sfx.lcmlog.truth.csv" --scan-log "$out/cell$sfx.lcmlog"
}
echo "== 64 x 64 pixels at 5 MHz (400 samples each): a soft cell (k 1.7-4 N/m) on a stiff substrate (12 N/m)"
echo "   (pooled along the scan line: parameter_drift_rel in $config; README Configuration)"
echo "   (a file is read as fast as the queue admits, so its windows wait in the full queue: the"
echo "    receive->publish latency below is queueing; live latency: tools/bench_daemon.sh)"
invert_and_map tools/demo/cell_scan.toml ""
# A scan that many acquisition systems record: 1 MHz, 1.25 ms per pixel (~2 min to simulate).
echo "== the same cell at 1 MHz: 64 x 64 pixels of 1250 samples"
invert_and_map tools/demo/cell_scan_1mhz.toml _1mhz
echo "== done: open $out/maps/truth_k_n_per_m.png and $out/maps/h_m.png (1 MHz: $out/maps_1mhz/)"
