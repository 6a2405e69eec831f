#!/usr/bin/env bash
# tools/lcm-spy.sh starts LCM's spy on this Java (no -Xincgc) and the spy finds every tipforce type
# in the jar the build made. Headless: the spy gets as far as opening its window, after it has
# scanned its classpath for types, and that is what is checked.
set -euo pipefail
src=$1 jar=$2
n_types=$(ls "$src"/msgs/*.lcm | wc -l)
out=$(JAVA_TOOL_OPTIONS=-Djava.awt.headless=true timeout 60 "$src/tools/lcm-spy.sh" --jar "$jar" --lcm-url memq:// 2>&1 || true)
if grep -q "Unrecognized option" <<< "$out"; then echo "$out"; exit 1; fi
grep -q "Found $n_types LCM types" <<< "$out" || { echo "$out" | grep -v ClassDiscoverer | head -20; echo "expected: Found $n_types LCM types"; exit 1; }
echo "lcm-spy found the $n_types tipforce types in $jar"
