#!/usr/bin/env bash
# Everything the tests need on a fresh machine: Debian packages, configure, build, run ctest.
# CUDA code is compiled where nvcc is found; GPU tests skip (with the reason) where no GPU is.
# Where clang is installed (tools/setup.sh installs it), the libFuzzer targets are built in a
# separate ASan+UBSan build and each runs for FUZZ_SECONDS (default 30; 0 skips them).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
build=${TIPFORCE_BUILD_DIR:-build}
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release > "$build.configure.log" 2>&1 || { cat "$build.configure.log"; exit 1; }
cmake --build "$build" -j"$(nproc)"
(cd "$build" && ctest -j"$(nproc)" --output-on-failure --timeout 900)

if [ "${FUZZ_SECONDS:-30}" = 0 ]; then
  echo "fuzz: FUZZ_SECONDS=0, skipped"
elif command -v clang++ >/dev/null 2>&1; then
  fuzz_build=${TIPFORCE_FUZZ_BUILD_DIR:-build-fuzz}
  cmake -S . -B "$fuzz_build" -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DTIPFORCE_FUZZ=ON -DTIPFORCE_CUDA=OFF -DTIPFORCE_TESTS=OFF -DTIPFORCE_NATIVE=OFF \
    > "$fuzz_build.configure.log" 2>&1 || { cat "$fuzz_build.configure.log"; exit 1; }
  cmake --build "$fuzz_build" -j"$(nproc)" --target fuzz_window_decode fuzz_config fuzz_log_reader
  fuzz/run_fuzzers.sh "$fuzz_build"
else
  echo "fuzz: clang++ not found, fuzz targets skipped (tools/setup.sh installs clang)"
fi
