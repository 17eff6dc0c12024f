"""Start-up of a render: first frame and its phases, a second ``jaxrt`` run, compile per estimator.

    python benchmarks/startup.py                    # all four, ~2.5 min on the 2-core machine
    python benchmarks/startup.py --only compile     # per-estimator compile times only
    python benchmarks/startup.py --only phases      # where a first frame's seconds go
    python benchmarks/startup.py --only first --accel bvh   # the box's first frame by a BVH

Every figure comes from a fresh interpreter (``subprocess``), as a user meets it:

- **first frame**: ``import jaxrt`` → a 64-spp 256² Cornell box with MIS (``render(...)``),
  no persistent caches of any kind; also the seconds of compilation inside it;
- **second run**: ``jaxrt render`` at 16², 16 spp, twice with the same empty cache directory
  (``XDG_CACHE_HOME``): the second run's wall time from process start to exit, and the
  compile seconds it prints (the second reads its pass from jaxrt's program cache);
- **compile per estimator**: trace, lower and XLA compile of the 256² pass (32 spp per pass,
  as ``render`` picks for 64 spp), each estimator in its own process, wall and CPU seconds;
  and the same pass read from :mod:`jaxrt.rendering.program_cache` by a second process;
- **phases** of the first frame, in a fresh process that runs what ``render`` runs step by
  step: imports, scene, trace, lower, XLA (split by XLA's own log into its HLO passes, on one
  thread, and its kernel modules, compiled on its worker threads: their count and summed
  MLIR and LLVM CPU seconds), then the two 32-spp passes; wall and CPU seconds of each.

The machine is shared: each figure is the median of ``--repeat`` runs, printed with the load
average (``os.getloadavg``) before and after and the share of CPU time the host stole
meanwhile (``/proc/stat``, where there is one); and first, the seconds of a pure-Python loop,
since a VM's speed moves with neither.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ESTIMATORS = ("mis", "mis_one_sample", "light_solid_angle", "light_area", "bsdf",
              "cosine_hemisphere", "uniform_hemisphere")

FIRST_FRAME = """
import sys, time
t0 = time.perf_counter()
from jaxrt.scene import builtin as scenes
from jaxrt.rendering.driver import render
r = render(scenes.cornell_box(256, 256, accel=sys.argv[1]), "mis", spp=64, seed=0,
           progress=False)
r.image.sum()
print(time.perf_counter() - t0, r.timings["compile"])
"""

COMPILE = """
import sys, time
import jax, jax.numpy as jnp
from jaxrt.scene import builtin as scenes
import jaxrt.rendering.passes as ps
from jaxrt.core.xla import compiler_options
from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.driver import default_spp_per_pass
est = make_estimator(sys.argv[1])
scene = prepare_scene(scenes.cornell_box(256, 256), est)
run = ps.RenderPass(scene, 0, jax.local_devices()[:1], 256, est=est, sampler="independent",
                    spp_total=64, batch_size=64)
args = (run.scene, run.seed, jnp.int32(0), run.firsts, run.zeros())
clock = lambda: (time.perf_counter(), time.process_time())
t = [clock()]
traced = ps.render_tiles.trace(*args, count=default_spp_per_pass(256 * 256, 64), **run.static)
t.append(clock())
lowered = traced.lower()
t.append(clock())
lowered.compile(compiler_options())
t.append(clock())
print(" ".join(f"{b[0] - a[0]:.4f} {b[1] - a[1]:.4f}" for a, b in zip(t, t[1:])))
"""


#: Subprocesses run here, so that ``-c``/``-m`` do not import a ``jaxrt`` from the current
#: directory instead of :data:`TREE`'s.
_NEUTRAL = tempfile.gettempdir()
#: The tree whose ``jaxrt`` package is measured (``--jaxrt``: e.g. an older checkout, to
#: compare before and after in the same period of machine load).
TREE = ROOT


PHASES = """
import time
clock = lambda: (time.perf_counter(), time.process_time())
t = [clock()]
import jax
t.append(clock())
from jaxrt.scene import builtin as scenes
import jaxrt.rendering.passes as ps
from jaxrt.core.xla import compiler_options_soon
from jaxrt.integrators.config import make_estimator, prepare_scene
t.append(clock())
est = make_estimator("mis")
options = compiler_options_soon()
scene = prepare_scene(scenes.cornell_box(256, 256), est)
run = ps.RenderPass(scene, 0, jax.local_devices()[:1], 256, est=est, sampler="independent",
                    spp_total=64, batch_size=64)
args = (run.scene, run.seed, run._start(0), run.firsts, run.zeros())
t.append(clock())
traced = ps.render_tiles.trace(*args, count=32, **run.static)
t.append(clock())
lowered = traced.lower()
t.append(clock())
exe = lowered.compile(options.result())
t.append(clock())
sums = jax.block_until_ready(exe(*args))
sums = jax.block_until_ready(exe(run.scene, run.seed, run._start(32), run.firsts, sums))
t.append(clock())
print(" ".join(f"{b[0] - a[0]:.4f} {b[1] - a[1]:.4f}" for a, b in zip(t, t[1:])))
"""
#: the phases PHASES times, in order
PHASE_NAMES = ("import jax", "import jaxrt", "scene", "trace", "lower", "XLA", "two passes")


CACHED = """
import sys, time
import jax
from jaxrt.rendering import program_cache
from jaxrt.scene import builtin as scenes
from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.passes import RenderPass
from jaxrt.rendering.driver import default_spp_per_pass
program_cache.set_directory(sys.argv[2])
est = make_estimator(sys.argv[1])
scene = prepare_scene(scenes.cornell_box(256, 256), est)
run = RenderPass(scene, 0, jax.local_devices()[:1], 256, est=est, sampler="independent",
                 spp_total=64, batch_size=64)
c0 = time.process_time()
wall = run.compile(default_spp_per_pass(256 * 256, 64))
print(wall, time.process_time() - c0, program_cache.STATS["hits"])
"""


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(TREE) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               **extra)
    return env


def _cpu_times() -> list[int] | None:
    """The machine's cumulative CPU time per state (``/proc/stat``: user … steal), or None."""
    try:
        with open("/proc/stat") as f:
            return [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None


_LAST_TIMES = _cpu_times()


def _load() -> str:
    """Load averages, and the share of CPU time stolen by the host since the last reading:
    a shared VM at steal ≳ 5 % (or whose wall time exceeds its CPU time in a two-thread
    pass) is running slower than its load says (benchmarks/README.md#method)."""
    global _LAST_TIMES
    one, five, fifteen = os.getloadavg()
    text = f"load {one:.2f} {five:.2f} {fifteen:.2f}"
    now = _cpu_times()
    if now is not None and _LAST_TIMES is not None:
        spent = [b - a for a, b in zip(_LAST_TIMES, now, strict=True)]
        if sum(spent) > 0:
            text += f", steal {100 * spent[7] / sum(spent):.0f} % since the last reading"
    _LAST_TIMES = now
    return text


def _python_speed() -> str:
    """Seconds this machine takes for a 10⁷-step pure-Python loop (best of three), printed
    beside the figures: on one VM kind it can take 4–5× as long from one day to another with
    no steal and no load, and every start-up figure (tracing is Python) moves with it."""
    import time

    best = float("inf")
    for _ in range(3):
        t0, s = time.perf_counter(), 0
        for i in range(10**7):
            s += i
        best = min(best, time.perf_counter() - t0)
    return f"10^7-step Python loop {best:.2f} s"


def _child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def first_frame(repeat: int = 3, accel: str = "auto") -> dict:
    """Seconds from a fresh interpreter to a 64-spp 256² MIS image, and the compile in it
    (and the process's CPU seconds); ``accel`` as ``build_scene`` takes it ("bvh": the
    same box traversed by a BVH)."""
    runs = []
    for _ in range(repeat):
        cpu = _child_cpu()
        out = subprocess.run([sys.executable, "-c", FIRST_FRAME, accel], capture_output=True,
                             cwd=_NEUTRAL,
                             text=True, check=True, timeout=600,
                             env=_env(JAX_ENABLE_COMPILATION_CACHE="false",
                                      JAXRT_NO_COMPILE_CACHE="1"))
        runs.append([float(x) for x in out.stdout.split()[-2:]] + [_child_cpu() - cpu])
    return {"first_frame_s": statistics.median(r[0] for r in runs),
            "first_frame_compile_s": statistics.median(r[1] for r in runs),
            "first_frame_cpu_s": statistics.median(r[2] for r in runs), "runs": runs}


def _xla_log(log: str) -> dict:
    """XLA's own account of the pass's compile, from its log (``TF_CPP_VMODULE``): seconds of
    HLO passes, and the kernel modules compiled with their summed MLIR and LLVM seconds."""
    seconds = lambda v, unit: float(v) * {"s": 1.0, "ms": 1e-3, "us": 1e-6}[unit]
    hlo = [seconds(*m) for m in re.findall(
        r"Running HLO passes on \[jit_render_tiles\] for CPU time: ([0-9.]+) (s|ms|us)", log)]
    mlir = [seconds(*m) for m in re.findall(
        r"Compiled MLIR module: \S+ time: ([0-9.]+) (s|ms|us)", log)]
    llvm = [seconds(*m) for m in re.findall(
        r"Compiled LLVM module: \S+ time: ([0-9.]+) (s|ms|us)", log)]
    return {"hlo_passes": hlo[-1] if hlo else float("nan"), "modules": len(mlir),
            "mlir_cpu": sum(mlir), "llvm_cpu": sum(llvm)}


def phases(repeat: int = 3) -> dict:
    """{phase: (wall, CPU) seconds} of a first frame, medians over ``repeat`` fresh processes
    (:data:`PHASE_NAMES`), and XLA's split of its compile (:func:`_xla_log`)."""
    runs, logs = [], []
    for _ in range(repeat):
        out = subprocess.run([sys.executable, "-c", PHASES], capture_output=True,
                             cwd=_NEUTRAL, text=True, check=True, timeout=600,
                             env=_env(JAX_ENABLE_COMPILATION_CACHE="false",
                                      TF_CPP_MIN_LOG_LEVEL="0",
                                      TF_CPP_VMODULE="cpu_compiler=1,fusion_compiler=1,"
                                                     "ir_compiler=1"))
        runs.append([float(x) for x in out.stdout.split()[-2 * len(PHASE_NAMES):]])
        logs.append(_xla_log(out.stderr))
    res = {name: (statistics.median(r[2 * i] for r in runs),
                  statistics.median(r[2 * i + 1] for r in runs))
           for i, name in enumerate(PHASE_NAMES)}
    res["total"] = (statistics.median(sum(r[0::2]) for r in runs),
                    statistics.median(sum(r[1::2]) for r in runs))
    res["xla_log"] = {k: statistics.median(g[k] for g in logs) for k in logs[0]}
    return res


def second_run(repeat: int = 3) -> dict:
    """Wall seconds of a second ``jaxrt render`` (16², 16 spp) and the compile it reports."""
    import time

    walls, compiles, firsts, cpus = [], [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            argv = [sys.executable, "-m", "jaxrt", "render", "--width", "16", "--height",
                    "16", "--spp", "16", "-q", "-o", os.path.join(tmp, "out.exr")]
            env = _env(XDG_CACHE_HOME=os.path.join(tmp, "cache"))
            env.pop("JAXRT_NO_COMPILE_CACHE", None)
            for k in range(2):
                t0, cpu = time.perf_counter(), _child_cpu()
                out = subprocess.run(argv, capture_output=True, cwd=_NEUTRAL, text=True,
                                     check=True,
                                     timeout=600, env=env)
                wall = time.perf_counter() - t0
                compile_s = float(re.search(r"\+([0-9.]+) s compile", out.stdout).group(1))
                (firsts if k == 0 else walls).append(wall)
                if k:
                    compiles.append(compile_s)
                    cpus.append(_child_cpu() - cpu)
    return {"second_run_wall_s": statistics.median(walls),
            "second_run_compile_s": statistics.median(compiles),
            "second_run_cpu_s": statistics.median(cpus),
            "first_run_wall_s": statistics.median(firsts),
            "walls": walls, "compiles": compiles}


def compile_times(repeat: int = 1, estimators=ESTIMATORS) -> dict:
    """{estimator: (trace, lower, xla) wall and CPU seconds}, medians over ``repeat``."""
    res = {}
    for name in estimators:
        runs = []
        for _ in range(repeat):
            out = subprocess.run([sys.executable, "-c", COMPILE, name], capture_output=True,
                                 cwd=_NEUTRAL,
                                 text=True, check=True, timeout=600,
                                 env=_env(JAX_ENABLE_COMPILATION_CACHE="false"))
            runs.append([float(x) for x in out.stdout.split()[-6:]])
        med = [statistics.median(r[i] for r in runs) for i in range(6)]
        res[name] = {"trace": med[0], "lower": med[2], "xla": med[4],
                     "total": med[0] + med[2] + med[4],
                     "total_cpu": med[1] + med[3] + med[5]}
        # a second run: the pass read from the program cache (the first run fills it)
        hits = []
        with tempfile.TemporaryDirectory() as tmp:
            for k in range(1 + repeat):
                out = subprocess.run([sys.executable, "-c", CACHED, name, tmp],
                                     capture_output=True, cwd=_NEUTRAL, text=True,
                                     check=True, timeout=600,
                                     env=_env(JAX_ENABLE_COMPILATION_CACHE="false"))
                wall, cpu, hit = out.stdout.split()[-3:]
                if k:
                    assert hit == "1", out.stdout
                    hits.append((float(wall), float(cpu)))
        res[name]["cached"] = statistics.median(h[0] for h in hits)
        res[name]["cached_cpu"] = statistics.median(h[1] for h in hits)
    return res


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", choices=("first", "second", "compile", "phases"), default=None)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--accel", choices=("auto", "brute", "bvh"), default="auto",
                   help="the first frame's intersection (bvh: the same box by a BVH)")
    p.add_argument("--json", default=None, help="also write the figures here")
    p.add_argument("--jaxrt", default=None, metavar="DIR",
                   help="measure the jaxrt package in DIR (default: this checkout)")
    a = p.parse_args(argv)
    global TREE
    TREE = Path(a.jaxrt).resolve() if a.jaxrt else ROOT
    out = {}
    print(_python_speed(), flush=True)
    if a.only in (None, "first"):
        print(_load(), flush=True)
        out["first"] = first_frame(a.repeat, a.accel)
        what = "" if a.accel == "auto" else f" (accel {a.accel})"
        print(f"first frame{what}: {out['first']['first_frame_s']:.2f} s (compile "
              f"{out['first']['first_frame_compile_s']:.2f} s, CPU "
              f"{out['first']['first_frame_cpu_s']:.2f} s), runs {out['first']['runs']}; "
              f"{_load()}", flush=True)
    if a.only in (None, "phases"):
        out["phases"] = ph = phases(a.repeat)
        print(f"first frame by phase (MIS, 256², 64 spp; medians of {a.repeat} fresh processes, "
              f"wall / CPU s):", flush=True)
        for name in PHASE_NAMES + ("total",):
            print(f"  {name:12s} {ph[name][0]:6.2f} {ph[name][1]:6.2f}")
        g = ph["xla_log"]
        print(f"  XLA's log: HLO passes {g['hlo_passes']:.2f} s (one thread), then "
              f"{g['modules']:.0f} kernel modules, MLIR {g['mlir_cpu']:.2f} + LLVM "
              f"{g['llvm_cpu']:.2f} CPU-s; {_load()}", flush=True)
    if a.only in (None, "second"):
        out["second"] = second_run(a.repeat)
        s = out["second"]
        print(f"second jaxrt run: {s['second_run_wall_s']:.2f} s wall (compile "
              f"{s['second_run_compile_s']:.2f} s, CPU {s['second_run_cpu_s']:.2f} s; first run "
              f"{s['first_run_wall_s']:.2f} s), "
              f"walls {s['walls']}; {_load()}", flush=True)
    if a.only in (None, "compile"):
        out["compile"] = compile_times(a.repeat)
        print("| estimator | trace | lower | XLA | total (wall) | total CPU | "
              "program cache hit (wall / CPU) |")
        for name, c in out["compile"].items():
            print(f"| {name} | {c['trace']:.2f} | {c['lower']:.2f} | {c['xla']:.2f} | "
                  f"{c['total']:.2f} | {c['total_cpu']:.2f} | {c['cached']:.2f} / "
                  f"{c['cached_cpu']:.2f} |")
        print(_load(), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
