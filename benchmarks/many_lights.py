"""Many lights: the efficiency of light sampling, MIS and RIS on the lamp-grid room.

Efficiency is ``1 / (MSE × CPU-seconds)`` of a render against a converged reference (MIS at
``--ref-spp``), MSE over every pixel and channel less the reference's own variance, CPU-seconds of
this process (``time.process_time``, every thread) and wall seconds of the render alone (compiled
before, by a warm-up render). Rounds interleave the estimators (A B C, C B A, …) and the
table reports each estimator's median efficiency, relative to power-selected light sampling.

Run (a few minutes on 2 cores)::

    python benchmarks/many_lights.py [--size 96] [--spp 16] [--rounds 3] [--ref-spp 1024]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

import jaxrt
from jaxrt.scene.builtin import lamp_grid

#: (label, estimator, parameters)
VARIANTS = (
    ("light_solid_angle", "light_solid_angle", {}),
    ("mis", "mis", {}),
    ("ris M=4", "ris", {"ris_candidates": 4}),
    ("ris M=8", "ris", {"ris_candidates": 8}),
    ("ris M=16", "ris", {"ris_candidates": 16}),
)


def _timed_render(scene, estimator, params, spp, seed):
    c0, w0 = time.process_time(), time.perf_counter()
    r = jaxrt.render(scene, estimator, spp=spp, seed=seed, progress=False, **params)
    return r, time.process_time() - c0, time.perf_counter() - w0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=96, help="image width (height 3/4 of it)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=1024)
    args = ap.parse_args(argv)
    scene = lamp_grid(args.size, args.size * 3 // 4)
    print(scene.summary(), flush=True)
    load0 = os.getloadavg()
    ref = jaxrt.render(scene, "mis", spp=args.ref_spp, seed=12345, progress=False)
    ref_image = np.asarray(ref.image, np.float64)
    ref_mse = float(np.mean(np.asarray(ref.stderr, np.float64) ** 2))
    for _, e, p in VARIANTS:  # compile outside the timed rounds
        jaxrt.render(scene, e, spp=args.spp, seed=0, progress=False, **p)
    eff = {label: [] for label, _, _ in VARIANTS}
    wall_eff = {label: [] for label, _, _ in VARIANTS}
    for k in range(args.rounds):
        order = VARIANTS if k % 2 == 0 else VARIANTS[::-1]
        for label, e, p in order:
            r, cpu, wall = _timed_render(scene, e, p, args.spp, seed=1 + k)
            # the reference's own variance, independent of the render's, comes off the MSE
            mse = float(np.mean((np.asarray(r.image, np.float64) - ref_image) ** 2)) - ref_mse
            eff[label].append(1 / (mse * cpu))
            wall_eff[label].append(1 / (mse * wall))
    load1 = os.getloadavg()
    first = VARIANTS[0][0]
    base, base_w = statistics.median(eff[first]), statistics.median(wall_eff[first])
    print(f"\nreference: mis {args.ref_spp} spp, its own MSE (σ²) {ref_mse:.3g}; "
          f"load {load0[0]:.2f} -> {load1[0]:.2f}")
    print(f"{args.size}x{args.size * 3 // 4}, {args.spp} spp, {args.rounds} interleaved rounds\n")
    print("| estimator | efficiency per CPU-s (× light_solid_angle) | per wall s |")
    print("|---|---|---|")
    for label, _, _ in VARIANTS:
        print(f"| {label} | {statistics.median(eff[label]) / base:.2f} | "
              f"{statistics.median(wall_eff[label]) / base_w:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
