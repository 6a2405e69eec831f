#!/bin/sh
# Runs a command inside a private network namespace that stands for a small LAN: a bridge (br0)
# in that namespace, and N more namespaces ("hosts"), each joined to the bridge by a veth pair,
# with a link-local address and a multicast route over the link. The command runs on the
# bridge's namespace, which has an address too and is a host itself (the acquisition). Host i
# (1..N) is entered with
#   nsenter --net=/proc/PID/ns/net PROGRAM ...
# where PID is the i-th entry of $TFD_HOST_PIDS, the processes that hold the namespaces.
# Multicast with TTL 1 crosses the bridge; nothing ever leaves these namespaces (the tests send
# only to 239.255.76.67). Exits 77 (ctest SKIP) when the namespaces cannot be made.
# Usage: netns_hosts.sh N COMMAND [ARGS...]
set -u
hosts=$1
shift
if [ "${TFD_IN_NETNS:-0}" != 1 ]; then
  export TFD_IN_NETNS=1
  if [ "$(id -u)" = 0 ] && unshare --net true 2>/dev/null; then
    exec unshare --net "$0" "$hosts" "$@"
  fi
  if unshare --net --map-root-user true 2>/dev/null; then
    exec unshare --net --map-root-user "$0" "$hosts" "$@"
  fi
  echo "SKIP: cannot create a network namespace (unshare --net and --map-root-user not permitted)"
  exit 77
fi
skip() {
  echo "SKIP: $1"
  exit 77
}
command -v nsenter >/dev/null 2>&1 || skip "nsenter not found (util-linux)"
ip link set lo up || skip "cannot configure the namespace's loopback (is iproute2 installed?)"
# No IGMP snooping: the bridge floods multicast to every port, as a plain switch does.
ip link add br0 type bridge mcast_snooping 0 forward_delay 0 || skip "cannot create a bridge"
ip link set br0 up
ip addr add 169.254.77.1/24 dev br0
ip route add 224.0.0.0/4 dev br0

pids=""
cleanup() {
  for pid in $pids; do kill "$pid" 2>/dev/null; done
}
trap cleanup EXIT
i=1
while [ "$i" -le "$hosts" ]; do
  # The holder: a process in a network namespace of its own, for as long as the command runs.
  unshare --net sleep 86400 &
  pid=$!
  pids="$pids $pid"
  # Until the holder has entered its namespace, /proc/PID/ns/net is still ours.
  tries=0
  while [ "$(readlink /proc/$pid/ns/net)" = "$(readlink /proc/self/ns/net)" ] && [ $tries -lt 100 ]; do
    sleep 0.05
    tries=$((tries + 1))
  done
  ip link add "host$i" type veth peer name eth0 netns "$pid" || skip "cannot create a veth pair"
  ip link set "host$i" master br0 up
  nsenter --net=/proc/$pid/ns/net sh -c "ip link set lo up && ip link set eth0 up && \
    ip addr add 169.254.77.$((10 + i))/24 dev eth0 && ip route add 224.0.0.0/4 dev eth0" ||
    skip "cannot configure host $i's link"
  i=$((i + 1))
done
export TFD_HOST_PIDS="${pids# }"
"$@"
exit $?
