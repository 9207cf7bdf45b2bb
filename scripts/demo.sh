#!/bin/sh
# The main job on the bundled data, run by `make demo` after the build:
#   1. render Spot on the ground plane under both bundled environment maps, with SH soft shadows
#      and without (the unshadowed baseline of shadow-free differentiable rasterizers);
#   2. ray-trace the same scene with the Embree reference renderer and measure both renders'
#      error against it;
#   3. print the SH-visibility accuracy table at 4 bands;
#   4. solve the headline inverse problem: Spot's lighting and 6-D pose recovered together from
#      a ray-traced image (256x256), with shadows and with --no-shadows, metrics side by side.
# About two minutes on two cores (the first run also fits Spot's 32 spheres, then caches them).
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
echo "== Inverse problem: Spot's lighting (4 SH bands) and pose from a ray-traced image"
echo "   (256x256, start 10.8 degrees and 0.1 away; examples/optimize/spot_demo.json)"
"$PEN" reference "$ROOT/examples/optimize/spot_truth.json" -o "$OUT/spot_target.exr" --spp 256 \
    --lighting sh > /dev/null
for mode in shadows no-shadows; do
    flag=""
    [ $mode = no-shadows ] && flag=--no-shadows
    "$PEN" optimize "$ROOT/examples/optimize/spot_demo.json" -o "$OUT/inverse_$mode" \
        --target "$OUT/spot_target.exr" $flag -q
done
# A member of a result.json ("-" when absent).
field() { # file name
    v=$(sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([^,]*\),\{0,1\}$/\1/p" "$1" | head -n 1)
    echo "${v:--}"
}
row() { # label printf-format name
    a=$(field "$OUT/inverse_shadows/result.json" "$3")
    b=$(field "$OUT/inverse_no-shadows/result.json" "$3")
    printf "   %-26s %12s %12s\n" "$1" "$(printf "$2" "$a")" "$(printf "$2" "$b")"
}
printf "   %-26s %12s %12s\n" "" "shadows" "no shadows"
row "iterations" "%s" iterations
row "seconds" "%.1f" seconds
row "rotation error (deg)" "%.2f" rotation_error_deg
row "translation error" "%.4f" translation_error
row "lighting rel. error" "%.3f" lighting_rel_error
row "image RMSE vs target" "%.4f" image_rmse
echo "   outputs: $OUT/inverse_shadows/ and $OUT/inverse_no-shadows/ (compare.png: target,"
echo "   start, result, error; result.json, scene.json, loss.svg, snapshots/)"
echo
echo "penumbra demo: images and tables are in $OUT/ (spot_*.png: SH render, spot_*_reference.png:"
echo "ray-traced truth at $SPP spp); README.md explains the numbers."
