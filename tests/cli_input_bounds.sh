#!/bin/sh
# Command-line round trips at the inputs' bounds: what `penumbra import-cameras` and `penumbra
# optimize` write from a calibrated camera far from the origin looking away (its look-at target
# once landed beyond +-1e6) is read back by `optimize`, `render` and `import-cameras`' readers;
# a disk light of the documented minimum radius 0.01 renders and reference-renders, and 0.0099
# is refused by both with the same line; "lights": {"max": 4, "add": [...]} gives the map's sun
# and the listed light, and a bad "add" is one line naming the key.
# Usage: sh cli_input_bounds.sh PENUMBRA_BIN SOURCE_DIR
set -u
BIN=$1
SRC=$2
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# An 8x8 image to observe, from an empty scene.
cat > "$T/grey.json" <<'JSON'
{"camera": {"width": 8, "height": 8, "fov_y_deg": 40, "eye": [0, 0, 3], "target": [0, 0, 0]},
 "lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1, "objects": [], "background": [0.5, 0.5, 0.5]}
JSON
mkdir -p "$T/model"
"$BIN" render "$T/grey.json" -o "$T/model/a.exr" > /dev/null 2> "$T/err" || fail "render: $(cat "$T/err")"

# COLMAP: identity rotation, t = (0, 0, -9e5): the centre (0, 0, 9e5) looks along +z, away.
printf '1 PINHOLE 8 8 8 8 4 4\n' > "$T/model/cameras.txt"
printf '1 1 0 0 0 0 0 -900000 1 a.exr\n\n' > "$T/model/images.txt"
"$BIN" import-cameras --colmap "$T/model" -o "$T/views.json" > /dev/null 2> "$T/err" ||
    fail "import-cameras: $(cat "$T/err")"
grep -q '1800000\|1.8e+06' "$T/views.json" && fail "views.json holds a target beyond 1e6"
printf '{"scene": "grey.json", "views": "views.json", "optimize": ["lighting"], "iterations": 2}\n' \
    > "$T/task.json"
"$BIN" optimize "$T/task.json" -o "$T/out" -q > /dev/null 2> "$T/err" ||
    fail "optimize reading import-cameras' views: $(cat "$T/err")"
# optimize's own views.json is a task's views again
printf '{"scene": "grey.json", "views": "out/views.json", "optimize": ["lighting"], "iterations": 2}\n' \
    > "$T/task2.json"
"$BIN" optimize "$T/task2.json" -o "$T/out2" -q > /dev/null 2> "$T/err" ||
    fail "optimize reading optimize's views.json: $(cat "$T/err")"

# A scene whose own camera is that pose: optimize's scene.json renders.
cat > "$T/far.json" <<'JSON'
{"camera": {"width": 8, "height": 8, "intrinsics": {"fx": 8, "fy": 8, "cx": 4, "cy": 4},
            "world_to_camera": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, -900000]}},
 "lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1, "objects": [], "background": [0.5, 0.5, 0.5]}
JSON
printf '{"scene": "far.json", "target": "model/a.exr", "optimize": ["lighting"], "iterations": 2}\n' \
    > "$T/task3.json"
"$BIN" optimize "$T/task3.json" -o "$T/out3" -q > /dev/null 2> "$T/err" ||
    fail "optimize with the far camera: $(cat "$T/err")"
"$BIN" render "$T/out3/scene.json" -o "$T/again.exr" > /dev/null 2> "$T/err" ||
    fail "render of optimize's scene.json: $(cat "$T/err")"
"$BIN" compare "$T/again.exr" "$T/out3/final.exr" > "$T/cmp" 2> "$T/err" ||
    fail "compare: $(cat "$T/err")"
grep -q '"rmse":[[:space:]]*0[,}]' "$T/cmp" || fail "scene.json renders otherwise: $(cat "$T/cmp")"

# The minimum light radius, in both renderers; below it, one message for both.
light() {
    cat > "$T/light.json" <<JSON
{"camera": {"width": 8, "height": 8, "fov_y_deg": 40, "eye": [0, 1, 3], "target": [0, 0, 0]},
 "lighting": {"sh": [[0.1, 0.1, 0.1]], "lights": [{"direction": [0, 1, 0.2],
   "angular_radius_deg": $1, "irradiance": [2, 2, 2]}]},
 "sh_bands": 1, "objects": [], "ground": {}}
JSON
}
light 0.01
"$BIN" render "$T/light.json" -o "$T/l.exr" > /dev/null 2> "$T/err" ||
    fail "render with a 0.01 degree light: $(cat "$T/err")"
"$BIN" reference "$T/light.json" -o "$T/lr.exr" --spp 1 > /dev/null 2> "$T/err" ||
    fail "reference with a 0.01 degree light: $(cat "$T/err")"
light 0.0099
"$BIN" render "$T/light.json" -o "$T/l2.exr" > /dev/null 2> "$T/err_render" &&
    fail "render accepted a 0.0099 degree light"
"$BIN" reference "$T/light.json" -o "$T/lr2.exr" --spp 1 > /dev/null 2> "$T/err_reference" &&
    fail "reference accepted a 0.0099 degree light"
grep -q 'light.json: lighting.lights\[0\].angular_radius_deg: expected a number of degrees in \[0.01, 45\], got 0.0099' \
    "$T/err_render" || fail "render's message: $(cat "$T/err_render")"
[ "$(sed 's/^penumbra [a-z]*: //' "$T/err_render")" = "$(sed 's/^penumbra [a-z]*: //' "$T/err_reference")" ] ||
    fail "the messages differ: $(cat "$T/err_render") / $(cat "$T/err_reference")"
[ ! -e "$T/l2.exr" ] && [ ! -e "$T/lr2.exr" ] || fail "an output was written on failure"

# Found and added lights: the city map's sun first, then the listed light; a bad "add", one line.
added() {
    cat > "$T/add.json" <<JSON
{"camera": {"width": 8, "height": 8, "fov_y_deg": 40, "eye": [0, 1, 3], "target": [0, 0, 0]},
 "lighting": {"envmap": "$SRC/data/envmaps/city.hdr", "scale": 0.25,
   "lights": {"max": 4, "add": $1}}, "sh_bands": 1, "objects": []}
JSON
}
added '[{"direction": [0, 1, 0.2], "angular_radius_deg": 1, "irradiance": [2, 2, 2]}]'
"$BIN" info "$T/add.json" > "$T/info" 2> "$T/err" || fail "info with added lights: $(cat "$T/err")"
grep -q 'light 0 (found in city.hdr)' "$T/info" && grep -q 'light 1 (given)' "$T/info" &&
    ! grep -q 'light 2 ' "$T/info" || fail "info's lights: $(cat "$T/info")"
added 3
"$BIN" render "$T/add.json" -o "$T/a.exr" > /dev/null 2> "$T/err" && fail "render accepted \"add\": 3"
[ "$(wc -l < "$T/err")" -eq 1 ] &&
    grep -q 'add.json: lighting.lights.add: expected an array of lights, got ' "$T/err" ||
    fail "a bad \"add\": $(cat "$T/err")"
[ ! -e "$T/a.exr" ] || fail "an output was written on failure"

[ $fails -eq 0 ] && echo "cli_input_bounds: ok"
exit $((fails > 0))
