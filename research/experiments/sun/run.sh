# The sun-recovery experiment (docs/results/optimize.md "The sun found from one image",
# docs/optimize.md "Finding the lights"):
# Spot under the full city map, one ray-traced image (128x128), SH lighting from black and no
# lights at the start. Recovers the SH environment plus one disk light (the optimizer's global
# search creates it, then Adam refines everything), and the SH environment alone beside it; both
# judged by the angle to the map's sun and by the recovered lighting rendered from a novel view
# against the full-map truth there.
#   sh research/experiments/sun/run.sh [build/penumbra]
#   (env: PEN_SUN_OUT, PEN_SUN_SPP, PEN_SUN_ITERATIONS)
# About 1.5 minutes on the shared 2-core machine (nice'd), most of it the search and the descent.
set -e
PEN=${1:-build/penumbra}
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
OUT=${PEN_SUN_OUT:-out/sun}
SPP=${PEN_SUN_SPP:-256}
ITER=${PEN_SUN_ITERATIONS:+--iterations $PEN_SUN_ITERATIONS}
mkdir -p "$OUT"
# The observed image and the novel view's truth: the full map (--lighting envmap), not its SH.
# Another seed for the novel view, so that the two images' sampling noise is independent.
nice "$PEN" reference "$HERE/sun_truth.json" -o "$OUT/target.exr" --spp "$SPP" --lighting envmap \
    > /dev/null
nice "$PEN" reference "$HERE/sun_truth.json" -o "$OUT/target.png" --spp "$SPP" --lighting envmap \
    > /dev/null
nice "$PEN" reference "$HERE/sun_truth_novel.json" -o "$OUT/novel.exr" --spp "$SPP" \
    --lighting envmap --seed 2 > /dev/null
# What the model can reach: the truth's own light (the sun found in the map + the rest in 4 SH
# bands) rendered by penumbra from the novel view.
nice "$PEN" render "$HERE/sun_truth_novel.json" -o "$OUT/novel_model.exr" -q
floor=$("$PEN" compare "$OUT/novel_model.exr" "$OUT/novel.exr" |
        sed -n 's/.*"rel_rmse": \([^,]*\),.*/\1/p' | xargs printf %.4f)
OUTABS=$(cd "$OUT" && pwd)
for run in lights sh_only; do
    # the task with its paths made absolute and its images in $OUT
    sed -e "s|\"sun_|\"$HERE/sun_|g" -e "s|[.][.]/[.][.]/[.][.]/out/sun/|$OUTABS/|g" \
        "$HERE/sun_$run.json" > "$OUT/sun_$run.json"
    nice "$PEN" optimize "$OUT/sun_$run.json" -o "$OUT/$run" $ITER -q
done
. "$ROOT/scripts/result_table.sh"
row() { # label printf-format name
    result_row "$1" "$2" "$3" "$OUT/lights" "$OUT/sh_only" 44 14
}
echo "== The sun found from one image: Spot under the full city map, 128x128, $SPP spp,"
echo "   SH from black and no lights at the start (research/experiments/sun)"
printf "   %-44s %14s %14s\n" "" "SH + 1 light" "SH only"
row "light's angle to the sun (deg, goal <= 3)" "%.2f" light_direction_error_deg
row "novel view rel. RMSE vs full-map truth (<= 0.12)" "%.4f" image_rel_rmse
row "image RMSE (the fitted view)" "%.4f" image_rmse
row "search renders" "%s" renders
row "iterations" "%s" iterations
echo "   the truth's own light rendered by penumbra, novel view: rel. RMSE $floor (the model's floor)"
echo "   pictures: $OUT/lights/compare.png, $OUT/sh_only/compare.png; scenes: */scene.json"
