#!/usr/bin/env python3
"""Perturbs a sphere-set JSON (penumbra's {"spheres": [{"center": [...], "radius": r}, ...]}):
the initial guesses of the shape-from-shadow experiments.

Every radius is multiplied by --scale and every centre moved by --shift (object space, scene
units); other members of the file are dropped, the overlap weights too: the renderer computes
those of the perturbed set when it loads it. Standard library only. Example:

    python3 perturb_spheres.py spheres.json start.json --scale 0.75 --shift 0.1 0 -0.12
"""
import argparse
import json
import os


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--scale", type=float, default=1.0, help="radius factor (> 0)")
    ap.add_argument("--shift", type=float, nargs=3, default=[0.0, 0.0, 0.0])
    a = ap.parse_args()
    if not a.scale > 0:
        ap.error("--scale must be positive")
    with open(a.input) as f:
        spheres = json.load(f)["spheres"]
    out = [{"center": [c + d for c, d in zip(s["center"], a.shift)],
            "radius": s["radius"] * a.scale} for s in spheres]
    tmp = a.output + ".tmp"
    with open(tmp, "w") as f:
        json.dump({"spheres": out}, f, indent=1)
        f.write("\n")
    os.replace(tmp, a.output)


if __name__ == "__main__":
    main()
