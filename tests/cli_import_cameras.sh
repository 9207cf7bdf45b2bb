#!/bin/sh
# Command-line contract of `penumbra import-cameras`: a COLMAP model and a transforms.json written
# here become views files that render through `penumbra render` with the imported camera; bad
# input exits non-zero with one error line and leaves an existing output as it was.
# Usage: sh cli_import_cameras.sh PENUMBRA_BIN SOURCE_DIR
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
expect_error() { # name cmd...: exit 1 and one line, or a usage error (exit 2, a hint line more)
    name=$1; shift
    "$@" > "$T/out" 2> "$T/err"
    rc=$?
    lines=$(wc -l < "$T/err")
    { [ $rc -eq 1 ] && [ "$lines" -eq 1 ]; } || { [ $rc -eq 2 ] && [ "$lines" -le 2 ]; } ||
        fail "$name: exit status $rc, stderr $(cat "$T/err")"
    [ ! -s "$T/out" ] || fail "$name: wrote to stdout"
}

mkdir -p "$T/model" "$T/images" "$T/nerf"
cp "$SRC/data/meshes/spot_texture.png" "$T/images/a.png"
cp "$SRC/data/meshes/spot_texture.png" "$T/nerf/r_0.png"
printf '# cameras\n1 PINHOLE 32 24 30 30 16 12\n' > "$T/model/cameras.txt"
printf '# images\n1 1 0 0 0 0 -0.5 3 1 a.png\n\n' > "$T/model/images.txt"
"$BIN" import-cameras --colmap "$T/model" --images "$T/images" -o "$T/views.json" > "$T/out" 2> "$T/err" ||
    fail "colmap import: $(cat "$T/err")"
grep -q '"views": 1' "$T/out" || fail "colmap import: stdout $(cat "$T/out")"
grep -q '"target":[[:space:]]*"images/a.png"' "$T/views.json" || fail "colmap: target path: $(cat "$T/views.json")"
grep -q '"fx":[[:space:]]*30' "$T/views.json" || fail "colmap: intrinsics"

# The imported camera renders: identity rotation, t = (0, -0.5, 3): eye (0, 0.5, -3) looking +Z.
cam=$(sed -n '/"camera"/,/"target":[[:space:]]*"images/p' "$T/views.json" | sed '$d' | sed '1s/.*"camera":/ /' | tr -d '\n\t' | sed 's/,[[:space:]]*$//')
cat > "$T/scene.json" <<JSON
{"camera": $cam,
 "lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1,
 "objects": [{"mesh": "$SRC/data/meshes/blub.obj", "albedo": [0.5, 0.5, 0.5]}]}
JSON
"$BIN" render "$T/scene.json" -o "$T/r.png" --no-shadows > /dev/null 2> "$T/err" || fail "render with the imported camera: $(cat "$T/err")"

printf '{"camera_angle_x": 0.7, "w": 16, "h": 16, "frames": [{"file_path": "r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0.5], [0, 0, 1, 3], [0, 0, 0, 1]]}]}' > "$T/nerf/transforms.json"
"$BIN" import-cameras --transforms "$T/nerf/transforms.json" -o "$T/nerf_views.json" > "$T/out" 2> "$T/err" ||
    fail "transforms import: $(cat "$T/err")"
grep -q '"target":[[:space:]]*"nerf/r_0.png"' "$T/nerf_views.json" || fail "transforms: target path"

# Bad input: one line naming the file, the existing output untouched.
echo keep > "$T/keep.json"
printf '1 OPENCV 32 24 30 30 16 12 0 0 0 0\n' > "$T/model/cameras.txt"
expect_error "distorted model" "$BIN" import-cameras --colmap "$T/model" -o "$T/keep.json"
grep -q "cameras.txt:1: camera model OPENCV" "$T/err" || fail "distorted model: message $(cat "$T/err")"
[ "$(cat "$T/keep.json")" = keep ] || fail "distorted model: output changed"
expect_error "both sources" "$BIN" import-cameras --colmap "$T/model" --transforms x -o "$T/o.json"
expect_error "no output" "$BIN" import-cameras --colmap "$T/model"
[ ! -e "$T/o.json" ] || fail "an output was written on failure"

[ $fails -eq 0 ] && echo "cli_import_cameras: ok"
exit $((fails > 0))
