"""Every direct-illumination estimator on the Cornell box at EQUAL TIME, side by side.

Each estimator renders progressively (``spp_per_pass`` samples per pass) until its time budget
is spent (compilation is not counted), then its RMSE is measured against a MIS reference
rendered ``--reference-factor`` times longer. Writes one labelled PNG (estimator, spp
reached, RMSE in each title) and prints a table.

Usage: python examples/estimators_equal_time.py [--time 10] [--size 128] [-o equal_time.png]
       [--scene cornell_box] [--reference-factor 16] [--spp-per-pass 4]
       [--estimators mis light_area ...]
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jaxrt.integrators.config import DIRECT_ESTIMATORS
from jaxrt.rendering.driver import render  # noqa: E402
from jaxrt.scene import builtin as scenes  # noqa: E402
from jaxrt.scene.images import srgb_oetf  # noqa: E402

# the spp ceiling of a time-budgeted render; the same for every estimator and the reference,
# because the sample stream's total is a compile-time constant (one compile per estimator)
MAX_SPP = 1 << 16


def tonemap(image: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance → display sRGB in [0, 1]: exposure ``scale``, clamp, sRGB OETF."""
    return srgb_oetf(np.clip(image * scale, 0.0, 1.0))


def rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """Root mean square error over pixels and channels, sqrt(mean((x − ref)²))."""
    return float(np.sqrt(np.mean((image.astype(np.float64) - reference) ** 2)))


def main(argv=None) -> dict:
    """Run the comparison; returns {"reference": (H, W, 3) image, "rows": one dict per
    estimator (estimator, spp, passes, seconds, last_pass, compile, msps, rmse, nonfinite,
    image)}."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--time", type=float, default=10.0, help="seconds of rendering per estimator")
    p.add_argument("--size", type=int, default=128, help="image width and height")
    p.add_argument("--scene", default="cornell_box", choices=sorted(scenes.BUILTIN))
    p.add_argument("--reference-factor", type=float, default=16.0,
                   help="the MIS reference renders this many times longer than each estimator")
    p.add_argument("--estimators", nargs="+", default=list(DIRECT_ESTIMATORS),
                   choices=DIRECT_ESTIMATORS)  # the reference is direct light (MIS)
    p.add_argument("--spp-per-pass", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", default="equal_time.png")
    args = p.parse_args(argv)

    scene = scenes.by_name(args.scene, width=args.size, height=args.size)
    print(scene.summary())
    common = dict(spp_per_pass=args.spp_per_pass, progress=False)
    # an independent seed: the reference's noise must not correlate with the MIS panel's
    # (same spp ceiling and pass size as the MIS panel: the reference compiles nothing new)
    ref = render(scene, "mis", spp=MAX_SPP, seed=args.seed + 10_007,
                 time_budget=args.reference_factor * args.time, **common)
    reference = ref.image.astype(np.float64)
    print(f"reference: mis, {ref.spp} spp, mean relative error {ref.relative_error:.4f}")

    rows = []
    for name in args.estimators:
        r = render(scene, name, spp=MAX_SPP, seed=args.seed, time_budget=args.time, **common)
        rows.append(dict(estimator=name, spp=r.spp, passes=r.passes, seconds=r.timings["render"],
                         last_pass=r.timings["last_pass"], compile=r.timings["compile"],
                         msps=r.timings["samples_per_s"] / 1e6,
                         rmse=rmse(r.image, reference), nonfinite=r.nonfinite, image=r.image))

    # one exposure for every panel: the reference's 99th percentile maps to white
    scale = 1.0 / max(float(np.percentile(reference, 99)), 1e-8)
    panels = [(f"reference: mis, {ref.spp} spp", reference)] + [
        (f"{r['estimator']}\n{r['spp']} spp, RMSE {r['rmse']:.4f}", r["image"]) for r in rows]
    cols = 4
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols, 3.6 * nrows), squeeze=False,
                             layout="constrained")
    for ax in axes.flat:
        ax.axis("off")
    for ax, (title, image) in zip(axes.flat, panels, strict=False):
        ax.imshow(tonemap(image, scale), interpolation="nearest")
        ax.set_title(title, fontsize=9)
    fig.suptitle(f"{args.scene} {args.size}×{args.size}, {args.time:g} s of rendering each "
                 "(compile excluded)", fontsize=11)
    fig.savefig(args.output, dpi=100)
    plt.close(fig)

    print(f"{'estimator':20s} {'spp':>7s} {'passes':>6s} {'render s':>8s} {'compile s':>9s} "
          f"{'M smp/s':>8s} {'RMSE':>9s} {'RMSE²·s':>9s}")
    for r in rows:
        # RMSE² × time: inverse efficiency (lower is better), comparable across estimators
        print(f"{r['estimator']:20s} {r['spp']:7d} {r['passes']:6d} {r['seconds']:8.2f} "
              f"{r['compile']:9.2f} {r['msps']:8.3f} {r['rmse']:9.5f} "
              f"{r['rmse'] ** 2 * r['seconds']:9.2e}"
              + (f"  ({r['nonfinite']} non-finite dropped)" if r["nonfinite"] else ""))
    print(f"wrote {args.output}")
    return {"reference": reference, "rows": rows}


if __name__ == "__main__":
    main()
