"""Convergence study: error vs samples and vs time of every estimator on the built-in scenes.

Run::

    python benchmarks/convergence.py --quick          # 2 scenes, 4 estimators, 64×64: minutes
    python benchmarks/convergence.py                  # all scenes × all estimators
    python benchmarks/convergence.py --mitsuba        # also the jaxrt-vs-Mitsuba section

For each (scene, estimator) the image is rendered *progressively* (passes of ``pass_spp``
samples, one compiled program per (estimator, scene structure)) and its error is read at the
spp levels (1, 4, 16, 64 by default) against a cached high-spp MIS reference
(``benchmarks/.cache/*.exr``, with the reference's own per-pixel standard error as an extra
channel). Reported per level:

- ``rmse`` = √mean((I − R)²) over pixels and channels (raw, reference noise included);
- ``mse`` = mean((I − R)²) − mean(σ_R²): the reference's own variance removed, so the figure
  estimates the error against the true image (``E[(I−R)²] = MSE(I) + Var(R)`` for independent
  I and R);
- ``rel_mse`` = mean((I − R)² / (R² + ε)), ε = (10⁻² · mean R)² (keeps black pixels finite);
- ``seconds``: render wall time up to that level, compile excluded (reported apart);
- ``efficiency`` = 1 / (mse · seconds) (higher is better; constant for an unbiased estimator
  with fixed cost per sample).

The progressive levels of one run share their samples (the 64-spp image contains the 16-spp
one), which is how a progressive renderer behaves. ``spp`` only changes the *stratified*
sampler's stream, so "independent" and "sobol" levels equal separate renders bit for bit; for
"stratified" the strata are laid out for the largest level.

Plots (matplotlib Agg) go to ``benchmarks/plots/``, the markdown tables and a description of
the machine (CPU, cores, jax version, load average at the start) to
``benchmarks/.cache/results.md`` (not tracked), between ``<!-- convergence:begin/end -->``
markers (the rest of the file is kept); the current tables belong in ``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE_DIR = HERE / ".cache"
PLOT_DIR = HERE / "plots"
RESULTS = HERE / ".cache" / "results.md"
VS_MITSUBA_JSON = CACHE_DIR / "vs_mitsuba.json"

QUICK_SCENES = ("cornell_box", "cornell_box_small")  # one scene structure: compiles are shared
QUICK_ESTIMATORS = ("cosine_hemisphere", "bsdf", "light_solid_angle", "mis")
LEVELS = (1, 4, 16, 64)


# ---------------------------------------------------------------------------------------------
# machine and progressive rendering
# ---------------------------------------------------------------------------------------------

def machine_description() -> dict:
    """CPU model, cores, jax/numpy versions, load average and UTC time, for the results file."""
    import jax

    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count(), "jax": jax.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "devices": [str(d) for d in jax.devices()],
            "loadavg": os.getloadavg(),
            "utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}


def _render_pass(scene, estimator: str, sampler: str, seed: int, tile_size: int,
                 batch_size: int, devices: int, spp_total: int, **params):
    """jaxrt's :class:`~jaxrt.rendering.passes.RenderPass` for ``scene`` (what ``render`` runs), and
    a function from its carried sums after ``n`` samples to ``(image, stderr)``, (H, W, 3)
    float64."""
    import jax

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.rendering.driver import _mean_and_error
    from jaxrt.rendering.passes import LANES, RenderPass, Sums

    est = make_estimator(estimator, **params)
    scene = prepare_scene(scene, est)
    run = RenderPass(scene, seed, jax.devices()[:devices], LANES * math.ceil(tile_size / LANES),
                     est=est, sampler=sampler, spp_total=spp_total, batch_size=batch_size)
    h, w = scene.height, scene.width

    def image(sums, n: int):
        s1, s2, _ = Sums(*(a[: h * w] for a in run.host(sums))).totals()
        mean, err = _mean_and_error(s1, s2, n)
        return mean.reshape(h, w, 3), err.reshape(h, w, 3)

    return run, image


def progressive(scene, estimator: str = "mis", levels=LEVELS, sampler: str = "independent",
                seed: int = 0, pass_spp: int = 1, tile_size: int = 256, batch_size: int = 64,
                devices: int = 1, **params) -> tuple[list[dict], float]:
    """Render ``scene`` progressively and snapshot the image at each spp in ``levels``.

    Uses the same machinery as :func:`jaxrt.rendering.driver.render` (its ``RenderPass``: same
    tiles, same sample indices, the sums carried from pass to pass, so the image at ``n`` spp is
    bit-identical to ``render(..., spp=n)`` for the independent and Sobol samplers) but
    compiles one pass of ``pass_spp`` samples and reuses it for every level. Returns
    ``(rows, compile_seconds)``; each row has ``spp``, ``seconds`` (cumulative render time,
    compile excluded), ``image`` and ``stderr`` ((H, W, 3) float64).
    """
    levels = sorted(int(n) for n in levels)
    if any(n % pass_spp for n in levels):
        raise ValueError(f"every level must be a multiple of pass_spp={pass_spp}: {levels}")
    # spp only shapes the stratified stream: fixing it elsewhere lets levels share a program
    run, image = _render_pass(scene, estimator, sampler, seed, tile_size, batch_size, devices,
                              levels[-1] if sampler == "stratified" else 1, **params)
    t_compile = run.compile(pass_spp)
    h, w = scene.height, scene.width
    sums = run.zeros()
    rows, done, elapsed = [], 0, 0.0
    for level in levels:
        t0 = time.perf_counter()
        while done < level:
            sums = run(sums, done, pass_spp)
            done += pass_spp
        elapsed += time.perf_counter() - t0
        mean, err = image(sums, done)
        rows.append({"spp": level, "seconds": elapsed, "image": mean, "stderr": err,
                     "samples_per_s": level * h * w / max(elapsed, 1e-12)})
    return rows, t_compile


def reference(name: str, width: int, height: int, spp: int, refresh: bool = False):
    """Cached MIS reference of built-in scene ``name``: ``(image, stderr)`` float64 arrays.

    Rendered with the independent sampler, seed 10⁶ (disjoint from the study's seeds), and
    stored as ``benchmarks/.cache/jaxrt_<name>_<W>x<H>_<spp>spp.exr`` with the per-pixel
    standard error in the extra layer ``stderr``.
    """
    from jaxrt.scene.builtin import by_name
    from jaxrt.scene.images import read_exr, write_exr

    path = CACHE_DIR / f"jaxrt_{name}_{width}x{height}_{spp}spp.exr"
    if path.exists() and not refresh:
        img, extra = read_exr(path)
        return img.astype(np.float64), extra["stderr"].astype(np.float64)
    rows, _ = progressive(by_name(name, width=width, height=height), "mis", (spp,),
                          seed=1_000_000, pass_spp=1)
    img, err = rows[-1]["image"], rows[-1]["stderr"]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, img.astype(np.float32), {"stderr": err.astype(np.float32)})
    return img, err


def errors(image, ref, ref_stderr) -> dict:
    """rmse (raw), mse (reference variance removed) and rel_mse of ``image`` against ``ref``."""
    d2 = (np.asarray(image, np.float64) - ref) ** 2
    eps = (1e-2 * float(np.mean(ref))) ** 2
    return {"rmse": float(np.sqrt(d2.mean())),
            "mse": max(float(d2.mean() - np.mean(ref_stderr ** 2)), 1e-30),
            "rel_mse": float(np.mean(d2 / (ref * ref + eps)))}


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------

def study(scenes, estimators, width: int, height: int, levels=LEVELS, ref_spp: int = 1024,
          sampler: str = "independent", log=print) -> list[dict]:
    """Rows (scene, estimator, spp, seconds, rmse, mse, rel_mse, efficiency, compile_s)."""
    from jaxrt.scene.builtin import by_name

    out = []
    for name in scenes:
        scene = by_name(name, width=width, height=height)
        # estimators first, so the compile time is charged to them, not to the reference
        runs = [progressive(scene, est, levels, sampler=sampler, seed=1 + k)
                for k, est in enumerate(estimators)]
        t0 = time.perf_counter()
        ref, ref_err = reference(name, width, height, ref_spp)
        log(f"[{name}] reference {ref_spp} spp ready in {time.perf_counter() - t0:.1f} s")
        for est, (rows, t_compile) in zip(estimators, runs, strict=True):
            for r in rows:
                e = errors(r["image"], ref, ref_err)
                out.append({"scene": name, "estimator": est, "sampler": sampler,
                            "spp": r["spp"], "seconds": r["seconds"],
                            "samples_per_s": r["samples_per_s"], "compile_s": t_compile,
                            **e, "efficiency": 1.0 / (e["mse"] * max(r["seconds"], 1e-9)),
                            "rel_efficiency": 1.0 / (e["rel_mse"] * max(r["seconds"], 1e-9))})
            last = out[-1]
            log(f"[{name}] {est:18s} compile {t_compile:5.1f} s, {last['spp']} spp in "
                f"{last['seconds']:.2f} s, rmse {last['rmse']:.4g}, rel_mse {last['rel_mse']:.3g}")
    return out


def plot(rows: list[dict], path_prefix: Path) -> list[Path]:
    """One PNG per scene: log-log relMSE vs spp, relMSE vs time, 1/(relMSE·s) vs spp.

    relMSE rather than MSE: on scenes with a visible bright light the MSE is dominated by the
    light's edge pixels (pixel-jitter noise of the emitted term, the same for every estimator).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (NullFormatter below)

    paths = []
    for name in dict.fromkeys(r["scene"] for r in rows):
        fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), dpi=72)
        for est in dict.fromkeys(r["estimator"] for r in rows if r["scene"] == name):
            rs = [r for r in rows if r["scene"] == name and r["estimator"] == est]
            spp = [r["spp"] for r in rs]
            axes[0].loglog(spp, [r["rel_mse"] for r in rs], "o-", label=est)
            axes[1].loglog([r["seconds"] for r in rs], [r["rel_mse"] for r in rs], "o-",
                           label=est)
            axes[2].loglog(spp, [r["rel_efficiency"] for r in rs], "o-", label=est)
        axes[0].set(xlabel="spp", ylabel="relMSE", title=f"{name}: error vs spp")
        axes[1].set(xlabel="render seconds (no compile)", ylabel="relMSE",
                    title="error vs time")
        axes[2].set(xlabel="spp", ylabel="1 / (relMSE · s)", title="efficiency")
        axes[0].legend(fontsize=7)
        axes[1].xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())  # no overlaps
        fig.tight_layout()
        path = Path(f"{path_prefix}_{name}.png")
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path)
        plt.close(fig)
        paths.append(path)
    return paths


def markdown(rows: list[dict], machine: dict, width: int, height: int, ref_spp: int,
             plots: list[Path]) -> str:
    """The convergence section of the results file (:data:`RESULTS`)."""
    la = ", ".join(f"{x:.2f}" for x in machine["loadavg"])
    lines = [
        "## Convergence study (`benchmarks/convergence.py`)", "",
        f"Machine: {machine['cpu']}, {machine['cores']} cores, jax {machine['jax']}, "
        f"numpy {machine['numpy']}, Python {machine['python']}; run started "
        f"{machine['utc']} UTC with load average {la} (shared machine: absolute times are "
        "several times an idle machine's; compare estimators within a scene).", "",
        f"{width}×{height}, sampler `{rows[0]['sampler']}`, reference: MIS at {ref_spp} spp "
        "(its own variance subtracted from the MSE). Seconds exclude compilation "
        "(`compile s`, once per estimator and scene structure).", "",
        "`compile s` 0.0 means the program was already compiled (same estimator and scene "
        "structure: `cornell_box_small` is `cornell_box`'s structure with other numbers).", "",
        "| scene | estimator | spp | seconds | Msamples/s | RMSE | MSE | relMSE | 1/(MSE·s) "
        "| 1/(relMSE·s) | compile s |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['estimator']} | {r['spp']} | {r['seconds']:.3f} | "
                     f"{r['samples_per_s'] / 1e6:.3f} | {r['rmse']:.4g} | {r['mse']:.3g} | "
                     f"{r['rel_mse']:.3g} | {r['efficiency']:.3g} | {r['rel_efficiency']:.3g} | "
                     f"{r['compile_s']:.1f} |")
    lines += ["", "Estimators per scene at the largest spp, best first by 1/(relMSE·s):", ""]
    top = max(r["spp"] for r in rows)
    for name in dict.fromkeys(r["scene"] for r in rows):
        rs = sorted((r for r in rows if r["scene"] == name and r["spp"] == top),
                    key=lambda r: -r["rel_efficiency"])
        order = " > ".join(f"{r['estimator']} ({r['rel_efficiency']:.3g})" for r in rs)
        lines.append(f"- {name}: {order}")
    lines += [""] + [f"![{p.stem}](plots/{p.name})" for p in plots] + [""]
    return "\n".join(lines)


def write_section(key: str, text: str, path: Path = RESULTS) -> None:
    """Replace (or append) the block between ``<!-- key:begin -->`` and ``<!-- key:end -->``."""
    begin, end = f"<!-- {key}:begin -->", f"<!-- {key}:end -->"
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.exists() else "# jaxrt benchmark results\n"
    block = f"{begin}\n{text}\n{end}"
    if begin in old and end in old:
        head, rest = old.split(begin, 1)
        new = head + block + rest.split(end, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(new)


# ---------------------------------------------------------------------------------------------
# jaxrt vs Mitsuba 3 (same Cornell box, MIS with one light and one BSDF sample)
# ---------------------------------------------------------------------------------------------

def _timed(fn, *args, repeats: int = 3) -> tuple[float, float]:
    """(compile seconds, median run seconds) of a jitted ``fn(*args)``."""
    import jax

    t0 = time.perf_counter()
    exe = jax.jit(fn).lower(*args).compile()
    t_compile = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(exe(*args))
        times.append(time.perf_counter() - t0)
    return t_compile, float(np.median(times))


def profile_jaxrt(size: int = 256, repeats: int = 3) -> dict:
    """Where one MIS camera sample's time goes, each stage vmapped over ``size²`` pixels.

    Stages (each a separate jitted program over the same N = size² rays/points): camera ray
    generation; the first hit (``scene.intersect``, brute force over the 32 triangles); a
    shadow ray (``scene.unoccluded``) from each hit point to the light's centre; light
    sampling (``lights.sample_li``); the whole camera sample (``camera_sample``: ray, hit,
    light sample + shadow ray, BSDF sample + second ray, MIS weights). Returns ns per ray per
    stage and each stage's share of the whole.
    """
    import jax
    import jax.numpy as jnp

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.integrators.techniques import camera_sample
    from jaxrt.scene import lights as lt
    from jaxrt.scene.builtin import cornell_box
    from jaxrt.scene.camera import generate_ray
    from jaxrt.scene.queries import intersect, unoccluded

    est = make_estimator("mis")
    scene = cornell_box(size, size)
    scene = prepare_scene(scene, est)
    n = size * size
    pix = jnp.arange(n, dtype=jnp.int32)
    xy = jnp.stack([pix % size, pix // size], -1)
    u2 = jax.random.uniform(jax.random.key(0), (n, 2))
    u3 = jax.random.uniform(jax.random.key(1), (n, 3))
    inf = jnp.float32(jnp.inf)

    def rays(cam, xy, u):
        return jax.vmap(generate_ray, (None, 0, 0))(cam, xy, u)

    o, d = jax.jit(rays)(scene.camera, xy, u2)

    def hits(sc, o, d):
        h = jax.vmap(intersect, (None, 0, 0, None))(sc, o, d, inf)
        return h.p, h.ng, h.t

    p, ng, _ = jax.jit(hits)(scene, o, d)
    p = p - 1e-4 * d  # pull hit points towards the camera so shadow rays start outside
    light_c = jnp.asarray(_light_centre(), jnp.float32)

    def shadows(sc, p):
        dirs = light_c - p
        dist = jnp.linalg.norm(dirs, axis=-1)
        return jax.vmap(unoccluded, (None, 0, 0, 0))(sc, p, dirs / dist[:, None], dist * 0.999)

    def light_samples(lights, p, ng, u):
        ls = jax.vmap(lt.sample_li, (None, 0, 0, 0))(lights, p, ng, u)
        return ls.wi, ls.pdf, ls.li

    def whole(sc, pix):
        return jax.vmap(lambda q: camera_sample(sc, est, q, jnp.uint32(0), jnp.uint32(0),
                                                "independent", 1))(pix)

    stages = {"camera rays": (rays, scene.camera, xy, u2),
              "closest hit (camera ray)": (hits, scene, o, d),
              "any hit (shadow ray)": (shadows, scene, p),
              "light sampling": (light_samples, scene.lights, p, ng, u3),
              "whole MIS camera sample": (whole, scene, pix)}
    out = {"rays": n}
    for name, (fn, *args) in stages.items():
        tc, tr = _timed(fn, *args, repeats=repeats)
        out[name] = {"compile_s": tc, "seconds": tr, "ns_per_ray": tr / n * 1e9}
    total = out["whole MIS camera sample"]["seconds"]
    for name in stages:
        out[name]["share_of_whole"] = out[name]["seconds"] / total
    return out


def _light_centre():
    """A point 1 mm below the centre of the box's light quad (target of the shadow rays)."""
    from jaxrt.scene.builtin import cornell

    meshes = cornell.cornell_meshes()
    light = next(m for m in meshes if m.emission is not None)
    return light.vertices.mean(0) - np.array([0.0, 1e-3, 0.0])


def block_z(image, stderr, ref, ref_var_scale: float, block: int = 16) -> np.ndarray:
    """z-scores of block means of ``image − ref``: (H/b · W/b · 3,) float64.

    Pixels are independent, so a block mean's variance is Σσ²/n²; the reference's own
    variance is taken as ``ref_var_scale`` times the image's (same estimator, more samples).
    """
    h, w, _ = image.shape
    hb, wb = h // block, w // block
    d = (np.asarray(image, np.float64) - ref)[: hb * block, : wb * block]
    v = np.asarray(stderr, np.float64)[: hb * block, : wb * block] ** 2 * (1 + ref_var_scale)
    dm = d.reshape(hb, block, wb, block, 3).mean((1, 3))
    vm = v.reshape(hb, block, wb, block, 3).sum((1, 3)) / block**4
    ok = vm > 0  # black blocks (ceiling above the light: exactly 0 in both) have no test
    return (dm[ok] / np.sqrt(vm[ok])).ravel()


def level_renderer(scene, estimator: str, levels, sampler: str = "independent",
                   seed: int = 0, tile_size: int = 256, batch_size: int = 64, **params):
    """One render of ``n`` spp from scratch for every ``n`` in ``levels``, compiled up front.

    Returns ``(render, compile_seconds)``; ``render(n)`` runs ONE pass of ``n`` samples per
    pixel (jaxrt's :class:`~jaxrt.rendering.passes.RenderPass`, as ``render(scene, spp=n)`` runs it
    when ``n`` fits one pass) and returns ``(image, stderr)``, (H, W, 3) float64. The image equals
    :func:`progressive`'s level ``n`` bit for bit (a pass's split never changes the sums).
    This is how a Mitsuba render of ``n`` spp is timed, so the two error-vs-time tables compare
    renders with renders (a progressive run pays each level's pass on top of the earlier ones).
    """
    run, image = _render_pass(scene, estimator, sampler, seed, tile_size, batch_size, 1,
                              max(levels) if sampler == "stratified" else 1, **params)
    t_compile = sum(run.compile(int(n)) for n in sorted(set(levels)))
    return (lambda n: image(run(run.zeros(), 0, int(n)), int(n))), t_compile


def paired_level_times(renderers: dict, rounds: int = 3) -> tuple[dict, dict]:
    """Time every renderer at every spp in interleaved rounds, in this process.

    ``renderers``: name -> ``(spps, fn)`` with ``fn(i, spp)`` rendering the ``i``-th spp of
    ``spps`` and returning its image (after any warm-up the renderer needs). Each round runs
    every (renderer, spp) once, in an order reversed every other round, so a change in the
    machine's load falls on all of them alike. Returns ``(images, times)``: the image of the
    first round, and per (name, spp) the median over rounds of ``seconds`` (wall, until the
    image is on the host) and ``cpu_seconds`` (this process's CPU time over the same span).
    """
    jobs = [(name, i, spp) for name, (spps, _) in renderers.items()
            for i, spp in enumerate(spps)]
    for spps, fn in renderers.values():
        fn(0, spps[0])  # warm-up: Dr.Jit's kernels, first calls
    images, samples = {n: {} for n in renderers}, {n: {} for n in renderers}
    for r in range(rounds):
        for name, i, spp in (jobs if r % 2 == 0 else jobs[::-1]):
            c0, t0 = time.process_time(), time.perf_counter()
            image = renderers[name][1](i, spp)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            images[name].setdefault(spp, image)
            samples[name].setdefault(spp, []).append((dt, dc))
    times = {n: {spp: {"seconds": float(np.median([x[0] for x in v])),
                       "cpu_seconds": float(np.median([x[1] for x in v]))}
                 for spp, v in per.items()} for n, per in samples.items()}
    return images, times


def mitsuba_comparison(levels=(1, 2, 4, 8, 16), mitsuba_spps=(1, 2, 4, 8, 16, 32, 64),
                       ref_spp: int = 128, size: int = 256, rounds: int = 5,
                       log=print) -> dict:
    """jaxrt vs Mitsuba 3 on the 256² Cornell box, MIS with 1 light + 1 BSDF sample, one run.

    Error vs time: every row is one render of that many spp from scratch, timed in
    ``rounds`` interleaved rounds with all the other rows (:func:`paired_level_times`; wall
    and CPU seconds, medians).

    Returns a JSON-able dict (also saved to ``benchmarks/.cache/vs_mitsuba.json``):
    ``mitsuba`` (samples/s best/median, error-vs-time rows against its 4096-spp reference),
    ``jaxrt`` per sampler (independent, sobol: samples/s, compile s, error-vs-time rows
    against jaxrt's own ``ref_spp`` reference with that reference's variance removed),
    ``ratios`` (samples/s, time to equal RMSE at three targets), ``agreement`` (block
    z-scores and region means of jaxrt's reference vs Mitsuba's) and ``profile``.
    """
    sys.path.insert(0, str(HERE))
    import mitsuba_cornell as mc

    from jaxrt.scene.builtin import cornell_box

    res = {"machine": machine_description(), "size": size, "ref_spp": ref_spp,
           "rounds": rounds}
    log("mitsuba: samples/s")
    res["mitsuba"] = {k: v for k, v in mc.mitsuba_samples_per_second(
        spp=16, repeats=5, width=size, height=size).items()}
    ref_mi = mc.mitsuba_reference(4096, size, size)
    scene = cornell_box(size, size)
    renderers = {"mitsuba": (mitsuba_spps, lambda i, spp: mc.render_mitsuba(
        spp, 101 + i, size, size, "box", 1.0)[0])}
    compile_s = {}
    for sampler in ("independent", "sobol"):
        log(f"jaxrt: compile {sampler}")
        fn, compile_s[sampler] = level_renderer(scene, "mis", levels, sampler=sampler, seed=7)
        renderers[sampler] = (levels, lambda i, spp, fn=fn: fn(spp)[0])
    log(f"error vs time: {rounds} interleaved rounds")
    images, times = paired_level_times(renderers, rounds)
    res["mitsuba"]["rows"] = [
        {"spp": spp, **times["mitsuba"][spp], "rmse": mc.rmse(images["mitsuba"][spp], ref_mi)}
        for spp in mitsuba_spps]
    mean_ref = float(np.mean(ref_mi))
    for row in res["mitsuba"]["rows"]:
        row.update(rel_rmse=row["rmse"] / mean_ref,
                   efficiency=1.0 / (row["rmse"] ** 2 * row["seconds"]),
                   samples_per_second=size * size * row["spp"] / row["seconds"])
    log("jaxrt: reference")
    ref_j, ref_j_err = reference("cornell_box", size, size, ref_spp)
    ref_var = float(np.mean(ref_j_err ** 2))
    res["jaxrt"] = {}
    for sampler in ("independent", "sobol"):
        out = []
        for spp in levels:
            image, t = images[sampler][spp], times[sampler][spp]
            d2 = float(np.mean((image - ref_j) ** 2))
            mse = max(d2 - ref_var, 1e-30)
            out.append({"spp": spp, **t, "rmse_raw": d2 ** 0.5,
                        "rmse": mse ** 0.5, "rmse_vs_mitsuba_ref":
                        float(np.sqrt(np.mean((image - ref_mi) ** 2))),
                        "samples_per_s": spp * size * size / t["seconds"],
                        "efficiency": 1.0 / (mse * max(t["seconds"], 1e-9))})
        res["jaxrt"][sampler] = {"compile_s": compile_s[sampler], "rows": out,
                                 "samples_per_s": out[-1]["samples_per_s"]}
    mi_sps = res["mitsuba"]["samples_per_second"]
    mi_med = res["mitsuba"]["median_samples_per_second"]
    ratios = {"samples_per_s_vs_best": res["jaxrt"]["independent"]["samples_per_s"] / mi_sps,
              "samples_per_s_vs_median":
                  res["jaxrt"]["independent"]["samples_per_s"] / mi_med, "time_to_rmse": {}}
    on_cpu = lambda rows: [dict(r, seconds=r["cpu_seconds"]) for r in rows]  # noqa: E731
    for target in (0.1, 0.05, 0.03):
        t_mi = mc.time_to_rmse(res["mitsuba"]["rows"], target)
        c_mi = mc.time_to_rmse(on_cpu(res["mitsuba"]["rows"]), target)
        entry = {"mitsuba_s": t_mi, "mitsuba_cpu_s": c_mi}
        for sampler in res["jaxrt"]:
            t_j = mc.time_to_rmse(res["jaxrt"][sampler]["rows"], target)
            c_j = mc.time_to_rmse(on_cpu(res["jaxrt"][sampler]["rows"]), target)
            entry[f"jaxrt_{sampler}_s"] = t_j
            entry[f"ratio_{sampler}"] = t_j / t_mi
            entry[f"jaxrt_{sampler}_cpu_s"] = c_j
            entry[f"ratio_{sampler}_cpu"] = c_j / c_mi
        ratios["time_to_rmse"][str(target)] = entry
    res["ratios"] = ratios
    z = block_z(ref_j, ref_j_err, ref_mi, ref_spp / 4096)
    masks = mc.cornell_region_masks(size, size)
    rm_j, rm_m = mc.region_means(ref_j, masks), mc.region_means(ref_mi, masks)
    region = {}
    for name, mask in masks.items():
        se = np.sqrt((ref_j_err[mask] ** 2).sum(0)) / max(int(mask.sum()), 1)
        # float32 rounding floor: the light's pixels are constant, their σ is ~0
        se = np.maximum(se, 1e-6 * np.abs(np.nan_to_num(rm_m[name])))
        region[name] = {"jaxrt": rm_j[name].tolist(), "mitsuba": rm_m[name].tolist(),
                        "z": np.where(se > 0, (rm_j[name] - rm_m[name]) /
                                      np.where(se > 0, se, 1), 0).tolist()}
    res["agreement"] = {"blocks": int(z.size), "max_abs_z": float(np.abs(z).max()),
                        "frac_abs_z_gt_3": float(np.mean(np.abs(z) > 3)),
                        "mean_z": float(z.mean()), "std_z": float(z.std()),
                        "max_abs_z_light_2pct_brighter":
                            float(np.abs(block_z(1.02 * ref_j, ref_j_err, ref_mi,
                                                 ref_spp / 4096)).max()),
                        "regions": region}
    log("jaxrt: profile")
    res["profile"] = profile_jaxrt(size)
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    VS_MITSUBA_JSON.write_text(json.dumps(res, indent=1, default=float))
    return res


def mitsuba_markdown(res: dict) -> str:
    """The jaxrt-vs-Mitsuba section of the results file from :func:`mitsuba_comparison`'s dict."""
    m, j, r = res["mitsuba"], res["jaxrt"], res["ratios"]
    la = ", ".join(f"{x:.2f}" for x in res["machine"]["loadavg"])
    lines = [
        "## jaxrt vs Mitsuba 3 (`benchmarks/test_bench_vs_mitsuba.py`, "
        "`convergence.py --mitsuba-only`)", "",
        f"One run, {res['machine']['utc']} UTC, load average at start {la}; Cornell box "
        f"{res['size']}², MIS with 1 light + 1 BSDF sample per camera sample in both, box "
        f"filter. Mitsuba {m['mitsuba_version']} `{m['variant']}`.", "",
        "| | Msamples/s (best) | median | compile / warm-up s |", "|---|---:|---:|---:|",
        f"| Mitsuba | {m['samples_per_second'] / 1e6:.3f} | "
        f"{m['median_samples_per_second'] / 1e6:.3f} | {m['warmup_seconds']:.2f} |"]
    for s, v in j.items():
        lines.append(f"| jaxrt ({s}) | {v['samples_per_s'] / 1e6:.3f} | – | "
                     f"{v['compile_s']:.1f} |")
    lines += ["", f"**Samples/s ratio jaxrt / Mitsuba: {r['samples_per_s_vs_best']:.3f} "
              f"(vs Mitsuba's best), {r['samples_per_s_vs_median']:.3f} (vs its median)**; "
              "target ≥ 0.6: " + ("met" if r["samples_per_s_vs_median"] >= 0.6
                                  else "**not met**") + ".", "",
              "Error vs time (each against its own converged reference: Mitsuba 4096 spp; "
              f"jaxrt {res['ref_spp']} spp with that reference's variance removed):", "",
              f"Each row is one render of that many spp from scratch, median of "
              f"{res.get('rounds', 1)} interleaved rounds (wall and process CPU seconds):", "",
              "| renderer | spp | seconds | CPU s | RMSE | 1/(MSE·s) |",
              "|---|---:|---:|---:|---:|---:|"]
    for s, rows in [("Mitsuba", m["rows"])] + [(f"jaxrt {s}", v["rows"]) for s, v in j.items()]:
        for row in rows:
            lines.append(f"| {s} | {row['spp']} | {row['seconds']:.3f} | "
                         f"{row.get('cpu_seconds', float('nan')):.3f} | {row['rmse']:.4f} | "
                         f"{row['efficiency']:.3g} |")
    lines += ["", "Time to reach the same RMSE (log-log interpolation, "
              "`mitsuba_cornell.time_to_rmse`), jaxrt ÷ Mitsuba per wall second and per "
              "CPU-second (the target: Sobol ≤ 0.5× at RMSE 0.03):", "",
              "| RMSE | Mitsuba s | jaxrt independent s | ratio (CPU) | jaxrt sobol s | "
              "ratio (CPU) |", "|---:|---:|---:|---:|---:|---:|"]
    for target, e in r["time_to_rmse"].items():
        cpu = lambda k, e=e: f" ({e[k]:.2f})" if k in e else ""  # noqa: E731
        lines.append(f"| {target} | {e['mitsuba_s']:.3f} | {e['jaxrt_independent_s']:.3f} | "
                     f"{e['ratio_independent']:.2f}{cpu('ratio_independent_cpu')} | "
                     f"{e['jaxrt_sobol_s']:.3f} | {e['ratio_sobol']:.2f}"
                     f"{cpu('ratio_sobol_cpu')} |")
    a = res["agreement"]
    lines += ["", f"Converged images agree: {a['blocks']} block z-scores (16×16-pixel blocks × "
              f"RGB) of jaxrt's {res['ref_spp']}-spp reference minus Mitsuba's 4096-spp one: "
              f"max |z| {a['max_abs_z']:.2f}, {100 * a['frac_abs_z_gt_3']:.2f} % beyond 3 "
              f"(≈ 0.27 % expected), mean {a['mean_z']:.3f}, sd {a['std_z']:.3f} (1 expected). "
              f"The same statistic with jaxrt's image 2 % brighter: max |z| "
              f"{a['max_abs_z_light_2pct_brighter']:.1f}.", "",
              "| region | jaxrt RGB | Mitsuba RGB | z |", "|---|---|---|---|"]
    for name, v in a["regions"].items():
        f3 = lambda x: "(" + ", ".join(f"{t:.4f}" for t in x) + ")"  # noqa: E731
        lines.append(f"| {name} | {f3(v['jaxrt'])} | {f3(v['mitsuba'])} | "
                     f"{', '.join(f'{t:.1f}' for t in v['z'])} |")
    p = res["profile"]
    lines += ["", f"Where jaxrt's time goes ({p['rays']} rays/points, each stage its own "
              "jitted vmapped program, median of 3):", "",
              "| stage | ns per ray | share of whole sample | compile s |",
              "|---|---:|---:|---:|"]
    for name, v in p.items():
        if isinstance(v, dict):
            lines.append(f"| {name} | {v['ns_per_ray']:.0f} | {100 * v['share_of_whole']:.0f} % "
                         f"| {v['compile_s']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Command line: run the study, write plots and the results file's section."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"scenes {QUICK_SCENES}, estimators {QUICK_ESTIMATORS}")
    ap.add_argument("--scenes", nargs="*")
    ap.add_argument("--estimators", nargs="*")
    ap.add_argument("--size", type=int, default=64, help="image width = height")
    ap.add_argument("--levels", type=int, nargs="*", default=list(LEVELS))
    ap.add_argument("--ref-spp", type=int, default=None,
                    help="reference spp (default 1024 quick, 4096 full)")
    ap.add_argument("--sampler", default="independent")
    ap.add_argument("--mitsuba", action="store_true", help="also run the Mitsuba comparison")
    ap.add_argument("--mitsuba-only", action="store_true",
                    help="only the Mitsuba comparison (reuses benchmarks/.cache/vs_mitsuba.json "
                    "when --cached)")
    ap.add_argument("--cached", action="store_true")
    ap.add_argument("--no-write", action="store_true", help="print only, write no files")
    args = ap.parse_args(argv)
    if args.mitsuba_only:
        res = (json.loads(VS_MITSUBA_JSON.read_text()) if args.cached
               else mitsuba_comparison(log=print))
        write_section("mitsuba", mitsuba_markdown(res))
        return 0

    from jaxrt.integrators.config import DIRECT_ESTIMATORS
    from jaxrt.scene.builtin import BUILTIN

    machine = machine_description()
    print(f"machine: {machine}")
    scenes = args.scenes or (QUICK_SCENES if args.quick else tuple(BUILTIN))
    estimators = args.estimators or (QUICK_ESTIMATORS if args.quick else DIRECT_ESTIMATORS)
    ref_spp = args.ref_spp or (1024 if args.quick else 4096)
    rows = study(scenes, estimators, args.size, args.size, args.levels, ref_spp, args.sampler)
    if args.no_write:
        return 0
    plots = plot(rows, PLOT_DIR / "convergence")
    write_section("convergence", markdown(rows, machine, args.size, args.size, ref_spp, plots))
    if args.mitsuba:
        res = mitsuba_comparison(log=print)
        write_section("mitsuba", mitsuba_markdown(res))
    print(f"wrote {RESULTS} and {len(plots)} plot(s) in {PLOT_DIR}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    raise SystemExit(main())
