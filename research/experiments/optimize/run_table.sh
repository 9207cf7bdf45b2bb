#!/bin/sh
# The inverse-problem experiment table of docs/results/optimize.md: every task solved with
# shadows and with --no-shadows, against targets ray-traced by `penumbra reference` from the
# ground-truth scenes. Tasks (per mesh, Spot and Bob):
#   lighting, albedo, pose, lighting_pose   the scene of <mesh>_truth.json (256x256, city map);
#                        these tasks and scenes are the user examples of examples/optimize/
#   deformation          the mesh bent sideways (bend_obj.py) recovered through the embedded
#                        deformation graph from the unbent mesh
#   shape_from_shadow    the proxy spheres recovered from the shadows alone (the spheres are not
#                        drawn; the camera looks straight down at the object, its whole shadow
#                        in the frame, <mesh>_shadow_truth.json), from a perturbed start
#                        (perturb_spheres.py); own lighting, a 4-band sun (sun_sh.py)
# Usage: sh research/experiments/optimize/run_table.sh PENUMBRA_BIN [LIGHTING [MESH ...]]
#   LIGHTING  the targets' light: envmap (default; the map itself, so sharp shadows the 4-band
#             model cannot reproduce) or sh (the map's 4-band projection, which the model
#             represents exactly: what is left is the error of the proxies and SH visibility).
#             The shape-from-shadow targets are lit by their scene's SH sun either way.
#   MESH      spot, bob (default both)
# The tasks run from copies in out/tasks_ENVMAP[_lights-L]/: examples/optimize's JSONs and this
#   folder's (deformation and shape from shadow, whose inputs prepare.sh makes), side by side.
# Environment: PEN_TABLE_ENVMAP (city, default, or interior) picks the bundled map of the
#   scenes and targets: for interior city.hdr is replaced by interior.hdr in the copies (same
#   scale and rotation), and the results go to out/optimize/interior_LIGHTING/; PEN_TABLE_TASKS
#   (default "lighting albedo pose lighting_pose deformation shape_from_shadow") picks rows;
#   PEN_TABLE_ITERATIONS caps every run's iterations (a quick smoke run of the whole table:
#   PEN_TABLE_ITERATIONS=5); PEN_TABLE_LIGHTS picks the disk lights of the tasks' scenes: none
#   (default: the scenes' "lights": "none", the SH light alone), map
#   (the lights the loader finds in the map, the scenes' "lights" key removed: for the pose,
#   albedo, deformation and shape rows the lighting is known, so the map's lights are the right
#   model; the lighting rows solve the SH part with the found lights held at their true values)
#   or search (as map, but the lighting rows start from a scene without lights and optimise
#   ["lighting", "lights"] with "light_count": 1: the optimizer's global search for a sun; the
#   ground truth keeps the map's lights). With lights the results go to
#   out/optimize/[interior_]LIGHTING_lights-L/.
# Writes out/optimize/ (ignored by git): meshes/<mesh>_bent.obj, spheres/<mesh>_start.json,
# targets/<mesh>.exr (envmap), <mesh>_sh.exr, <mesh>_bent[_sh].exr, <mesh>_shadow.exr, one folder
# per run (LIGHTING/<mesh>_<task>_<shadows|no-shadows>/ with result.json, scene.json, final.png,
# compare.png, loss.svg, snapshots/, checkpoint.bin), LIGHTING/results.tsv, and a markdown
# table on stdout.
# Cost on the 2-core development machine (shared): about 0.1-0.3 s per shadowed iteration at
# 256x256 and 0.01-0.2 s unshadowed; the whole table for one LIGHTING and both meshes takes
# about an hour (docs/results/optimize.md lists the measured iterations and s/it of every row).
set -eu
BIN=$1
LIGHTING=${2:-envmap}
[ $# -ge 2 ] && shift 2 || shift $#
MESHES=${*:-spot bob}
TASKS=${PEN_TABLE_TASKS:-lighting albedo pose lighting_pose deformation shape_from_shadow}
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
EXAMPLES=$ROOT/examples/optimize
GEN=$ROOT/out/optimize
TARGETS=$GEN/targets
ENVMAP=${PEN_TABLE_ENVMAP:-city}
LIGHTS=${PEN_TABLE_LIGHTS:-none}
case $ENVMAP in
city) env="" OUT=$GEN/$LIGHTING ;;
interior) env=_interior OUT=$GEN/interior_$LIGHTING ;;
*) echo "unknown envmap $ENVMAP (expected city or interior)" >&2 && exit 2 ;;
esac
case $LIGHTS in
none) lights="" ;;
map|search) lights=_lights-$LIGHTS OUT=${OUT}_lights-$LIGHTS ;;
*) echo "unknown PEN_TABLE_LIGHTS $LIGHTS (expected none, map or search)" >&2 && exit 2 ;;
esac
case $LIGHTING in
envmap) suffix="" ;;
# the 4-band targets hold the found lights too when the scenes keep them
sh) suffix=_sh$lights ;;
*) echo "unknown lighting $LIGHTING (expected envmap or sh)" >&2 && exit 2 ;;
esac
# The tasks and scenes in one folder two below the root, like examples/optimize, so that their
# relative paths hold: examples/optimize's as they are, this folder's (three below the root) with
# their paths made two-deep and their references to examples/optimize made local. Each scene's map
# is the chosen one; without lights each scene's "lights": "none" is dropped (the loader then
# finds the map's lights); for the search the original scenes stay beside them as
# *_nolights.json, the lighting rows' starting scenes.
TASKS_DIR=$ROOT/out/tasks_$ENVMAP$lights
mkdir -p "$TASKS_DIR"
for f in "$EXAMPLES"/*.json "$HERE"/*.json; do
    b=$(basename "$f" .json)
    sed -e "s#/city\\.hdr#/$ENVMAP.hdr#g" -e 's#"\.\./\.\./\.\./examples/optimize/#"#g' \
        -e 's#"\.\./\.\./\.\./#"../../#g' "$f" > "$TASKS_DIR/${b}_nolights.json"
    if [ $LIGHTS = none ]; then
        mv "$TASKS_DIR/${b}_nolights.json" "$TASKS_DIR/$b.json"
    else
        sed 's#,[[:space:]]*"lights":[[:space:]]*"none"##' "$TASKS_DIR/${b}_nolights.json" \
            > "$TASKS_DIR/$b.json"
    fi
done
if [ $LIGHTS = search ]; then
    for f in "$TASKS_DIR"/*_lighting.json "$TASKS_DIR"/*_lighting_pose.json; do
        sed -e 's#"scene": "\([^"]*\)\.json"#"scene": "\1_nolights.json"#' \
            -e 's#"optimize": \["lighting"#"light_count": 1, "optimize": ["lighting", "lights"#' \
            "$f" > "$f.tmp" && mv "$f.tmp" "$f"
    done
fi
mkdir -p "$TARGETS" "$OUT" "$GEN/meshes" "$GEN/spheres"

# The value of a top-level or metrics member of a result.json ("-" when absent).
field() { # file name
    v=$(sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([^,]*\),\{0,1\}$/\1/p" "$1" | head -n 1)
    echo "${v:--}"
}
fmt() { # printf-format value
    case $2 in -|null) echo "-" ;; *) printf "$1" "$2" ;; esac
}
reference() { # truth.json target.exr [--lighting L]
    [ -s "$2" ] || "$BIN" reference "$1" -o "$2" --spp 256 ${3:-} ${4:-} > /dev/null
}

# Generated inputs: the bent meshes (deformation) and the perturbed spheres (shape from shadow).
. "$HERE/prepare.sh"
prepare() { pen_prepare "$HERE" "$ROOT" "$BIN" "$GEN" "$1"; }

printf 'mesh\ttask\tshadows\titerations\tconverged\ts_per_it\tfinal_loss\timage_rmse\tlighting_rel_error\tlighting_rel_error_sky\talbedo_psnr_db\talbedo_shadow_psnr_db\talbedo_shadow_fraction\talbedo_texel_psnr_db\talbedo_observed\trotation_error_deg\ttranslation_error\ttranslation_error_rel\tvertex_rmse\tsphere_iou\tsphere_chamfer\tshadow_iou\tlight_direction_error_deg\n' > "$OUT/results.tsv"
echo "| mesh | task | shadows | iterations | s/it | image RMSE | lighting rel. error (bands 0–2) | albedo PSNR, view (in shadow) (dB) | rotation error (°) | translation error (% of size) | vertex RMSE | shadow IoU (sphere IoU) |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
for mesh in $MESHES; do
    prepare $mesh
    for task in $TASKS; do
        case $task in
        deformation)
            target="$TARGETS/${mesh}_bent$env$suffix.exr"
            reference "$TASKS_DIR/${mesh}_bent_truth.json" "$target" --lighting $LIGHTING ;;
        shape_from_shadow)
            target="$TARGETS/${mesh}_shadow.exr"
            reference "$TASKS_DIR/${mesh}_shadow_truth.json" "$target" ;;
        *)
            target="$TARGETS/$mesh$env$suffix.exr"
            reference "$TASKS_DIR/${mesh}_truth.json" "$target" --lighting $LIGHTING ;;
        esac
        for mode in shadows no-shadows; do
            dir="$OUT/${mesh}_${task}_$mode"
            set -- --target "$target" -q
            [ $mode = no-shadows ] && set -- "$@" --no-shadows
            [ -n "${PEN_TABLE_ITERATIONS:-}" ] && set -- "$@" --iterations "$PEN_TABLE_ITERATIONS"
            "$BIN" optimize "$TASKS_DIR/${mesh}_$task.json" -o "$dir" "$@"
            r="$dir/result.json"
            printf '%s\t%s\t%s' $mesh $task $mode >> "$OUT/results.tsv"
            for f in iterations converged seconds_per_iteration final_loss image_rmse \
                lighting_rel_error lighting_rel_error_sky albedo_psnr_db albedo_shadow_psnr_db \
                albedo_shadow_fraction \
                albedo_texel_psnr_db albedo_observed \
                rotation_error_deg translation_error translation_error_rel vertex_rmse \
                sphere_iou sphere_chamfer \
                shadow_iou light_direction_error_deg; do
                printf '\t%s' "$(field "$r" $f)" >> "$OUT/results.tsv"
            done
            printf '\n' >> "$OUT/results.tsv"
            conv=""
            [ "$(field "$r" converged)" = true ] || conv=" (limit)"
            light="$(fmt %.3f "$(field "$r" lighting_rel_error)")"
            [ "$light" = - ] || light="$light ($(fmt %.3f "$(field "$r" lighting_rel_error_bands_0_2)"))"
            albedo="$(fmt %.1f "$(field "$r" albedo_psnr_db)")"
            # in shadow: "-" when the view has no shadowed pixel, "inf" for a perfect match
            in_shadow="$(field "$r" albedo_shadow_psnr_db)"
            [ "$in_shadow" = null ] && in_shadow=inf || in_shadow="$(fmt %.1f "$in_shadow")"
            [ "$albedo" = - ] || albedo="$albedo ($in_shadow)"
            trans="$(fmt %.4f "$(field "$r" translation_error)")"
            rel="$(field "$r" translation_error_rel)"
            case $rel in -|null) ;; *) trans="$trans ($(echo "$rel" | awk '{printf "%.1f%%", 100 * $1}'))" ;; esac
            shadow="$(fmt %.3f "$(field "$r" shadow_iou)")"
            [ "$shadow" = - ] || shadow="$shadow ($(fmt %.3f "$(field "$r" sphere_iou)"))"
            echo "| $mesh | $task | $mode | $(field "$r" iterations)$conv |" \
                "$(fmt %.2f "$(field "$r" seconds_per_iteration)") |" \
                "$(fmt %.4f "$(field "$r" image_rmse)") | $light |" \
                "$albedo |" \
                "$(fmt %.2f "$(field "$r" rotation_error_deg)") |" \
                "$trans |" \
                "$(fmt %.4f "$(field "$r" vertex_rmse)") | $shadow |"
        done
    done
done
