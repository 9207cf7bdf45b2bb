#!/bin/sh
# Accuracy of `render` against the Embree reference on the bundled scenes (Spot and Bob on the
# ground plane, city and interior maps, 512x512), and what the reference costs.
# Usage: sh scripts/reference_table.sh PENUMBRA_BIN OUTDIR [SPP] [SIZE]
#   SPP  samples per pixel of the ground truth (default 1024), SIZE the image side (default 512).
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
set -eu
BIN=$1
OUT=$2
SPP=${3:-1024}
SIZE=${4:-512}
DATA=$(cd "$(dirname "$0")/../data" && pwd)
mkdir -p "$OUT/scenes"

# The scenes follow examples/scenes/spot_*.json (camera, pose, map scale and rotation); Bob
# stands in the same place. Spheres: 32 fitted at load time (`render` needs the fitter).
scene() { # name mesh albedo-json-fragment lift env scale exp
    cat > "$OUT/scenes/$1.json" <<EOF
{ "camera": {"width": $SIZE, "height": $SIZE, "fov_y_deg": 35, "eye": [3.0, 1.9, 3.4], "target": [0, 0.5, 0.1], "up": [0, 1, 0]},
  "lighting": {"envmap": "$DATA/envmaps/$5.hdr", "scale": $6, "rotation_y_deg": 0},
  "sh_bands": 4,
  "shadow": {"exp": "$7"},
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
rel() { "$BIN" compare "$1" "$2" | sed -n 's/^{"rmse": [^,]*, "rel_rmse": \([^,]*\),.*/\1/p'; }
has_render=0
"$BIN" render --help > /dev/null 2>&1 && has_render=1

printf 'scene\tkind\tspp\tseconds\trel_rmse\n' > "$OUT/results.tsv"
row() { printf '%s\t%s\t%s\t%s\t%s\n' "$@" >> "$OUT/results.tsv"; }

for name in spot_city spot_interior bob_city bob_interior; do
    make_scene $name
    S="$OUT/scenes/$name.json"
    truth="$OUT/${name}_truth.exr"
    t=$("$BIN" reference "$S" -o "$truth" --spp "$SPP" --seed 1 --lighting sh | seconds)
    row $name truth "$SPP" "$t" 0
    for n in $((SPP / 4)) $((SPP / 16)); do
        img="$OUT/${name}_envmap$n.exr"
        t=$("$BIN" reference "$S" -o "$img" --spp $n --seed $((200 + n)) --lighting envmap | seconds)
        row $name envmap $n "$t" "$(rel "$img" "$truth")"
    done
    for n in 1 4 16 64 256; do
        img="$OUT/${name}_ref$n.exr"
        t=$("$BIN" reference "$S" -o "$img" --spp $n --seed $((100 + n)) --lighting sh | seconds)
        row $name ladder $n "$t" "$(rel "$img" "$truth")"
    done
    if [ $has_render -eq 1 ]; then
        for exp in paper exact calibrated; do
            make_scene $name $exp
            img="$OUT/${name}_render_$exp.exr"
            t0=$(date +%s.%N)
            "$BIN" render "$OUT/scenes/${name}_$exp.json" -o "$img" > /dev/null
            t=$(echo "$(date +%s.%N) $t0" | awk '{printf "%.3f", $1 - $2}')
            row $name "render_$exp" - "$t" "$(rel "$img" "$truth")"
        done
        img="$OUT/${name}_render_noshadows.exr"
        t0=$(date +%s.%N)
        "$BIN" render "$S" -o "$img" --no-shadows > /dev/null
        t=$(echo "$(date +%s.%N) $t0" | awk '{printf "%.3f", $1 - $2}')
        row $name render_noshadows - "$t" "$(rel "$img" "$truth")"
    fi
done

# Summary: per scene, the noise model from the ladder, then each render's error and the spp (and
# time, scaled from the truth's seconds per spp) the reference needs to reach it.
awk -F'\t' -v SPP="$SPP" '
NR == 1 { next }
{ key = $1 SUBSEP $2 SUBSEP $3; sec[key] = $4; err[key] = $5; if (!($1 in seen)) { seen[$1] = 1; order[++n] = $1 } }
$2 ~ /^render/ { rk[$1, ++nr[$1]] = $2 }
END {
    printf "| scene | truth: %d spp, s | noise of truth (rel) | envmap vs SH light (rel) | ladder rel_rmse at 1 / 16 / 256 spp |\n", SPP
    printf "|---|---|---|---|---|\n"
    for (i = 1; i <= n; ++i) {
        s = order[i]
        e64 = err[s, "ladder", 64]; e256 = err[s, "ladder", 256]
        var = (e64 * e64 - e256 * e256) / (1 / 64 - 1 / 256)
        sigma[s] = var > 0 ? sqrt(var) : 0
        persec[s] = sec[s, "truth", SPP] / SPP
        n1 = SPP / 4; n2 = SPP / 16; m1 = err[s, "envmap", n1]; m2 = err[s, "envmap", n2]
        v = (m2 * m2 - m1 * m1) / (1 / n2 - 1 / n1)
        b2 = m1 * m1 - v / n1 - sigma[s] * sigma[s] / SPP
        band = b2 > 0 ? sprintf("%.4f", sqrt(b2)) : "below noise"
        printf "| %s | %.1f | %.4f | %s | %.4f / %.4f / %.4f |\n", s, sec[s, "truth", SPP], sigma[s] / sqrt(SPP),
               band, err[s, "ladder", 1], err[s, "ladder", 16], err[s, "ladder", 256]
    }
    any = 0
    for (i = 1; i <= n; ++i) if (nr[order[i]] > 0) any = 1
    if (!any) { print "\n(render rows pending: `penumbra render` is not available in this build)"; exit }
    printf "\n| scene | method | rel_rmse | render s | reference spp for that error | reference s |\n|---|---|---|---|---|---|\n"
    for (i = 1; i <= n; ++i) {
        s = order[i]
        for (j = 1; j <= nr[s]; ++j) {
            k = rk[s, j]; e = err[s, k, "-"]
            floor2 = sigma[s] * sigma[s] / SPP
            e2 = e * e - floor2
            spp = e2 > 0 ? sigma[s] * sigma[s] / e2 : 0
            need = (spp > 0) ? sprintf("%.1f", spp) : "below the truth noise"
            cost = (spp > 0) ? sprintf("%.2f", spp * persec[s]) : "-"
            printf "| %s | %s | %.4f | %.3f | %s | %s |\n", s, substr(k, 8), e, sec[s, k, "-"], need, cost
        }
    }
}' "$OUT/results.tsv"
