#!/bin/sh
# Reproduces vocabulary/default.stitchvoc from its training data:
#  - the 15 photographs of Debian 12's lomiri-wallpapers-16.04 package (version 20.04.0-2;
#    licences CC-BY-4.0, CC-BY-SA-4.0 and CC0-1.0, see vocabulary/README.md), fetched with
#    apt-get download (needs access to a Debian archive);
#  - three synthetic survey flights rendered by stitch with seeds 101-103 (never seed 1, the
#    flight `stitch run` evaluates) at 45, 70 and 110 m, every 4th frame.
# Run from the repository root after building: vocabulary/train-default.sh [OUT]
set -eu
out=${1:-vocabulary/default.stitchvoc}
stitch=build/bin/stitch
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && apt-get download lomiri-wallpapers-16.04=20.04.0-2 >/dev/null && \
  dpkg-deb -x lomiri-wallpapers-16.04_20.04.0-2_all.deb photos)
for spec in "101 45" "102 70" "103 110"; do
  set -- $spec
  cat > "$work/flight.yaml" <<YAML
synthetic:
  seed: $1
  flight:
    num_frames: 600
    altitude_m: $2
YAML
  $stitch render --config "$work/flight.yaml" --failures none --out "$work/flight-$1" >/dev/null
done
$stitch vocab train --out "$out" --branching 10 --depth 5 --seed 1 \
  --images "$work/photos/usr/share/backgrounds" \
  --datasets "$work/flight-101,$work/flight-102,$work/flight-103" --every 4
