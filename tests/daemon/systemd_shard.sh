#!/usr/bin/env bash
# Issue 12 and systemd.
#   systemd_shard.sh verify BUILD_DIR
#     Installs the build to a temporary prefix and checks the template unit there: ExecStart names
#     the installed tipforced with --shard-index %i, and systemd-analyze verifies an instance.
#     Exit 77 (skipped) without systemd-analyze.
#   systemd_shard.sh restart TIPFORCED TFD_TOOL   (inside netns_run.sh's namespace)
#     Acceptance 2: two shards (by line) as transient units (systemd-run, Restart=always), joined
#     to this network namespace; the acquisition streams windows; shard 1 is killed (SIGKILL).
#     systemd must restart it (NRestarts >= 1, a new MainPID, answers again), and the windows of
#     its share sent while it was down are the ones the acquisition saw unanswered. Exit 77 where
#     systemd is not running as the init system, or without root (transient system units).
set -euo pipefail
mode=${1:?verify or restart}

if [ "$mode" = verify ]; then
  build=${2:?build directory}
  command -v systemd-analyze >/dev/null 2>&1 || { echo "SKIP: systemd-analyze not found"; exit 77; }
  prefix=$(mktemp -d)
  trap 'rm -rf "$prefix"' EXIT
  cmake --install "$build" --prefix "$prefix" >"$prefix.log" 2>&1 || { cat "$prefix.log"; rm -f "$prefix.log"; exit 1; }
  rm -f "$prefix.log"
  unit=$prefix/lib/systemd/system/tipforced@.service
  [ -f "$unit" ] || { echo "$unit was not installed"; exit 1; }
  grep -qx "ExecStart=$prefix/bin/tipforced --config /etc/tipforce/tipforced.toml --shard-index %i" "$unit" || {
    echo "ExecStart of the template is not the installed tipforced with --shard-index %i:"
    grep ExecStart "$unit"
    exit 1
  }
  # An instance, as `systemctl start tipforced@1` makes it: the template resolved in its directory.
  (cd "$(dirname "$unit")" && systemd-analyze verify ./tipforced@1.service)
  echo "systemd-analyze verify tipforced@1.service (from $unit): ok"
  exit 0
fi

[ "$mode" = restart ] || { echo "unknown mode $mode"; exit 2; }
tipforced=${2:?tipforced}
tool=${3:?tfd_tool}
[ -d /run/systemd/system ] || { echo "SKIP: systemd is not the init system here (no /run/systemd/system)"; exit 77; }
command -v systemd-run >/dev/null 2>&1 || { echo "SKIP: systemd-run not found"; exit 77; }
# Real root, not the root of a user namespace (netns_run.sh makes one where it is not root).
[ "$(id -u)" = 0 ] && [ "$(awk '{print $1 $2 $3}' /proc/self/uid_map)" = 004294967295 ] ||
  { echo "SKIP: transient system units need root"; exit 77; }
systemctl show -p Version --value >/dev/null 2>&1 || { echo "SKIP: cannot reach the system manager"; exit 77; }
[ "${TFD_IN_NETNS:-0}" = 1 ] || { echo "SKIP: run through netns_run.sh"; exit 77; }
command -v lcm-logger >/dev/null 2>&1 || { echo "SKIP: lcm-logger not found"; exit 77; }

work=$(mktemp -d /tmp/tipforced-systemd.XXXXXX)
url="udpm://239.255.76.67:7667?ttl=0"
units=()
cleanup() {
  for u in "${units[@]}"; do systemctl stop "$u" >/dev/null 2>&1 || true; systemctl reset-failed "$u" >/dev/null 2>&1 || true; done
  [ -n "${logger:-}" ] && kill "$logger" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
cat > "$work/c.toml" <<TOML
[daemon]
stats_period_s = 0.5
backend = "cpu"
cpu_threads = 1
shard = { count = 2, by = "line" }
[probe.tip]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
modes = 3
model = "spring"
unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }
TOML
# 600 windows of 10 per line, at 40 windows/s: 15 s.
"$tool" scan --config "$work/c.toml" --windows 600 --samples 400 --out "$work/scan.lcmlog" >/dev/null
lcm-logger -f --lcm-url="$url" --channel=TIPFORCE_ESTIMATE "$work/rec.lcmlog" >/dev/null 2>&1 &
logger=$!
for i in 0 1; do
  u=tipforced-shardtest-$$-$i
  units+=("$u")
  # The unit joins this test's network namespace: its multicast never leaves it.
  systemd-run --unit="$u" -p Type=notify -p NotifyAccess=main -p Restart=always -p RestartSec=1 \
    -p NetworkNamespacePath=/proc/$$/ns/net \
    "$tipforced" --config "$work/c.toml" --shard-index "$i" --input-url "$url" >/dev/null
done
pid_before=$(systemctl show -p MainPID --value "${units[1]}")
"$tool" pace --url "$url" --in "$work/scan.lcmlog" --rate 40 >/dev/null &
pacer=$!
sleep 4
kill -KILL "$pid_before"
wait $pacer
sleep 3
restarts=$(systemctl show -p NRestarts --value "${units[1]}")
pid_after=$(systemctl show -p MainPID --value "${units[1]}")
state=$(systemctl is-active "${units[1]}" || true)
for u in "${units[@]}"; do systemctl stop "$u"; done
sleep 1
kill -INT $logger; wait $logger || true; logger=
# Which windows were answered (the acquisition's view), by line parity (shard = pixel_y mod 2).
"$tool" summarize --in "$work/rec.lcmlog" --print | awk '/^[0-9]+ / {print $1}' | sort -n | uniq > "$work/answered.txt"
unanswered0=0; unanswered1=0; answered1_late=0
for seq in $(seq 0 599); do
  line=$(( seq / 10 ))
  if grep -qx "$seq" "$work/answered.txt"; then
    [ $(( line % 2 )) = 1 ] && [ "$seq" -ge 400 ] && answered1_late=$((answered1_late + 1))
  else
    if [ $(( line % 2 )) = 0 ]; then unanswered0=$((unanswered0 + 1)); else unanswered1=$((unanswered1 + 1)); fi
  fi
done
echo "shard 1: killed (pid $pid_before), restarts $restarts, now pid $pid_after ($state)"
echo "acquisition: 600 windows sent; unanswered: shard 0 $unanswered0, shard 1 $unanswered1; shard 1 answered $answered1_late of its windows after seq 400"
fail=0
[ "${restarts:-0}" -ge 1 ] || { echo "FAIL: systemd did not restart shard 1"; fail=1; }
[ "$pid_after" != "$pid_before" ] && [ "$pid_after" != 0 ] || { echo "FAIL: no new main process"; fail=1; }
[ "$unanswered0" = 0 ] || { echo "FAIL: shard 0 left windows unanswered"; fail=1; }
[ "$unanswered1" -gt 0 ] || { echo "FAIL: no window went unanswered while shard 1 was down (was it killed?)"; fail=1; }
[ "$answered1_late" -gt 0 ] || { echo "FAIL: the restarted shard 1 answered nothing"; fail=1; }
exit $fail
