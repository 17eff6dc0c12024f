"""Veach's MIS scene: light sampling, BSDF sampling and MIS at EQUAL SPP, side by side.

Four plates, rough (top) to nearly smooth (bottom), reflect four sphere lights of equal power,
large (left) to tiny (right). Expected (Veach 1997, fig. 9.2):
  - light sampling (``light_solid_angle``): clean on the rough plates and the small lights,
    noisy on the smooth plates under the large lights;
  - BSDF sampling (``bsdf``): clean on the smooth plates and the large lights, speckled on
    the rough plates under the small lights;
  - MIS (``mis``): clean everywhere.

Usage: python examples/mis_scene.py [--spp 16] [--width 384 --height 256] [-o mis.png]
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jaxrt.rendering.driver import render  # noqa: E402
from jaxrt.scene import builtin as scenes  # noqa: E402
from jaxrt.scene.images import srgb_oetf  # noqa: E402

PANELS = (("light_solid_angle", "light sampling"), ("bsdf", "BSDF sampling"),
          ("mis", "MIS (power heuristic)"))


def main(argv=None) -> dict:
    """Render the three panels; returns {estimator: RenderResult}."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--width", type=int, default=384)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--exposure", type=float, default=0.0, help="extra exposure, in stops")
    p.add_argument("-o", "--output", default="mis.png")
    args = p.parse_args(argv)

    scene = scenes.veach_mis(width=args.width, height=args.height)
    print(scene.summary())
    results = {}
    for name, _ in PANELS:
        r = render(scene, name, spp=args.spp, seed=args.seed, progress=False)
        results[name] = r
        print(f"{name:18s} {r.spp} spp in {r.timings['render']:.2f} s "
              f"(+{r.timings['compile']:.1f} s compile), mean relative error "
              f"{r.relative_error:.4f}" + (f", {r.nonfinite} non-finite" if r.nonfinite else ""))

    # one exposure for all panels: the MIS image's 99.5th percentile maps to white (the tiny
    # lights are thousands of times brighter than the plates and would take the whole range)
    white = max(float(np.percentile(results["mis"].image, 99.5)), 1e-8)
    scale = 2.0 ** args.exposure / white
    fig, axes = plt.subplots(1, len(PANELS), figsize=(4.2 * len(PANELS),
                                                      4.2 * args.height / args.width + 0.8),
                             layout="constrained")
    for ax, (name, label) in zip(axes, PANELS, strict=True):
        r = results[name]
        ax.imshow(srgb_oetf(np.clip(r.image * scale, 0.0, 1.0)), interpolation="nearest")
        ax.set_title(f"{label} ({name})\n{r.spp} spp, mean rel. error {r.relative_error:.3f}",
                     fontsize=9)
        ax.axis("off")
    fig.suptitle("Veach MIS scene: plates rough (top) → smooth (bottom), lights large (left) "
                 "→ small (right)", fontsize=10)
    fig.savefig(args.output, dpi=110)
    plt.close(fig)
    print(f"wrote {args.output}")
    return results


if __name__ == "__main__":
    main()
