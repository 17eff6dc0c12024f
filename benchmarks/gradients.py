"""Gradients and batches: peak memory vs spp, gradient-pass cost, vmap throughput.

    python benchmarks/gradients.py memory     # fresh processes, ~3 min on the 2-core machine
    python benchmarks/gradients.py cost       # one process, interleaved rounds, ~2 min
    python benchmarks/gradients.py batch      # vmap over 8 albedo sets vs a loop of render
    python benchmarks/gradients.py zscores    # z of every analytic derivative check, ~2 min

memory: peak resident set (``ru_maxrss``) of a fresh process that computes the gradient of
an L2 loss w.r.t. every :func:`jaxrt.rendering.differentiable.scene_params` of the 64² Cornell box
(the loss's cotangent from a 4-spp image), (a) by :func:`jaxrt.image_vjp` in its default
passes (render's size: all ≤ 256 spp in one pass at 64²),
(b) by one ``jax.vjp`` of :func:`jaxrt.estimate_image` (the whole sample loop taped), at
16 … 256 spp. A process that only renders the image (``spp`` samples) sets the baseline.

zscores: the table of z = (estimate − reference) / standard error of every derivative check
against a closed form or a float64 quadrature in ``tests/rendering/test_differentiable.py`` (the
same functions, seeds and sample counts the tests use), parameter × estimator.

cost: one derivative pass (:func:`jaxrt.rendering.differentiable._vjp_pass`) against one primal pass
of the same samples (the program ``render`` runs, with its compiler options), Cornell box, MIS,
64² at 4 spp and 256² at 1 spp (image_vjp's default pass there); both compiled first, then
timed alternately (A B B A …) for 10 rounds, wall and process CPU time per round; ratios per
round (median and range), the machine's load before and after.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxrt
from jaxrt.core.xla import compiler_options
from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.differentiable import (
    _image_sums,
    _vjp_pass,
    estimate_image,
    image_vjp,
    scene_params,
    with_params,
)
from jaxrt.scene import builtin as scenes


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(mode: str, spp: int) -> None:
    scene = scenes.cornell_box(64, 64)
    target = jnp.zeros((64, 64, 3))
    theta = scene_params(scene)
    t0 = time.perf_counter()
    if mode == "image":
        np.asarray(estimate_image(scene, spp=spp))
    elif mode == "passes":
        c = 2 * (estimate_image(scene, spp=4) - target) / target.size
        g = image_vjp(scene, c, spp=spp, seed=1)  # default passes (render's size)
        np.asarray(g["materials.kd"])
    else:
        _, vjp = jax.vjp(lambda t: estimate_image(with_params(scene, t), spp=spp, seed=1), theta)
        c = 2 * (estimate_image(scene, spp=4) - target) / target.size
        np.asarray(vjp(c)[0]["materials.kd"])
    print(json.dumps({"mode": mode, "spp": spp, "maxrss_mb": _maxrss_mb(),
                      "seconds": time.perf_counter() - t0}))


def memory() -> None:
    print("| spp | image only (MB) | image_vjp, default passes (MB) | one jax.vjp (MB) |")
    print("|---:|---:|---:|---:|")
    for spp in (16, 64, 256):
        row = []
        for mode in ("image", "passes", "whole"):
            out = subprocess.run([sys.executable, __file__, "child", mode, str(spp)],
                                 capture_output=True, text=True, check=True)
            row.append(json.loads(out.stdout.strip().splitlines()[-1])["maxrss_mb"])
        print(f"| {spp} | {row[0]:.0f} | {row[1]:.0f} | {row[2]:.0f} |", flush=True)


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def cost(rounds: int = 10) -> None:
    """Primal pass vs gradient pass of the same samples, in one process, interleaved."""
    print(_uptime())
    for size, count in ((64, 4), (256, 1)):
        _cost(size, count, rounds)
    print(_uptime())


def _cost(size: int, count: int, rounds: int) -> None:
    est = make_estimator("mis")
    scene = prepare_scene(scenes.cornell_box(size, size), est)
    theta = scene_params(scene)
    static = dict(est=est, sampler="independent", spp_total=count, count=count,
                  tile_size=256, batch_size=64)
    c = jnp.ones((size, size, 3), jnp.float32)
    seed, start = jnp.uint32(0), jnp.int32(0)
    # the primal as render compiles it (its compiler options: 512-bit vectors)
    primal = jax.jit(lambda s: _image_sums(s, seed, start, **static),
                     compiler_options=compiler_options())
    t0 = time.perf_counter()
    primal = primal.lower(scene).compile()
    t_cp = time.perf_counter() - t0
    t0 = time.perf_counter()
    grad = _vjp_pass.program().lower(scene, theta, c, seed, start, **static).compile()
    t_cg = time.perf_counter() - t0
    runs = {"primal": lambda: primal(scene),
            "gradient": lambda: grad(scene, theta, c, seed, start)}
    for f in runs.values():
        jax.block_until_ready(f())
    wall = {k: [] for k in runs}
    cpu = {k: [] for k in runs}
    for r in range(rounds):
        for k in (("primal", "gradient") if r % 2 == 0 else ("gradient", "primal")):
            w0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(runs[k]())
            wall[k].append(time.perf_counter() - w0)
            cpu[k].append(time.process_time() - c0)
    rw = np.array(wall["gradient"]) / np.array(wall["primal"])
    rc = np.array(cpu["gradient"]) / np.array(cpu["primal"])
    samples = size * size * count
    print(f"{size}² Cornell MIS, {count} spp per pass, {len(theta)} parameter arrays: "
          f"primal {min(wall['primal']) * 1e3:.0f} ms best "
          f"({samples / min(wall['primal']) / 1e6:.2f} Msamples/s), gradient "
          f"{min(wall['gradient']) * 1e3:.0f} ms best; gradient / primal per round: wall "
          f"median {np.median(rw):.2f}× [{rw.min():.2f}–{rw.max():.2f}], CPU-seconds median "
          f"{np.median(rc):.2f}× [{rc.min():.2f}–{rc.max():.2f}]; compile {t_cp:.1f} s / "
          f"{t_cg:.1f} s", flush=True)


def zscores() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import test_differentiable as td

    from jaxrt.integrators.config import ESTIMATORS

    cols = {e: {} for e in ESTIMATORS}
    t0 = time.perf_counter()
    for e in ESTIMATORS:
        checks = td.emission_checks(e) + td.light_checks(e) + td.env_map_checks(e)
        checks += td.phong_checks(e)
        if e in ("bsdf", "mis", "mis_one_sample"):
            for name in ("ggx", "phong"):
                checks += td.sampler_dependent_checks(name, e)
        for c in checks:
            for name, z in zip(c.params, c.z, strict=True):
                if name is not None:
                    cols[e][name] = float(z)
    rows = list(dict.fromkeys(k for e in ESTIMATORS for k in cols[e]))
    print(f"| parameter | {' | '.join(ESTIMATORS)} |")
    print("|---|" + "---:|" * len(ESTIMATORS))
    for r in rows:
        cells = [f"{cols[e][r]:+.2f}" if r in cols[e] else "—" for e in ESTIMATORS]
        print(f"| {r} | {' | '.join(cells)} |")
    zs = np.array([z for e in ESTIMATORS for z in cols[e].values()])
    print(f"\n{len(zs)} checks in {time.perf_counter() - t0:.0f} s: "
          f"max |z| {np.abs(zs).max():.2f}, mean z {zs.mean():+.2f}, "
          f"rms z {np.sqrt(np.mean(zs**2)):.2f} (≈ 1 if unbiased with right standard errors), "
          f"{int(np.sum(np.abs(zs) > 2))} with |z| > 2")


def batch(size: int = 32, spp: int = 4, n: int = 8) -> None:
    scene = scenes.cornell_box(size, size)
    kd = scene_params(scene)["materials.kd"]
    kds = kd[None] * jnp.linspace(0.5, 1.0, n)[:, None, None]
    f = jax.jit(jax.vmap(lambda k: estimate_image(with_params(scene, {"materials.kd": k}),
                                                  spp=spp)))
    t0 = time.perf_counter()
    f(kds).block_until_ready()
    t_compile = time.perf_counter() - t0
    # interleaved rounds (batch, loop, loop, batch, …), wall and process CPU seconds each
    rounds = {"vmap": [], "loop": [], "loop_render": []}
    for r in range(rounds_ := 6):
        for name in ("vmap", "loop") if r % 2 == 0 else ("loop", "vmap"):
            w0, c0 = time.perf_counter(), time.process_time()
            if name == "vmap":
                f(kds).block_until_ready()
            else:
                render_only = 0.0
                for k in kds:
                    res = jaxrt.render(with_params(scene, {"materials.kd": k}), spp=spp,
                                       progress=False)
                    render_only += res.timings["render"]
                rounds["loop_render"].append(render_only)
            rounds[name].append((time.perf_counter() - w0, time.process_time() - c0))
    med = lambda xs, i: float(np.median([x[i] for x in xs]))  # noqa: E731
    vw, vc, lw, lc = (med(rounds["vmap"], 0), med(rounds["vmap"], 1), med(rounds["loop"], 0),
                      med(rounds["loop"], 1))
    lr = float(np.median(rounds["loop_render"]))
    print(f"{n} albedo sets, {size}², {spp} spp, {rounds_} interleaved rounds (medians), load "
          f"{os.getloadavg()[0]:.1f}: vmap {vw / n * 1e3:.1f} ms per image ({vc / n * 1e3:.1f} "
          f"CPU-ms; compile {t_compile:.1f} s, once); loop of render {lw / n * 1e3:.0f} ms per "
          f"image ({lc / n * 1e3:.0f} CPU-ms; {lr / n * 1e3:.1f} ms of it rendering): "
          f"{lw / vw:.0f}× per wall s, {lc / vc:.0f}× per CPU-s, {lr / vw:.1f}× against the "
          f"loop's rendering alone")


if __name__ == "__main__":
    if sys.argv[1] == "child":
        child(sys.argv[2], int(sys.argv[3]))
    else:
        {"memory": memory, "cost": cost, "batch": batch, "zscores": zscores}[sys.argv[1]]()
