#!/usr/bin/env bash
# Everything the tests need on a fresh machine: Debian packages, configure, build, run ctest.
# CUDA code is compiled where nvcc is found; GPU tests skip (with the reason) where no GPU is.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
build=${TIPFORCE_BUILD_DIR:-build}
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release > "$build.configure.log" 2>&1 || { cat "$build.configure.log"; exit 1; }
cmake --build "$build" -j"$(nproc)"
cd "$build"
ctest -j"$(nproc)" --output-on-failure --timeout 900
