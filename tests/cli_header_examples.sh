#!/bin/sh
# The public headers are the manual, and their usage examples are what users copy: every example
# of include/penumbra/*.h and the C program of README.md ("## C") is compiled as written against
# the build's libpenumbra.so and run, so that none can drift from the API.
#
# The convention (the headers follow it; this script enforces it):
#   - An example sits in a comment block under a heading line " * Usage:" or
#     " * Usage (what it shows):", optionally followed by one blank comment line " *".
#   - Each code line is " * " plus exactly 4 spaces plus C (deeper indentation is the code's own).
#     The example ends at the next blank comment line " *" or at the end of the comment; any other
#     line there is an error (no prose glued to the code).
#   - Notes are C comments, `// ...` (allowed inside a /* */ block: its text is not parsed), never
#     bare words after the code; an elision is a `// ...` line.
#   - The first line is `// given: NAMES`: the names the example takes from the program around it,
#     each optionally followed by a note in parentheses. The names the harness provides are ctx,
#     scene_path, mesh_path, target and task_path (tests/header_examples.h says what each is).
#   - The example is C11 that compiles without warnings (-Wall -Wextra -Wshadow
#     -Wdouble-promotion) inside a main(); it frees what it makes (the sanitizer build checks).
# Every example runs in a folder of its own; it passes when it exits 0, leaves no error in the
# context and passes the checks listed below for it (run before its first pen_*_free or
# pen_*_destroy). A heading that yields no example, a given name the harness does not know, a
# compiler error (shown, with the header's line numbers) or a failed run fails the test.
# The README's program is run as written: `readme SCENE.json OUT.png` on the bundled
# examples/scenes/spot_city.json (with PEN_TEST_QUICK=1, on the 64 x 64 scene of the harness).
# About 30 s on 2 cores once Spot's 32 spheres are in the fit cache (the fit.h example fits its
# own, 5 to 10 s), about as long in the sanitizer build.
# Usage: sh cli_header_examples.sh PENUMBRA_BIN SRC_DIR
#   (PEN_EXAMPLES_ONLY=render.h runs one header's examples, README.md the README's; for editing)
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
BUILD=$(cd "$(dirname "$BIN")" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
CC=${CC:-cc}
# Sphere fits are cached: never in the user's own cache (ctest sets the build's).
XDG_CACHE_HOME=${XDG_CACHE_HOME:-$BUILD/test-cache}
export XDG_CACHE_HOME
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
now() { date +%s.%N 2>/dev/null || date +%s; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f s", b - a }'; }

LIB=$BUILD/libpenumbra.so.0
[ -e "$LIB" ] || { echo "FAIL: no $LIB beside $BIN"; exit 1; }
# A sanitizer build's library is instrumented: the programs using it are built with the same
# sanitizers (as tests/cli_install.sh does).
SAN=
if ldd "$LIB" 2>/dev/null | grep -q 'libasan[.]so'; then
    SAN="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
fi
CFLAGS="-std=c11 -O1 -g -Wall -Wextra -Wshadow -Wdouble-promotion -Wstrict-prototypes -Werror $SAN"
INCLUDES="-I$SRC/include -I$SRC/tests"
LIBS="-L$BUILD -lpenumbra -Wl,-rpath,$BUILD -lm"

# ---- The given inputs ---------------------------------------------------------------------------
start=$(now)
# shellcheck disable=SC2086
if ! $CC $CFLAGS $INCLUDES -o "$T/setup" "$SRC/tests/header_examples_setup.c" $LIBS \
    >"$T/setup.log" 2>&1; then
    cat "$T/setup.log"
    echo "FAIL: tests/header_examples_setup.c does not compile"
    exit 1
fi
if ! "$T/setup" "$SRC/examples/scenes/spot_city.json" "$T"; then
    echo "FAIL: the harness's inputs (tests/header_examples_setup.c)"
    exit 1
fi
cat >"$T/task.json" <<'EOF'
{"scene": "scene.json", "target": "target.exr", "optimize": ["pose"], "iterations": 10}
EOF
echo "inputs: $(since "$start")"

# ---- Checks of each example's results (header:example number) -----------------------------------
checks() {
    case $1 in
    render.h:1) cat <<'EOF'
CHECK(harness_image_ok(&img));
CHECK(isfinite(loss) && loss > 0);
/* The pose moved towards the target's (from x = 0 to HARNESS_TRUTH_DX). */
CHECK(scene.objects[0].pose.translation[0] > 0.2f * HARNESS_TRUTH_DX);
CHECK(scene.objects[0].pose.translation[0] < 1.5f * HARNESS_TRUTH_DX);
EOF
    ;;
    flat.h:1) cat <<'EOF'
CHECK(harness_floats_ok(image, sizeof image / sizeof image[0]));
CHECK(harness_floats_ok(d_sh, sizeof d_sh / sizeof d_sh[0]));
CHECK(harness_floats_ok(d_pose, 6));
EOF
    ;;
    raster.h:1) cat <<'EOF'
CHECK(harness_floats_ok(image, sizeof image / sizeof image[0]));
CHECK(harness_floats_ok(d_world, sizeof d_world / sizeof d_world[0]));
CHECK(harness_floats_ok(d_pose.translation, 3));
EOF
    ;;
    fit.h:1) cat <<'EOF'
CHECK(spheres.count == 32 && harness_floats_ok(spheres.data, 4 * (size_t)spheres.count));
CHECK(m.surface_coverage > 0.5 && m.surface_coverage <= 1);
CHECK(harness_file_ok("spheres.json"));
EOF
    ;;
    reference.h:1) cat <<'EOF'
CHECK(harness_image_ok(&img));
CHECK(img.width == HARNESS_SIZE && img.height == HARNESS_SIZE && img.channels == 3);
CHECK(harness_file_ok("reference.exr"));
EOF
    ;;
    optim.h:1) cat <<'EOF'
CHECK(res.iterations > 0 && isfinite(res.final_loss));
CHECK(res.final_loss <= res.losses[0]);
CHECK(harness_file_ok("out/result.json"));
EOF
    ;;
    esac
}

# ---- One example: wrap, compile, run ------------------------------------------------------------
# run_example HEADER_PATH (relative to SRC) NUMBER BODY FIRST_LINE
run_example() {
    hdr=$1 n=$2 body=$3 line=$4
    base=$(basename "$hdr")
    name="$hdr example $n"
    dir=$T/run/$base.$n
    mkdir -p "$dir"
    given=$(sed -n '1s#^// given: *##p' "$body")
    if [ -z "$given" ]; then
        fail "$name (line $line): the first line must be '// given: NAMES' (e.g. '// given: ctx')"
        return
    fi
    decls=$dir/decls post=$dir/post
    : >"$decls"
    : >"$post"
    for g in $(echo "$given" | sed 's/([^)]*)//g' | tr ',' ' '); do
        case $g in
        ctx) echo "    pen_context *ctx = harness_ctx;" ;;
        scene_path) echo "    const char *scene_path = \"$T/scene.json\";" ;;
        mesh_path) echo "    const char *mesh_path = \"$SRC/data/meshes/spot_triangulated.obj\";" ;;
        task_path) echo "    const char *task_path = \"$T/task.json\";" ;;
        target)
            echo "    pen_image target = harness_image(harness_ctx, \"$T/target.exr\");"
            echo "    pen_image_free(&target);" >>"$post" ;;
        *) echo "$g" >>"$dir/unknown" ;;
        esac >>"$decls"
    done
    if [ -s "$dir/unknown" ]; then
        fail "$name (line $line): not a name the harness gives: $(echo $(cat "$dir/unknown"))" \
             "(it gives ctx, scene_path, mesh_path, target, task_path: tests/header_examples.h)"
        return
    fi
    checks "$base:$n" >"$dir/checks"
    src=$dir/example.c
    {
        echo '#include "header_examples.h"'
        echo 'int main(void) {'
        echo '    pen_context *harness_ctx = harness_begin();'
        cat "$decls"
        echo '    {'
        echo "#line $line \"$hdr\""
        # The checks go before the first top-level pen_*_free / pen_*_destroy (or at the end).
        awk -v checks="$dir/checks" -v hdr="$hdr" -v first="$line" -v what="$base example $n" '
            function put_checks(   l) {
                if (done) return
                done = 1
                printf "#line 1 \"checks of %s (tests/cli_header_examples.sh)\"\n", what
                while ((getline l < checks) > 0) print l
                printf "#line %d \"%s\"\n", first + NR - 1, hdr
            }
            /^pen_[a-z0-9_]+_(free|destroy)\(/ { put_checks() }
            { print }
            END { put_checks() }' "$body"
        echo "#line 1 \"harness of $base example $n (tests/cli_header_examples.sh)\""
        echo '    }'
        cat "$post"
        echo '    return harness_end(harness_ctx);'
        echo '}'
    } >"$src"
    # shellcheck disable=SC2086
    if ! $CC $CFLAGS $INCLUDES -o "$dir/example" "$src" $LIBS >"$dir/cc.log" 2>&1; then
        sed 's/^/    /' "$dir/cc.log"
        fail "$name does not compile (the compiler's lines above, numbered as in $hdr)"
        return
    fi
    t0=$(now)
    if (cd "$dir" && ./example) >"$dir/run.log" 2>&1; then
        echo "ok: $name ($(since "$t0"))"
    else
        sed 's/^/    /' "$dir/run.log"
        fail "$name ran and failed (its output above)"
    fi
}

# ---- Every header -------------------------------------------------------------------------------
total=0
summary=
for h in "$SRC"/include/penumbra/*.h; do
    hdr=include/penumbra/$(basename "$h")
    ex=$T/ex/$(basename "$h")
    mkdir -p "$ex"
    # Prints the number of examples; errors ("HEADER:LINE: ...") on stderr, exit 1.
    count=$(awk -v out="$ex" -v hdr="$hdr" '
        function err(msg) { printf "%s:%d: %s\n", hdr, NR, msg > "/dev/stderr"; bad = 1 }
        function close_example() {
            if (state == 1 && !code) err("a Usage heading with no example under it")
            if (state == 1 && code) close(out "/" n ".body")
            state = 0
        }
        state == 0 && /^ *[*]? *Usage/ {
            if ($0 !~ /^ [*] Usage( [(].*[)])?:$/)
                err("a Usage heading is \" * Usage:\" or \" * Usage (what it shows):\", one line")
            n++; state = 1; code = 0; blank = 0
            next
        }
        state == 1 && !code && !blank && /^ [*]$/ { blank = 1; next }
        state == 1 && /^ [*]     / {
            if (!code) print NR > (out "/" n ".line")
            code++
            print substr($0, 8) > (out "/" n ".body")
            next
        }
        state == 1 {
            if (code && $0 !~ /^ [*]$/ && $0 !~ /^ [*]\/$/)
                err("an example ends at a blank comment line \" *\" (code: \" *\" + 5 spaces)")
            close_example()
        }
        END { close_example(); print n + 0; exit bad }' "$h")
    if [ $? -ne 0 ]; then
        fail "$hdr breaks the usage-example convention (above)"
    fi
    count=${count:-0}
    [ "$count" -gt 0 ] && summary="$summary $(basename "$h"):$count"
    case ${PEN_EXAMPLES_ONLY:-$(basename "$h")} in "$(basename "$h")") ;; *) continue ;; esac
    i=1
    while [ "$i" -le "$count" ]; do
        if [ -s "$ex/$i.body" ]; then
            run_example "$hdr" "$i" "$ex/$i.body" "$(cat "$ex/$i.line")"
            total=$((total + 1))
        fi
        i=$((i + 1))
    done
done

# ---- README.md's C program ----------------------------------------------------------------------
awk '/^## C$/ {s = 1; next} s && /^## / {exit} s && /^```c$/ {b = 1; next} b && /^```$/ {exit} b' \
    "$SRC/README.md" >"$T/readme.c"
if [ -n "${PEN_EXAMPLES_ONLY:-}" ] && [ "$PEN_EXAMPLES_ONLY" != README.md ]; then
    :
elif [ ! -s "$T/readme.c" ]; then
    fail "README.md has no \`\`\`c block in its section \"## C\""
else
    total=$((total + 1))
    summary="$summary README.md:1"
    readme_scene=$SRC/examples/scenes/spot_city.json
    [ "${PEN_TEST_QUICK:-0}" = 1 ] && readme_scene=$T/scene.json
    # shellcheck disable=SC2086
    if ! $CC $CFLAGS $INCLUDES -o "$T/readme" "$T/readme.c" $LIBS >"$T/readme.log" 2>&1; then
        sed 's/^/    /' "$T/readme.log"
        fail "README.md's C program does not compile (lines numbered from its \`\`\`c line)"
    else
        t0=$(now)
        if (cd "$T" && ./readme "$readme_scene" readme.png) >"$T/readme_run.log" 2>&1 &&
            [ -s "$T/readme.png" ]; then
            echo "ok: README.md's C program on $(basename "$readme_scene") ($(since "$t0"))"
        else
            sed 's/^/    /' "$T/readme_run.log"
            fail "README.md's C program did not render $(basename "$readme_scene") to a PNG"
        fi
    fi
fi

echo "examples:$summary ($total in all, $(since "$start"))"
[ "$total" -gt 0 ] || fail "no usage example found"
if [ "$fails" -ne 0 ]; then
    echo "$fails failure(s)"
    exit 1
fi
echo "PASS: every usage example compiles and runs"
