"""The ``jaxrt`` command.

    jaxrt render [SCENE-FILE | built-in name] --estimator mis --spp 64 --seed 0 \\
                 -o out.exr --png out.png [--time-budget S] [--target-error E]
    jaxrt scenes                      # list the built-in scenes
    jaxrt gallery -o warps.png        # every sampling warp: points, histogram, pdf

With no scene, ``render`` renders the built-in Cornell box.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _render(args) -> int:
    from jaxrt import io, scenes
    from jaxrt.render import render

    size = {}
    if args.width:
        size["width"] = args.width
    if args.height:
        size["height"] = args.height
    if args.scene is None or args.scene in scenes.BUILTIN:
        name = args.scene or "cornell_box"
        scene = scenes.by_name(name, accel=args.accel, **size)
    else:
        from jaxrt.scene_file import load_scene

        path = Path(args.scene)
        if not path.exists():
            print(f"jaxrt: no such scene file or built-in scene: {args.scene!r} (built-ins: "
                  f"{', '.join(sorted(scenes.BUILTIN))})", file=sys.stderr)
            return 2
        scene = load_scene(path, accel=args.accel, **size)
    print(scene.summary())
    params = {}
    if args.light_samples is not None:
        params["light_samples"] = args.light_samples
    if args.bsdf_samples is not None:
        params["bsdf_samples"] = args.bsdf_samples
    if args.heuristic is not None:
        params["heuristic"] = args.heuristic
    result = render(scene, args.estimator, spp=args.spp, seed=args.seed, sampler=args.sampler,
                    time_budget=args.time_budget, target_error=args.target_error,
                    progress=not args.quiet, **params)
    t = result.timings
    print(f"{result.spp} spp in {t['render']:.2f} s (+{t['compile']:.2f} s compile): "
          f"{t['samples_per_s'] / 1e6:.2f} M samples/s, mean relative error "
          f"{result.relative_error:.4f}, stopped by {result.stopped_by}"
          + (f", {result.nonfinite} non-finite samples dropped" if result.nonfinite else ""))
    io.write_exr(args.output, result.image, extra_channels={"stderr": result.stderr})
    print(f"wrote {args.output}")
    if args.png:
        io.write_png(args.png, result.image, exposure=args.exposure)
        print(f"wrote {args.png}")
    return 0


def _scenes(args) -> int:
    from jaxrt import scenes

    for name, fn in sorted(scenes.BUILTIN.items()):
        print(f"{name:20s} {(fn.__doc__ or '').strip().splitlines()[0]}")
    return 0


def _gallery(args) -> int:
    from jaxrt.gallery import make_gallery

    make_gallery(args.output, num_samples=args.samples)
    print(f"wrote {args.output}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from jaxrt.estimators import ESTIMATORS
    from jaxrt.sampler import SAMPLER_KINDS

    p = argparse.ArgumentParser(prog="jaxrt", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a scene to an EXR (and a PNG preview)")
    r.add_argument("scene", nargs="?", default=None,
                   help="a scene file (.json) or a built-in scene name (default: cornell_box)")
    r.add_argument("--estimator", default="mis", choices=ESTIMATORS)
    r.add_argument("--spp", type=int, default=64, help="samples per pixel (maximum)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--sampler", default="independent", choices=SAMPLER_KINDS)
    r.add_argument("--light-samples", type=int, default=None, help="MIS light samples")
    r.add_argument("--bsdf-samples", type=int, default=None, help="MIS BSDF samples")
    r.add_argument("--heuristic", choices=("balance", "power"), default=None)
    r.add_argument("--time-budget", type=float, default=None, help="stop after S seconds")
    r.add_argument("--target-error", type=float, default=None,
                   help="stop at this mean relative standard error")
    r.add_argument("--width", type=int, default=None)
    r.add_argument("--height", type=int, default=None)
    r.add_argument("--accel", default="auto", choices=("auto", "brute", "bvh"))
    r.add_argument("-o", "--output", default="out.exr", help="EXR output (RGB + stderr)")
    r.add_argument("--png", default=None, help="also write an sRGB PNG preview")
    r.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_render)

    s = sub.add_parser("scenes", help="list the built-in scenes")
    s.set_defaults(func=_scenes)

    g = sub.add_parser("gallery", help="draw every sampling warp into one PNG")
    g.add_argument("-o", "--output", default="warp_gallery.png")
    g.add_argument("--samples", type=int, default=200_000)
    g.set_defaults(func=_gallery)
    return p


def main(argv=None) -> int:
    """Entry point of the ``jaxrt`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, OSError) as e:
        print(f"jaxrt: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
