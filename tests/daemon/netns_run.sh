#!/bin/sh
# Runs a command inside a private network namespace whose loopback carries multicast, so that the
# udpm tests never send a packet outside this process tree. Exits 77 (ctest SKIP_RETURN_CODE)
# when no namespace can be made (e.g. unprivileged user namespaces disabled).
# Usage: netns_run.sh COMMAND [ARGS...]
set -u
if [ "${TFD_IN_NETNS:-0}" != 1 ]; then
  export TFD_IN_NETNS=1
  if [ "$(id -u)" = 0 ] && unshare --net true 2>/dev/null; then
    exec unshare --net "$0" "$@"
  fi
  if unshare --net --map-root-user true 2>/dev/null; then
    exec unshare --net --map-root-user "$0" "$@"
  fi
  echo "SKIP: cannot create a network namespace (unshare --net and --map-root-user not permitted)"
  exit 77
fi
if ! { ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo; }; then
  echo "SKIP: cannot enable multicast on the namespace's loopback (is iproute2 installed?)"
  exit 77
fi
exec "$@"
