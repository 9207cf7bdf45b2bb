#!/bin/sh
# A user's own mesh, rendered by the README's commands: the shell block of README.md's "Your own
# mesh" paragraph is run as written, with only the paths of the command and of the Python package
# changed, on a fixture the repository does not ship (tests/own_mesh_fixture.c: a chair of boxes in
# centimetres off the origin, its .mtl, a JPEG texture, an HDR sky with a sun). The image must show
# the chair framed (in view, near the centre, not cut by the border, in its texture's colour), the
# chair must stand on the ground (penumbra info of the scene), render must print the sun it found
# and no warning, and Python's image must be the command's. Then the mistakes a first scene makes
# must be told: a centimetre mesh without "units", the camera inside it, a missing .mtl, a missing
# texture, an open mesh, a mesh wound inside out.
# Exit 77 (skipped) only when /usr/bin/python3 cannot import torch, after everything else passed.
# Usage: sh cli_own_mesh.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$2
CC=${CC:-cc}
LIBDIR=$(cd "$(dirname "$BIN")" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# The fixture, written by a small C program (libjpeg for the JPEG, libpng to read masks back).
if ! $CC -O1 -o "$T/fixture" "$SRC/tests/own_mesh_fixture.c" -ljpeg -lpng -lm; then
    echo "FAIL: cannot compile tests/own_mesh_fixture.c with $CC"
    exit 1
fi
mkdir "$T/chair"
"$T/fixture" write "$T/chair" || { echo "FAIL: fixture"; exit 1; }

# The README's block: from the line opening "Your own mesh" to the end of the next sh block.
awk '/^Your own mesh/ {p = 1} p && /^```sh/ {b = 1; next} b && /^```/ {exit} b' \
    "$SRC/README.md" > "$T/readme.sh"
grep -q 'penumbra info chair.obj' "$T/readme.sh" && grep -q '"frame": true' "$T/readme.sh" ||
    { echo "FAIL: README.md has no \"Your own mesh\" sh block with info and a framed camera"; exit 1; }
# Only the paths change: the command, and the Python package of this source tree.
sed -e "s#build/penumbra#'$BIN'#g" -e "s#PYTHONPATH=python #PYTHONPATH='$SRC/python' #" \
    "$T/readme.sh" > "$T/run.sh"
grep -v 'python3' "$T/run.sh" > "$T/run_cli.sh"
grep 'python3' "$T/run.sh" > "$T/run_py.sh"

cd "$T/chair" || exit 1
if ! sh -e "$T/run_cli.sh" > "$T/cli.out" 2> "$T/cli.err"; then
    fail "the README's commands failed:"
    cat "$T/cli.out" "$T/cli.err"
fi
[ -s "$T/cli.err" ] && { fail "the README's commands printed on stderr (a warning?):"; cat "$T/cli.err"; }
# info of the mesh: its size in centimetres, closed, its files found.
grep -q '48 vertices, 72 triangles' "$T/cli.out" || fail "info: counts"
grep -q 'size: 45 x 95 x 45' "$T/cli.out" || fail "info: size"
grep -q 'likely cm: give the object "units": "cm"' "$T/cli.out" || fail "info: units hint"
grep -q 'closed: yes' "$T/cli.out" || fail "info: closed"
grep -q 'texture .*wood.jpg (chair.mtl:3): found' "$T/cli.out" || fail "info: texture found"
# render: the sun of the map (elevation 45, azimuth 60 degrees), found and printed.
sun=$(grep '^light 0 (found in sky.hdr): elevation' "$T/cli.out")
echo "$sun" | awk '{e = $7; a = $10; exit !(e > 44 && e < 46 && a > 59 && a < 61)}' ||
    fail "render: the sun (elevation 45, azimuth 60) not printed: '$sun'"
[ -f chair.png ] || fail "render wrote no chair.png"
cat "$T/cli.out"

# The image: the chair in view, over the centre, inside the border, in the texture's red.
"$BIN" render chair.json -o "$T/again.png" --mask "$T/mask.png" -q 2> "$T/mask.err" ||
    fail "render --mask"
"$BIN" compare "$T/again.png" chair.png | grep -q '"rmse": 0,' || fail "a second render differs"
stats=$("$T/fixture" mask "$T/mask.png" chair.png)
echo "image: $stats"
echo "$stats" | awk '{exit !($2 > 0.05 && $4 > 0.9 && $6 == 0 && $8 > 1.5)}' ||
    fail "the chair is not framed in its colour: $stats (want objects > 0.05, centre > 0.9, border 0, red > 1.5)"
# Standing on the ground: the scene's chair has its lowest point on the plane.
"$BIN" info chair.json > "$T/info.out" || fail "info chair.json"
grep -q 'touches the ground' "$T/info.out" || { fail "the chair does not touch the ground"; cat "$T/info.out"; }
grep -q 'warnings: none' "$T/info.out" || fail "info chair.json lists warnings"
"$BIN" info chair.json --json | grep -q '"ground_contact": "touches", "above_ground": ' ||
    fail "info --json: ground contact"

# The mistakes a first scene makes, each told in one line on stderr; the render still succeeds.
warns() { # name expected-text...; renders scene $T/chair/$1.json
    name=$1
    shift
    "$BIN" render "$name.json" -o "$T/$name.png" -q 2> "$T/$name.err" || fail "$name: render failed"
    for want in "$@"; do
        grep -q "^penumbra render: warning: .*$want" "$T/$name.err" ||
            { fail "$name: no warning with '$want'"; cat "$T/$name.err"; }
    done
}
cat > cm.json <<'JSON'
{"camera": {"width": 64, "height": 64, "fov_y_deg": 35, "eye": [10, 80, 0], "target": [0, 0, 0]},
 "lighting": {"envmap": "sky.hdr"}, "ground": {},
 "objects": [{"mesh": "chair.obj", "spheres": {"fit": 8}}]}
JSON
warns cm 'is inside objects\[0\] (chair.obj)' 'is 45 x 95 x 45 but the ground square is 8 x 8: a mesh in centimetres? give the object "units": "cm"'
mv chair.mtl chair.mtl.away
warns chair 'material library .*chair.mtl (named at chair.obj:2) is not found: its materials are lost and the object renders with the albedo \[0.8, 0.8, 0.8\]'
"$BIN" info chair.obj | grep -q 'material library .*chair.mtl (chair.obj:2): MISSING' ||
    fail "info: missing .mtl"
mv chair.mtl.away chair.mtl
mv wood.jpg wood.away
"$BIN" render chair.json -o "$T/x.png" -q 2> "$T/tex.err" && fail "render without the texture succeeded"
grep -q "^penumbra render: .*chair.json: objects\[0\].mesh: .*chair.mtl:3: map_Kd of material 'wood': .*wood.jpg" \
    "$T/tex.err" || { fail "missing texture: error does not name the map_Kd line"; cat "$T/tex.err"; }
"$BIN" info chair.obj | grep -q 'texture .*wood.jpg (chair.mtl:3): MISSING' ||
    fail "info: missing texture"
mv wood.away wood.jpg
head -n -1 chair.obj > open.obj # the back's last quad left out
"$BIN" info open.obj | grep -q 'closed: no: 4 open edges' || fail "info: an open mesh"
"$BIN" info chair.obj | grep -q 'closed: yes.* facing outwards' || fail "info: shells outwards"
# Every face's corners in reverse order: the same closed mesh wound inside out.
awk '$1 == "f" { s = "f"; for (i = NF; i > 1; i--) s = s " " $i; print s; next } { print }' \
    chair.obj > inside_out.obj
"$BIN" info inside_out.obj | grep -q 'but \([0-9]*\) of its \1 shells face inwards' ||
    fail "info: an inside-out mesh"
"$BIN" info inside_out.obj --json | grep -q '"inward_shells": [1-9]' ||
    fail "info --json: inward shells"
"$BIN" info nothing.obj 2> "$T/none.err" && fail "info of a missing file succeeded"
grep -q '^penumbra info: nothing.obj: ' "$T/none.err" || fail "info: missing file error"

# Python: the README's line, the command's image.
PY=/usr/bin/python3
if [ ! -x "$PY" ] || ! "$PY" -c "import torch, numpy" >/dev/null 2>&1; then
    [ "$fails" -eq 0 ] || { echo "$fails failure(s)"; exit 1; }
    echo "skipped: python3-torch not installed (the command's part passed)"
    exit 77
fi
# A sanitizer build: the interpreter loads the library only with the runtimes preloaded.
san() { ldd "$LIBDIR/libpenumbra.so" 2>/dev/null | awk -v n="$1" '$1 ~ n {print $3}'; }
PRELOAD=$(echo $(san '^libasan[.]so') $(san '^libubsan[.]so'))
SAN_OPTS=${ASAN_OPTIONS:-}
[ -n "$PRELOAD" ] && SAN_OPTS="${SAN_OPTS:+$SAN_OPTS:}detect_leaks=0"
if ! env LD_PRELOAD="$PRELOAD" ASAN_OPTIONS="$SAN_OPTS" PYTHONDONTWRITEBYTECODE=1 \
    PENUMBRA_LIB="$LIBDIR/libpenumbra.so" sh -e "$T/run_py.sh" > "$T/py.out" 2>&1; then
    fail "the README's Python line failed:"
    cat "$T/py.out"
fi
"$BIN" compare chair_py.png chair.png | grep -q '"rmse": 0,' || fail "Python's image differs"

[ "$fails" -eq 0 ] || { echo "$fails failure(s)"; exit 1; }
echo "ok: the README's commands render a user's centimetre chair framed, on the ground"
