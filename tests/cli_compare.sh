#!/bin/sh
# Command-line contract of `penumbra compare` and `penumbra reference`: metrics on images with
# known errors, JSON on stdout, exit status and one error line on stderr, no partial outputs.
# Usage: sh cli_compare.sh PENUMBRA_BIN SOURCE_DIR
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# A flat (uncompressed) Radiance HDR of W x H pixels, every pixel the RGBE bytes given in octal:
# \200\200\200\200 is 0.5, \200\200\200\201 is 1.0 (mantissa 128/256, exponent 128 or 129).
hdr() { # file w h rgbe
    printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n' "$3" "$2" > "$1"
    i=0
    while [ $i -lt $(($2 * $3)) ]; do printf "$4" >> "$1"; i=$((i + 1)); done
}
half='\200\200\200\200'
one='\200\200\200\201'
zero='\000\000\000\000'

# Runs a command expected to fail: non-zero exit, exactly one line on stderr, nothing on stdout.
expect_error() { # name cmd...
    name=$1; shift
    "$@" > "$T/out" 2> "$T/err"
    rc=$?
    [ $rc -ne 0 ] || fail "$name: exit status 0"
    [ "$(wc -l < "$T/err")" -eq 1 ] || fail "$name: stderr has $(wc -l < "$T/err") lines: $(cat "$T/err")"
    [ ! -s "$T/out" ] || fail "$name: wrote to stdout"
}

# JSON field by name (first occurrence, or inside "mask" with prefix mask.).
field() { # file key
    case $2 in
    mask.*) sed -n 's/.*"mask": {\(.*\)}.*/\1/p' "$1" | sed -n "s/.*\"${2#mask.}\": \([^,}]*\).*/\1/p" ;;
    *) sed 's/, "mask": {.*//' "$1" | sed -n "s/.*\"$2\": \([^,}]*\).*/\1/p" ;;
    esac
}
near() { # a b tol
    awk -v a="$1" -v b="$2" -v t="$3" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d <= t) }'
}

# ---- compare: known errors ----
hdr "$T/a.hdr" 4 3 "$half"
hdr "$T/b.hdr" 4 3 "$one"
hdr "$T/c.hdr" 5 3 "$one"
"$BIN" compare "$T/a.hdr" "$T/b.hdr" > "$T/j" 2> "$T/err" || fail "compare a b: exit $? ($(cat "$T/err"))"
near "$(field "$T/j" rmse)" 0.5 1e-6 || fail "rmse: $(cat "$T/j")"
near "$(field "$T/j" rel_rmse)" 0.5 1e-6 || fail "rel_rmse: $(cat "$T/j")"
near "$(field "$T/j" psnr_db)" 6.0206 1e-3 || fail "psnr_db: $(cat "$T/j")"
[ "$(field "$T/j" pixels)" = 12 ] || fail "pixels: $(cat "$T/j")"
"$BIN" compare "$T/b.hdr" "$T/b.hdr" > "$T/j" || fail "compare b b"
[ "$(field "$T/j" rmse)" = 0 ] && [ "$(field "$T/j" psnr_db)" = null ] || fail "identical: $(cat "$T/j")"

# mask: the left half (2 of 4 columns) selected; the error is uniform, so the same numbers
{ printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 3 +X 4\n'
  for r in 1 2 3; do printf "$one$one$zero$zero"; done; } > "$T/m.hdr"
"$BIN" compare "$T/a.hdr" "$T/b.hdr" --mask "$T/m.hdr" > "$T/j" || fail "compare --mask"
[ "$(field "$T/j" mask.pixels)" = 6 ] || fail "mask pixels: $(cat "$T/j")"
near "$(field "$T/j" mask.rmse)" 0.5 1e-6 || fail "mask rmse: $(cat "$T/j")"

# ---- compare: errors ----
expect_error "compare: size mismatch" "$BIN" compare "$T/a.hdr" "$T/c.hdr"
grep -q "4x3" "$T/err" && grep -q "5x3" "$T/err" || fail "size mismatch message: $(cat "$T/err")"
expect_error "compare: missing file" "$BIN" compare "$T/a.hdr" "$T/nope.hdr"
grep -q "nope.hdr" "$T/err" || fail "missing file message: $(cat "$T/err")"
expect_error "compare: mask size" "$BIN" compare "$T/a.hdr" "$T/b.hdr" --mask "$T/c.hdr"
grep -q "c.hdr: the mask is 5x3 but the images are 4x3" "$T/err" ||
    fail "mask size message does not name the mask: $(cat "$T/err")"
"$BIN" compare "$T/a.hdr" > /dev/null 2>&1 && fail "compare with one image succeeded"

# ---- reference ----
cat > "$T/scene.json" <<EOF
{ "camera": {"width": 24, "height": 16, "fov_y_deg": 40, "eye": [0, 1.2, 3], "target": [0, 0.3, 0], "up": [0, 1, 0]},
  "lighting": {"envmap": "$SRC/data/envmaps/city.hdr", "scale": 1.0, "rotation_y_deg": 30},
  "sh_bands": 3,
  "objects": [ {"mesh": "$SRC/data/meshes/blub.obj", "albedo": [0.6, 0.5, 0.4], "spheres": {"fit": 4}} ],
  "ground": {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 4},
  "background": "envmap" }
EOF
"$BIN" reference "$T/scene.json" -o "$T/r1.exr" --spp 4 --seed 3 > "$T/j" 2> "$T/err" \
    || fail "reference: exit $? ($(cat "$T/err"))"
grep -q '"lighting": "envmap"' "$T/j" || fail "reference JSON: $(cat "$T/j")"
"$BIN" reference "$T/scene.json" -o "$T/r2.exr" --spp 4 --seed 3 --threads 1 > /dev/null 2>&1 \
    || fail "reference --threads 1"
"$BIN" compare "$T/r1.exr" "$T/r2.exr" > "$T/j" || fail "compare r1 r2"
[ "$(field "$T/j" rmse)" = 0 ] || fail "same seed, other thread count differs: $(cat "$T/j")"
"$BIN" reference "$T/scene.json" -o "$T/r3.exr" --spp 4 --seed 4 --lighting sh > "$T/j" 2>&1 \
    || fail "reference --lighting sh"
"$BIN" compare "$T/r1.exr" "$T/r3.exr" > "$T/j" || fail "compare r1 r3"
awk -v r="$(field "$T/j" rel_rmse)" 'BEGIN { exit !(r > 0 && r < 1) }' || fail "envmap vs sh: $(cat "$T/j")"

"$BIN" reference "$T/scene.json" -o "$T/r4.exr" --spp 4 --seed 3 --coverage "$T/cov.png" > /dev/null 2>&1 \
    || fail "reference --coverage"
"$BIN" compare "$T/r1.exr" "$T/r4.exr" > "$T/j" || fail "compare r1 r4"
[ "$(field "$T/j" rmse)" = 0 ] || fail "--coverage changed the image: $(cat "$T/j")"
"$BIN" compare "$T/r1.exr" "$T/r3.exr" --mask "$T/cov.png" > "$T/j" || fail "compare --mask coverage"
pix=$(field "$T/j" mask.pixels)
[ "$pix" -gt 0 ] && [ "$pix" -lt 384 ] || fail "coverage mask selects $pix of 384 pixels"

expect_error "reference: missing scene" "$BIN" reference "$T/none.json" -o "$T/x.exr"
[ ! -e "$T/x.exr" ] || fail "reference left an output for a missing scene"
expect_error "reference: unwritable output" "$BIN" reference "$T/scene.json" -o "$T/no/dir/x.exr" --spp 1
expect_error "reference: unwritable output with coverage" "$BIN" reference "$T/scene.json" \
    -o "$T/no/dir/x.exr" --coverage "$T/x_cov.png" --spp 1
[ ! -e "$T/x_cov.png" ] || fail "reference left the coverage of a failed run"
grep -q "no/dir/x.exr: cannot write into the folder" "$T/err" || fail "unwritable: $(cat "$T/err")"
# An image that fails to write after the coverage was written: the earlier coverage file is put
# back as it was (a name longer than NAME_MAX passes the folder check, then fails to open).
cp "$T/cov.png" "$T/keep_cov.png"
long=$(printf 'x%.0s' $(seq 1 300))
expect_error "reference: image fails after the coverage" "$BIN" reference "$T/scene.json" \
    -o "$T/$long.exr" --coverage "$T/keep_cov.png" --spp 1
cmp -s "$T/cov.png" "$T/keep_cov.png" || fail "a failed reference run changed the earlier coverage"
ls "$T" | grep -q penumbra-keep && fail "a kept file left behind: $(ls "$T")"
rm -f "$T/keep_cov.png"
ls "$T/no" > /dev/null 2>&1 && fail "reference created a folder"
"$BIN" reference "$T/scene.json" -o "$T/x.exr" --lighting moon > /dev/null 2>&1 && fail "bad --lighting accepted"
"$BIN" reference "$T/scene.json" -o "$T/x.exr" --spp 0 > /dev/null 2>&1 && fail "--spp 0 accepted"
[ ! -e "$T/x.exr" ] || fail "reference left an output after a usage error"
leftover=$(ls "$T" | grep -v -E '^(a|b|c|m)\.hdr$|^r[1234]\.exr$|^(scene\.json|cov\.png|j|out|err)$')
[ -z "$leftover" ] || fail "stray files: $leftover"

[ $fails -eq 0 ] && echo "cli_compare: all passed" || echo "cli_compare: $fails failed"
exit $fails
