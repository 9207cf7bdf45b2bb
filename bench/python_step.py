"""Times one optimisation step of the Python binding: Spot under the city map
(examples/scenes/spot_city.json) at SIZE x SIZE, gradients of lighting, texture, proxy spheres
and pose (the set of `penumbra bench`'s headline), an L2 loss against the first render.

With --fresh every render gets a new C render state (render_scene without a renderer, as the
binding did before penumbra.Renderer existed; this also runs on such older packages); without it
one penumbra.Renderer keeps its state and caches between steps. Prints the median and quartiles
of the step time in ms.

    PYTHONPATH=python /usr/bin/python3 bench/python_step.py [--size 256] [--steps 20] [--fresh]
"""

import argparse
import dataclasses
import os
import statistics
import time

import torch

import penumbra


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--fresh", action="store_true", help="a new render state for every call")
    a = ap.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    scene = penumbra.load_scene(os.path.join(here, "..", "examples", "scenes", "spot_city.json"))
    scene.camera = dataclasses.replace(scene.camera, width=a.size, height=a.size)
    ob = scene.objects[0]
    renderer = None if a.fresh else penumbra.Renderer(a.threads)

    def render():
        if renderer is None:
            return penumbra.render_scene(scene, threads=a.threads)
        return renderer.render_scene(scene)

    with torch.no_grad():
        target = render() * 0.9
    for t in (scene.sh, ob.texture, ob.spheres, ob.pose):
        t.requires_grad_()
    times = []
    for step in range(a.warmup + a.steps):
        t0 = time.perf_counter()
        loss = (render() - target).square().mean()
        loss.backward()
        times.append(1e3 * (time.perf_counter() - t0))
    q = statistics.quantiles(times[a.warmup:], n=4)
    print("%s, %dx%d, %d steps: median %.1f ms (quartiles %.1f, %.1f), load %.1f"
          % ("fresh state per call" if a.fresh else "one Renderer", a.size, a.size, a.steps, q[1],
             q[0], q[2], os.getloadavg()[0]))


if __name__ == "__main__":
    main()
