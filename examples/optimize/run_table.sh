#!/bin/sh
# The inverse-problem experiment table of docs/optimize.md: every task of this folder (lighting,
# albedo, pose, lighting + pose; Spot and Bob) solved with shadows and with --no-shadows, against
# targets ray-traced by `penumbra reference` from the ground-truth scenes.
# Usage: sh examples/optimize/run_table.sh PENUMBRA_BIN [LIGHTING [MESH ...]]
#   LIGHTING  the targets' light: envmap (default; the map itself, so sharp shadows the 4-band
#             model cannot reproduce) or sh (the map's 4-band projection, which the model
#             represents exactly: what is left is the error of the proxies and SH visibility)
#   MESH      spot, bob (default both)
# Writes out/optimize/ (ignored by git): targets/<mesh>.exr (envmap) and <mesh>_sh.exr, one folder
# per run (LIGHTING/<mesh>_<task>_<shadows|no-shadows>/ with result.json, scene.json,
# final.png, compare.png, loss.svg), LIGHTING/results.tsv, and a markdown table on stdout.
# Cost on the 2-core development machine: about 0.35 s per shadowed iteration at 256x256.
set -eu
BIN=$1
LIGHTING=${2:-envmap}
[ $# -ge 2 ] && shift 2 || shift $#
MESHES=${*:-spot bob}
HERE=$(cd "$(dirname "$0")" && pwd)
TARGETS=$HERE/../../out/optimize/targets
OUT=$HERE/../../out/optimize/$LIGHTING
mkdir -p "$TARGETS" "$OUT"

# The value of a top-level or metrics member of a result.json ("-" when absent).
field() { # file name
    v=$(sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([^,]*\),\{0,1\}$/\1/p" "$1" | head -n 1)
    echo "${v:--}"
}
fmt() { # printf-format value
    case $2 in -|null) echo "-" ;; *) printf "$1" "$2" ;; esac
}

printf 'mesh\ttask\tshadows\titerations\tconverged\ts_per_it\tfinal_loss\timage_rmse\tlighting_rel_error\talbedo_psnr_db\talbedo_texel_psnr_db\talbedo_observed\trotation_error_deg\ttranslation_error\tvertex_rmse\n' > "$OUT/results.tsv"
echo "| mesh | task | shadows | iterations | s/it | image RMSE | lighting rel. error | albedo PSNR (dB) | rotation error (°) | translation error |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for mesh in $MESHES; do
    case $LIGHTING in
    envmap) target="$TARGETS/$mesh.exr" ;;
    sh) target="$TARGETS/${mesh}_sh.exr" ;;
    *) echo "unknown lighting $LIGHTING" >&2 && exit 2 ;;
    esac
    [ -s "$target" ] || "$BIN" reference "$HERE/${mesh}_truth.json" -o "$target" --spp 256 \
        --lighting $LIGHTING > /dev/null
    for task in lighting albedo pose lighting_pose; do
        for mode in shadows no-shadows; do
            dir="$OUT/${mesh}_${task}_$mode"
            flag=""
            [ $mode = no-shadows ] && flag=--no-shadows
            "$BIN" optimize "$HERE/${mesh}_$task.json" -o "$dir" --target "$target" $flag -q
            r="$dir/result.json"
            printf '%s\t%s\t%s' $mesh $task $mode >> "$OUT/results.tsv"
            for f in iterations converged seconds_per_iteration final_loss image_rmse \
                lighting_rel_error albedo_psnr_db albedo_texel_psnr_db albedo_observed rotation_error_deg \
                translation_error vertex_rmse; do
                printf '\t%s' "$(field "$r" $f)" >> "$OUT/results.tsv"
            done
            printf '\n' >> "$OUT/results.tsv"
            conv=""
            [ "$(field "$r" converged)" = true ] || conv=" (limit)"
            echo "| $mesh | $task | $mode | $(field "$r" iterations)$conv |" \
                "$(fmt %.2f "$(field "$r" seconds_per_iteration)") |" \
                "$(fmt %.4f "$(field "$r" image_rmse)") |" \
                "$(fmt %.3f "$(field "$r" lighting_rel_error)") |" \
                "$(fmt %.1f "$(field "$r" albedo_psnr_db)") |" \
                "$(fmt %.2f "$(field "$r" rotation_error_deg)") |" \
                "$(fmt %.4f "$(field "$r" translation_error)") |"
        done
    done
done
