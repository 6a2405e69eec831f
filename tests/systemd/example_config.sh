#!/usr/bin/env bash
# The shipped example configuration (systemd/tipforced.toml.example) inverts windows of the demo's
# probe, afm1, as it is: a small scan simulated with the demo's settings, inverted with the example.
set -euo pipefail
tipforce=$1 src=$2
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
sed -e 's/^pixels_x = .*/pixels_x = 3/' -e 's/^pixels_y = .*/pixels_y = 1/' \
    -e 's|"cell_k_n_per_m.csv"|3.0|' -e 's|"cell_h_m.csv"|40e-9|' "$src/tools/demo/cell_scan.toml" > "$dir/scan.toml"
"$tipforce" simulate --config "$src/tools/demo/demo.toml" --probe afm1 --scan "$dir/scan.toml" --out "$dir/scan.lcmlog"
"$tipforce" invert --backend cpu --config "$src/systemd/tipforced.toml.example" --in "$dir/scan.lcmlog" --out "$dir/est.lcmlog" \
  | tee "$dir/summary"
grep -q "windows 3, .* rejected 0 " "$dir/summary"
