"""Accuracy of `penumbra render` against the full-map truth, with and without disk lights.

Disk lights: docs/design.md sec. 1.13.

Usage: python3 research/experiments/accuracy/lights_table.py PENUMBRA_BIN OUTDIR [--size S]
           [--spp N] [--meshes a,b] [--maps a,b] [--suffix S] [--self MODE]

For every mesh x map cell it measures rel. RMSE against `penumbra reference --lighting envmap`
(the full environment map, importance-sampled, with exact visibility against the real mesh and
ground: the light users' photos have) of three renders of the same scene:
  lights     the scene as written (its lights found in the map: "lights" absent, the default)
  none       "lighting": {"lights": "none"}: the map's 4-band SH projection alone (the renderer
             before disk lights)
  no-shadows the default scene rendered with --no-shadows
over the whole image, over the surfaces (object and ground: the reference's coverage) and over the
object's own pixels (coverage of the scene without its ground). The truth's own noise is measured
from a second reference at N/4 spp (seed 2): noise = err(second vs truth) / sqrt(5).
Scenes, poses, cameras and map scales are those of visibility_table.py beside it (whose functions
this script uses); 32 fitted spheres ("spheres": {"fit": 32}, cached). Existing images are reused;
--suffix S names the renders (not the truths) so that a second binary is compared with the same
truths; --self MODE writes "shadow": {"self": MODE} into every scene (visibility_table.py's
--self). Writes OUTDIR/scenes, OUTDIR/img, OUTDIR/lights<S>.tsv and a markdown table on stdout.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import visibility_table as vt  # noqa: E402

MESHES = ["spot_triangulated", "bob_tri", "scorpion", "koala", "blub", "goathead"]
MAPS = ["city", "interior", "forest", "night", "sunset", "courtyard"]


def main():
    args = sys.argv[1:]
    if len(args) < 2:
        sys.exit(__doc__)
    bin_, out = os.path.abspath(args[0]), os.path.abspath(args[1])
    opts, _ = vt.parse_options(args[2:], {"--size": "128", "--spp": "4096",
                                          "--meshes": ",".join(MESHES), "--maps": ",".join(MAPS),
                                          "--suffix": "", "--self": ""})
    vt.SELF = opts["--self"] or None
    size, spp, suffix = int(opts["--size"]), int(opts["--spp"]), opts["--suffix"]
    for d in ("scenes", "img"):
        os.makedirs(os.path.join(out, d), exist_ok=True)
    images = vt.Images(bin_, out, suffix, "envmap")
    img, ref, render = images.img, images.ref, images.render

    def err(a, b, mask):
        j = json.loads(vt.run([bin_, "compare", a, b, "--mask", mask]))
        return j["rel_rmse"], j["mask"]["rel_rmse"]

    rows = []
    tsv = open(os.path.join(out, "lights%s.tsv" % suffix), "w")
    tsv.write("mesh\tmap\tkind\trel_image\trel_surfaces\trel_object\n")
    for mesh in opts["--meshes"].split(","):
        mpath = os.path.join(vt.DATA, "meshes", mesh + ".obj")
        albedo = os.path.join(vt.DATA, "meshes", "spot_texture.png") \
            if mesh == "spot_triangulated" else None
        pose = vt.pose_and_camera(mesh)
        for env in opts["--maps"].split(","):
            cell = "%s_%s" % (mesh, env)
            sdir = os.path.join(out, "scenes")
            base = vt.scene_json(os.path.join(sdir, cell + ".json"), size, mpath, {"fit": 32},
                                 pose[:2], pose[2:], env, 1.0, albedo=albedo)
            with open(base) as f:
                sc = json.load(f)
            sc["lighting"]["lights"] = "none"
            none = os.path.join(sdir, cell + "_none.json")
            with open(none, "w") as f:
                json.dump(sc, f, indent=1)
            del sc["ground"]
            sc["lighting"].pop("lights")
            bare = os.path.join(sdir, cell + "_object.json")
            with open(bare, "w") as f:
                json.dump(sc, f, indent=1)
            surf = img(cell + "_surfaces")
            truth = ref(base, cell + "_truth", spp, 1, surf)
            second = ref(base, cell + "_truth2", spp // 4, 2)
            obj = img(cell + "_objmask")
            if not os.path.exists(obj):
                ref(bare, cell + "_objref", 4, 1, obj)
            noise = [e / 5 ** 0.5 for e in err(second, truth, surf)] + \
                [err(second, truth, obj)[1] / 5 ** 0.5]
            for kind, scene, flags in (("lights", base, ()), ("none", none, ()),
                                       ("no-shadows", base, ("--no-shadows",))):
                r = render(scene, cell + "_" + kind, flags)
                v = list(err(r, truth, surf)) + [err(r, truth, obj)[1]]
                rows.append((mesh, env, kind, v))
                tsv.write("%s\t%s\t%s\t%.5f\t%.5f\t%.5f\n" % (mesh, env, kind, *v))
                tsv.flush()
            rows.append((mesh, env, "truth noise", noise))
            tsv.write("%s\t%s\ttruth noise\t%.5f\t%.5f\t%.5f\n" % (mesh, env, *noise))
    tsv.close()
    print("| mesh | map | lights (image / surfaces / object) | \"none\" | --no-shadows | truth "
          "noise |")
    print("|---|---|---|---|---|---|")
    cells = {}
    for m, e, k, v in rows:
        cells.setdefault((m, e), {})[k] = "%.3f / %.3f / %.3f" % tuple(v)
    for (m, e), c in cells.items():
        print("| %s | %s | %s | %s | %s | %s |" % (m, e, c["lights"], c["none"], c["no-shadows"],
                                                  c["truth noise"]))


if __name__ == "__main__":
    main()
