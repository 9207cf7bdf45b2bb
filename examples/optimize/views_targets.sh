#!/bin/sh
# The observed images of spot_views.json's four views: spot_truth.json seen from each of its
# cameras, ray traced by `penumbra reference` (or, with --render, rendered by `penumbra render`:
# seconds instead of minutes, the model's own image). With photos there is nothing to make:
# their views file comes from `penumbra import-cameras` (docs/optimize.md, "Several views").
#   sh examples/optimize/views_targets.sh build/penumbra [--render] [--spp N]
# Writes out/optimize/targets/spot_view_<i>.exr (and spot_view_<i>.json, the truth with camera
# i) under the repository root, where spot_views.json looks for them. It reads one camera per
# line of spot_views.json.
set -eu
PEN=$1
shift
MODE=reference SPP=256
while [ $# -gt 0 ]; do
    case $1 in
    --render) MODE=render ;;
    --spp) SPP=$2 && shift ;;
    *) echo "views_targets.sh: unknown option $1" >&2 && exit 2 ;;
    esac
    shift
done
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
OUT=$ROOT/out/optimize/targets
mkdir -p "$OUT"
i=0
grep -o '"camera": {[^}]*}' "$HERE/spot_views.json" | while read -r camera; do
    # the truth with this camera, its paths made absolute (it is written elsewhere)
    sed -e "s#\"camera\": {[^}]*}#$camera#" -e "s#\"\\.\\./\\.\\./#\"$ROOT/#g" \
        "$HERE/spot_truth.json" > "$OUT/spot_view_$i.json"
    if [ $MODE = render ]; then
        "$PEN" render "$OUT/spot_view_$i.json" -o "$OUT/spot_view_$i.exr" -q
    else
        "$PEN" reference "$OUT/spot_view_$i.json" -o "$OUT/spot_view_$i.exr" --spp "$SPP" \
            > /dev/null
    fi
    echo "$OUT/spot_view_$i.exr"
    i=$((i + 1))
done
