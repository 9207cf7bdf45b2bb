"""Recover an object's 6-D pose from an image of it with a torch optimizer, through penumbra's
differentiable soft shadows: where the shadow falls on the ground tells where the object stands.

    /usr/bin/python3 examples/python/fit_pose.py [TRUTH.json [START.json]] [--size 128]
        [--iterations 100] [--lr-rotation 0.5] [--lr-translation 0.01] [--target IMAGE.exr]
        [--no-shadows] [--out DIR]

TRUTH.json is the scene as observed (default examples/optimize/spot_truth.json); START.json
gives the objects' starting poses (default spot_pose_init.json beside it: Spot turned by 11
degrees and moved 0.1 units along the ground). The target is TRUTH rendered (or an observed
linear image of its camera at --size, --target). Adam moves every object's rotation (axis times
angle, degrees, rate --lr-rotation) and translation (scene units, --lr-translation) on the L2
image loss; the scale stays. The scene first goes through penumbra.gradient_model(scene, ["pose"]):
the objects' own shadows and their ground shadows from the proxy spheres, the model whose pose
gradient is exact (the default transfer is ray traced once per pose and has none; a render
asked for a pose gradient under it raises PenumbraError). `penumbra optimize
examples/optimize/spot_pose.json` is the same problem on the command line.
Run from the repository root after `make build` (the package is found in ../../python and the
library in build/, or through PYTHONPATH and PENUMBRA_LIB).
"""

import argparse
import dataclasses
import os
import sys
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "python"))
import penumbra  # noqa: E402


def fit_pose(scene, target, starts, iterations=100, lr_rotation=0.5, lr_translation=0.01,
             shadows=True, log=None):
    """Fits the rotation and translation of every object of the scene to the target image
    (H, W, 3), from the (7,) poses `starts` (one per object); returns the fitted poses and the
    loss per iteration. The scene is left as it was."""
    # The model whose pose gradient is exact (a copy: the scene's objects keep their poses).
    model = penumbra.gradient_model(scene, ["pose"])
    rotations = [p[0:3].clone().requires_grad_() for p in starts]
    translations = [p[3:6].clone().requires_grad_() for p in starts]
    opt = torch.optim.Adam([{"params": rotations, "lr": lr_rotation},
                            {"params": translations, "lr": lr_translation}])
    renderer = penumbra.Renderer()  # keeps the render state and its caches between iterations
    losses = []
    for it in range(iterations):
        opt.zero_grad()
        for ob, r, t, p in zip(model.objects, rotations, translations, starts):
            ob.pose = torch.cat([r, t, p[6:7]])  # the scale stays
        loss = (renderer.render_scene(model, shadows=shadows) - target).square().mean()
        loss.backward()  # the C backward: d loss / d pose through the shadows
        opt.step()
        losses.append(loss.item())
        if log and (it % 20 == 0 or it == iterations - 1):
            log("iteration %4d  loss %.3e" % (it, losses[-1]))
    fitted = [torch.cat([r.detach(), t.detach(), p[6:7]])
              for r, t, p in zip(rotations, translations, starts)]
    return fitted, losses


def pose_error(pose, truth):
    """(rotation difference in degrees, translation difference) of two (7,) poses: the angle
    of R_truth^T R, from the axis-angle vectors."""
    def matrix(v):
        angle = torch.linalg.norm(v)
        if float(angle) == 0.0:
            return torch.eye(3)
        k = v / angle
        kx = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        a = torch.deg2rad(angle)
        return torch.eye(3) + torch.sin(a) * kx + (1 - torch.cos(a)) * kx @ kx

    d = matrix(truth[0:3].double()).T @ matrix(pose[0:3].double())
    cos = ((torch.trace(d) - 1) / 2).clamp(-1.0, 1.0)
    return float(torch.rad2deg(torch.arccos(cos))), float(torch.linalg.norm(pose[3:6] - truth[3:6]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("truth", nargs="?",
                    default=os.path.join(HERE, "..", "optimize", "spot_truth.json"))
    ap.add_argument("start", nargs="?", help="scene JSON of the starting poses "
                    "(default: spot_pose_init.json beside TRUTH)")
    ap.add_argument("--size", type=int, default=128, help="render size (square), default 128")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--lr-rotation", type=float, default=0.5, help="degrees per step, about")
    ap.add_argument("--lr-translation", type=float, default=0.01, help="units per step, about")
    ap.add_argument("--target", help="observed linear image (EXR/HDR) of the scene at --size")
    ap.add_argument("--no-shadows", action="store_true", help="fit without shadows")
    ap.add_argument("--out", help="folder for target.png, initial.png and fitted.png")
    args = ap.parse_args()
    start_path = args.start or os.path.join(os.path.dirname(args.truth), "spot_pose_init.json")

    scene = penumbra.load_scene(args.truth)  # fits {"fit": N} sphere sets once (cached)
    scene.camera = dataclasses.replace(scene.camera, width=args.size, height=args.size)
    starts = [ob.pose for ob in penumbra.load_scene(start_path, fit_spheres=False).objects]
    if len(starts) != len(scene.objects):
        sys.exit("fit_pose: %s has %d objects, %s %d" % (start_path, len(starts), args.truth,
                                                         len(scene.objects)))
    target = penumbra.load_image(args.target) if args.target else penumbra.render_scene(scene)
    shadows = not args.no_shadows
    t0 = time.time()
    fitted, losses = fit_pose(scene, target, starts, args.iterations, args.lr_rotation,
                              args.lr_translation, shadows, log=print)
    seconds = time.time() - t0
    print("%d iterations in %.1f s (%.0f ms each); loss %.3e -> %.3e"
          % (len(losses), seconds, 1000 * seconds / len(losses), losses[0], losses[-1]))
    for i, (ob, start, pose) in enumerate(zip(scene.objects, starts, fitted)):
        (r0, t0), (r1, t1) = pose_error(start, ob.pose), pose_error(pose, ob.pose)
        print("object %d: rotation off %.2f -> %.2f degrees, translation off %.4f -> %.4f"
              % (i, r0, r1, t0, t1))
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        model = penumbra.gradient_model(scene, ["pose"])
        for name, poses in (("initial", starts), ("fitted", fitted)):
            posed = dataclasses.replace(model, objects=[dataclasses.replace(ob, pose=p)
                                                        for ob, p in zip(model.objects, poses)])
            penumbra.save_image(os.path.join(args.out, name + ".png"),
                                penumbra.render_scene(posed, shadows=shadows))
        penumbra.save_image(os.path.join(args.out, "target.png"), target)
        print("wrote %s/{target,initial,fitted}.png" % args.out)


if __name__ == "__main__":
    main()
