#!/bin/sh
# The inverse-problem examples of examples/optimize run as examples/README.md gives them, in a
# scratch copy of the repository's layout (examples/optimize copied, data/ linked), so that their
# outputs land there and not in the source tree. Smaller than the README's commands in two ways
# only: targets rendered by penumbra instead of ray traced (seconds) and 10 pose steps.
#  - lighting: spot_lighting.json from spot_truth.json's image, solved by least squares;
#  - pose: spot_pose.json from 11 degrees and 0.1 units off, the loss and the offset falling;
#  - several views: views_targets.sh --render, then spot_lighting_views.json from all four, the
#    lighting closer to the truth than from one view.
# The C examples run in cli_install.sh (built against an installed copy), the Python ones in
# cli_python.sh (python/tests/test_examples.py). About 30 s on 2 cores once Spot's 32 spheres are
# in the fit cache (ctest's test-cache; 15 s more the first time).
# Usage: sh cli_examples.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
mkdir -p "$T/examples"
cp -r "$SRC/examples/optimize" "$T/examples/"
ln -s "$SRC/data" "$T/data"
cd "$T" || exit 1

# A number member of a result.json ("" when absent).
field() { # result.json name
    sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([^,]*\),\{0,1\}$/\1/p" "$1" | head -n 1
}
# awk's exit status of a comparison of numbers: less A B is true when A < B.
less() { awk -v a="$1" -v b="$2" 'BEGIN { exit !(a != "" && b != "" && a + 0 < b + 0) }'; }

# Lighting and pose from one view: the task's own target path, out/optimize/targets/spot.exr.
mkdir -p out/optimize/targets
"$BIN" render examples/optimize/spot_truth.json -o out/optimize/targets/spot.exr -q ||
    fail "render the target"
if "$BIN" optimize examples/optimize/spot_lighting.json -o out/spot_lighting -q; then
    r=out/spot_lighting/result.json
    grep -q '"stop_reason":[[:space:]]*"solved"' "$r" || fail "lighting: not solved"
    one=$(field "$r" lighting_rel_error)
    less "$one" 0.5 || fail "lighting: lighting_rel_error $one"
else
    fail "optimize spot_lighting.json"
fi
if "$BIN" optimize examples/optimize/spot_pose.json -o out/spot_pose --iterations 10 -q; then
    r=out/spot_pose/result.json
    less "$(field "$r" final_loss)" "$(field "$r" initial_loss)" || fail "pose: the loss did not fall"
    # The start is 0.1 units off along the ground: 10 steps bring it under half of that.
    less "$(field "$r" translation_error)" 0.05 ||
        fail "pose: translation_error $(field "$r" translation_error)"
    [ -n "$(field "$r" rotation_error_deg)" ] || fail "pose: no rotation_error_deg"
else
    fail "optimize spot_pose.json"
fi

# Several views: the targets where spot_views.json names them, then the task.
if sh examples/optimize/views_targets.sh "$BIN" --render >"$T/targets"; then
    [ "$(wc -l <"$T/targets")" -eq 4 ] || fail "views_targets.sh: $(cat "$T/targets")"
else
    fail "views_targets.sh"
fi
if "$BIN" optimize examples/optimize/spot_lighting_views.json -o out/spot_views -q; then
    r=out/spot_views/result.json
    for f in final_0.exr final_1.exr final_2.exr final_3.exr views.png; do
        [ -s "out/spot_views/$f" ] || fail "views: no $f"
    done
    four=$(field "$r" lighting_rel_error)
    less "$four" "${one:-0}" || fail "views: lighting_rel_error $four, one view's ${one:-?}"
else
    fail "optimize spot_lighting_views.json"
fi

if [ "$fails" -ne 0 ]; then
    echo "cli_examples: $fails failure(s)"
    exit 1
fi
echo "cli_examples: ok (lighting error one view $one, four views $four)"
