"""Gradients and batches: peak memory vs spp, gradient-pass cost, vmap throughput.

    python benchmarks/gradients.py memory     # fresh processes, ~3 min on the 2-core machine
    python benchmarks/gradients.py cost       # one process, interleaved rounds, ~2 min
    python benchmarks/gradients.py batch      # vmap over 8 albedo sets vs a loop of render
    python benchmarks/gradients.py zscores    # z of every analytic derivative check, ~2 min

memory: peak resident set (``ru_maxrss``) of a fresh process that computes the gradient of
an L2 loss w.r.t. every :func:`jaxrt.differentiable.scene_params` of the 64² Cornell box
(the loss's cotangent from a 4-spp image), (a) by :func:`jaxrt.image_vjp` in passes of 4 spp,
(b) by one ``jax.vjp`` of :func:`jaxrt.estimate_image` (the whole sample loop taped), at
16 … 256 spp. A process that only renders the image (``spp`` samples) sets the baseline.

zscores: the table of z = (estimate − reference) / standard error of every derivative check
against a closed form or a float64 quadrature in ``tests/test_differentiable.py`` (the same
functions, seeds and sample counts the tests use), parameter × estimator.

cost: one derivative pass (``jax.vjp`` of a 4-spp pass, :func:`jaxrt.differentiable._vjp_pass`)
against one primal pass of the same samples (the same program ``render`` runs), 64² Cornell
box, MIS; both compiled first, then timed alternately (A B B A …), best of 6.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxrt
from jaxrt import scenes
from jaxrt.differentiable import (
    _image_sums,
    _vjp_pass,
    estimate_image,
    image_vjp,
    scene_params,
    with_params,
)
from jaxrt.estimators import make_estimator, prepare_scene


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
        g = image_vjp(scene, c, spp=spp, spp_per_pass=4, seed=1)
        np.asarray(g["materials.kd"])
    else:
        _, vjp = jax.vjp(lambda t: estimate_image(with_params(scene, t), spp=spp, seed=1), theta)
        c = 2 * (estimate_image(scene, spp=4) - target) / target.size
        np.asarray(vjp(c)[0]["materials.kd"])
    print(json.dumps({"mode": mode, "spp": spp, "maxrss_mb": _maxrss_mb(),
                      "seconds": time.perf_counter() - t0}))


def memory() -> None:
    print("| spp | image only (MB) | image_vjp, 4 spp/pass (MB) | one jax.vjp (MB) |")
    print("|---:|---:|---:|---:|")
    for spp in (16, 64, 256):
        row = []
        for mode in ("image", "passes", "whole"):
            out = subprocess.run([sys.executable, __file__, "child", mode, str(spp)],
                                 capture_output=True, text=True, check=True)
            row.append(json.loads(out.stdout.strip().splitlines()[-1])["maxrss_mb"])
        print(f"| {spp} | {row[0]:.0f} | {row[1]:.0f} | {row[2]:.0f} |", flush=True)


def cost(size: int = 64, count: int = 4, rounds: int = 6) -> None:
    est = make_estimator("mis")
    scene = prepare_scene(scenes.cornell_box(size, size), est)
    theta = scene_params(scene)
    static = dict(est=est, sampler="independent", spp_total=count, count=count, tile_size=256,
                  batch_size=64)
    c = jnp.ones((size, size, 3), jnp.float32)
    seed, start = jnp.uint32(0), jnp.int32(0)
    primal = jax.jit(lambda s: _image_sums(s, seed, start, **static))
    t0 = time.perf_counter()
    primal(scene).block_until_ready()
    t_cp = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(_vjp_pass(scene, theta, c, seed, start, **static))
    t_cg = time.perf_counter() - t0
    tp, tg = [], []
    for r in range(rounds):
        for which in ((0, 1) if r % 2 == 0 else (1, 0)):
            t0 = time.perf_counter()
            if which == 0:
                primal(scene).block_until_ready()
                tp.append(time.perf_counter() - t0)
            else:
                jax.block_until_ready(_vjp_pass(scene, theta, c, seed, start, **static))
                tg.append(time.perf_counter() - t0)
    samples = size * size * count
    print(f"{size}² Cornell MIS, {count} spp per pass, {len(theta)} parameter arrays: "
          f"primal pass {min(tp) * 1e3:.0f} ms ({samples / min(tp) / 1e6:.2f} Msamples/s), "
          f"gradient pass {min(tg) * 1e3:.0f} ms: ratio {min(tg) / min(tp):.2f}× "
          f"(median {np.median(tg) / np.median(tp):.2f}×); compile {t_cp:.1f} s / {t_cg:.1f} s")


def zscores() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import test_differentiable as td

    from jaxrt.estimators import ESTIMATORS

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
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        f(kds).block_until_ready()
        best = min(best, time.perf_counter() - t0)
    t0 = time.perf_counter()
    render_only = 0.0
    for k in kds:
        r = jaxrt.render(with_params(scene, {"materials.kd": k}), spp=spp, progress=False)
        render_only += r.timings["render"]
    loop = time.perf_counter() - t0
    print(f"{n} albedo sets, {size}², {spp} spp: vmap {best / n * 1e3:.1f} ms per image "
          f"(compile {t_compile:.1f} s, once); loop of render {loop / n * 1e3:.0f} ms per image "
          f"(each call compiles its pass; {render_only / n * 1e3:.1f} ms of it rendering): "
          f"{loop / best:.0f}× / {render_only / best:.2f}×")


if __name__ == "__main__":
    if sys.argv[1] == "child":
        child(sys.argv[2], int(sys.argv[3]))
    else:
        {"memory": memory, "cost": cost, "batch": batch, "zscores": zscores}[sys.argv[1]]()
