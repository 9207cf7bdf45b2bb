# The frame seen only by its shadow (docs/results/optimize.md "A frame seen only by its shadow"):
# a stool frame of thin tubes (make_frame.py: radius 1 % of its size), out of the camera's view,
# under a sun 25 degrees up; the 6-D pose from 12 degrees and 8 % of the size away, through N
# fitted spheres (the model pose tasks render with). Prints the rotation error, the translation
# error, and the translation split along the sun's direction (what one distant light's shadow
# cannot tell: moving the frame along it moves no shadow) and across it.
#   sh research/experiments/thin_pose/run.sh [build/penumbra] [N ...]
#   (env: PEN_THIN_OUT, default out/thin_pose)
# About a minute on the shared 2-core machine for N = 32 64 128.
set -e
PEN=$(cd "$(dirname "${1:-build/penumbra}")" && pwd)/$(basename "${1:-build/penumbra}")
[ $# -gt 0 ] && shift
COUNTS=${*:-32 64 128}
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${PEN_THIN_OUT:-out/thin_pose}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
python3 "$HERE/make_frame.py" "$OUT/frame.obj"
# The scenes beside the mesh, the map's path made absolute.
MAP=$(cd "$HERE/../../../data/envmaps" && pwd)
for f in frame_truth frame_init frame_pose; do
    sed "s|[.][.]/[.][.]/[.][.]/data/envmaps|$MAP|" "$HERE/$f.json" > "$OUT/$f.json"
done
"$PEN" reference "$OUT/frame_truth.json" -o "$OUT/target.exr" --spp 256 --lighting sh > /dev/null
printf '| spheres | rotation error (deg) | translation error | along the sun | across it (share of size) |\n'
printf '|---|---|---|---|---|\n'
for n in $COUNTS; do
    sed "s|\"fit\": 128|\"fit\": $n|" "$OUT/frame_init.json" > "$OUT/init_$n.json"
    sed "s|\"fit\": 128|\"fit\": $n|" "$OUT/frame_truth.json" > "$OUT/truth_$n.json"
    sed -e "s|frame_init.json|init_$n.json|" -e "s|frame_truth.json|truth_$n.json|" \
        "$OUT/frame_pose.json" > "$OUT/task_$n.json"
    "$PEN" optimize "$OUT/task_$n.json" -o "$OUT/n$n" -q 2> /dev/null
    python3 - "$OUT/n$n" "$n" <<'PY'
import json, math, sys
d, n = sys.argv[1], sys.argv[2]
m = json.load(open(d + "/result.json"))["metrics"]
t = json.load(open(d + "/scene.json"))["objects"][0]["pose"]["translation"]
sun = [0.544, 0.423, -0.725]
k = math.sqrt(sum(x * x for x in sun))
sun = [x / k for x in sun]
along = sum(a * b for a, b in zip(t, sun))
across = math.sqrt(sum((a - along * b) ** 2 for a, b in zip(t, sun)))
print("| %s | %.2f | %.3f | %.3f | %.4f (%.2f %%) |" % (n, m["rotation_error_deg"],
      m["translation_error"], along, across, 100 * across / 1.12))
PY
done
