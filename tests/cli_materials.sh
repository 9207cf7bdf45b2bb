#!/bin/sh
# Command-line tests of meshes with several materials (docs/file-formats.md, "Materials and vertex
# colours as albedo"): `penumbra render` of a two-material OBJ of quads, and `penumbra optimize`
# of its albedo, whose recovered scene names the optimised atlas with its layout and renders to
# the final image again.
# Usage: sh cli_materials.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# Two small textures: renders of an empty scene with a coloured background.
texture() { # name r g b
    cat > "$T/bg.json" <<JSON
{"camera": {"width": 8, "height": 4, "fov_y_deg": 30, "eye": [0, 0, 1], "target": [0, 0, 0]},
 "sh_bands": 1, "lighting": {"sh": [[1, 1, 1]]}, "objects": [], "background": [$2, $3, $4]}
JSON
    "$BIN" render "$T/bg.json" -o "$T/$1" -q || fail "texture $1"
}
texture red.png 0.8 0.1 0.1
texture blue.png 0.1 0.2 0.7

# Two quads (ngons, negative indices in the second), two materials, a third Kd-only one.
cat > "$T/two.mtl" <<MTL
newmtl red
map_Kd red.png
newmtl blue
map_Kd blue.png
newmtl green
Kd 0.1 0.6 0.1
MTL
cat > "$T/two.obj" <<OBJ
mtllib two.mtl
v -1 -0.5 0
v 0 -0.5 0
v 0 0.5 0
v -1 0.5 0
v 1 -0.5 0
v 1 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl red
f 1/1 2/2 3/3 4/4
usemtl blue
f -5/-4 -2/-3 -1/-2 -4/-1
usemtl green
f 4/1 3/2 1/3
OBJ
cat > "$T/scene.json" <<JSON
{"camera": {"width": 32, "height": 16, "fov_y_deg": 30, "eye": [0, 0, 2.2], "target": [0, 0, 0]},
 "sh_bands": 1, "lighting": {"sh": [[1, 1, 1]]},
 "objects": [{"mesh": "two.obj"}], "background": [0, 0, 0]}
JSON
"$BIN" render "$T/scene.json" -o "$T/render.exr" --no-shadows -q || fail "render two materials"
"$BIN" reference "$T/scene.json" -o "$T/target.exr" --spp 4 > /dev/null || fail "reference"

# Optimising the albedo writes the atlas as EXR and names its layout.
cat > "$T/task.json" <<JSON
{"scene": "scene.json", "target": "target.exr", "optimize": ["albedo"], "iterations": 3}
JSON
"$BIN" optimize "$T/task.json" -o "$T/out" --no-shadows -q || fail "optimize albedo"
[ -s "$T/out/texture_0.exr" ] || fail "no recovered atlas written"
grep -q '"albedo_texture_layout":[[:space:]]*"baked"' "$T/out/scene.json" ||
    fail "scene.json does not name the atlas layout"
"$BIN" render "$T/out/scene.json" -o "$T/again.exr" --no-shadows -q ||
    fail "render the recovered scene"
rmse=$("$BIN" compare "$T/again.exr" "$T/out/final.exr" | sed 's/.*"rmse": *\([^,]*\),.*/\1/')
awk -v r="$rmse" 'BEGIN { exit !(r < 1e-6) }' || fail "recovered scene renders $rmse off final"

# Deforming the mesh writes it with the atlas UVs, and the atlas as a plain texture beside it.
sed 's/"mesh": "two.obj"}/"mesh": "two.obj", "spheres": [{"center": [0, 0, -0.5], "radius": 0.3}]}/' \
    "$T/scene.json" > "$T/deform.json"
cat > "$T/task_deform.json" <<JSON
{"scene": "deform.json", "target": "target.exr", "optimize": ["deformation"], "iterations": 2}
JSON
"$BIN" optimize "$T/task_deform.json" -o "$T/def" --no-shadows -q || fail "optimize deformation"
[ -s "$T/def/mesh_0.obj" ] && [ -s "$T/def/texture_0.exr" ] || fail "no mesh or atlas written"
grep -q '"albedo_texture_layout"' "$T/def/scene.json" && fail "a deformed mesh keeps the layout"
"$BIN" render "$T/def/scene.json" -o "$T/def_again.exr" --no-shadows -q ||
    fail "render the deformed scene"
rmse=$("$BIN" compare "$T/def_again.exr" "$T/def/final.exr" | sed 's/.*"rmse": *\([^,]*\),.*/\1/')
awk -v r="$rmse" 'BEGIN { exit !(r < 1e-6) }' || fail "deformed scene renders $rmse off final"

# A map_Kd naming a missing file: one line naming the .mtl line and the object's key.
sed 's/blue.png/gone.png/' "$T/two.mtl" > "$T/gone.mtl"
sed 's/two.mtl/gone.mtl/' "$T/two.obj" > "$T/gone.obj"
sed 's/two.obj/gone.obj/' "$T/scene.json" > "$T/gone.json"
if "$BIN" render "$T/gone.json" -o "$T/bad.png" 2> "$T/err"; then fail "missing map_Kd accepted"; fi
grep -q "objects\[0\].mesh: .*gone.mtl:4: map_Kd" "$T/err" || fail "error: $(cat "$T/err")"
[ ! -e "$T/bad.png" ] || fail "failed render left a file"

[ "$fails" -eq 0 ] || exit 1
echo "cli_materials: all passed"
