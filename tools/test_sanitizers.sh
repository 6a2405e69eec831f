#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (issue 10): a GCC build in
# build-asan (CPU only, portable), then ctest there without the slow tests. Every spawned
# tipforced and tipforce is instrumented too; a report fails its test (halt_on_error, leaks on).
# Not part of tools/test.sh: on the 2-core CI machine the build alone takes longer than CI's
# budget leaves (README: what runs where). Usage: tools/test_sanitizers.sh [BUILD_DIR]
#   env: SAN_JOBS (default nproc), SAN_EXCLUDE (ctest -E regex of tests left out; default: the
#   slow ones, listed below with their times)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build-asan}
jobs=${SAN_JOBS:-$(nproc)}
# Without UBSan's vptr check: GCC 12's instrumentation of LCM's header-only member-function
# subscriptions (lcm::LCMMHUntypedSubscription::cb_func) calls through a garbage object pointer; a
# 15-line program that subscribes a member function on memq:// and publishes once segfaults under
# g++ -fsanitize=undefined (and runs clean without vptr, plain, under ASan alone, or with clang's
# -fsanitize=address,undefined). Every other UBSan check stays on.
flags="-fsanitize=address,undefined -fno-sanitize=vptr -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
t0=$(date +%s)
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTIPFORCE_CUDA=OFF -DTIPFORCE_NATIVE=OFF \
  -DCMAKE_CXX_FLAGS="$flags" -DCMAKE_C_FLAGS="$flags" \
  -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" -DCMAKE_SHARED_LINKER_FLAGS="-fsanitize=address,undefined" \
  > "$build.configure.log" 2>&1 || { cat "$build.configure.log"; exit 1; }
cmake --build "$build" -j"$jobs"
t1=$(date +%s)
# Slow under the sanitizers (times on the 2-core machine, see docs/issue-10-safety.md): the
# honesty test (label long), the forward-solver sweep against the adaptive reference, and the
# 4096-window poisoning scan, which the release build runs.
exclude=${SAN_EXCLUDE:-ForwardSolverSweep|Poisoning|Honesty}
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0:halt_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
# fontconfig's process-lifetime caches (the maps' text, through Pango) are not leaks of ours.
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/tools/lsan.supp:print_suppressions=0}
(cd "$build" && ctest -j"$jobs" -LE long -E "$exclude" --output-on-failure --timeout 1800)
t2=$(date +%s)
echo "sanitizers: build $((t1 - t0)) s, tests $((t2 - t1)) s (left out: -L long and -E '$exclude')"
