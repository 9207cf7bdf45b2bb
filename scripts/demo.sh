# The main job on the bundled data, run by `make demo` after the build:
#   1. render Spot on the ground plane under both bundled environment maps: with the lights found
#      in the map (the default: sun and lamps as disk lights with their own soft shadows, the rest
#      of the map in 4 SH bands), with the SH light alone ("lights": "none", the renderer before
#      disk lights), and without shadows (the baseline of shadow-free differentiable rasterizers);
#   2. ray-trace the same scene with the Embree reference renderer under the FULL map (the light a
#      photo has) and measure the three renders' error against it; and ray-trace it under the
#      light the renderer uses (--lighting sh: SH part plus the lights) to separate the visibility
#      model's error from the lighting's;
#   3. print the SH-visibility accuracy table at 4 bands;
#   4. solve the headline inverse problem: Spot's lighting and 6-D pose recovered together from
#      a ray-traced image (256x256), with shadows and with --no-shadows, metrics side by side
#      (the SH light alone, "lights": "none" in examples/optimize);
#   5. the sun found from one image (research/experiments/sun/run.sh, small): Spot under the
#      full city map, SH from black and no lights at the start; the optimizer's global search
#      creates the sun's disk light, Adam refines it with the SH, and the SH alone is fitted
#      beside it.
# A few minutes on two cores (the first run also fits Spot's 32 spheres, then caches them).
set -e
PEN=${1:-build/penumbra}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OUT=${PEN_DEMO_OUT:-out/demo}
SPP=${PEN_DEMO_SPP:-64}
mkdir -p "$OUT"
for env in city interior; do
    scene="$ROOT/examples/scenes/spot_$env.json"
    # The same scene with the SH light alone (paths made absolute for the copy in $OUT).
    none="$OUT/spot_${env}_nolights.json"
    sed -e 's|"lighting": {|"lighting": {"lights": "none", |' -e "s|[.][.]/[.][.]/data|$ROOT/data|g" \
        "$scene" > "$none"
    echo "== Spot under $env.hdr (512x512, 32 fitted spheres, 4 SH bands + the map's lights)"
    "$PEN" render "$scene" -o "$OUT/spot_$env.png"
    "$PEN" render "$scene" -o "$OUT/spot_$env.exr"
    "$PEN" render "$none" -o "$OUT/spot_${env}_nolights.exr"
    "$PEN" render "$none" -o "$OUT/spot_${env}_nolights.png"
    "$PEN" render "$scene" -o "$OUT/spot_${env}_noshadows.exr" --no-shadows
    "$PEN" reference "$scene" -o "$OUT/spot_${env}_truth.exr" --spp "$((4 * SPP))" \
        --lighting envmap > /dev/null
    "$PEN" reference "$scene" -o "$OUT/spot_${env}_truth.png" --spp "$((4 * SPP))" \
        --lighting envmap > /dev/null
    "$PEN" reference "$scene" -o "$OUT/spot_${env}_reference.exr" --spp "$SPP" --lighting sh \
        > /dev/null
    echo "   against the ray-traced truth under the full map ($((4 * SPP)) spp):"
    printf '     with the lights (default): '
    "$PEN" compare "$OUT/spot_$env.exr" "$OUT/spot_${env}_truth.exr"
    printf '     SH light alone ("none"):   '
    "$PEN" compare "$OUT/spot_${env}_nolights.exr" "$OUT/spot_${env}_truth.exr"
    printf '     no shadows:                '
    "$PEN" compare "$OUT/spot_${env}_noshadows.exr" "$OUT/spot_${env}_truth.exr"
    printf '   against exact visibility under the same light (--lighting sh, %s spp): ' "$SPP"
    "$PEN" compare "$OUT/spot_$env.exr" "$OUT/spot_${env}_reference.exr"
done
echo
echo "== SH visibility accuracy against ray-tested truth (penumbra sh-accuracy --bands 4)"
"$PEN" sh-accuracy --bands 4 | tee "$OUT/sh-accuracy.txt"

echo
echo "== Inverse problem: Spot's lighting (4 SH bands, no disk lights) and pose from a ray-traced image"
echo "   (256x256, start 10.8 degrees and 0.1 away; examples/optimize/spot_demo.json)"
"$PEN" reference "$ROOT/examples/optimize/spot_truth.json" -o "$OUT/spot_target.exr" --spp 256 \
    --lighting sh > /dev/null
for mode in shadows no-shadows; do
    flag=""
    [ $mode = no-shadows ] && flag=--no-shadows
    "$PEN" optimize "$ROOT/examples/optimize/spot_demo.json" -o "$OUT/inverse_$mode" \
        --target "$OUT/spot_target.exr" $flag -q
done
. "$ROOT/scripts/result_table.sh"
row() { # label printf-format name
    result_row "$1" "$2" "$3" "$OUT/inverse_shadows" "$OUT/inverse_no-shadows" 26 12
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
echo "== The sun found from one image (research/experiments/sun/run.sh, 64 spp, 100 iterations)"
PEN_SUN_OUT="$OUT/sun" PEN_SUN_SPP=64 PEN_SUN_ITERATIONS=100 \
    sh "$ROOT/research/experiments/sun/run.sh" "$PEN"
echo
echo "penumbra demo: images and tables are in $OUT/ (spot_<map>.png: render with the lights,"
echo "spot_<map>_nolights.png: SH light alone, spot_<map>_truth.png: ray-traced under the full map);"
echo "README.md explains the numbers."
