#!/bin/sh
# Seconds per iteration of a multi-view task against the number of views, with 1 and 2 threads
# and 1 and 2 MPI ranks (docs/optimize.md "Views in parallel"). The task: Spot's
# lighting and pose (from examples/optimize/spot_pose_init.json, 11 degrees and 0.1 units off,
# black lighting) from N views on a circle around it, targets rendered by `penumbra render` from
# examples/optimize/spot_truth.json with each view's camera (the timing does not need ray-traced
# targets). Each cell is the best of R runs of a fixed number of Adam steps (the stopping rule
# cannot end a run early: its window is longer than the run).
# Usage: sh research/experiments/views/time_views.sh PENUMBRA_BIN
# Environment: PEN_TIME_SIZES (default "128 256"), PEN_TIME_VIEWS (default "1 2 4 8"),
#   PEN_TIME_REPEAT (default 3), PEN_TIME_STEPS (default "20 8": Adam steps at each size).
# Modes: t1 (1 thread), t2_turn (2 threads, views one after the other), t2_once (2 threads, 2
# views at once), r2 (mpirun -np 2 --oversubscribe, 1 thread each; skipped without mpirun or
# with a CLI built without MPI).
# Writes out/views/timing/ (ignored by git): targets, tasks, runs, and timing.tsv; a markdown
# table on stdout. Run it on an otherwise idle machine: the cells compare ways of spending the
# same cores, which another job's load distorts (see the noisy table in docs/results/views.md).
set -eu
BIN=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
OUT=$ROOT/out/views/timing
SIZES=${PEN_TIME_SIZES:-128 256}
COUNTS=${PEN_TIME_VIEWS:-1 2 4 8}
REPEAT=${PEN_TIME_REPEAT:-3}
STEPS=${PEN_TIME_STEPS:-20 8}
mkdir -p "$OUT"
MPI=""
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 # CI and containers run as root
if command -v mpirun >/dev/null 2>&1 && ldd "$BIN" 2>/dev/null | grep -q libmpi; then
    MPI=mpirun
fi

# Cameras, truth scenes and task files: one python3 pass (standard library only).
python3 - "$ROOT" "$OUT" "$SIZES" "$COUNTS" <<'EOF'
import json, math, os, sys
root, out, sizes, counts = sys.argv[1], sys.argv[2], sys.argv[3].split(), sys.argv[4].split()
opt = os.path.join(root, "examples", "optimize")
truth = json.load(open(os.path.join(opt, "spot_truth.json")))
init = json.load(open(os.path.join(opt, "spot_pose_init.json")))

def absolute(scene):
    """The scene with its file paths made absolute (it is written to another folder)."""
    s = json.loads(json.dumps(scene))
    s["lighting"]["envmap"] = os.path.normpath(os.path.join(opt, s["lighting"]["envmap"]))
    for ob in s["objects"]:
        for k in ("mesh", "albedo_texture"):
            if k in ob:
                ob[k] = os.path.normpath(os.path.join(opt, ob[k]))
    return s

def camera(i, n, size):
    a = 2 * math.pi * i / n
    return {"width": size, "height": size, "fov_y_deg": 35, "target": [0, 0.5, 0.1],
            "eye": [4.5 * math.sin(a + 0.72), 1.9, 4.5 * math.cos(a + 0.72)], "up": [0, 1, 0]}

t, s0 = absolute(truth), absolute(init)
json.dump(t, open(os.path.join(out, "truth.json"), "w"))
json.dump(s0, open(os.path.join(out, "init.json"), "w"))
for size in sizes:
    for n in counts:
        n = int(n)
        views = []
        for i in range(n):
            cam = camera(i, n, int(size))
            name = "t_%s_%d_%d" % (size, n, i)
            json.dump(dict(t, camera=cam), open(os.path.join(out, name + ".json"), "w"))
            views.append({"camera": cam, "target": name + ".exr"})
        task = {"scene": "init.json", "ground_truth": "truth.json",
                "optimize": ["lighting", "pose"], "lighting_solver": "adam",
                "window": 1000, "views": views}
        json.dump(task, open(os.path.join(out, "task_%s_%d.json" % (size, n)), "w"))
EOF
cd "$OUT"
for f in t_*.json; do
    [ -f "${f%.json}.exr" ] || "$BIN" render "$f" -o "${f%.json}.exr" -q
done

best() { # the smallest seconds_per_iteration of REPEAT runs of "$@"
    b=""
    for r in $(seq "$REPEAT"); do
        rm -rf run
        "$@" >/dev/null 2>&1 || { echo "failed"; return; }
        v=$(python3 -c "import json; print(json.load(open('run/result.json'))['seconds_per_iteration'])")
        b=$(python3 -c "print(min(float('$v'), float('${b:-inf}')))")
    done
    printf '%.3f' "$b"
}

printf 'size\tviews\tt1\tt2_turn\tt2_once\tr2\n' > timing.tsv
echo "| views | 1 thread | 2 threads, views in turn | 2 threads, 2 views at once | 2 ranks x 1 thread |"
echo "|---|---|---|---|---|"
set -- $STEPS
for size in $SIZES; do
    steps=$1
    [ $# -gt 1 ] && shift
    for n in $COUNTS; do
        task=task_${size}_$n.json
        common="--iterations $steps --checkpoint-every 0 --snapshot-every 0 -q -o run"
        t1=$(best "$BIN" optimize "$task" $common --threads 1 --view-workers 1)
        t2t=$(best "$BIN" optimize "$task" $common --threads 2 --view-workers 1)
        t2o=-
        [ "$n" -ge 2 ] && t2o=$(best "$BIN" optimize "$task" $common --threads 2 --view-workers 2)
        r2=-
        [ -n "$MPI" ] && [ "$n" -ge 2 ] &&
            r2=$(best mpirun -np 2 --oversubscribe "$BIN" optimize "$task" $common --threads 1)
        printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$size" "$n" "$t1" "$t2t" "$t2o" "$r2" >> timing.tsv
        echo "| $n x ${size}² | $t1 | $t2t | $t2o | $r2 |"
    done
done
