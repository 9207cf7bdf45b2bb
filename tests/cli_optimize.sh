#!/bin/sh
# Contract tests of `penumbra optimize` (docs/design.md sec. 3): the output folder's files, the
# result.json fields, a recovered scene that `penumbra render` reproduces, --no-shadows, and
# one-line errors naming the file and the JSON key, with no output folder left behind.
# Usage: sh cli_optimize.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$2
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

. "$SRC/tests/optimize_truth.sh"
truth '"albedo": [0.8, 0.6, 0.4]' > "$T/truth.json"
truth "\"albedo_texture\": \"$SRC/data/meshes/spot_texture.png\"" > "$T/truth_tex.json"
"$BIN" reference "$T/truth.json" -o "$T/target.exr" --spp 16 > /dev/null || fail "reference"
"$BIN" reference "$T/truth_tex.json" -o "$T/target_tex.exr" --spp 16 > /dev/null ||
    fail "reference (textured)"

# 1. Lighting from black by Adam (the sections below step it), scene and ground truth by path.
cat > "$T/task.json" <<JSON
{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"],
 "lighting_solver": "adam", "iterations": 60, "ground_truth": "truth.json"}
JSON
out=$("$BIN" optimize "$T/task.json" -o "$T/out") || fail "optimize lighting"
case "$out" in *"$T/out: "*"iterations"*"lighting_rel_error"*) ;; *) fail "summary line: $out" ;; esac
for f in result.json scene.json final.exr final.png compare.png loss.svg loss.png; do
    [ -s "$T/out/$f" ] || fail "no $f written"
done
grep -q '"seconds_per_iteration":[[:space:]]*[0-9]' "$T/out/result.json" ||
    fail "60 Adam steps: seconds_per_iteration is not a number"
case "$out" in
*"  adam ("*" iterations, "*" s/it): "*" -> "*) ;;
*) fail "adam stage line: $out" ;;
esac
for key in '"iterations"' '"seconds"' '"seconds_per_iteration"' '"final_loss"' '"converged"' \
    '"metrics"' '"image_rmse"' '"lighting_rel_error"' '"losses"' '"shadows":[[:space:]]*true'; do
    grep -q "$key" "$T/out/result.json" || fail "result.json lacks $key"
done
grep -q '"rotation_error_deg"' "$T/out/result.json" && fail "result.json has a pose metric"
grep -q '"sh"' "$T/out/scene.json" || fail "the recovered scene has no inline SH lighting"
grep -q '<svg' "$T/out/loss.svg" || fail "loss.svg is not an SVG"
# The recovered scene renders to the final image.
"$BIN" render "$T/out/scene.json" -o "$T/again.exr" -q || fail "render the recovered scene"
rmse=$("$BIN" compare "$T/again.exr" "$T/out/final.exr" | sed 's/.*"rmse": *\([^,]*\),.*/\1/')
awk -v r="$rmse" 'BEGIN { exit !(r < 1e-6) }' || fail "recovered scene renders $rmse off final"
ls "$T/out" | grep -q tmp- && fail "temporary file left in the output folder"

# 1b. The default solver ("auto"): least squares for the lighting alone, ended by the solve with
# the ridge 1e-2 in the stated loss; Adam with ridge 0 for lighting and pose.
printf '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"]}\n' > "$T/auto.json"
out=$("$BIN" optimize "$T/auto.json" -o "$T/auto") || fail "optimize lighting (auto)"
case "$out" in *"0 iterations (solved)"*) ;; *) fail "auto summary line: $out" ;; esac
for key in '"lighting_solver":[[:space:]]*"least_squares"' '"lighting_ridge":[[:space:]]*0.01' \
    '"stop_reason":[[:space:]]*"solved"' '"converged":[[:space:]]*true' '"iterations":[[:space:]]*0,' \
    '"final_image_loss"' '"final_ridge_loss"'; do
    grep -q "$key" "$T/auto/result.json" || fail "auto: result.json lacks $key"
done
# Its summary starts from the initial guess (black lighting), before the solve: the one stage,
# least squares, goes from there down; with no Adam step there is no time per step.
json_number() { # file key: the first "key": number of a result.json
    sed -n "s/^[[:space:]]*\"$2\":[[:space:]]*\([-+.0-9eE]*\),\{0,1\}\$/\1/p" "$1" | head -n 1
}
case "$out" in
*"  least squares: "*" -> "*) ;;
*) fail "auto: no least squares stage line: $out" ;;
esac
before=$(json_number "$T/auto/result.json" loss_before)
after=$(json_number "$T/auto/result.json" loss_after)
initial=$(json_number "$T/auto/result.json" initial_loss)
final=$(json_number "$T/auto/result.json" final_loss)
grep -q '"name":[[:space:]]*"least_squares"' "$T/auto/result.json" ||
    fail "auto: no least_squares stage"
awk -v b="$before" -v a="$after" 'BEGIN { exit !(b > 10 * a && a > 0) }' ||
    fail "auto: least squares stage $before -> $after does not fall"
[ -n "$initial" ] && [ "$initial" = "$before" ] ||
    fail "auto: initial_loss $initial is not the loss before the solve $before"
awk -v i="$initial" -v f="$final" 'BEGIN { exit !(i > 10 * f) }' ||
    fail "auto: initial_loss $initial, final_loss $final"
first=$(printf '%s\n' "$out" | sed -n 's/.*, loss \([^ ]*\) -> .*/\1/p' | head -n 1)
awk -v p="$first" -v i="$initial" 'BEGIN { exit !(p > 0 && (p - i) * (p - i) < 1e-6 * i * i) }' ||
    fail "auto: the summary line's initial loss $first is not $initial"
grep -q '"seconds_per_iteration":[[:space:]]*null' "$T/auto/result.json" ||
    fail "auto: seconds_per_iteration is not null with 0 iterations"
# loss.png: a PNG of 640 x 400 that decodes (compare reads it), and a plot of its own run's
# losses: the least-squares run's differs from the Adam run's.
[ "$(head -c 8 "$T/auto/loss.png" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ] ||
    fail "loss.png is not a PNG"
plots=$("$BIN" compare "$T/auto/loss.png" "$T/out/loss.png") || fail "compare the loss.png files"
case "$plots" in *'"pixels": 256000'*) ;; *) fail "loss.png is not 640 x 400: $plots" ;; esac
rmse=$(printf '%s' "$plots" | sed 's/.*"rmse": *\([^,]*\),.*/\1/')
awk -v r="$rmse" 'BEGIN { exit !(r > 0.01) }' ||
    fail "the two runs' loss.png are alike (rmse $rmse)"

printf '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting", "pose"], "iterations": 2}\n' \
    > "$T/auto_lp.json"
"$BIN" optimize "$T/auto_lp.json" -o "$T/auto_lp" -q || fail "optimize lighting + pose (auto)"
for key in '"lighting_solver":[[:space:]]*"adam"' '"lighting_ridge":[[:space:]]*0,' \
    '"final_ridge_loss":[[:space:]]*0,' '"stop_reason":[[:space:]]*"iteration_limit"'; do
    grep -q "$key" "$T/auto_lp/result.json" || fail "auto (lighting + pose): result.json lacks $key"
done

# 2. --no-shadows writes "shadows": false; --iterations overrides the task.
"$BIN" optimize "$T/task.json" -o "$T/flat" --no-shadows --iterations 5 -q || fail "--no-shadows"
grep -q '"shadows":[[:space:]]*false' "$T/flat/result.json" || fail "--no-shadows not recorded"
grep -q '"iterations":[[:space:]]*5,' "$T/flat/result.json" || fail "--iterations not applied"

# 3. Texture and pose together, inline scene: the texture is written beside the scene.
sed 's/"rotation_axis_angle_deg": \[0, 30, 0\]/"rotation_axis_angle_deg": [0, 34, 0]/' \
    "$T/truth_tex.json" > "$T/start_tex.json"
{
    printf '{"scene": '
    cat "$T/start_tex.json"
    printf ', "target": "target_tex.exr", "optimize": ["albedo", "pose"], "iterations": 30,\n'
    printf ' "lr": {"albedo": 0.02, "pose": 0.005}, "loss": "l1", "ground_truth": "truth_tex.json"}\n'
} > "$T/task_tex.json"
"$BIN" optimize "$T/task_tex.json" -o "$T/tex" -q || fail "optimize albedo + pose"
[ -s "$T/tex/texture_0.png" ] || fail "no recovered texture written"
grep -q '"albedo_texture":[[:space:]]*"texture_0.png"' "$T/tex/scene.json" ||
    fail "scene.json does not reference the recovered texture"
for key in '"albedo_psnr_db"' '"rotation_error_deg"' '"translation_error"' '"vertex_rmse"' \
    '"loss":[[:space:]]*"l1"'; do
    grep -q "$key" "$T/tex/result.json" || fail "result.json (texture) lacks $key"
done
"$BIN" render "$T/tex/scene.json" -o "$T/tex_again.exr" -q || fail "render recovered textured"

# 4. Deformation: the deformed mesh is written beside the scene and referenced by it.
cat > "$T/task_def.json" <<JSON
{"scene": "truth.json", "target": "target.exr", "optimize": ["deformation"], "iterations": 4,
 "deformation": {"k": 3, "w_rot": 0.001, "w_reg": 0.01}, "ground_truth": "truth.json"}
JSON
"$BIN" optimize "$T/task_def.json" -o "$T/def" -q || fail "optimize deformation"
[ -s "$T/def/mesh_0.obj" ] || fail "no deformed mesh written"
grep -q '"mesh":[[:space:]]*"mesh_0.obj"' "$T/def/scene.json" ||
    fail "scene.json does not reference the deformed mesh"
grep -q '"vertex_rmse"' "$T/def/result.json" || fail "result.json (deformation) lacks vertex_rmse"
grep -q '"w_reg":[[:space:]]*0.01' "$T/def/result.json" || fail "result.json lacks the weights"
"$BIN" render "$T/def/scene.json" -o "$T/def_again.exr" -q || fail "render the deformed scene"

# 5. Checkpoints: 40 iterations in one go equal 23, then --resume to 40, bit for bit (the
# renderer reduces in a fixed order, so this holds with any thread count); snapshots every K.
same_run() { # dir-a dir-b what
    for f in final.exr scene.json; do
        cmp -s "$1/$f" "$2/$f" || fail "$3: $f differs"
    done
    grep -v -e '"seconds' -e '"resumed_from"' -e '"memory_' "$1/result.json" > "$T/ra"
    grep -v -e '"seconds' -e '"resumed_from"' -e '"memory_' "$2/result.json" > "$T/rb"
    cmp -s "$T/ra" "$T/rb" || fail "$3: result.json differs: $(diff "$T/ra" "$T/rb" | head -4)"
}
"$BIN" optimize "$T/task.json" -o "$T/once" --iterations 40 --checkpoint-every 7 \
    --snapshot-every 10 -q || fail "uninterrupted run"
for k in 00000 00010 00020 00030; do
    [ -s "$T/once/snapshots/iter_$k.png" ] || fail "no snapshot iter_$k.png"
done
[ -e "$T/once/snapshots/iter_00040.png" ] && fail "a snapshot beyond the last iteration"
[ -s "$T/once/checkpoint.bin" ] || fail "no checkpoint written"
"$BIN" optimize "$T/task.json" -o "$T/res" --iterations 23 --checkpoint-every 7 -q ||
    fail "first leg"
out=$("$BIN" optimize "$T/task.json" -o "$T/res" --iterations 40 --resume) || fail "--resume"
case "$out" in *"resumed at 23"*) ;; *) fail "resume summary: $out" ;; esac
grep -q '"resumed_from":[[:space:]]*23' "$T/res/result.json" || fail "resumed_from not recorded"
same_run "$T/once" "$T/res" "23 + resume to 40"
# Resuming a finished run to the same limit changes nothing.
"$BIN" optimize "$T/task.json" -o "$T/res" --iterations 40 --resume -q || fail "resume at the end"
same_run "$T/once" "$T/res" "resume at the limit"
# Refused checkpoints: one line naming the file and what is wrong.
expect_resume_error() { # dir fragment [options]
    d=$1 frag=$2
    shift 2
    if "$BIN" optimize "$T/task.json" -o "$d" --resume "$@" 2>"$T/err" >/dev/null; then
        fail "--resume accepted for '$frag'"
    fi
    grep -q -- "$frag" "$T/err" || fail "--resume error lacks '$frag': $(cat "$T/err")"
    [ "$(wc -l < "$T/err")" -eq 1 ] || fail "--resume error for '$frag' is not one line"
}
expect_resume_error "$T/nosuchdir" "nosuchdir/checkpoint.bin: cannot open the checkpoint"
expect_resume_error "$T/res" "checkpoint.bin: the checkpoint is at iteration 40, beyond the iteration limit 30" --iterations 30
expect_resume_error "$T/res" "checkpoint.bin: made with shadows, this run is with --no-shadows" --no-shadows
expect_resume_error "$T/res" "checkpoint.bin: made for another target image" --target "$T/target_tex.exr"
# The task's scene edited where no parameter is (its ground's albedo; the lighting still starts
# from black): the run would go on under another scene.
cp "$T/truth.json" "$T/truth.keep"
sed 's/"ground": {"albedo": \[0.7, 0.7, 0.7\]}/"ground": {"albedo": [0.6, 0.7, 0.7]}/' \
    "$T/truth.keep" > "$T/truth.json"
cmp -s "$T/truth.json" "$T/truth.keep" && fail "the ground's albedo was not edited"
expect_resume_error "$T/res" "checkpoint.bin: made for another scene"
mv "$T/truth.keep" "$T/truth.json"
cp -r "$T/res" "$T/bad"
size=$(wc -c < "$T/bad/checkpoint.bin")
printf 'X' | dd of="$T/bad/checkpoint.bin" bs=1 seek=$((size - 20)) conv=notrunc 2>/dev/null
expect_resume_error "$T/bad" "checkpoint.bin: damaged checkpoint (checksum mismatch)" --iterations 50
head -c $((size - 9)) "$T/res/checkpoint.bin" > "$T/bad/checkpoint.bin"
expect_resume_error "$T/bad" "checkpoint.bin: truncated checkpoint" --iterations 50
echo "not a checkpoint" > "$T/bad/checkpoint.bin"
expect_resume_error "$T/bad" "checkpoint.bin: not a penumbra optimize checkpoint"
printf '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting", "pose"]}\n' \
    > "$T/task_lp.json"
"$BIN" optimize "$T/task_lp.json" -o "$T/res" --resume 2>"$T/err" >/dev/null &&
    fail "--resume of another task accepted"
grep -q "checkpoint.bin: made for another task: 12 parameters in 1 segments, this task has 18 in 3" \
    "$T/err" || fail "--resume of another task: $(cat "$T/err")"

# 6. Ctrl-C: the run stops after the current iteration, writes everything, exits 130.
if command -v timeout > /dev/null; then
    printf '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"],\n' > "$T/long.json"
    printf ' "lighting_solver": "adam",\n' >> "$T/long.json"
    printf ' "iterations": 1000000, "window": 10000}\n' >> "$T/long.json"
    # 5 s: loading must be over when the signal comes (an earlier one aborts without output);
    # --foreground: one signal, to the command only (without it timeout signals the process
    # group too, and the second SIGINT kills, as a second Ctrl-C should)
    timeout --foreground --preserve-status -s INT 5 "$BIN" optimize "$T/long.json" -o "$T/int" -q
    st=$?
    [ $st -eq 130 ] || fail "SIGINT: exit status $st, not 130"
    grep -q '"interrupted":[[:space:]]*true' "$T/int/result.json" || fail "SIGINT: not recorded"
    [ -s "$T/int/scene.json" ] || fail "SIGINT: no recovered scene"
    # Resumed from where Ctrl-C stopped it, the run ends as one that was never stopped.
    n=$(sed -n 's/^[[:space:]]*"iterations":[[:space:]]*\([0-9]*\),/\1/p' "$T/int/result.json")
    n=$((n + 25))
    "$BIN" optimize "$T/long.json" -o "$T/int" --resume --iterations $n -q || fail "resume after SIGINT"
    "$BIN" optimize "$T/long.json" -o "$T/int_once" --iterations $n -q || fail "run to $n"
    same_run "$T/int_once" "$T/int" "SIGINT + resume to $n"
fi

# Errors: exit 1, one line on stderr naming the file and key, no output folder.
expect_error() { # expected-fragment task-text
    frag=$1
    printf '%s\n' "$2" > "$T/bad.json"
    rm -rf "$T/badout"
    if "$BIN" optimize "$T/bad.json" -o "$T/badout" 2>"$T/err" >/dev/null; then
        fail "no error for: $2"
    fi
    grep -q -- "$frag" "$T/err" || fail "stderr lacks '$frag' for: $2 -> $(cat "$T/err")"
    lines=$(wc -l < "$T/err")
    [ "$lines" -eq 1 ] || fail "$lines lines on stderr for: $2"
    [ -e "$T/badout" ] && fail "output folder left for: $2"
    return 0
}
expect_error 'bad.json: optimize\[0\]: unknown group "colour"' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["colour"]}'
expect_error 'bad.json: optimize: expected a non-empty array' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": []}'
expect_error 'bad.json: optimize\[1\]: "lighting" is listed twice' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting", "lighting"]}'
expect_error 'bad.json: target: .*unknown image format' \
    '{"scene": "truth.json", "target": "target.tif", "optimize": ["lighting"]}'
expect_error 'bad.json: target_encoding: ' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"], "target_encoding": "gamma"}'
expect_error 'bad.json: target: ' \
    '{"scene": "truth.json", "target": "nosuch.exr", "optimize": ["lighting"]}'
expect_error 'bad.json: scene: ' \
    '{"scene": "nosuch.json", "target": "target.exr", "optimize": ["lighting"]}'
expect_error 'bad.json:scene: camera' \
    '{"scene": {"objects": []}, "target": "target.exr", "optimize": ["lighting"]}'
expect_error 'bad.json: iterations: expected an integer' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"], "iterations": 0}'
expect_error 'bad.json: lr.albedo: expected a positive' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["albedo"], "lr": {"albedo": -1}}'
expect_error 'bad.json: loss: unknown loss "l3"' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["albedo"], "loss": "l3"}'
expect_error 'bad.json: iteratoins: unknown key' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["albedo"], "iteratoins": 3}'
sed 's/"width": 32/"width": 16/' "$T/truth.json" > "$T/small.json"
"$BIN" render "$T/small.json" -o "$T/small.exr" -q --no-shadows || fail "render small"
expect_error 'bad.json: target: .*small.exr: the image is 16x32 but the scene' \
    '{"scene": "truth.json", "target": "small.exr", "optimize": ["lighting"]}'
expect_error 'bad.json: ground_truth: objects\[0\]: a texture albedo, but the scene' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["albedo"], "ground_truth": "truth_tex.json"}'
expect_error 'bad.json: optimize\[1\]: "deformation" and "spheres" both move the spheres' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["spheres", "deformation"]}'
expect_error 'bad.json: deformation.k: expected an integer in \[1, 32\]' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["deformation"], "deformation": {"k": 0}}'
expect_error 'bad.json: spheres.w_smooth: expected a weight >= 0' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["spheres"], "spheres": {"w_smooth": -1}}'
expect_error 'bad.json: spheres.w_reg: unknown key' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["spheres"], "spheres": {"w_reg": 1}}'
expect_error 'bad.json: lighting_solver: unknown lighting solver "newton"' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"], "lighting_solver": "newton"}'
expect_error 'bad.json: lighting_solver: "least_squares" needs "lighting" in optimize and the l2 loss' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"], "lighting_solver": "least_squares", "loss": "l1"}'
expect_error 'bad.json: lighting_ridge: expected a ridge in \[0, 1e6\]' \
    '{"scene": "truth.json", "target": "target.exr", "optimize": ["lighting"], "lighting_ridge": -1}'
expect_error 'bad.json:[0-9]*:[0-9]*: invalid JSON' '{"scene": '
# An output path that is a file: the run fails before writing anything.
echo x > "$T/afile"
if "$BIN" optimize "$T/task.json" -o "$T/afile" --iterations 2 2>"$T/err" >/dev/null; then
    fail "no error for an output path that is a file"
fi
grep -q "afile: exists and is not a folder" "$T/err" || fail "outdir error: $(cat "$T/err")"
# A group with nothing to move is refused instead of running with zero parameters.
sed '/"spheres"/,/"radius": 0.2}\],/d' "$T/truth.json" > "$T/nosph.json"
grep -q spheres "$T/nosph.json" && fail "the sphere-less scene still has spheres"
expect_error 'bad.json: optimize: "spheres": no object of the scene has spheres, nothing to optimise' \
    '{"scene": "nosph.json", "target": "target.exr", "optimize": ["spheres"]}'
expect_error 'bad.json: optimize: "deformation": no object of the scene has spheres' \
    '{"scene": "nosph.json", "target": "target.exr", "optimize": ["deformation"]}'
# A run that fails after its first steps (here a snapshot path taken by a folder) removes the
# snapshots and checkpoint it made, and leaves what the folder held before.
mkdir -p "$T/failrun/snapshots/iter_00002.png"
echo keep > "$T/failrun/earlier.txt"
if "$BIN" optimize "$T/task.json" -o "$T/failrun" --iterations 5 --snapshot-every 1 \
    --checkpoint-every 1 2>"$T/err" >/dev/null; then
    fail "no error for an unwritable snapshot"
fi
[ "$(wc -l < "$T/err")" -eq 1 ] || fail "failed run: $(cat "$T/err")"
left=$(cd "$T/failrun" && find . | sort | tr '\n' ' ')
[ "$left" = ". ./earlier.txt ./snapshots ./snapshots/iter_00002.png " ] ||
    fail "a failed run left files or removed earlier ones: $left"
# A write that fails after some outputs were replaced puts the earlier run's files back.
"$BIN" optimize "$T/task.json" -o "$T/rewrite" --iterations 2 -q || fail "first run to rewrite"
cp "$T/rewrite/final.exr" "$T/final_before.exr"
cp "$T/rewrite/result.json" "$T/result_before.json"
rm "$T/rewrite/loss.svg" && mkdir "$T/rewrite/loss.svg" # written after final.* and compare.png
if "$BIN" optimize "$T/task.json" -o "$T/rewrite" --iterations 6 -q 2>"$T/err" >/dev/null; then
    fail "no error for an unwritable loss.svg"
fi
cmp -s "$T/rewrite/final.exr" "$T/final_before.exr" || fail "a failed write lost the earlier final.exr"
cmp -s "$T/rewrite/result.json" "$T/result_before.json" || fail "a failed write changed result.json"
ls "$T/rewrite" | grep -q -e previous -e tmp- && fail "kept files left: $(ls "$T/rewrite")"
# --target replaces the task's target, with the same checks.
"$BIN" optimize "$T/task.json" -o "$T/retarget" --target "$T/target_tex.exr" --iterations 2 -q ||
    fail "--target"
"$BIN" optimize "$T/task.json" -o "$T/retarget2" --target "$T/small.exr" 2>"$T/err" >/dev/null &&
    fail "--target of the wrong size accepted"
grep -q -- "small.exr: the image is 16x32" "$T/err" || fail "--target error: $(cat "$T/err")"
[ -e "$T/retarget2" ] && fail "output folder left after a --target error"
printf '{"scene": "truth.json", "optimize": ["lighting"], "iterations": 2}\n' > "$T/notarget.json"
"$BIN" optimize "$T/notarget.json" -o "$T/retarget3" --target "$T/target.exr" -q ||
    fail "--target for a task without a target"
# Several views: two cameras of the truth (targets rendered by penumbra), a views file as
# import-cameras writes it, a held-back view; per-view outputs and result.json arrays.
sed 's/"eye": \[2.5, 1.8, 3.0\]/"eye": [-2.5, 1.8, -3.0]/' "$T/truth.json" > "$T/truth_back.json"
"$BIN" render "$T/truth.json" -o "$T/v0.exr" > /dev/null || fail "render view 0"
"$BIN" render "$T/truth_back.json" -o "$T/v1.exr" > /dev/null || fail "render view 1"
cam() { # eye
    printf '{"width": 32, "height": 32, "fov_y_deg": 40, "eye": %s, "target": [0, 0.5, 0]}' "$1"
}
printf '{"views": [{"camera": %s, "target": "v0.exr"}, {"camera": %s, "target": "v1.exr", "weight": 0.5}]}\n' \
    "$(cam '[2.5, 1.8, 3.0]')" "$(cam '[-2.5, 1.8, -3.0]')" > "$T/views.json"
printf '{"scene": "truth.json", "views": "views.json", "optimize": ["lighting"], "lighting_solver": "least_squares", "validation_views": [{"camera": %s, "target": "v1.exr"}], "ground_truth": "truth.json"}\n' \
    "$(cam '[-2.5, 1.8, -3.0]')" > "$T/views_task.json"
"$BIN" optimize "$T/views_task.json" -o "$T/views_out" > "$T/views_stdout" 2>"$T/err" ||
    fail "multi-view task: $(cat "$T/err")"
grep -q "2 views" "$T/views_stdout" || fail "multi-view summary: $(cat "$T/views_stdout")"
for f in final_0.exr final_1.exr validation_0.exr views.png views.json result.json compare.png; do
    [ -f "$T/views_out/$f" ] || fail "multi-view output $f missing"
done
for key in '"views"' '"validation_views"' '"image_rel_rmse"' '"stop_reason"'; do
    grep -q "$key" "$T/views_out/result.json" || fail "multi-view result.json lacks $key"
done
# Photos: view 1 an 8-bit sRGB PNG at another exposure, the "exposure" group; the output's
# views.json (with the recovered exposure) is a task's views.
"$BIN" render "$T/truth_back.json" -o "$T/v1.png" > /dev/null || fail "render view 1 as PNG"
printf '{"scene": "truth.json", "optimize": ["lighting", "exposure"], "iterations": 3, "views": [{"camera": %s, "target": "v0.exr"}, {"camera": %s, "target": "v1.png", "exposure": 0.8}]}\n' \
    "$(cam '[2.5, 1.8, 3.0]')" "$(cam '[-2.5, 1.8, -3.0]')" > "$T/photo_task.json"
"$BIN" optimize "$T/photo_task.json" -o "$T/photo_out" -q 2>"$T/err" ||
    fail "PNG views with exposure: $(cat "$T/err")"
grep -q '"exposure_fixed_view"' "$T/photo_out/result.json" || fail "result.json lacks the gauge"
grep -q '"exposure"' "$T/photo_out/views.json" || fail "views.json lacks the exposures"
printf '{"scene": "truth.json", "optimize": ["lighting"], "iterations": 1, "views": "photo_out/views.json"}\n' \
    > "$T/again_task.json"
"$BIN" optimize "$T/again_task.json" -o "$T/again_out" -q 2>"$T/err" ||
    fail "a task on the output's views.json: $(cat "$T/err")"
printf '{"scene": "truth.json", "target": "v0.exr", "optimize": ["lighting", "exposure"]}\n' \
    > "$T/single_exposure.json"
"$BIN" optimize "$T/single_exposure.json" -o "$T/single_out" 2>"$T/err" >/dev/null &&
    fail "exposure on a single-view task accepted"
grep -q 'needs "views" with at least 2 views' "$T/err" || fail "exposure error: $(cat "$T/err")"
printf '{"scene": "truth.json", "views": "views.json", "target": "v0.exr", "optimize": ["lighting"]}\n' > "$T/both.json"
"$BIN" optimize "$T/both.json" -o "$T/both_out" 2>"$T/err" >/dev/null && fail "views and target accepted"
grep -q 'both.json: views: a task has either "views" or a "target", not both' "$T/err" ||
    fail "views + target error: $(cat "$T/err")"
[ -e "$T/both_out" ] && fail "output folder left after a views error"
# Memory: result.json has the estimate made before the run and the peak it held, within a factor
# of 2 of each other (not under the sanitizers, whose shadow memory and quarantine multiply the
# peak); a limit below the estimate refuses the task before it starts, in one line naming the
# task and the bytes, with no output folder.
est=$(json_number "$T/out/result.json" memory_estimate_bytes)
peak=$(json_number "$T/out/result.json" memory_peak_bytes)
awk -v e="$est" -v p="$peak" 'BEGIN { exit !(e > 0 && p > 0) }' ||
    fail "memory estimate $est or peak $peak missing"
if ! ldd "$BIN" 2>/dev/null | grep -q 'libasan[.]so'; then
    awk -v e="$est" -v p="$peak" 'BEGIN { exit !(e < 2 * p && p < 2 * e) }' ||
        fail "memory estimate $est against peak $peak"
fi
rm -rf "$T/memout"
"$BIN" optimize "$T/task.json" -o "$T/memout" --memory-limit 0.01 2>"$T/err" >/dev/null &&
    fail "a task over --memory-limit ran"
grep -q 'task.json: needs about 0\.[0-9] GB of memory, more than the 0\.0 GB allowed (--memory-limit)' \
    "$T/err" || fail "memory limit error: $(cat "$T/err")"
[ "$(wc -l < "$T/err")" -eq 1 ] || fail "memory limit: not one line: $(cat "$T/err")"
[ -e "$T/memout" ] && fail "output folder left after the memory limit"
# Usage errors exit 2.
"$BIN" optimize "$T/task.json" 2>/dev/null
[ $? -eq 2 ] || fail "missing -o is not a usage error"

if [ "$fails" -ne 0 ]; then
    echo "$fails failures"
    exit 1
fi
echo "cli_optimize: all passed"
