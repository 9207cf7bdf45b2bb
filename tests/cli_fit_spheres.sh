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
# A preview that cannot be written takes the sphere file with it.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4 --voxels 24 --iterations 20 \
    -o "$T/a.json" --preview "$T/no/such/dir/p.png" > /dev/null 2> "$T/err"
[ $? -eq 1 ] || fail "unwritable preview should exit 1"
[ ! -e "$T/a.json" ] || fail "unwritable preview left the sphere file"
ls "$T" | grep -q tmp && fail "temporary file left behind"
echo "ok"
