#!/bin/sh
# The main job on the bundled data, run by `make demo` after the build:
#   1. render Spot on the ground plane under both bundled environment maps, with SH soft shadows
#      and without (the unshadowed baseline of shadow-free differentiable rasterizers);
#   2. ray-trace the same scene with the Embree reference renderer and measure both renders'
#      error against it;
#   3. print the SH-visibility accuracy table at 4 bands.
# About a minute on two cores (the first run also fits Spot's 32 spheres, then caches them).
set -e
PEN=${1:-build/penumbra}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=${PEN_DEMO_OUT:-out/demo}
SPP=${PEN_DEMO_SPP:-64}
mkdir -p "$OUT"
for env in city interior; do
    scene="$ROOT/examples/scenes/spot_$env.json"
    echo "== Spot under $env.hdr (512x512, 32 fitted spheres, 4 SH bands)"
    "$PEN" render "$scene" -o "$OUT/spot_$env.png"
    "$PEN" render "$scene" -o "$OUT/spot_$env.exr"
    "$PEN" render "$scene" -o "$OUT/spot_${env}_noshadows.exr" --no-shadows
    "$PEN" reference "$scene" -o "$OUT/spot_${env}_reference.exr" --spp "$SPP" --lighting sh
    "$PEN" reference "$scene" -o "$OUT/spot_${env}_reference.png" --spp "$SPP" --lighting sh >/dev/null
    printf '   SH shadows  vs reference: '
    "$PEN" compare "$OUT/spot_$env.exr" "$OUT/spot_${env}_reference.exr"
    printf '   no shadows  vs reference: '
    "$PEN" compare "$OUT/spot_${env}_noshadows.exr" "$OUT/spot_${env}_reference.exr"
done
echo
echo "== SH visibility accuracy against ray-tested truth (penumbra sh-accuracy --bands 4)"
"$PEN" sh-accuracy --bands 4 | tee "$OUT/sh-accuracy.txt"
echo
echo "penumbra demo: images and tables are in $OUT/ (spot_*.png: SH render, spot_*_reference.png:"
echo "ray-traced truth at $SPP spp); README.md explains the numbers."
