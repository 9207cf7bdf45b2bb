#!/bin/sh
# Accuracy of `render` against the Embree reference on the bundled scenes (Spot and Bob on the
# ground plane, city and interior maps, 512x512), and what the reference costs. The scenes use the
# SH light alone ("lights": "none"), as the README's table was measured before disk lights;
# lights_table.py beside it measures the default, with the lights found in the map.
# Usage: sh research/experiments/accuracy/reference_table.sh PENUMBRA_BIN OUTDIR [SPP] [SIZE]
#   SPP  samples per pixel of the ground truth (default 1024), SIZE the image side (default 512).
#   REUSE=1 keeps the reference images (and their rows) of an earlier run into the same OUTDIR
#   and redoes only the `render` rows. OVERLAP=none renders with the plain sphere sum (scene
#   "shadow": {"overlap": "none"}) instead of the overlap weights, for the before/after table.
#   GROUND=receiver renders with "shadow": {"ground": "receiver"} (the ground receives shadows but
#   does not occlude the objects, the renderer before ground occlusion) instead of the default
#   "occludes"; the reference always ray-traces the ground.
# Times: the reference's own "seconds" (Embree build + render) and render's own (pen_render_fwd),
# neither counting process start, scene loading (meshes, textures, sphere fits) or saving.
# Writes OUTDIR/scenes/*.json, the images, OUTDIR/results.tsv, and a markdown table on stdout.
# Per scene:
#   truth   reference --lighting sh at SPP (seed 1): the light `render` uses, exact visibility
#   envmap  reference --lighting envmap at SPP/4 and SPP/16 vs truth: the error of band-limiting
#           the light alone, b, after removing both renders' noise (e^2 = b^2 + v/n + truth noise^2,
#           v fitted from the two points)
#   ladder  reference --lighting sh at 1, 4, 16, 64, 256 spp (fresh seeds) vs truth; the per-spp
#           variance s^2 is fitted from the 64 and 256 points (e^2 = s^2/n + s^2/SPP), giving the
#           truth's own noise floor s/sqrt(SPP) and the spp that reaches a given error, e: (s/e)^2
#   render  (once `penumbra render` exists) each shadow.exp method and --no-shadows vs truth
# Every error is given over the whole image and over the surfaces alone (compare --mask with the
# truth's coverage): the background differs between renderers by texture detail only.
set -eu
BIN=$1
OUT=$2
SPP=${3:-1024}
SIZE=${4:-512}
DATA=$(cd "$(dirname "$0")/../../../data" && pwd)
mkdir -p "$OUT/scenes"

# The scenes follow examples/scenes/spot_*.json (camera, pose, map scale and rotation); Bob
# stands in the same place. Spheres: 32 fitted at load time (`render` needs the fitter).
scene() { # name mesh albedo-json-fragment lift env scale exp
    cat > "$OUT/scenes/$1.json" <<EOF
{ "camera": {"width": $SIZE, "height": $SIZE, "fov_y_deg": 35, "eye": [3.0, 1.9, 3.4], "target": [0, 0.5, 0.1], "up": [0, 1, 0]},
  "lighting": {"envmap": "$DATA/envmaps/$5.hdr", "scale": $6, "rotation_y_deg": 0, "lights": "none"},
  "sh_bands": 4,
  "shadow": {"exp": "$7", "overlap": "${OVERLAP:-weights}", "ground": "${GROUND:-occludes}"},
  "objects": [ {"mesh": "$DATA/meshes/$2", $3 "spheres": {"fit": 32},
                "pose": {"rotation_axis_angle_deg": [0, 140, 0], "translation": [0, $4, 0], "scale": 1}} ],
  "ground": {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 4},
  "background": "envmap" }
EOF
}
make_scene() { # name [exp]
    case $1 in
    spot_*) mesh=spot_triangulated.obj alb="\"albedo_texture\": \"$DATA/meshes/spot_texture.png\"," lift=0.737 ;;
    bob_*) mesh=bob_tri.obj alb="" lift=0.512 ;;
    esac
    case $1 in
    *_city*) env=city scale=0.25 ;;
    *_interior*) env=interior scale=0.22 ;;
    esac
    scene "$1${2:+_$2}" $mesh "$alb" $lift $env $scale "${2:-calibrated}"
}
seconds() { sed -n 's/.*"seconds": \([0-9.]*\).*/\1/p'; }
# "full masked" rel_rmse of $1 against $2, masked by $3
rel() {
    "$BIN" compare "$1" "$2" --mask "$3" |
        sed -n 's/^{"rmse": [^,]*, "rel_rmse": \([^,]*\),.*"mask": {"rmse": [^,]*, "rel_rmse": \([^,]*\),.*/\1 \2/p'
}
has_render=0
"$BIN" render --help > /dev/null 2>&1 && has_render=1

old="$OUT/results.old"
rm -f "$old"
trap 'rm -f "$old"' EXIT
[ "${REUSE:-0}" = 1 ] && [ -f "$OUT/results.tsv" ] && mv "$OUT/results.tsv" "$old"
printf 'scene\tkind\tspp\tseconds\trel_rmse\trel_rmse_surfaces\n' > "$OUT/results.tsv"
row() { printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$1" "$2" "$3" "$4" "${5% *}" "${5#* }" >> "$OUT/results.tsv"; }
# reused scene kind spp image: copies the earlier row when REUSE=1 and the image is still there
reused() {
    [ -f "$old" ] && [ -f "$4" ] || return 1
    line=$(awk -F'\t' -v a="$1" -v b="$2" -v c="$3" '$1 == a && $2 == b && $3 == c' "$old")
    [ -n "$line" ] && echo "$line" >> "$OUT/results.tsv"
}

for name in spot_city spot_interior bob_city bob_interior; do
    make_scene $name
    S="$OUT/scenes/$name.json"
    truth="$OUT/${name}_truth.exr"
    mask="$OUT/${name}_coverage.png"
    if ! reused $name truth "$SPP" "$truth"; then
        t=$("$BIN" reference "$S" -o "$truth" --coverage "$mask" --spp "$SPP" --seed 1 --lighting sh | seconds)
        row $name truth "$SPP" "$t" "0 0"
    fi
    for n in $((SPP / 4)) $((SPP / 16)); do
        img="$OUT/${name}_envmap$n.exr"
        reused $name envmap $n "$img" && continue
        t=$("$BIN" reference "$S" -o "$img" --spp $n --seed $((200 + n)) --lighting envmap | seconds)
        row $name envmap $n "$t" "$(rel "$img" "$truth" "$mask")"
    done
    for n in 1 4 16 64 256; do
        img="$OUT/${name}_ref$n.exr"
        reused $name ladder $n "$img" && continue
        t=$("$BIN" reference "$S" -o "$img" --spp $n --seed $((100 + n)) --lighting sh | seconds)
        row $name ladder $n "$t" "$(rel "$img" "$truth" "$mask")"
    done
    if [ $has_render -eq 1 ]; then
        for exp in paper exact calibrated noshadows; do
            if [ $exp = noshadows ]; then
                sc="$S" flag=--no-shadows
            else
                make_scene $name $exp
                sc="$OUT/scenes/${name}_$exp.json" flag=
            fi
            img="$OUT/${name}_render_$exp.exr"
            t=$("$BIN" render "$sc" -o "$img" $flag | sed -n 's/.*, \([0-9.]*\) s$/\1/p' | tail -1)
            row $name "render_$exp" - "$t" "$(rel "$img" "$truth" "$mask")"
        done
    fi
done

# Summary. Per scene and metric (c = 5 whole image, 6 surfaces) the ladder gives the per-spp
# variance s^2 from its 64 and 256 points (e^2 = s^2/n + s^2/SPP); the truth's own noise is
# s/sqrt(SPP), removed from every error below; a render error e needs (s/e)^2 reference spp.
awk -F'\t' -v SPP="$SPP" '
function noise(s, c,   e64, e256, v) {
    e64 = err[s, "ladder", 64, c]; e256 = err[s, "ladder", 256, c]
    v = (e64 * e64 - e256 * e256) / (1 / 64 - 1 / 256)
    return v > 0 ? sqrt(v) : 0
}
function clean(e, sig) { e = e * e - sig * sig / SPP; return e > 0 ? sqrt(e) : 0 }
function band(s, c,   n1, n2, m1, m2, v, b2) {
    n1 = SPP / 4; n2 = SPP / 16; m1 = err[s, "envmap", n1, c]; m2 = err[s, "envmap", n2, c]
    v = (m2 * m2 - m1 * m1) / (1 / n2 - 1 / n1)
    b2 = m1 * m1 - v / n1 - sig[s, c] * sig[s, c] / SPP
    return b2 > 0 ? sprintf("%.3f", sqrt(b2)) : "< noise"
}
NR == 1 { next }
{
    err[$1, $2, $3, 5] = $5; err[$1, $2, $3, 6] = $6; sec[$1, $2, $3] = $4
    if (!($1 in seen)) { seen[$1] = 1; order[++n] = $1 }
    if ($2 ~ /^render/) rk[$1, ++nr[$1]] = $2
}
END {
    for (i = 1; i <= n; ++i) for (c = 5; c <= 6; ++c) sig[order[i], c] = noise(order[i], c)
    printf "| scene | truth (%d spp) s | truth noise, image / surfaces | band-limited light vs the map, image / surfaces | reference at 1 / 16 / 256 spp (surfaces) |\n", SPP
    printf "|---|---|---|---|---|\n"
    for (i = 1; i <= n; ++i) {
        s = order[i]
        printf "| %s | %.0f | %.3f / %.3f | %s / %s | %.3f / %.3f / %.3f |\n", s, sec[s, "truth", SPP],
               sig[s, 5] / sqrt(SPP), sig[s, 6] / sqrt(SPP), band(s, 5), band(s, 6),
               err[s, "ladder", 1, 6], err[s, "ladder", 16, 6], err[s, "ladder", 256, 6]
    }
    any = 0
    for (i = 1; i <= n; ++i) if (nr[order[i]] > 0) any = 1
    if (!any) { print "\n(render rows pending: `penumbra render` is not available in this build)"; exit }
    printf "\n| scene | render | rel_rmse image | rel_rmse surfaces | render s | reference spp (s) for the same error, surfaces |\n|---|---|---|---|---|---|\n"
    for (i = 1; i <= n; ++i) {
        s = order[i]; persec = sec[s, "truth", SPP] / SPP
        for (j = 1; j <= nr[s]; ++j) {
            k = rk[s, j]
            e5 = clean(err[s, k, "-", 5], sig[s, 5]); e6 = clean(err[s, k, "-", 6], sig[s, 6])
            spp = e6 > 0 ? sig[s, 6] * sig[s, 6] / (e6 * e6) : 0
            need = (spp >= 1) ? sprintf("%.1f (%.2f)", spp, spp * persec) : \
                   (spp > 0) ? sprintf("< 1 (1 spp: %.2f)", persec) : "below the truth noise"
            printf "| %s | %s | %.3f | %.3f | %.2f | %s |\n", s, substr(k, 8), e5, e6, sec[s, k, "-"], need
        }
    }
}' "$OUT/results.tsv"
