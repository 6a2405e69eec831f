#!/usr/bin/env bash
# lcm-spy with tipforce's message types. Debian's /usr/bin/lcm-spy passes -Xincgc, which Java 9+
# refuses ("Unrecognized option: -Xincgc"), and knows none of tipforce's types; this starts the
# same spy (lcm.spy.Spy from LCM's lcm.jar) with the types jar the build makes.
#
#   tools/lcm-spy.sh [--jar PATH] [--dry-run] [lcm-spy options, e.g. --lcm-url udpm://239.255.76.67:7667]
#
# The types jar: --jar, else $TIPFORCE_TYPES_JAR, else build/tools/java/tipforce_types.jar, else
# the installed share/tipforce/java/tipforce_types.jar. Needs a Java runtime and lcm.jar
# (apt-get install default-jdk-headless liblcm-java) and a display.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
jar=${TIPFORCE_TYPES_JAR:-}
dry=0
args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --jar) jar=$2; shift 2 ;;
    --dry-run) dry=1; shift ;;
    *) args+=("$1"); shift ;;
  esac
done
if [ -z "$jar" ]; then
  for candidate in "$here/../build/tools/java/tipforce_types.jar" "$here/../share/tipforce/java/tipforce_types.jar" \
                   /usr/local/share/tipforce/java/tipforce_types.jar /usr/share/tipforce/java/tipforce_types.jar; do
    if [ -f "$candidate" ]; then jar=$candidate; break; fi
  done
fi
[ -n "$jar" ] && [ -f "$jar" ] || {
  echo "lcm-spy.sh: no tipforce_types.jar (build with javac and liblcm-java installed, or give --jar)" >&2; exit 2; }
lcm_jar=/usr/share/java/lcm.jar
[ -f "$lcm_jar" ] || { echo "lcm-spy.sh: $lcm_jar not found (apt-get install liblcm-java)" >&2; exit 2; }
classpath=$lcm_jar:$jar
# The spy's charts use jchart2d where it is installed; the rest works without.
[ -f /usr/share/java/jchart2d.jar ] && classpath=$classpath:/usr/share/java/jchart2d.jar
cmd=(java -Djava.net.preferIPv4Stack=true -Xmx128m -Xms64m -ea -cp "$classpath" lcm.spy.Spy "${args[@]+"${args[@]}"}")
if [ "$dry" = 1 ]; then
  printf '%q ' "${cmd[@]}"; echo
  exit 0
fi
exec "${cmd[@]}"
