"""Load an OBJ with an emissive (``Ke``) material, inspect the scene, write an EXR and a PNG.

``examples/data/scene.json`` places ``room.obj`` (whose ``room.mtl`` gives the ceiling panel
``Ke 12 11 9``: it becomes triangle lights automatically) next to an inline wall and a small
sphere light. The EXR holds the image (``R``, ``G``, ``B``) and its per-pixel standard error
(``stderr.R``, ``stderr.G``, ``stderr.B``).

Usage: python examples/load_obj.py [scene.json] [--spp 16] [--size 128] [-o room.exr]
       [--png room.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from jaxrt.rendering.driver import render
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import read_exr, write_exr, write_png

DATA = Path(__file__).resolve().parent / "data"


def main(argv=None):
    """Load, print the summary, render, write EXR (+ stderr) and PNG; returns the RenderResult."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene", nargs="?", default=str(DATA / "scene.json"))
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--size", type=int, default=None, help="override the file's width and height")
    p.add_argument("--estimator", default="mis")
    p.add_argument("-o", "--output", default="room.exr")
    p.add_argument("--png", default="room.png")
    args = p.parse_args(argv)

    scene = load_scene(args.scene, width=args.size, height=args.size)
    print(scene.summary())
    lights = scene.lights
    if lights.triangle is not None:
        radiance = np.unique(np.asarray(lights.triangle.radiance), axis=0)
        print(f"emissive triangles: {lights.triangle.radiance.shape[0]}, radiance {radiance}")

    result = render(scene, args.estimator, spp=args.spp, progress=False)
    t = result.timings
    print(f"{result.spp} spp in {t['render']:.2f} s (+{t['compile']:.1f} s compile), mean "
          f"relative error {result.relative_error:.4f}")
    write_exr(args.output, result.image, extra_channels={"stderr": result.stderr})
    write_png(args.png, result.image)
    image, extra = read_exr(args.output)  # read back: what other tools will see
    print(f"wrote {args.output} (channels RGB + {', '.join(sorted(extra))}, "
          f"{image.shape[1]}x{image.shape[0]}) and {args.png}")
    return result


if __name__ == "__main__":
    main()
