#!/bin/sh
# The reliability audit's groups as a new user meets them on the command line, with inputs made
# here: a damaged, extreme or oversized input ends the command at once with a non-zero exit, one
# line on stderr naming the input at fault (the file, key path, pixel or count, never only the
# output) and no output file; the largest valid inputs run to the end. Cases that other scripts
# already cover (fit-spheres --preview keeping out.json, optimize's snapshots and sphere groups,
# compare --mask) are left to them; docs/reliability.md maps every case to its test.
# Usage: sh cli_reliability.sh PENUMBRA_BIN SOURCE_DIR
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
# Every command gets a time limit: the hangs of group 1 fail here instead of stalling the suite.
LIMIT=120

# Runs a command expected to fail: exit status 1 (WANT_RC=2 for a usage error; not a crash, not
# the time limit), exactly one line on stderr matching each given fragment (basic regular
# expressions), nothing on stdout, no file out.* left in $T.
expect_error() { # name fragments (separated by |) cmd...
    name=$1 frags=$2
    shift 2
    timeout $LIMIT "$@" > "$T/stdout" 2> "$T/err"
    rc=$?
    [ $rc -eq "${WANT_RC:-1}" ] || fail "$name: exit status $rc ($(cat "$T/err"))"
    [ "$(wc -l < "$T/err")" -eq 1 ] || fail "$name: stderr has $(wc -l < "$T/err") lines: $(cat "$T/err")"
    [ ! -s "$T/stdout" ] || fail "$name: wrote to stdout"
    old_ifs=$IFS
    IFS='|'
    set -f
    for f in $frags; do
        grep -q -e "$f" "$T/err" || fail "$name: stderr lacks '$f': $(cat "$T/err")"
    done
    set +f
    IFS=$old_ifs
    ls "$T" | grep -q '^out\.' && fail "$name: left an output: $(ls "$T" | grep '^out\.')"
    rm -f "$T"/out.*
    return 0
}
# Runs a command expected to succeed within the time limit and write $T/out.EXT (saving refuses
# NaN and Inf, so a written image is finite).
expect_ok() { # name ext cmd...
    name=$1 ext=$2
    shift 2
    timeout $LIMIT "$@" > /dev/null 2> "$T/err" || fail "$name: exit status $? ($(cat "$T/err"))"
    [ -s "$T/out.$ext" ] || fail "$name: no output"
    rm -f "$T"/out.*
}

# A flat (uncompressed) Radiance HDR of W x H pixels, every pixel the RGBE bytes given in octal.
hdr() { # file w h rgbe
    printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n' "$3" "$2" > "$1"
    i=0
    while [ $i -lt $(($2 * $3)) ]; do printf "$4" >> "$1"; i=$((i + 1)); done
}
one='\200\200\200\201'
hdr "$T/ok.hdr" 8 4 "$one"

# Scene JSON: camera (size W H), two bands of SH lighting unless $LIGHT is given, the objects, a
# ground and any further top-level members.
SH2='"lighting": {"sh": [[1, 1, 1], [0, 0.6, 0], [0, 0, 0], [0, 0, 0]]}, "sh_bands": 2'
scene() { # file w h objects [extra top-level members]
    printf '{"camera": {"width": %d, "height": %d, "fov_y_deg": 40, "eye": [0, 1.5, 3], "target": [0, 0.3, 0]},
 %s, "objects": [%s], "ground": {"half_size": 4}%s}\n' "$2" "$3" "${LIGHT:-$SH2}" "$4" \
        "${5:+, $5}" > "$1"
}
printf 'v -0.5 0 0\nv 0.5 0 0\nv 0 1 0\nf 1 2 3\n' > "$T/tri.obj"
printf 'v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 4/4 3/3 2/2\n' \
    > "$T/quad.obj"
TRI='{"mesh": "tri.obj", "spheres": [{"center": [0, 0.4, 0], "radius": 0.3}]}'

# ---- Group 1: hangs ------------------------------------------------------------------------------
# A run-length encoded HDR of about 1.2 KB (30 rows of 8 pixels in literal spans), cut inside its
# last rows, and the first 3000 bytes of a bundled map: stb spun forever on both.
{
    printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 30 +X 8\n'
    r=0
    while [ $r -lt 30 ]; do
        printf '\002\002\000\010'
        for c in 1 2 3; do printf '\010\100\101\102\103\104\105\106\107'; done
        printf '\010\201\201\201\201\201\201\201\201'
        r=$((r + 1))
    done
} > "$T/rle_full.hdr"
head -c 1100 "$T/rle_full.hdr" > "$T/rle_cut.hdr"
head -c 3000 "$SRC/data/envmaps/city.hdr" > "$T/city_3000.hdr"
"$BIN" compare "$T/rle_full.hdr" "$T/rle_full.hdr" > /dev/null 2>&1 || fail "the uncut RLE file is refused"
expect_error "compare: truncated RLE HDR" "rle_cut.hdr: scanline 2[0-9] truncated" \
    "$BIN" compare "$T/rle_cut.hdr" "$T/ok.hdr"
expect_error "compare: city.hdr's first 3000 bytes" "city_3000.hdr: .*cannot hold 512 scanlines" \
    "$BIN" compare "$T/ok.hdr" "$T/city_3000.hdr"
LIGHT='"lighting": {"envmap": "rle_cut.hdr"}' scene "$T/env_cut.json" 16 12 "$TRI"
expect_error "render: truncated RLE envmap" "lighting.envmap|rle_cut.hdr: scanline" \
    "$BIN" render "$T/env_cut.json" -o "$T/out.exr"
expect_error "reference: truncated RLE envmap" "lighting.envmap|rle_cut.hdr: scanline" \
    "$BIN" reference "$T/env_cut.json" -o "$T/out.exr" --spp 1

# Overlap weights: a sphere file of 20 000 spheres without weights (the audit measured more than
# 120 s and 3.3 GB) is refused with the count; with "overlap": "none" it needs no weights.
awk 'BEGIN { srand(3); printf "{\"spheres\": ["
             for (i = 0; i < 20000; ++i)
                 printf "%s{\"center\": [%.4f, %.4f, %.4f], \"radius\": 0.02}", i ? ", " : "",
                        rand() - 0.5, 0.5 * rand(), rand() - 0.5
             print "]}" }' > "$T/many_spheres.json"
scene "$T/many.json" 12 10 '{"mesh": "tri.obj", "spheres": "many_spheres.json"}'
expect_error "render: 20000 spheres without weights" "20000 spheres (limit 4096)" \
    "$BIN" render "$T/many.json" -o "$T/out.exr"
# The refusal names the scene, the object and its sphere file.
grep -q "many.json: objects\[0\].spheres (.*many_spheres.json): overlap weights: 20000 spheres" "$T/err" ||
    fail "the overlap-weight refusal does not name the input: $(cat "$T/err")"
scene "$T/many_none.json" 12 10 '{"mesh": "tri.obj", "spheres": "many_spheres.json"}' \
    '"shadow": {"overlap": "none"}'
expect_ok "render: 20000 spheres, overlap none" exr "$BIN" render "$T/many_none.json" -o "$T/out.exr" -q
# A fit of more spheres than the cap: a usage error (exit 2, the hint line after it), no output.
"$BIN" fit-spheres "$SRC/data/meshes/blub.obj" -n 4097 -o "$T/out.json" > /dev/null 2> "$T/err"
[ $? -eq 2 ] || fail "fit-spheres -n 4097: exit status"
grep -q "^penumbra fit-spheres: -n: expected an integer in \[1, 4096\], got '4097'" "$T/err" ||
    fail "fit-spheres -n 4097: $(cat "$T/err")"
[ ! -e "$T/out.json" ] || fail "fit-spheres -n 4097 left an output"

# ---- Group 2: the reference at huge coordinates ------------------------------------------------
# Past the loaders' ranges: refused where the value enters, naming the key (Embree aborted).
for case in 'camera.eye\[1\]|{"width": 8, "height": 6, "fov_y_deg": 40, "eye": [0, 1e30, 3], "target": [0, 0, 0]}||' \
            'objects\[0\].pose.scale||{"mesh": "tri.obj", "pose": {"scale": 1e30}}|' \
            'ground.half_size|||{"half_size": 1e30}' \
            'objects\[0\].mesh: .*huge.obj: vertex 2: coordinate 1||{"mesh": "huge.obj"}|'; do
    key=${case%%|*} rest=${case#*|}
    cam=${rest%%|*} rest=${rest#*|}
    obj=${rest%%|*} gnd=${rest#*|}
    printf 'v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n' > "$T/huge.obj"
    [ -n "$cam" ] || cam='{"width": 8, "height": 6, "fov_y_deg": 40, "eye": [0, 1, 3], "target": [0, 0, 0]}'
    [ -n "$obj" ] || obj=$TRI
    [ -n "$gnd" ] || gnd='{}'
    printf '{"camera": %s, "lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1, "objects": [%s], "ground": %s}\n' \
        "$cam" "$obj" "$gnd" > "$T/huge.json"
    expect_error "reference: huge $key" "huge.json: $key" \
        "$BIN" reference "$T/huge.json" -o "$T/out.exr" --spp 1
done
# The largest accepted: camera at 1e6 looking through the origin, a mesh of 1e6 scaled by 1e6
# and moved by 1e6, a ground of half size 1e6 (world coordinates near 2e12).
printf 'v 0 0 0\nv 1e6 0 0\nv 0 -1e6 1e6\nf 1 2 3\n' > "$T/edge.obj"
printf '{"camera": {"width": 8, "height": 6, "fov_y_deg": 40, "eye": [1e6, 1e6, 1e6], "target": [-1e6, -1e6, -1e6]},
 "lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1, "ground": {"height": -1e6, "half_size": 1e6},
 "objects": [%s, {"mesh": "edge.obj", "pose": {"scale": 1e6, "translation": [1e6, -1e6, 1e6]},
              "spheres": [{"center": [1e6, 0, -1e6], "radius": 1e6, "weight": 1e6}]}]}\n' "$TRI" \
    > "$T/edge.json"
expect_ok "reference: largest accepted coordinates" exr \
    "$BIN" reference "$T/edge.json" -o "$T/out.exr" --spp 2
expect_ok "render: largest accepted coordinates" exr "$BIN" render "$T/edge.json" -o "$T/out.exr" -q

# ---- Group 3: corrupt data -----------------------------------------------------------------------
# PNGs written here byte by byte (CRCs computed when the test was written): a 2 x 1 palette image
# of one colour whose second pixel has index 5, the same image valid, and with a flipped bit in
# its IDAT CRC. stb read past the palette (so `compare X X` was not 0) and never checked CRCs.
printf '\211\120\116\107\015\012\032\012\000\000\000\015\111\110\104\122\000\000\000\002\000\000\000\001\010\003\000\000\000\303\374\217\270\000\000\000\003\120\114\124\105\310\144\062\361\200\005\001\000\000\000\013\111\104\101\124\170\332\143\140\140\005\000\000\010\000\006\351\365\246\165\000\000\000\000\111\105\116\104\256\102\140\202' > "$T/badpal.png"
printf '\211\120\116\107\015\012\032\012\000\000\000\015\111\110\104\122\000\000\000\002\000\000\000\001\010\003\000\000\000\303\374\217\270\000\000\000\003\120\114\124\105\310\144\062\361\200\005\001\000\000\000\013\111\104\101\124\170\332\143\140\140\000\000\000\003\000\001\053\011\115\204\000\000\000\000\111\105\116\104\256\102\140\202' > "$T/pal.png"
printf '\211\120\116\107\015\012\032\012\000\000\000\015\111\110\104\122\000\000\000\002\000\000\000\001\010\003\000\000\000\303\374\217\270\000\000\000\003\120\114\124\105\310\144\062\361\200\005\001\000\000\000\013\111\104\101\124\170\332\143\140\140\000\000\000\003\000\001\053\011\115\205\000\000\000\000\111\105\116\104\256\102\140\202' > "$T/crc.png"
"$BIN" compare "$T/pal.png" "$T/pal.png" > "$T/j" 2> "$T/err" || fail "valid palette PNG: $(cat "$T/err")"
grep -q '"rmse": 0,' "$T/j" || fail "valid palette PNG against itself: $(cat "$T/j")"
expect_error "compare: palette index past the palette" \
    "badpal.png: pixel (1, 0) has palette index 5, the palette has 1 entries" \
    "$BIN" compare "$T/badpal.png" "$T/badpal.png"
expect_error "compare: PNG CRC" "crc.png: .*CRC" "$BIN" compare "$T/crc.png" "$T/pal.png"
LIGHT='"lighting": {"sh": [[1, 1, 1]]}, "sh_bands": 1' scene "$T/tex.json" 12 10 \
    '{"mesh": "quad.obj", "albedo_texture": "badpal.png"}'
expect_error "render: texture with a palette index past the palette" \
    "objects\[0\].albedo_texture|badpal.png: pixel (1, 0)" "$BIN" render "$T/tex.json" -o "$T/out.png"

# Radiance: header only, a flat file cut short, and a run-length file whose second row is flat
# (Radiance reads each row on its own; stb restarted the whole image and returned up to 1e36).
printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n' > "$T/head_only.hdr"
expect_error "compare: header-only HDR" "head_only.hdr: .*cannot hold 4 scanlines" \
    "$BIN" compare "$T/head_only.hdr" "$T/ok.hdr"
head -c $(($(wc -c < "$T/ok.hdr") - 6)) "$T/ok.hdr" > "$T/flat_cut.hdr"
expect_error "compare: truncated flat HDR" "flat_cut.hdr: scanline 3 truncated" \
    "$BIN" compare "$T/flat_cut.hdr" "$T/ok.hdr"
lit='\010\100\101\102\103\104\105\106\107'
rgbe_row='\100\100\100\201\101\101\101\201\102\102\102\201\103\103\103\201\104\104\104\201\105\105\105\201\106\106\106\201\107\107\107\201'
{ printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n'
  printf '\002\002\000\010'"$lit$lit$lit"'\010\201\201\201\201\201\201\201\201'
  printf "$rgbe_row"; } > "$T/mixed.hdr"
{ printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n'; printf "$rgbe_row$rgbe_row"; } > "$T/flat2.hdr"
"$BIN" compare "$T/mixed.hdr" "$T/flat2.hdr" > "$T/j" 2> "$T/err" || fail "mixed rows: $(cat "$T/err")"
grep -q '"rmse": 0,' "$T/j" || fail "an RLE file with a flat row differs from the flat file: $(cat "$T/j")"

# PLY ascii rows that do not match the header: refused at the row instead of shifting vertices.
ply_head='ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n'
printf "$ply_head"'0 0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n' > "$T/rows.ply"
scene "$T/ply.json" 12 10 '{"mesh": "rows.ply"}'
expect_error "render: PLY row longer than its header" "objects\[0\].mesh|rows.ply:10: vertex 0" \
    "$BIN" render "$T/ply.json" -o "$T/out.png"

# ---- Group 4: finite inputs that overflowed --------------------------------------------------------
# Each refused where it enters, naming the key (the error used to name the output file).
printf 'v 0 0 0\nv 1e7 0 0\nv 0 1 0\nf 1 2 3\n' > "$T/far.obj"
hdr "$T/hot.hdr" 8 4 '\377\377\377\377' # 255 * 2^119: about 1.7e38, near FLT_MAX
S='"spheres": [{"center": [0, 0.4, 0], "radius": %s, "weight": %s}]'
for case in "objects\[0\].pose.scale|{\"mesh\": \"tri.obj\", \"pose\": {\"scale\": 1e30}}|" \
            "objects\[0\].pose.translation\[1\]|{\"mesh\": \"tri.obj\", \"pose\": {\"translation\": [0, 3e38, 0]}}|" \
            "objects\[0\].spheres\[0\].radius|{\"mesh\": \"tri.obj\", $(printf "$S" 1e30 1)}|" \
            "objects\[0\].spheres\[0\].weight|{\"mesh\": \"tri.obj\", $(printf "$S" 0.3 1e30)}|" \
            "objects\[0\].spheres\[0\].center\[2\]|{\"mesh\": \"tri.obj\", \"spheres\": [{\"center\": [0, 0, 3e38], \"radius\": 1}]}|" \
            "objects\[0\].mesh: .*far.obj: vertex 2|{\"mesh\": \"far.obj\"}|" \
            "shadow.epsilon|$TRI|\"shadow\": {\"epsilon\": 1e30}" \
            "lighting.scale|$TRI|\"lighting\": {\"envmap\": \"ok.hdr\", \"scale\": 1e30}" \
            "lighting.envmap: .*hot.hdr: pixel (0, 0)|$TRI|\"lighting\": {\"envmap\": \"hot.hdr\"}" \
            "objects\[0\].albedo_texture: .*hot.hdr: pixel (0, 0)|{\"mesh\": \"quad.obj\", \"albedo_texture\": \"hot.hdr\"}|"; do
    key=${case%%|*} rest=${case#*|}
    obj=${rest%%|*} extra=${rest#*|}
    case $extra in
    \"lighting\"*) LIGHT=$extra scene "$T/big.json" 12 10 "$obj" ;;
    *) scene "$T/big.json" 12 10 "$obj" "$extra" ;;
    esac
    expect_error "render: $key" "big.json: $key" "$BIN" render "$T/big.json" -o "$T/out.png"
    grep -q "out.png" "$T/err" && fail "render: $key: the error names the output: $(cat "$T/err")"
done
# Valid extremes render to the end: shadow.epsilon at its maximum, ~100 spheres stacked at one
# place without overlap weights, the largest object count (4096).
scene "$T/eps.json" 16 12 "$TRI" '"shadow": {"epsilon": 1e6}'
expect_ok "render: shadow.epsilon 1e6" exr "$BIN" render "$T/eps.json" -o "$T/out.exr" -q
stack=$(awk 'BEGIN { for (i = 0; i < 100; ++i) printf "%s{\"center\": [0, 0.6, 0], \"radius\": 0.4}", i ? ", " : "" }')
scene "$T/stack.json" 16 12 "{\"mesh\": \"tri.obj\", \"spheres\": [$stack]}" '"shadow": {"overlap": "none"}'
expect_ok "render: 100 stacked spheres, overlap none" exr "$BIN" render "$T/stack.json" -o "$T/out.exr" -q
objs=$(awk -v n=4096 'BEGIN { for (i = 0; i < n; ++i)
    printf "%s{\"mesh\": \"tri.obj\", \"pose\": {\"scale\": 0.02, \"translation\": [%.4f, 0, %.4f]}, \"spheres\": [{\"center\": [0, 0.4, 0], \"radius\": 0.3}]}",
           i ? ", " : "", -1 + 2 * (i % 64) / 63, -1 + 2 * int(i / 64) / 63 }')
scene "$T/objs.json" 16 12 "$objs"
expect_ok "render: 4096 objects" exr "$BIN" render "$T/objs.json" -o "$T/out.exr" -q
scene "$T/objs.json" 16 12 "$objs, $TRI"
expect_error "render: 4097 objects" "objs.json: objects: 4097 objects (limit 4096)" \
    "$BIN" render "$T/objs.json" -o "$T/out.exr"

# ---- Group 6: undefined behaviour -------------------------------------------------------------------
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n' > "$T/min.obj"
scene "$T/min.json" 12 10 '{"mesh": "min.obj"}'
expect_error "render: OBJ index -2^63" "objects\[0\].mesh|min.obj:4:" \
    "$BIN" render "$T/min.json" -o "$T/out.png"

# ---- Group 7: messages that name the input ------------------------------------------------------------
# A closed mesh scaled by 1e-20 is told to rescale (not "is the mesh closed?"), naming the mesh.
awk '/^v /{printf "v %.9g %.9g %.9g\n", $2 * 1e-20, $3 * 1e-20, $4 * 1e-20; next}
     /^f /{for (i = 2; i <= NF; ++i) { split($i, c, "/"); $i = c[1] } print}' \
    "$SRC/data/meshes/blub.obj" > "$T/tiny.obj"
expect_error "fit-spheres: a mesh scaled by 1e-20" "tiny.obj: fit: .*rescale" \
    "$BIN" fit-spheres "$T/tiny.obj" -n 4 --voxels 16 -o "$T/out.json"
grep -q closed "$T/err" && fail "fit-spheres 1e-20 blames the mesh for not being closed: $(cat "$T/err")"
# A PLY header comment over 255 characters is valid.
long=$(awk 'BEGIN { for (i = 0; i < 400; ++i) printf "c" }')
printf 'ply\nformat ascii 1.0\ncomment %s\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n-0.5 0 0\n0.5 0 0\n0 1 0\n3 0 1 2\n' \
    "$long" > "$T/comment.ply"
scene "$T/comment.json" 12 10 '{"mesh": "comment.ply", "spheres": [{"center": [0, 0.4, 0], "radius": 0.3}]}'
expect_ok "render: PLY with a 400-character comment" png "$BIN" render "$T/comment.json" -o "$T/out.png" -q

# ---- Group 8: resource limits ---------------------------------------------------------------------------
# A 16384 x 16384 camera (about 28 GB) is refused before allocating, naming the size and bytes.
scene "$T/cam.json" 16384 16384 "$TRI"
expect_error "render: 16384^2 camera" "camera 16384 x 16384 needs about .* GB" \
    "$BIN" render "$T/cam.json" -o "$T/out.exr"
# The reference takes this camera: it needs its image alone (3 GiB of floats at 16384^2; a failed
# allocation is a clear error) and traces W x H x spp rays, the work asked for; it finishes
# (docs/reliability.md, group 8).
# A PNG that declares 16384 x 16384 (a 780 KB file can: 3 GiB of floats): refused from its header.
printf '\211\120\116\107\015\012\032\012\000\000\000\015\111\110\104\122\000\000\100\000\000\000\100\000\010\002\000\000\000\046\252\207\323\000\000\000\000\111\105\116\104\256\102\140\202' > "$T/big.png"
expect_error "compare: PNG of 16384^2" "big.png: image size 16384 x 16384 is 268435456 pixels, over the limit" \
    "$BIN" compare "$T/big.png" "$T/big.png"

leftover=$(ls "$T" | grep -e tmp -e penumbra-keep)
[ -z "$leftover" ] || fail "temporary files left: $leftover"
[ $fails -eq 0 ] && echo "cli_reliability: all passed" || echo "cli_reliability: $fails failed"
exit $fails
