"""jaxrt ÷ Mitsuba 3 on the 256² Cornell box (MIS 1 + 1, or path tracing), paired in one process.

    python benchmarks/paired_vs_mitsuba.py [--spp 32] [--rounds 4] [--estimator mis|path]

Both renderers run in this process, in interleaved rounds (j m, m j, j m, …), so a change in
the machine's load hits both. Each round is timed in wall seconds and in this process's CPU
seconds (``time.process_time``: every thread of the process), so the report gives samples per
wall second, samples per CPU-second and the cores each renderer kept busy. jaxrt runs its real
render pass (:class:`jaxrt.rendering.passes.RenderPass`, the program ``render`` runs); Mitsuba its
``direct`` integrator (``llvm_ad_rgb``, box filter; ``mitsuba_cornell.py``), or with
``--estimator path`` jaxrt's path tracer against Mitsuba's ``path`` integrator (both
unbounded, Russian roulette from depth 5). Also reported:
jaxrt's compile time, the kernel count of its compiled pass, and the first frame (a fresh
``jaxrt.render`` of 64 spp with its compile, in a new process so nothing is cached).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SIZE = 256

FIRST_FRAME = """
import time, sys
t0 = time.perf_counter()
from jaxrt.scene import builtin as scenes
from jaxrt.rendering.driver import render
r = render(scenes.cornell_box(256, 256), "mis", spp=64, seed=0, progress=False)
r.image.sum()
print(time.perf_counter() - t0, r.timings["compile"])
"""


def hlo_kernels(text: str) -> dict:
    """Kernels of an optimised HLO module: fusions, while loops, gathers."""
    return {"fusions": len(re.findall(r"= \S+ fusion\(", text)),
            "while loops": len(re.findall(r"\bwhile\(", text)),
            "gathers": len(re.findall(r"\bgather\(", text))}


def first_frame_seconds() -> tuple[float, float]:
    """(seconds from a fresh interpreter to a 64-spp 256² image, of which compile)."""
    out = subprocess.run([sys.executable, "-c", FIRST_FRAME], capture_output=True, text=True,
                         env=dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false"),
                         check=True, timeout=600)
    total, compile_s = (float(x) for x in out.stdout.split()[-2:])
    return total, compile_s


#: Mitsuba 3's integrator for each jaxrt estimator compared (the same estimator of the image).
MITSUBA_INTEGRATOR = {
    "mis": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
    "path": {"type": "path", "max_depth": -1, "rr_depth": 5},
}


def paired(spp: int = 32, rounds: int = 4, log=print, estimator: str = "mis") -> dict:
    """Interleaved rounds of jaxrt and Mitsuba on the same scene; see the module docstring."""
    import jax

    sys.path.insert(0, str(HERE))
    import mitsuba_cornell as mc

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.rendering.passes import RenderPass
    from jaxrt.scene.builtin import cornell_box

    est = make_estimator(estimator)
    scene = prepare_scene(cornell_box(SIZE, SIZE), est)
    run = RenderPass(scene, 0, jax.devices()[:1], 256, est=est, sampler="independent",
                     spp_total=spp, batch_size=64)
    t_compile = run.compile(spp)
    kernels = hlo_kernels(run.compiled[spp].as_text())
    sums = run(run.zeros(), 0, spp)  # warm-up
    mi = mc.import_mitsuba(mc.DEFAULT_VARIANT)
    desc = mc.cornell_scene_dict(SIZE, SIZE, "box", 1.0, mc.DEFAULT_VARIANT)
    desc["integrator"] = MITSUBA_INTEGRATOR[estimator]
    msc = mi.load_dict(desc)
    mc._render_once(mi, msc, spp, 0)  # warm-up (Dr.Jit kernels)
    times = {"jaxrt": [], "mitsuba": []}
    load_start = os.getloadavg()
    for r in range(rounds):
        for name in ("jaxrt", "mitsuba") if r % 2 == 0 else ("mitsuba", "jaxrt"):
            w0, c0 = time.perf_counter(), time.process_time()
            if name == "jaxrt":
                sums = run(sums, (r + 1) * spp, spp)
            else:
                mc._render_once(mi, msc, spp, r + 1)
            times[name].append((time.perf_counter() - w0, time.process_time() - c0))
    n = SIZE * SIZE * spp
    res = {"estimator": estimator, "spp": spp, "rounds": rounds, "load_start": load_start,
           "load_end": os.getloadavg(), "jaxrt_compile_s": t_compile, "jaxrt_kernels": kernels}
    for name, t in times.items():
        wall = float(np.median([w for w, _ in t]))
        cpu = float(np.median([c for _, c in t]))
        res[name] = {"samples_per_wall_s": n / wall, "samples_per_cpu_s": n / cpu,
                     "cores": cpu / wall, "wall_s": [w for w, _ in t], "cpu_s": [c for _, c in t]}
    res["ratio_per_cpu_s"] = (res["jaxrt"]["samples_per_cpu_s"]
                              / res["mitsuba"]["samples_per_cpu_s"])
    res["ratio_per_wall_s"] = (res["jaxrt"]["samples_per_wall_s"]
                               / res["mitsuba"]["samples_per_wall_s"])
    log(f"jaxrt {res['jaxrt']['samples_per_cpu_s'] / 1e6:.2f} Msamples/CPU-s "
        f"({res['jaxrt']['cores']:.2f} cores), Mitsuba "
        f"{res['mitsuba']['samples_per_cpu_s'] / 1e6:.2f} ({res['mitsuba']['cores']:.2f} cores): "
        f"jaxrt/Mitsuba {res['ratio_per_cpu_s']:.3f} per CPU-s, {res['ratio_per_wall_s']:.3f} "
        f"per wall s; compile {t_compile:.2f} s, {kernels}; load {load_start} -> "
        f"{res['load_end']}")
    return res


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--estimator", choices=tuple(MITSUBA_INTEGRATOR), default="mis")
    parser.add_argument("--first-frame", action="store_true",
                        help="also time a first frame in a fresh process")
    a = parser.parse_args(argv)
    res = paired(a.spp, a.rounds, estimator=a.estimator)
    if a.first_frame:
        total, compile_s = first_frame_seconds()
        res["first_frame_s"], res["first_frame_compile_s"] = total, compile_s
        print(f"first frame (fresh process, 64 spp): {total:.2f} s, compile {compile_s:.2f} s")
    print(json.dumps({k: v for k, v in res.items() if k not in ("jaxrt", "mitsuba")},
                     default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
