#!/bin/sh
# The main job on the bundled data, run by `make demo` after the build.
# Today: the SH-visibility accuracy table at 4 bands against ray-tested truth, with both bundled
# environment maps (about half a minute on two cores).
set -e
PEN=${1:-build/penumbra}
OUT=${PEN_DEMO_OUT:-out/demo}
mkdir -p "$OUT"
echo "penumbra demo: SH visibility accuracy against ray-tested truth (penumbra sh-accuracy --bands 4)"
"$PEN" sh-accuracy --bands 4 | tee "$OUT/sh-accuracy.txt"
echo
echo "penumbra demo: the table is in $OUT/sh-accuracy.txt; see README.md for what it means."
