#!/usr/bin/env bash
# Installs the Debian packages tipforce builds and tests with. Idempotent: prints nothing and
# touches nothing when every package is already present.
set -euo pipefail
pkgs=(
  build-essential cmake pkg-config
  libeigen3-dev libtomlplusplus-dev libspdlog-dev libfmt-dev libcli11-dev
  libboost-dev libboost-system-dev
  liblcm-dev liblcm-bin libglib2.0-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libpng-dev libsystemd-dev nlohmann-json3-dev
  iproute2 util-linux
  parallel  # issue 12: GNU parallel runs `tipforce invert --shard` side by side (README recipe, ctest)
  clang libclang-rt-dev
  # issue 11: tipforce import (HDF5), maps through Cairo + Pango, the tests' PDF and Python checks
  libhdf5-dev libcairo2-dev libpango1.0-dev fonts-dejavu-core poppler-utils python3-numpy python3-h5py
  # issue 11: lcm-spy with tipforce's types (tools/lcm-spy.sh): javac, LCM's lcm.jar, the spy's charts
  default-jdk-headless liblcm-java libjchart2d-java
)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "setup: installing ${missing[*]}"
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
