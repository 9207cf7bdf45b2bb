#!/bin/sh
# penumbra fit-spheres: outputs on success, exit codes and one error line, no partial files.
# Usage: sh cli_fit_spheres.sh PENUMBRA_BIN SRC_DIR
BIN=$1
SRC=$2
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 6 --voxels 24 --iterations 60 \
    -o "$T/s.json" --preview "$T/s.png" > "$T/out" 2> "$T/err" || fail "fit exited $?: $(cat "$T/err")"
[ -s "$T/s.json" ] || fail "no sphere file"
[ -s "$T/s.png" ] || fail "no preview"
grep -q '"spheres"' "$T/s.json" || fail "no spheres member"
grep -q '"surface_coverage"' "$T/s.json" || fail "no metrics in the file"
grep -q '"sov_fraction"' "$T/out" || fail "metrics not printed"
[ "$(grep -c '"radius"' "$T/s.json")" -eq 6 ] || fail "not 6 spheres"
[ "$(grep -c '"weight"' "$T/s.json")" -eq 6 ] || fail "not 6 overlap weights"
grep -q '"uncovered": {"tolerance"' "$T/out" || fail "no coverage report in the metrics"
grep -q "warning" "$T/err" && fail "a fit that covers its mesh warned: $(cat "$T/err")"

# A fit that leaves much of the surface uncovered says so, and where, on one stderr line; the
# spheres are written all the same.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 1 --voxels 24 --iterations 60 \
    -o "$T/one.json" > "$T/out" 2> "$T/err" || fail "one-sphere fit exited $?: $(cat "$T/err")"
[ -s "$T/one.json" ] || fail "no sphere file for the one-sphere fit"
[ "$(wc -l < "$T/err")" -eq 1 ] || fail "expected one warning line, got: $(cat "$T/err")"
grep -q "^penumbra fit-spheres: warning: .*blub.obj: 1 sphere leaves .*% of the surface .* around (" \
    "$T/err" || fail "warning: $(cat "$T/err")"

# render warns about an object whose fitted spheres leave much of it uncovered (pen_scene_check
# after the fits), once, naming the object; the bundled scene, fitted at its default, does not.
cat > "$T/few.json" <<EOF
{"camera": {"width": 24, "height": 24, "fov_y_deg": 40, "eye": [3, 2, 3], "target": [0, 0.4, 0]},
 "lighting": {"envmap": "$SRC/data/envmaps/city.hdr", "scale": 0.25},
 "objects": [{"mesh": "$SRC/data/meshes/blub.obj", "spheres": {"fit": 1}}]}
EOF
"$BIN" render "$T/few.json" -o "$T/few.png" -q 2> "$T/err" || fail "render exited $?: $(cat "$T/err")"
[ "$(grep -c "leaves .*uncovered" "$T/err")" -eq 1 ] || fail "render: no coverage warning: $(cat "$T/err")"
grep -q 'objects\[0\] (blub.obj): its 1 sphere leaves .*raise "fit"' "$T/err" ||
    fail "render warning: $(cat "$T/err")"
# optimize says the same before it starts (it fits first, then checks, as render does).
"$BIN" render "$T/few.json" -o "$T/few.exr" -q 2> /dev/null || fail "render few.exr exited $?"
echo "{\"scene\": \"$T/few.json\", \"target\": \"$T/few.exr\", \"optimize\": [\"lighting\"]}" \
    > "$T/few_task.json"
"$BIN" optimize "$T/few_task.json" -o "$T/few_out" -q 2> "$T/err" ||
    fail "optimize exited $?: $(cat "$T/err")"
[ "$(grep -c 'objects\[0\] (blub.obj): its 1 sphere leaves .*uncovered' "$T/err")" -eq 1 ] ||
    fail "optimize: no coverage warning: $(cat "$T/err")"
sed -e 's|"width": 512, "height": 512|"width": 24, "height": 24|' -e "s|[.][.]/[.][.]/data|$SRC/data|g" \
    "$SRC/examples/scenes/spot_city.json" > "$T/city.json"
"$BIN" render "$T/city.json" -o "$T/city.png" -q 2> "$T/err" || fail "city: $(cat "$T/err")"
grep -q "uncovered" "$T/err" && fail "the bundled scene warns about its spheres: $(cat "$T/err")"

# Usage errors: exit 2, nothing written.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -o "$T/a.json" 2> "$T/err"
[ $? -eq 2 ] || fail "missing -n should exit 2"
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --voxels 1 -o "$T/a.json" 2> "$T/err"
[ $? -eq 2 ] || fail "--voxels 1 should exit 2"
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --bogus -o "$T/a.json" 2> "$T/err"
[ $? -eq 2 ] || fail "unknown option should exit 2"
[ ! -e "$T/a.json" ] || fail "usage error left a file"

# Runtime errors: exit 1, one line naming the file, nothing written.
"$BIN" fit-spheres "$T/missing.obj" -n 4 -o "$T/a.json" 2> "$T/err"
[ $? -eq 1 ] || fail "missing mesh should exit 1"
[ "$(wc -l < "$T/err")" -eq 1 ] || fail "expected one error line, got: $(cat "$T/err")"
grep -q "missing.obj" "$T/err" || fail "error does not name the file: $(cat "$T/err")"
[ ! -e "$T/a.json" ] || fail "failed fit left a file"
# A preview that cannot be written: found before the fit, no sphere file written.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --voxels 24 --iterations 20 \
    -o "$T/a.json" --preview "$T/no/such/dir/p.png" > /dev/null 2> "$T/err"
[ $? -eq 1 ] || fail "unwritable preview should exit 1"
grep -q "no/such/dir/p.png: cannot write into the folder" "$T/err" || fail "preview: $(cat "$T/err")"
[ ! -e "$T/a.json" ] || fail "unwritable preview left the sphere file"
# ... and an existing sphere file stays as it was (it used to be deleted).
cp "$T/s.json" "$T/old.json"
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --voxels 24 --iterations 20 \
    -o "$T/old.json" --preview "$T/no/such/dir/p.png" > /dev/null 2> "$T/err"
[ $? -eq 1 ] || fail "unwritable preview should exit 1"
cmp -s "$T/s.json" "$T/old.json" || fail "a failed run changed or removed the existing sphere file"
# A preview that fails only when written (a name longer than NAME_MAX passes the folder check):
# the sphere file already written is replaced by the earlier one again.
long=$(printf 'p%.0s' $(seq 1 300))
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --voxels 24 --iterations 20 \
    -o "$T/old.json" --preview "$T/$long.png" > /dev/null 2> "$T/err"
[ $? -eq 1 ] || fail "unwritable long preview should exit 1"
cmp -s "$T/s.json" "$T/old.json" || fail "a failed preview write did not restore the sphere file"
ls "$T" | grep -q -e tmp -e penumbra-keep && fail "temporary file left behind: $(ls "$T")"
# An output that is a folder.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 -o "$T" 2> "$T/err"
[ $? -eq 1 ] || fail "a folder as output should exit 1"
grep -q "it is a folder" "$T/err" || fail "folder output: $(cat "$T/err")"

# Fitter errors name the mesh; a closed mesh at an absurd scale says so instead of blaming holes.
for s in 1e-20 1e20; do
    awk -v s=$s '/^v /{printf "v %.9g %.9g %.9g\n", $2 * s, $3 * s, $4 * s; next}
                 /^f /{for (i = 2; i <= NF; ++i) { split($i, c, "/"); $i = c[1] } print}' \
        "$SRC/data/meshes/blub.obj" > "$T/scaled.obj"
    "$BIN" fit-spheres "$T/scaled.obj" -n 4 --voxels 24 -o "$T/b.json" 2> "$T/err"
    [ $? -eq 1 ] || fail "scale $s: exit status"
    # 1e20 no longer loads: its coordinates are outside the loader's range (+-1e6), and that
    # message names the file and the vertex; 1e-20 loads and the fit says to rescale.
    grep -q "scaled.obj: fit: the mesh's longest side is .*rescale" "$T/err" ||
        grep -q "scaled.obj: vertex [0-9]*: coordinate [0-9]: .* outside" "$T/err" ||
        fail "scale $s: $(cat "$T/err")"
    grep -q "closed" "$T/err" && fail "scale $s: blames the mesh for not being closed"
done
# A mesh that is really open (one face): the fit's message names it.
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n' > "$T/open.obj"
"$BIN" fit-spheres "$T/open.obj" -n 4 --voxels 16 -o "$T/b.json" 2> "$T/err"
[ $? -eq 1 ] || fail "open mesh: exit status"
grep -q "^penumbra fit-spheres: .*open.obj: fit: " "$T/err" || fail "open mesh: $(cat "$T/err")"
[ ! -e "$T/b.json" ] || fail "a failed fit left a sphere file"
echo "ok"
