#!/bin/sh
# Contract tests of `penumbra render` (docs/design.md sec. 3): outputs in the three formats, the
# --no-shadows and --threads flags, one-line errors with a non-zero exit, no partial files.
# Usage: sh cli_render.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$2
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# A small scene: a textured Spot with three inline spheres on the ground, constant background.
cat > "$T/scene.json" <<JSON
{"camera": {"width": 48, "height": 40, "fov_y_deg": 40, "eye": [2.5, 1.8, 3.0], "target": [0, 0.5, 0]},
 "lighting": {"sh": [[1.5,1.5,1.5],[-1,-1,-1],[0.2,0.2,0.2],[-0.3,-0.3,-0.3],
                     [0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],
                     [0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0]]},
 "objects": [{"mesh": "$SRC/data/meshes/spot_triangulated.obj",
              "albedo_texture": "$SRC/data/meshes/spot_texture.png",
              "spheres": [{"center": [0, -0.07, 0.3], "radius": 0.36},
                          {"center": [0, 0.45, -0.4], "radius": 0.28},
                          {"center": [0, -0.55, 0.35], "radius": 0.2}],
              "pose": {"translation": [0, 0.737, 0]}}],
 "ground": {"albedo": [0.7, 0.7, 0.7]},
 "shadow": {"ground_shadow": "spheres"},
 "background": [0.1, 0.2, 0.3]}
JSON

for ext in png exr hdr; do
    if ! "$BIN" render "$T/scene.json" -o "$T/out.$ext" -q; then fail "render to .$ext"; fi
    [ -s "$T/out.$ext" ] || fail "no .$ext written"
done
"$BIN" render "$T/scene.json" -o "$T/plain.exr" --no-shadows --threads 1 -q || fail "--no-shadows"
"$BIN" render "$T/scene.json" -o "$T/t3.exr" --threads 3 -q || fail "--threads 3"
cmp -s "$T/out.exr" "$T/plain.exr" && fail "--no-shadows made no difference"
cmp -s "$T/out.exr" "$T/t3.exr" || fail "the image depends on the thread count"
# Overlap weights: "none" is the plain sum, the same image as weights of exactly 1, and differs
# from the default (weights computed at load for these overlapping spheres).
sed 's/"ground_shadow": "spheres"}/"ground_shadow": "spheres", "overlap": "none"}/' "$T/scene.json" > "$T/none.json"
sed 's/"radius": \([0-9.]*\)}/"radius": \1, "weight": 1}/g' "$T/scene.json" > "$T/ones.json"
"$BIN" render "$T/none.json" -o "$T/none.exr" -q || fail "overlap none"
"$BIN" render "$T/ones.json" -o "$T/ones.exr" -q || fail "weights of 1"
cmp -s "$T/none.exr" "$T/ones.exr" || fail "overlap none differs from weights of 1"
cmp -s "$T/none.exr" "$T/out.exr" && fail "overlap weights made no difference"
sed 's/"ground_shadow": "spheres"}/"ground_shadow": "spheres", "overlap": "half"}/' "$T/scene.json" > "$T/bad.json"
"$BIN" render "$T/bad.json" -o "$T/bad.exr" -q 2> "$T/err" && fail "overlap half accepted"
grep -q "shadow.overlap" "$T/err" || fail "overlap error: $(cat "$T/err")"
[ ! -e "$T/bad.exr" ] || fail "failed render left a file"
# The ground transfer's keys: an unknown mode and a grid out of range are refused by name.
sed 's/"ground_shadow": "spheres"/"ground_shadow": "mesh"/' "$T/scene.json" > "$T/badg.json"
"$BIN" render "$T/badg.json" -o "$T/bad.exr" -q 2> "$T/err" && fail "ground_shadow mesh accepted"
grep -q "shadow.ground_shadow" "$T/err" || fail "ground_shadow error: $(cat "$T/err")"
sed 's/"ground_shadow": "spheres"/"ground_grid": 1/' "$T/scene.json" > "$T/badn.json"
"$BIN" render "$T/badn.json" -o "$T/bad.exr" -q 2> "$T/err" && fail "ground_grid 1 accepted"
grep -q "shadow.ground_grid: expected an integer in \[2, 1024\]" "$T/err" || fail "ground_grid error: $(cat "$T/err")"
out=$("$BIN" render "$T/scene.json" -o "$T/again.png")
case "$out" in *"48x40"*"3 spheres"*) ;; *) fail "summary line: $out" ;; esac

# Errors: exit non-zero, exactly one line on stderr (usage errors may add a hint line), no file.
expect_error() { # expected-fragment args...
    frag=$1
    shift
    rm -f "$T/bad.png"
    if "$BIN" render "$@" 2>"$T/err" >/dev/null; then fail "no error for: $*"; fi
    grep -q -- "$frag" "$T/err" || fail "stderr lacks '$frag' for: $* -> $(cat "$T/err")"
    [ -e "$T/bad.png" ] && fail "partial output left for: $*"
    ls "$T" | grep -q tmp- && fail "temporary file left for: $*"
    return 0
}
expect_error "missing" "$T/scene.json"
expect_error "must end in" "$T/scene.json" -o "$T/bad.jpg"
expect_error "unknown option" "$T/scene.json" -o "$T/bad.png" --bogus
expect_error "threads" "$T/scene.json" -o "$T/bad.png" --threads 0
expect_error "nosuch.json" "$T/nosuch.json" -o "$T/bad.png"
lines=$("$BIN" render "$T/nosuch.json" -o "$T/bad.png" 2>&1 >/dev/null | wc -l)
[ "$lines" -eq 1 ] || fail "file error printed $lines lines"

# A malformed scene: the key path is named.
sed 's/"radius": 0.36/"radius": -1/' "$T/scene.json" > "$T/neg.json"
expect_error "radius" "$T/neg.json" -o "$T/bad.png"
# A scene asking for fitted spheres: fitted before rendering, cached in $XDG_CACHE_HOME/penumbra
# (a folder of this test: never the user's cache) and reused; not needed with --no-shadows.
# Nothing is written beside the mesh.
export XDG_CACHE_HOME="$T/cache"
unset PENUMBRA_NO_CACHE
cp "$SRC/data/meshes/spot_triangulated.obj" "$T/spot.obj"
sed -e 's/"spheres": \[{"center": \[0, -0.07, 0.3\], "radius": 0.36},/"spheres": {"fit": 4}, "_s": [{"center": [0, -0.07, 0.3], "radius": 0.36},/' \
    -e "s|$SRC/data/meshes/spot_triangulated.obj|spot.obj|" "$T/scene.json" > "$T/fit.json"
out=$("$BIN" render "$T/fit.json" -o "$T/fit.png" --threads 2) || fail "render with a fitted sphere set"
case "$out" in *"4 fitted spheres (fitted now"*"4 spheres, shadows"*) ;; *) fail "fit summary: $out" ;; esac
out=$("$BIN" render "$T/fit.json" -o "$T/fit2.png") || fail "render with a cached fit"
case "$out" in *"(from the cache"*) ;; *) fail "cached fit summary: $out" ;; esac
cmp -s "$T/fit.png" "$T/fit2.png" || fail "the cached fit renders differently"
ls "$T/cache/penumbra" | grep -q '^spot\.obj-[0-9a-f]*-4-[0-9a-f]*\.json$' ||
    fail "no cache file in \$XDG_CACHE_HOME/penumbra: $(ls -R "$T/cache" 2>&1)"
ls "$T" | grep -q 'fit-' && fail "a cache file beside the mesh: $(ls "$T")"
# --no-cache and PENUMBRA_NO_CACHE=1: fitted afresh, nothing read or written.
rm -rf "$T/cache"
out=$("$BIN" render "$T/fit.json" -o "$T/fit3.png" --no-cache) || fail "render --no-cache"
case "$out" in *"(fitted now"*) ;; *) fail "--no-cache summary: $out" ;; esac
out=$(PENUMBRA_NO_CACHE=1 "$BIN" render "$T/fit.json" -o "$T/fit3.png") || fail "PENUMBRA_NO_CACHE"
case "$out" in *"(fitted now"*) ;; *) fail "PENUMBRA_NO_CACHE=1 summary: $out" ;; esac
[ ! -e "$T/cache" ] || fail "--no-cache wrote the cache: $(ls -R "$T/cache")"
cmp -s "$T/fit.png" "$T/fit3.png" || fail "the uncached fit renders differently"
# A fit that fails names the mesh: a closed mesh scaled by 1e-20 is too small, not "open"
# (tiny rather than huge: huge coordinates may be refused by the loader itself).
awk '/^v /{printf "v %.9g %.9g %.9g\n", $2 * 1e-20, $3 * 1e-20, $4 * 1e-20; next} {print}' \
    "$T/spot.obj" > "$T/tiny.obj"
sed 's|"spot.obj"|"tiny.obj"|' "$T/fit.json" > "$T/tiny.json"
expect_error "tiny.obj: fit: the mesh's longest side" "$T/tiny.json" -o "$T/tiny.png"
grep -q "closed" "$T/err" && fail "a scaled closed mesh is blamed for not being closed"
"$BIN" render "$T/fit.json" -o "$T/fitplain.png" --no-shadows -q || fail "fit scene, --no-shadows"
# The output folder does not exist: an i/o error, nothing written.
expect_error "nodir" "$T/scene.json" -o "$T/nodir/bad.png"

# Beside the image: the object mask, depth and normals of the same frame (their values:
# tests/test_render.c test_aovs, python/tests/test_doors.py).
"$BIN" render "$T/scene.json" -o "$T/aov.exr" --mask "$T/mask.exr" --depth "$T/depth.exr" \
    --normals "$T/normals.exr" -q || fail "render with --mask --depth --normals"
"$BIN" render "$T/scene.json" -o "$T/aov.png" --mask "$T/mask.png" --normals "$T/normals.png" -q ||
    fail "render with a PNG mask and normal map"
[ -s "$T/mask.exr" ] && [ -s "$T/depth.exr" ] && [ -s "$T/normals.exr" ] && [ -s "$T/normals.png" ] ||
    fail "the mask, depth or normals were not written"
expect_error "depth needs .exr or .hdr" "$T/scene.json" -o "$T/bad.png" --depth "$T/depth.png"
expect_error "normals need .exr or .png" "$T/scene.json" -o "$T/bad.png" --normals "$T/n.hdr"
# All or nothing: an AOV path that cannot be written leaves no image either.
expect_error "nodir" "$T/scene.json" -o "$T/bad.png" --mask "$T/nodir/mask.png"

if [ "$fails" -ne 0 ]; then
    echo "$fails failed"
    exit 1
fi
echo "cli_render: all passed"
