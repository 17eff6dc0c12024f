"""Cost of carrying the sums through the passes: another checkout's pass against this tree's.

    python benchmarks/paired_pass_carry.py [--main /work/main] [--spp 32] [--rounds 8]
    python benchmarks/paired_pass_carry.py --end-to-end [--rounds 4]

Loads ``jaxrt/rendering/passes.py`` of another checkout (``--main``: one whose pass sums
float32 from zero in every pass, returned to the host) beside this tree's (a double-float32
TwoSum chain carried from pass to pass), compiles both for the 256² Cornell box (MIS, one
device, the default 32 spp per pass), and times passes in interleaved rounds (A B, B A, …)
in this process: per wall second and per CPU-second of the process (``time.process_time``),
with the load from ``os.getloadavg`` before and after. ``--end-to-end`` runs the two
``jaxrt.render`` drivers instead (the other checkout's ``driver.py`` on its own
``passes.py``), 256 spp in the default passes of 32, and times passes 2 … 8 of each render
(the first pass and the compile apart).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

import numpy as np

SIZE = 256


def load_passes(checkout: Path):
    """``jaxrt/rendering/passes.py`` of ``checkout`` as a module of its own (the rest from this
    tree)."""
    spec = importlib.util.spec_from_file_location("passes_other",
                                                  checkout / "jaxrt/rendering/passes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_render(checkout: Path, passes):
    """``jaxrt/rendering/driver.py`` of ``checkout``, importing ``passes`` as its
    ``jaxrt.rendering.passes``."""
    saved = sys.modules["jaxrt.rendering.passes"]
    sys.modules["jaxrt.rendering.passes"] = passes
    try:
        spec = importlib.util.spec_from_file_location("render_other",
                                                      checkout / "jaxrt/rendering/driver.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.modules["jaxrt.rendering.passes"] = saved
    return module


def end_to_end(checkout: Path, rounds: int) -> None:
    """Interleaved ``render(..., spp=256)`` of both drivers; passes 2 … 8 timed."""
    import jaxrt.rendering.driver  # noqa: F401
    from jaxrt.scene.builtin import cornell_box

    renders = {"old": load_render(checkout, load_passes(checkout)).render,
               "new": sys.modules["jaxrt.rendering.driver"].render}
    scene = cornell_box(SIZE, SIZE)
    times = {"old": [], "new": []}
    load_start = os.getloadavg()
    for r in range(rounds):
        for name in ("old", "new") if r % 2 == 0 else ("new", "old"):
            marks = []
            renders[name](scene, "mis", spp=256, progress=False,
                          on_pass=lambda done, marks=marks: marks.append(
                              (time.perf_counter(), time.process_time())))
            (w0, c0), (w1, c1) = marks[0], marks[-1]
            times[name].append((w1 - w0, c1 - c0))
    load_end = os.getloadavg()
    n = SIZE * SIZE * (256 - 32)
    for name, t in times.items():
        wall, cpu = np.array(t).T
        print(f"{name}: {n / np.median(wall) / 1e6:.3f} Msamples/wall-s, "
              f"{n / np.median(cpu) / 1e6:.3f} Msamples/CPU-s (medians of {len(t)})")
    pair = [o[1] / w[1] for o, w in zip(times["old"], times["new"], strict=True)]
    pair_wall = [o[0] / w[0] for o, w in zip(times["old"], times["new"], strict=True)]
    print(f"end to end, new / old: per-round CPU ratios median {np.median(pair):.4f} "
          f"({min(pair):.4f} … {max(pair):.4f}), wall {np.median(pair_wall):.4f}; "
          f"load {load_start} -> {load_end}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--main", type=Path, default=Path("/work/main"))
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--end-to-end", action="store_true",
                        help="time the two render drivers instead of the passes alone")
    a = parser.parse_args(argv)
    if a.end_to_end:
        end_to_end(a.main, a.rounds)
        return 0

    import jax

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.rendering import passes as new
    from jaxrt.scene.builtin import cornell_box

    old = load_passes(a.main)
    est = make_estimator("mis")
    scene = prepare_scene(cornell_box(SIZE, SIZE), est)
    static = dict(est=est, sampler="independent", spp_total=1 << 20, batch_size=64)
    device = jax.devices()[:1]
    run_old = old.RenderPass(scene, 0, device, 256, **static)
    run_new = new.RenderPass(scene, 0, device, 256, **static)
    compile_s = {"old": run_old.compile(a.spp), "new": run_new.compile(a.spp)}
    carry = run_new(run_new.zeros(), 0, a.spp)  # warm-up
    run_old(0, a.spp)
    done = a.spp

    def one(name):
        nonlocal carry, done
        if name == "old":
            run_old(done, a.spp)  # host arrays: it blocks
        else:
            carry = run_new(carry, done, a.spp)  # blocks; the carry stays on the device
        done += a.spp

    times = {"old": [], "new": []}
    load_start = os.getloadavg()
    for r in range(a.rounds):
        for name in ("old", "new") if r % 2 == 0 else ("new", "old"):
            w0, c0 = time.perf_counter(), time.process_time()
            one(name)
            times[name].append((time.perf_counter() - w0, time.process_time() - c0))
    load_end = os.getloadavg()
    n = SIZE * SIZE * a.spp
    for name, t in times.items():
        wall, cpu = np.array(t).T
        print(f"{name}: {n / np.median(wall) / 1e6:.3f} Msamples/wall-s, "
              f"{n / np.median(cpu) / 1e6:.3f} Msamples/CPU-s (medians of {len(t)}; cores "
              f"{cpu.sum() / wall.sum():.2f}); compile {compile_s[name]:.2f} s")
    ratio_wall = np.median([w for w, _ in times["old"]]) / np.median([w for w, _ in times["new"]])
    ratio_cpu = np.median([c for _, c in times["old"]]) / np.median([c for _, c in times["new"]])
    # per round: the pair run back to back sees the same load
    pair = [o[1] / w[1] for o, w in zip(times["old"], times["new"], strict=True)]
    print(f"new / old throughput: {ratio_cpu:.4f} per CPU-s, {ratio_wall:.4f} per wall s "
          f"(per-round CPU ratios: median {np.median(pair):.4f}, "
          f"min {min(pair):.4f}, max {max(pair):.4f}); load {load_start} -> {load_end}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
