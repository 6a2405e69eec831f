#!/usr/bin/env bash
# Installs the build to a temporary prefix and checks the service unit there with systemd's own
# verifier: ExecStart must name the installed tipforced (issue 11: it named /usr/bin/tipforced,
# which `cmake --install` never writes). Exit 77 (skipped) where systemd-analyze is missing.
set -euo pipefail
build=$1
if ! command -v systemd-analyze > /dev/null 2>&1; then
  echo "SKIP: systemd-analyze not found (systemd not installed)"
  exit 77
fi
prefix=$(mktemp -d)
trap 'rm -rf "$prefix"' EXIT
cmake --install "$build" --prefix "$prefix" > "$prefix.install.log" 2>&1 || { cat "$prefix.install.log"; exit 1; }
rm -f "$prefix.install.log"
unit=$prefix/lib/systemd/system/tipforced.service
grep -qx "ExecStart=$prefix/bin/tipforced --config /etc/tipforce/tipforced.toml" "$unit" || {
  echo "ExecStart does not name $prefix/bin/tipforced:"; grep ExecStart "$unit"; exit 1; }
if grep -q '^ExecReload=' "$unit"; then echo "ExecReload is back, but tipforced does not reload"; exit 1; fi
[ -x "$prefix/bin/tipforced" ] || { echo "$prefix/bin/tipforced was not installed"; exit 1; }
systemd-analyze verify "$unit"
echo "systemd-analyze verify $unit: ok"
