"""Render throughput: samples/s and compile time across estimators, scenes, sizes and options.

Run (timed; figures in ``benchmark.extra_info`` and printed with ``-s``)::

    pytest benchmarks/test_bench_render.py --benchmark-enable -s            # quick subset
    JAXRT_BENCH_FULL=1 pytest benchmarks/test_bench_render.py --benchmark-enable -s
    pytest benchmarks/test_bench_render.py --benchmark-enable -s \\
        --benchmark-json=out.json                                           # keep the numbers

Without ``--benchmark-enable`` every body runs once, untimed (a smoke test).

The full matrix is one factor at a time around a baseline (``cornell_box``, ``mis``, 64×64,
float32, independent sampler, ``accel="auto"``, tiles of 256 pixels, 1 CPU device), plus every
estimator × every built-in scene × {64², 256²}. A case records ``samples_per_s`` (median over
rounds; ``samples_per_s_best``), ``compile_s`` (the first ``render`` call's
``timings['compile']``: near 0 when an earlier case compiled the same program),
``speed_vs_baseline`` (its samples/s over the baseline's, rendered alternately in the same
rounds: the figure to trust on a loaded machine) and the case.

"Model only what the scene needs" is measured as *paired* ratios (the two
variants alternate within each round, so machine load hits both alike):
diffuse-only vs the same box with every BSDF kind compiled in (unused materials; the image
must not change), brute force vs BVH over subdivided boxes (36 → 2 k triangles), and a point
light vs the area light in the same geometry.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxrt.integrators.config import ESTIMATORS
from jaxrt.rendering.driver import render
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import BUILTIN, by_name, cornell
from jaxrt.scene.container import build_scene, mesh

FULL = os.environ.get("JAXRT_BENCH_FULL", "") not in ("", "0")
ROUNDS = 3
SPP = 2  # samples per pixel of a timed render (64² · 2 = 8 k samples: ~30 ms loaded)


def _median(xs):
    return float(np.median(xs))


def _ctx(dtype: str):
    return jax.enable_x64(True) if dtype == "float64" else contextlib.nullcontext()


_BASELINE: dict = {}


def _baseline_seconds(seed: int) -> float:
    """Render time of the baseline (cornell_box 64², mis, float32, 2 spp), compiled once."""
    if "scene" not in _BASELINE:
        _BASELINE["scene"] = cornell.cornell_box(64, 64)
        render(_BASELINE["scene"], "mis", spp=SPP)
    return render(_BASELINE["scene"], "mis", spp=SPP, seed=seed).timings["render"]


def _bench(benchmark, make_scene, estimator="mis", spp=SPP, dtype="float32", rounds=ROUNDS,
           **kw):
    """Compile with one render, then time ``rounds`` renders; fills ``extra_info``.

    Each round also renders the baseline (outside any x64 context), so
    ``speed_vs_baseline`` (samples/s ratio, same load) is a paired figure.
    """
    with _ctx(dtype):
        scene = make_scene()
        first = render(scene, estimator, spp=spp, seed=0, **kw)
    _baseline_seconds(0)
    times, base = [], []

    def run():
        base.append(_baseline_seconds(len(base) + 1))
        with _ctx(dtype):
            r = render(scene, estimator, spp=spp, seed=len(times) + 1, **kw)
        times.append(r.timings["render"])
        return r

    res = benchmark.pedantic(run, rounds=rounds, iterations=1)
    n = spp * scene.width * scene.height
    info = {"samples_per_s": n / _median(times), "samples_per_s_best": n / min(times),
            "compile_s": first.timings["compile"], "samples": n, "spp": spp,
            "speed_vs_baseline": n / _median(times) / (SPP * 64 * 64 / _median(base)),
            "size": f"{scene.width}x{scene.height}", "estimator": str(estimator),
            "dtype": dtype, **{k: str(v) for k, v in kw.items()}}
    benchmark.extra_info.update(info)
    print(f"\n  {benchmark.name}: {info['samples_per_s'] / 1e6:.3f} Msamples/s "
          f"(best {info['samples_per_s_best'] / 1e6:.3f}), compile {info['compile_s']:.1f} s, "
          f"×{info['speed_vs_baseline']:.2f} the baseline's samples/s in the same rounds")
    # the renders are real: finite, non-negative radiance, no dropped samples
    assert res.nonfinite == 0, "a benchmark render produced NaN/Inf samples"
    assert np.all(np.isfinite(res.image)) and res.image.min() >= 0
    return info


# ---------------------------------------------------------------------------------------------
# estimators × scenes × sizes
# ---------------------------------------------------------------------------------------------

_EST = ESTIMATORS if FULL else ("mis", "light_solid_angle")
_SCENES = tuple(BUILTIN) if FULL else ("cornell_box",)
_SIZES = (64, 256) if FULL else (64,)


@pytest.mark.parametrize("size", _SIZES)
@pytest.mark.parametrize("scene_name", _SCENES)
@pytest.mark.parametrize("estimator", _EST)
def test_bench_estimator(benchmark, estimator, scene_name, size):
    spp = SPP if size <= 64 else 1
    _bench(benchmark, lambda: by_name(scene_name, width=size, height=size), estimator, spp)


# ---------------------------------------------------------------------------------------------
# one factor at a time around the baseline
# ---------------------------------------------------------------------------------------------

def _box(size=64, **kw):
    return lambda: cornell.cornell_box(size, size, **kw)


@pytest.mark.parametrize("dtype", ("float32", "float64") if FULL else ("float64",))
def test_bench_dtype(benchmark, dtype):
    _bench(benchmark, _box(), dtype=dtype)


@pytest.mark.parametrize("sampler", ("independent", "stratified", "sobol") if FULL
                         else ("sobol",))
def test_bench_sampler(benchmark, sampler):
    _bench(benchmark, _box(), sampler=sampler)


@pytest.mark.parametrize("accel", ("brute", "bvh") if FULL else ("bvh",))
def test_bench_accel(benchmark, accel):
    _bench(benchmark, _box(accel=accel))


@pytest.mark.parametrize("tile_size", (64, 256, 1024, 4096) if FULL else (1024,))
def test_bench_tile_size(benchmark, tile_size):
    _bench(benchmark, _box(), tile_size=tile_size)


_TWO_DEVICES = textwrap.dedent("""
    import json, time, numpy as np, jax
    from jaxrt.rendering.driver import render
    from jaxrt.scene.builtin import cornell_box
    assert len(jax.devices()) == 2, jax.devices()
    scene = cornell_box({size}, {size})
    out = {{}}
    for dev in (1, 2):
        first = render(scene, "mis", spp={spp}, devices=dev)
        t = [render(scene, "mis", spp={spp}, seed=k + 1, devices=dev).timings["render"]
             for k in range({rounds})]
        out[dev] = {{"samples_per_s": {spp} * {size} ** 2 / float(np.median(t)),
                    "compile_s": first.timings["compile"]}}
    a = render(scene, "mis", spp=1, seed=9, devices=1).image
    b = render(scene, "mis", spp=1, seed=9, devices=2).image
    out["identical"] = bool(np.array_equal(a, b))
    print("RESULT" + json.dumps(out))
""")


def test_bench_two_devices(benchmark):
    """One vs two host devices, in a subprocess (XLA_FLAGS must be set before jax starts)."""
    size, spp = (256, 1) if FULL else (64, SPP)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    code = _TWO_DEVICES.format(size=size, spp=spp, rounds=ROUNDS)
    root = Path(__file__).resolve().parents[1]

    def run():
        p = subprocess.run([sys.executable, "-c", code], env=env, cwd=root, text=True,
                           capture_output=True, timeout=900)
        assert p.returncode == 0, p.stderr[-2000:]
        line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT"))
        return json.loads(line[len("RESULT"):])

    out = benchmark.pedantic(run, rounds=1, iterations=1)
    one, two = out["1"], out["2"]
    ratio = two["samples_per_s"] / one["samples_per_s"]
    benchmark.extra_info.update(samples_per_s_1dev=one["samples_per_s"],
                                samples_per_s_2dev=two["samples_per_s"], ratio_2_over_1=ratio,
                                compile_s_1dev=one["compile_s"], compile_s_2dev=two["compile_s"])
    print(f"\n  two devices: 1 dev {one['samples_per_s'] / 1e6:.3f}, 2 dev "
          f"{two['samples_per_s'] / 1e6:.3f} Msamples/s (×{ratio:.2f})")
    # render() splits tiles so the image cannot depend on the device count (bit-identical)
    assert out["identical"], "1-device and 2-device images differ"


# ---------------------------------------------------------------------------------------------
# item 4: model only what a scene requires (paired ratios)
# ---------------------------------------------------------------------------------------------

def _paired(benchmark, scene_a, scene_b, estimator="mis", spp=SPP, rounds=ROUNDS, **kw):
    """Compile both, then alternate A, B renders; returns (info, last image A, last image B)."""
    render(scene_a, estimator, spp=spp, **kw)
    render(scene_b, estimator, spp=spp, **kw)
    ta, tb, imgs = [], [], {}

    def run():
        ra = render(scene_a, estimator, spp=spp, seed=len(ta) + 1, **kw)
        rb = render(scene_b, estimator, spp=spp, seed=len(tb) + 1, **kw)
        ta.append(ra.timings["render"])
        tb.append(rb.timings["render"])
        imgs["a"], imgs["b"] = ra.image, rb.image

    benchmark.pedantic(run, rounds=rounds, iterations=1)
    n = spp * scene_a.width * scene_a.height
    info = {"samples_per_s_a": n / _median(ta), "samples_per_s_b": n / _median(tb),
            "ratio_a_over_b": _median(tb) / _median(ta)}
    benchmark.extra_info.update(info)
    return info, imgs["a"], imgs["b"]


def all_kinds_box(size=64):
    """The diffuse Cornell box with a material table holding every BSDF kind (unused extras)."""
    scene = cornell.cornell_box(size, size)
    mats = [m.material for m in cornell.cornell_meshes()]
    extra = [mt.phong(kd=0.3, ks=0.3, exponent=20.0), mt.conductor(alpha=0.1, ks=0.9),
             mt.mirror(0.9)]
    table, kinds = mt.material_table(mats + extra)  # surfaces still index the first rows
    return scene.replace(materials=table, material_kinds=kinds)


def test_bench_diffuse_only_vs_all_kinds(benchmark):
    a = cornell.cornell_box(64, 64)
    b = all_kinds_box(64)
    assert a.material_kinds == (0,) and b.material_kinds == (0, 1, 2, 3)
    info, ia, ib = _paired(benchmark, a, b)
    print(f"\n  diffuse-only {info['samples_per_s_a'] / 1e6:.3f} vs all kinds "
          f"{info['samples_per_s_b'] / 1e6:.3f} Msamples/s: ×{info['ratio_a_over_b']:.2f}")
    # same samples, same surfaces, only dead switch branches differ: equal up to the float32
    # rounding of a differently fused program (1e-5 relative, far below 1-spp noise ≈ 100 %)
    np.testing.assert_allclose(ia, ib, rtol=1e-5, atol=1e-7)


def subdivide(vertices, faces, levels: int):
    """Midpoint-subdivide a triangle mesh ``levels`` times (×4 triangles each; same surface)."""
    v = np.asarray(vertices, np.float64)[np.asarray(faces)]  # (F, 3, 3) triangle soup
    for _ in range(levels):
        a, b, c = v[:, 0], v[:, 1], v[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        v = np.concatenate([np.stack(t, 1) for t in
                            ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return v.reshape(-1, 3), np.arange(len(v) * 3).reshape(-1, 3)


def subdivided_box(levels: int, size: int, accel: str):
    """The Cornell box with every non-emissive mesh subdivided (the light quad kept as is)."""
    meshes = []
    for m in cornell.cornell_meshes():
        if m.emission is None:
            v, f = subdivide(m.vertices, m.faces, levels)
            m = mesh(v, f, m.material, name=m.name)
        meshes.append(m)
    return build_scene(meshes, cornell.cornell_camera(size, size), accel=accel)


@pytest.mark.parametrize("levels", (0, 1, 2, 3) if FULL else (2,))
def test_bench_brute_vs_bvh(benchmark, levels):
    size = 128  # 16 384 pixels: one full 16 384-lane step, as the default render batch
    a, b = subdivided_box(levels, size, "brute"), subdivided_box(levels, size, "bvh")
    info, ia, ib = _paired(benchmark, a, b, spp=1)
    info["triangles"] = a.num_triangles
    benchmark.extra_info["triangles"] = a.num_triangles
    print(f"\n  {a.num_triangles} triangles: brute {info['samples_per_s_a'] / 1e6:.4f} vs BVH "
          f"{info['samples_per_s_b'] / 1e6:.4f} Msamples/s: brute/BVH "
          f"×{info['ratio_a_over_b']:.2f}")
    # same rays, same closest hits: the images may differ only where a float32 tie between
    # two triangles resolves differently (≤ 1 % of pixels, measured 0 so far)
    assert np.mean(np.any(np.abs(ia - ib) > 1e-4, axis=-1)) <= 0.01


def point_light_box(size=64):
    """Same geometry as the box, its light quad non-emissive, a point light just below it."""
    meshes = cornell.cornell_meshes()
    light = meshes[-1]
    assert light.emission is not None
    centre = light.vertices.mean(0) - np.array([0, 0.01, 0])
    meshes[-1] = mesh(light.vertices, light.faces, light.material, name="light_fixture")
    return build_scene(meshes, cornell.cornell_camera(size, size),
                       [lt.point_light(centre, (5.0, 4.0, 3.0))])


def test_bench_point_light_vs_area_light(benchmark):
    a, b = point_light_box(64), cornell.cornell_box(64, 64)
    info, ia, _ = _paired(benchmark, a, b)
    print(f"\n  point light {info['samples_per_s_a'] / 1e6:.3f} vs area light "
          f"{info['samples_per_s_b'] / 1e6:.3f} Msamples/s: ×{info['ratio_a_over_b']:.2f}")
    assert ia.max() > 0, "the point-light box rendered black"


def _one_sample_ratio(benchmark, estimator: str, longer: int, spp_total: int) -> float:
    """A 1-spp pass's CPU time per spp against a ``longer``-spp pass's (256² Cornell box, the
    real pass, alternating rounds); records both and the wall-time ratio, prints them, and
    returns the CPU-time ratio."""
    import time

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.rendering.passes import RenderPass

    est = make_estimator(estimator)
    scene = prepare_scene(cornell.cornell_box(256, 256), est)
    run = RenderPass(scene, 0, jax.devices()[:1], 256, est=est, sampler="independent",
                     spp_total=spp_total, batch_size=64)
    counts = (1, longer)
    for count in counts:
        run.compile(count)
    sums, cpu, wall = run.zeros(), {c: [] for c in counts}, {c: [] for c in counts}
    rounds = 8 if not benchmark.disabled else 1

    def go():
        nonlocal sums
        for r in range(rounds):
            for count in counts if r % 2 == 0 else counts[::-1]:
                t0, w0 = time.process_time(), time.perf_counter()
                sums = run(sums, 0, count)
                cpu[count].append((time.process_time() - t0) / count)
                wall[count].append((time.perf_counter() - w0) / count)

    benchmark.pedantic(go, rounds=1, iterations=1)
    ratio = _median(cpu[1]) / _median(cpu[longer])
    ratio_wall = _median(wall[1]) / _median(wall[longer])
    benchmark.extra_info.update({"per_sample_cpu_s_1": _median(cpu[1]),
                                 f"per_sample_cpu_s_{longer}": _median(cpu[longer]),
                                 "ratio": ratio, "ratio_wall": ratio_wall,
                                 "load": os.getloadavg()})
    print(f"\n  {estimator}: 1-spp pass {_median(cpu[1]) * 1e3:.1f} CPU-ms per spp (65 536 "
          f"samples), {longer}-spp {_median(cpu[longer]) * 1e3:.1f}: {ratio:.2f}x per CPU-s, "
          f"{ratio_wall:.2f}x per wall s; load {os.getloadavg()[0]:.2f}")
    return ratio


@pytest.mark.parametrize("estimator", ["mis", "light_area", "bsdf"])
def test_bench_one_sample_pass(benchmark, estimator):
    """Per-sample time of a 1-spp pass against a 4-spp pass (256² Cornell box, the real pass,
    alternating rounds). ``render`` runs 1 spp per pass above 2^20 pixels (~1 megapixel)
    (``default_spp_per_pass``): there XLA inlines the sample loop, and unless the pass
    stores the sample (``jaxrt.rendering.passes.lane_sums``) the MIS value is fused into each
    of the fold's kernels and computed in each, 3-5x the per-sample time of a longer pass.
    Fails when a 1-spp pass takes above 2x a 4-spp pass's CPU time per sample (a
    pass of one sample also pays the prologue's camera hit and the step's slices of the sums
    once per sample); the wall-time ratio is recorded beside it."""
    ratio = _one_sample_ratio(benchmark, estimator, 4, 64)
    if not benchmark.disabled:
        assert ratio < 2.0


def test_bench_path_one_sample_pass(benchmark):
    """Per-sample time of a 1-spp path pass against an 8-spp one (256² Cornell box,
    unbounded paths, the real pass, alternating rounds), in a render long enough (2 048
    spp: 1.3·10⁸ samples) for ``path.compactions`` to compact a 1-spp pass's lanes three
    times. With one sample per lane there is no path regeneration, and every batch of lanes
    waits for its longest path: with one compaction a 1-spp pass takes 1.73x an 8-spp pass's
    CPU time per sample, with three 1.16x. Fails above 1.4x; the wall-time ratio is recorded
    beside it."""
    from jaxrt.integrators.path import compactions

    assert compactions(1, 256 * 256 * 2048) == 3
    ratio = _one_sample_ratio(benchmark, "path", 8, 2048)
    if not benchmark.disabled:
        assert ratio < 1.4
