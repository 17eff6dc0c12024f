"""Where one MIS camera sample's time goes: cumulative ablations of the real render program.

    python benchmarks/profile_render.py            # ~3 min on the 2-core machine
    python benchmarks/profile_render.py --trace    # also the per-kernel XLA:CPU trace

Every stage is measured *inside the render*: ``jaxrt.passes.render_tiles`` (256×256
``cornell_box``, 1 spp, the default 256-pixel tiles × 64 per ``lax.map`` step, i.e. 16 384
lanes)
is compiled once per level with its per-sample function replaced by a truncated MIS estimator
that stops after one more stage (each level's output depends on everything it computed, so XLA
cannot drop it). The cost of a stage is the difference between consecutive levels, taken per
round (levels alternate in every round, paired) and reported as the median; the stages add up
to the full render by construction. Levels:

0. nothing — the same tiles, lax.map, fori_loop and running sums around a constant sample
1. sample stream — all 8 dimensions one MIS sample draws (``jaxrt.sampler``)
2. camera ray — ``generate_ray``
3. closest hit — ``scene.intersect`` of the camera ray (brute force, 32 triangles), hit point
4. light sample — ``lights.sample_li`` (spherical triangle of one of the two light triangles)
5. shadow ray — robust ``spawn_ray_to`` + ``any_hit``
6. BSDF eval + pdf — of the light direction (diffuse)
7. BSDF sample — diffuse ``bsdf_sample``
8. BSDF ray — ``spawn_ray`` + closest hit + ``emitted``
9. pdf_li — the light pdf of the BSDF ray's hit
10. full render — the real pass (``camera_sample``'s two halves, the camera ray's hit found
    one sample ahead; adds emitted-by-camera-hit, the MIS weights and that overlap)

It also prints what the compiled full program contains (fusions, while loops, gathers). With
``--trace`` it records one full render with ``jax.profiler`` and lists the kernels (XLA:CPU
thunks) that take the most time.

Out of date since the eighth session: levels 3 and 8 still call the general
``scene.intersect``, while the real pass finds camera hits by the eye's planes and the BSDF
ray against occluders and emitters only, and the stage scopes wrap module attributes the pass
no longer calls through; on 2026-12-05 (AMD family 25) the ladder read negative costs for
three stages and left 80 % of the kernel time in "other". For where a pass's time goes today,
use ``benchmarks/kernel_sources.py`` (kernel time and distinct kernels by source line).
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import inspect
import json
import os
import re
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxrt.estimators as est_mod
import jaxrt.passes as ps
import jaxrt.terms as terms_mod
from jaxrt import lights as lt
from jaxrt import materials as mt
from jaxrt.camera import generate_ray
from jaxrt.estimators import camera_sample, compiler_options, make_estimator, prepare_scene
from jaxrt.render import render
from jaxrt.scene import emitted, intersect, material_at, shading_normal
from jaxrt.scenes import cornell_box
from jaxrt.spawn import spawn_ray
from jaxrt.vecmath import to_local, to_world

SIZE = 256
BATCH_SIZE = inspect.signature(render).parameters["batch_size"].default  # as render
LEVELS = ("nothing", "sample stream", "camera ray", "closest hit (camera ray)", "light sample",
          "shadow ray (any hit)", "BSDF eval + pdf (light dir)", "BSDF sample",
          "BSDF ray: closest hit + emitted", "pdf_li (BSDF ray)", "full render (+ MIS weights)")


def truncated_sample(level: int):
    """A per-sample function with ``camera_sample``'s signature that stops after ``level``."""
    if level == len(LEVELS) - 1:
        return camera_sample

    def sample(scene, est, pixel, index, seed, sampler="independent", spp=1):
        s = terms_mod.Stream.of(sampler, seed, pixel, index, spp)
        dtype = scene.triangles.dtype
        if level == 0:
            return jnp.broadcast_to(pixel.astype(dtype) * 1e-9, (3,))
        u_cam, u_light, u_sel, u_bsdf = s.u2(0), s.u2(2), s.u1(4), s.u2(6)
        acc = jnp.concatenate([u_cam, u_light[:1]]) + jnp.concatenate([u_sel[None], u_bsdf])
        if level == 1:
            return acc
        xy = jnp.stack([pixel % scene.width, pixel // scene.width]).astype(jnp.int32)
        o, d = generate_ray(scene.camera, xy, u_cam)
        acc = acc + d
        if level == 2:
            return acc
        hit = intersect(scene, o, d, jnp.asarray(jnp.inf, dtype))
        n = shading_normal(hit.ng, -d)
        x = terms_mod.ShadingPoint(hit, n, to_local(-d, n), material_at(scene, hit))
        acc = acc + hit.p + n + x.material.kd
        if level == 3:
            return acc
        ls = lt.sample_li(scene.lights, hit.p, n, jnp.concatenate([u_sel[None], u_light]))
        acc = acc + ls.wi * ls.pdf + ls.li + ls.dist
        if level == 4:
            return acc
        acc = acc + terms_mod._visible(scene, x, ls)
        if level == 5:
            return acc
        wi_local = to_local(ls.wi, n)
        f = mt.bsdf_eval(x.material, x.wo_local, wi_local, scene.material_kinds)
        acc = acc + f + mt.bsdf_pdf(x.material, x.wo_local, wi_local, scene.material_kinds)
        if level == 6:
            return acc
        bs = mt.bsdf_sample(x.material, x.wo_local, u_bsdf, scene.material_kinds)
        wi = to_world(bs.wi, n)
        acc = acc + wi * bs.pdf + bs.weight
        if level == 7:
            return acc
        o, d = spawn_ray(x.hit.p, x.n, wi, x.hit.p_error)
        h = intersect(scene, o, d, jnp.asarray(jnp.inf, o.dtype), emission_only=True)
        acc = acc + emitted(scene, h, -d) + h.p
        if level == 8:
            return acc
        return acc + lt.pdf_li(scene.lights, hit.p, wi, h.light, h.p)

    return sample


def compile_level(scene, est, level: int):
    """The render program of one pass of 1 spp with ``camera_sample`` truncated at ``level``."""
    jax.clear_caches()  # the per-sample function is looked up at trace time
    original = ps.camera_hit, ps.camera_radiance
    if level < len(LEVELS) - 1:
        # the pass runs camera_sample as its two halves, one sample apart (passes.lane_sums);
        # a truncated level runs whole in the second half, the first half returns a stub
        sample = truncated_sample(level)
        ps.camera_hit = lambda scene, pixel, s: (pixel, s.index)
        # (the stub's hit is the pixel; the pass's seed is 0, below)
        ps.camera_radiance = lambda scene, est, hit, wo, s: sample(
            scene, est, hit, s.index, jnp.uint32(0), s.kind, s.spp)
    try:
        static = dict(est=est, sampler="independent", spp_total=1, count=1, tile_size=256,
                      batch_size=BATCH_SIZE, num_tiles=SIZE * SIZE // 256)
        per_step, steps = ps.step_layout(SIZE * SIZE // 256, BATCH_SIZE)
        sums = ps.zero_sums((steps * per_step * 256,), scene.triangles.dtype)
        args = (scene, jnp.uint32(0), jnp.int32(0), jnp.int32(0), sums)
        t0 = time.perf_counter()
        exe = ps.render_tiles.lower(*args, **static).compile(compiler_options())
        return exe, args, time.perf_counter() - t0
    finally:
        ps.camera_hit, ps.camera_radiance = original


def hlo_stats(text: str) -> dict:
    """Counts of kernels and loops in an optimised HLO module (``compiled.as_text()``)."""
    return {"fusions": len(re.findall(r"= \S+ fusion\(", text)),
            "while loops": len(re.findall(r"\bwhile\(", text)),
            "gathers": len(re.findall(r"\bgather\(", text)),
            "custom (YNN) fusions": text.count('"__ynn_fusion"'),
            "divides": len(re.findall(r"\bdivide\(", text))}


def _trace_events(exe, args) -> list[dict]:
    """The perfetto trace events of one run of ``exe(*args)`` recorded with ``jax.profiler``."""
    with tempfile.TemporaryDirectory() as tmp:
        jax.profiler.start_trace(tmp, create_perfetto_trace=True)
        jax.block_until_ready(exe(*args))
        jax.profiler.stop_trace()
        path = glob.glob(os.path.join(tmp, "**", "perfetto_trace.json.gz"), recursive=True)[0]
        return json.load(gzip.open(path))["traceEvents"]


def kernel_trace(exe, args, top: int = 15) -> list[tuple[str, int, float]]:
    """(kernel, calls, ms) of one run recorded with ``jax.profiler`` (perfetto trace)."""
    events = _trace_events(exe, args)
    calls, ms = collections.Counter(), collections.defaultdict(float)
    for e in events:
        name = e.get("name", "")
        if e.get("ph") == "X" and not name.startswith(("$", "ThunkExecutor", "Pjit")):
            calls[name] += 1
            ms[name] += e.get("dur", 0) / 1e3
    return sorted(((k, calls[k], ms[k]) for k in ms), key=lambda r: -r[2])[:top]


# Kernel-level attribution: the real render with jax.named_scope around each stage's function,
# every XLA:CPU kernel of one traced run charged (exclusive time) to the scope of its root op.
SCOPES = (("shadow_ray", "shadow ray: spawn_ray_to + any hit"),
          ("bsdf_ray/closest_hit", "BSDF ray: closest hit (+ hit point)"),
          ("emitted", "emitted (camera hit + BSDF ray)"),
          ("bsdf_ray", "BSDF ray: trace_from (closest hit, emitted, pdf_li)"),
          ("pdf_li", "pdf_li (BSDF ray)"),
          ("closest_hit", "camera ray: closest hit (+ hit point)"),
          ("light_sample", "light sample (sample_li)"),
          ("bsdf", "BSDF sample / eval / pdf"),
          ("camera", "camera ray"),
          ("sampler", "sample stream"),
          ("mis_weight", "MIS weights"))


def _scoped(fn, name):
    def wrapper(*args, **kwargs):
        with jax.named_scope(name):
            return fn(*args, **kwargs)
    return wrapper


def _patch_scopes() -> list:
    """Wrap the stage functions the estimator calls in named scopes; returns the undo list."""
    targets = [(terms_mod, "generate_ray", "camera"), (est_mod, "intersect", "closest_hit"),
               (terms_mod, "intersect", "closest_hit"),
               (terms_mod, "_visible", "shadow_ray"), (terms_mod, "trace_from", "bsdf_ray"),
               (est_mod, "emitted", "emitted"), (terms_mod, "emitted", "emitted"),
               (est_mod, "mis_weight", "mis_weight"),
               (lt, "sample_li", "light_sample"), (lt, "pdf_li", "pdf_li"),
               (mt, "bsdf_eval", "bsdf"), (mt, "bsdf_pdf", "bsdf"), (mt, "bsdf_sample", "bsdf"),
               (terms_mod.Stream, "u1", "sampler"), (terms_mod.Stream, "u2", "sampler")]
    undo = []
    for obj, attr, name in targets:
        undo.append((obj, attr, getattr(obj, attr)))
        setattr(obj, attr, _scoped(getattr(obj, attr), name))
    return undo


def scoped_profile(scene, est) -> tuple[dict, float]:
    """Exclusive kernel time (ms, one traced render) per stage scope, and the traced total."""
    undo = _patch_scopes()
    try:
        exe, args, _ = compile_level(scene, est, len(LEVELS) - 1)
    finally:
        for obj, attr, fn in reversed(undo):
            setattr(obj, attr, fn)
    text = exe.as_text()
    op_name = dict(re.findall(r"^\s+%(\S+) = .*?op_name=\"([^\"]*)\"", text, re.M))
    jax.block_until_ready(exe(*args))
    events = _trace_events(exe, args)
    # exclusive time of every kernel: its duration minus that of kernels nested inside it
    by_thread = collections.defaultdict(list)
    for e in events:
        name = e.get("name", "")
        if e.get("ph") == "X" and name.split(" ")[-1] in op_name:
            by_thread[e.get("tid")].append((e["ts"], e["dur"], name.split(" ")[-1]))
    ms = collections.defaultdict(float)
    for evs in by_thread.values():
        evs.sort(key=lambda r: (r[0], -r[1]))
        stack: list = []  # [end, name, exclusive]
        for ts, dur, name in evs + [(float("inf"), 0, None)]:
            while stack and stack[-1][0] <= ts:
                end, nm, excl = stack.pop()
                ms[_scope_of(op_name[nm])] += excl / 1e3
            if name is None:
                break
            if stack:
                stack[-1][2] -= dur
            stack.append([ts + dur, name, dur])
    return dict(ms), sum(ms.values())


def _scope_of(op: str) -> str:
    for key, label in SCOPES:
        if key in op:
            return label
    return "other: shading frame, gathers, sums, tile loop"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--trace", action="store_true", help="per-kernel trace of the render")
    a = parser.parse_args()
    est = make_estimator("mis")
    scene = cornell_box(SIZE, SIZE)
    scene = prepare_scene(scene, est)
    n = SIZE * SIZE
    print(f"jax {jax.__version__}, {SIZE}x{SIZE} cornell_box, mis, 1 spp, "
          f"{256 * BATCH_SIZE} lanes per step; "
          f"load average at start {os.getloadavg()}")
    programs = []
    for level, name in enumerate(LEVELS):
        exe, args, tc = compile_level(scene, est, level)
        jax.block_until_ready(exe(*args))  # warm-up
        programs.append((exe, args))
        print(f"  compiled level {level:2d} {name!r} in {tc:.1f} s", flush=True)
    times = np.zeros((a.rounds, len(LEVELS)))
    for r in range(a.rounds):
        for k, (exe, args) in enumerate(programs):
            t0 = time.perf_counter()
            jax.block_until_ready(exe(*args))
            times[r, k] = (time.perf_counter() - t0) / n * 1e6
    whole = np.median(times[:, -1])
    print(f"\nload average at end {os.getloadavg()}; {a.rounds} rounds, levels alternating\n")
    print("| stage | µs per sample | share | level total µs |")
    print("|---|---:|---:|---:|")
    for k, name in enumerate(LEVELS):
        step = times[:, k] - (times[:, k - 1] if k else 0)
        print(f"| {name} | {np.median(step):.3f} | {np.median(step) / whole:.0%} "
              f"| {np.median(times[:, k]):.3f} |")
    print(f"\nfull render: {whole:.3f} µs per sample = {1 / whole:.3f} Msamples/s")
    full_exe, full_args = programs[-1]
    print("full program:", hlo_stats(full_exe.as_text()))
    ms, total = scoped_profile(scene, est)
    print(f"\nKernel time of one traced full render by stage ({total:.0f} ms of kernels; "
          "µs scaled to the paired full-render median)\n")
    print("| stage (scope of the kernel's root op) | µs per sample | share |\n|---|---:|---:|")
    for label, v in sorted(ms.items(), key=lambda kv: -kv[1]):
        print(f"| {label} | {v / total * whole:.3f} | {v / total:.0%} |")
    if a.trace:
        print("\n| kernel (one full render) | calls | ms |\n|---|---:|---:|")
        for name, c, ms in kernel_trace(full_exe, full_args):
            print(f"| {name} | {c} | {ms:.1f} |")


if __name__ == "__main__":
    main()
