#!/bin/bash
# A process on the aircraft's bus that publishes another flight's frames, statuses, keyframes and
# link statuses (docs/security.md, "A bus key for a side of several computers").
#
#   tools/security/bus-replay-attack.sh STITCH OUT record
#       flies 150 frames of the default flight and records those channels to OUT.lcmlog
#   tools/security/bus-replay-attack.sh STITCH OUT LOG [--set bus.key_file=KEY ...]
#       flies the same 150 frames while lcm-logplayer plays LOG onto the run's bus
#   tools/security/bus-replay-attack.sh STITCH OUT none [--set ...]
#       the same flight, clean
#
# STITCH: the stitch program (build/bin/stitch). Prints the run's summary lines and, per service,
# the last refusal it logged.
set -u
if [ $# -lt 3 ] || [ "$1" = -h ] || [ "$1" = --help ]; then
  sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
stitch=$1 out=$2 attack=$3
shift 3
rm -rf "$out"
"$stitch" run --max-frames 150 --out "$out" "$@" >"$out.log" 2>&1 &
run=$!
url=""
for _ in $(seq 100); do
  url=$(grep -o "bus udpm://[^ ,]*" "$out.log" | head -1 | cut -c5-)
  [ -n "$url" ] && break
  sleep 0.1
done
player=""
if [ "$attack" = record ]; then
  lcm-logger -q -c 'uav0/(FRAME|TRACKING_STATUS|LINK_STATUS|KEYFRAME)' --lcm-url="$url" -f "$out.lcmlog" &
  player=$!
elif [ "$attack" != none ]; then
  sleep 2
  lcm-logplayer --lcm-url="$url" "$attack" >/dev/null 2>&1 &
  player=$!
fi
wait $run
status=$?
[ -n "$player" ] && kill "$player" 2>/dev/null
grep -E "frames localized|submaps  |ATE RMSE" "$out.log"
for log in "$out"/logs/*.log; do
  last=$(grep "dropped a message" "$log" | tail -1)
  [ -n "$last" ] && echo "  $(basename "$log" .log): ${last#*dropped a message on }"
done
exit $status
