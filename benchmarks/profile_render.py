"""Where one MIS camera sample's time goes: cumulative ablations of the real render pass.

    python benchmarks/profile_render.py            # ~2 min on the 2-core machine
    python benchmarks/profile_render.py --trace    # also the per-kernel XLA:CPU trace

Every stage is measured *inside the render*: ``jaxrt.rendering.passes.render_tiles`` (256×256
``cornell_box``, a pass of :data:`SPP` samples per pixel as ``render`` runs them, 256-pixel
tiles × 64 per ``lax.map`` step, i.e. 16 384 lanes) is compiled once per level with the
pass's two halves of a sample (``camera_hit``, run one sample ahead, and
``camera_radiance``) replaced by the same functions stopped after one more stage. Each
level's output depends on everything it computed, so XLA cannot drop it. The stages are the
real pass's own functions (the camera hit by the eye's planes, the shadow ray against the
occluders and blocks, the BSDF ray against emitters and occluders: ``jaxrt.integrators.terms``), and
the last level is the real pass. The cost of a stage is the difference between consecutive
levels in CPU-seconds, taken per round (levels alternate in every round, paired) and
reported as the median; the stages add up to the full render by construction. Per CPU-second,
because XLA:CPU runs independent kernels (the next sample's camera loop beside this one's
shading) on its two threads: a level's wall time is not the sum of its stages' work.

A truncated level is a different program, and XLA:CPU may fuse it differently: a level can
read more CPU time per sample than the whole pass when XLA fuses the level's sum into the
kernel that forms the camera hit's point, a (N, 3) output in transposed layout whose three
elements each recompute all of its operations, and the next stage then reads a negative
cost. So read a stage's cost as a hint and check it against
the kernel-scope table below, which charges the real pass's own kernels.
Levels:

0. nothing — the same tiles, lax.map, pipelined sample loop and running sums around a
   constant sample
1. sample stream — the dimensions one MIS sample draws (``jaxrt.sampling.sampler``)
2. camera ray — ``terms.camera_ray``
3. camera hit — ``estimators.camera_hit`` (closest hit by the eye's planes, found one sample
   ahead) and the shading point (normal, local ``wo``, material)
4. light sample — ``lights.sample_li`` with the BSDF's value and pdf in its direction
5. shadow ray — ``terms._visible`` (robust spawn towards the light point + any hit)
6. BSDF sample — ``terms.bsdf_direction`` (sample, weight, spawned origin)
7. BSDF ray — ``terms.trace_from`` (closest hit against emitters and occluders, emitted
   radiance, light pdf of the hit)
8. full render — the real pass (adds emission seen by the camera and the MIS weights)

It also prints what the compiled full program contains (fusions, while loops, gathers), and
the kernel time of one traced full render by the named scope of each kernel's root
operation. With ``--trace`` it lists the kernels (XLA:CPU thunks) that take the most time.
``benchmarks/kernel_sources.py`` charges kernel time to source lines instead.
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

import jaxrt.integrators.direct as est_mod
import jaxrt.integrators.terms as terms_mod
import jaxrt.rendering.passes as ps
from jaxrt.core.vecmath import to_local
from jaxrt.core.xla import compiler_options
from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.driver import render
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import cornell_box

SIZE = 256
SPP = 32  # samples per pixel of the profiled pass: render's pass for a 256² image at 64 spp
BATCH_SIZE = inspect.signature(render).parameters["batch_size"].default  # as render
LEVELS = ("nothing", "sample stream", "camera ray", "camera hit + shading point",
          "light sample + BSDF value, pdf", "shadow ray (any hit)", "BSDF sample",
          "BSDF ray: closest hit + emitted + pdf_li", "full render (+ emitted, MIS weights)")


def truncated_halves(level: int):
    """``(camera_hit, camera_radiance)`` of a sample that stops after ``level``; the real
    pair at the last level."""
    if level == len(LEVELS) - 1:
        return est_mod.camera_hit, est_mod.camera_radiance

    def first(scene, pixel, s):
        if level >= 3:
            return est_mod.camera_hit(scene, pixel, s)
        return pixel, s.index  # a stub hit: the second half reads the pixel from it

    def second(scene, est, hit, wo, s):
        dtype = scene.triangles.dtype
        if level == 0:
            return jnp.broadcast_to(wo.astype(dtype) * 1e-9, (3,))
        # the dimensions the real MIS sample draws (1 light + 1 BSDF sample)
        u_light, u_sel, u_bsdf = s.u2(2), s.u1(4), s.u2(6)
        acc = jnp.concatenate([u_light, u_sel[None]]) + jnp.concatenate([u_bsdf, u_sel[None]])
        if level == 1:
            return acc + jnp.sum(s.u2(0))  # the camera ray's two dimensions as well
        if level == 2:
            return acc + terms_mod.camera_ray(scene, hit, s)[1]
        x = terms_mod.shading_point(scene, hit, wo)
        acc = acc + x.hit.p + x.n + x.wo_local + x.material.kd
        if level == 3:
            return acc
        ls = lt.sample_li(scene.lights, x.hit.p, x.n, jnp.concatenate([u_sel[None], u_light]))
        wi_local = to_local(ls.wi, x.n)
        f = mt.bsdf_eval(x.material, x.wo_local, wi_local, scene.material_kinds)
        pdf = mt.bsdf_pdf(x.material, x.wo_local, wi_local, scene.material_kinds)
        acc = acc + f * ls.li * jnp.abs(wi_local[2]) / ls.pdf + pdf
        if level == 4:
            return acc
        acc = acc + terms_mod._visible(scene, x, ls)
        if level == 5:
            return acc
        b = terms_mod.bsdf_direction(scene, x, u_bsdf)
        acc = acc + b.weight + b.o + b.wi * b.pdf
        if level == 6:
            return acc
        a = terms_mod.trace_from(scene, x.hit.p, b.o, b.wi, emission_only=True)
        return acc + a.le + a.pdf_light

    return first, second


def compile_level(scene, est, level: int):
    """The render program of one pass of :data:`SPP` samples with the sample truncated at
    ``level``: (executable, arguments, compile seconds)."""
    jax.clear_caches()  # the two halves are looked up at trace time
    original = ps.camera_hit, ps.camera_radiance
    ps.camera_hit, ps.camera_radiance = truncated_halves(level)
    try:
        static = dict(est=est, sampler="independent", spp_total=SPP, count=SPP,
                      tile_size=256, batch_size=BATCH_SIZE, num_tiles=SIZE * SIZE // 256)
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
    n = SIZE * SIZE * SPP
    print(f"jax {jax.__version__}, {SIZE}x{SIZE} cornell_box, mis, a pass of {SPP} spp, "
          f"{256 * BATCH_SIZE} lanes per step; "
          f"load average at start {os.getloadavg()}")
    programs = []
    for level, name in enumerate(LEVELS):
        exe, args, tc = compile_level(scene, est, level)
        jax.block_until_ready(exe(*args))  # warm-up
        programs.append((exe, args))
        print(f"  compiled level {level:2d} {name!r} in {tc:.1f} s", flush=True)
    # CPU time as well as wall: XLA:CPU runs independent kernels (the next sample's camera
    # loop beside this one's shading) on its two threads, so a level's wall time is not the
    # sum of its stages' work, and a stage that adds parallel work can shorten it
    wall = np.zeros((a.rounds, len(LEVELS)))
    cpu = np.zeros((a.rounds, len(LEVELS)))
    for r in range(a.rounds):
        order = range(len(LEVELS)) if r % 2 == 0 else reversed(range(len(LEVELS)))
        for k in order:
            exe, args = programs[k]
            w0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(exe(*args))
            wall[r, k] = (time.perf_counter() - w0) / n * 1e6
            cpu[r, k] = (time.process_time() - c0) / n * 1e6
    whole = np.median(cpu[:, -1])
    print(f"\nload average at end {os.getloadavg()}; {a.rounds} rounds, levels alternating\n")
    print("| stage | CPU µs per sample | share | level total, CPU µs | level total, wall µs |")
    print("|---|---:|---:|---:|---:|")
    for k, name in enumerate(LEVELS):
        step = cpu[:, k] - (cpu[:, k - 1] if k else 0)
        print(f"| {name} | {np.median(step):.3f} | {np.median(step) / whole:.0%} "
              f"| {np.median(cpu[:, k]):.3f} | {np.median(wall[:, k]):.3f} |")
    print(f"\nfull render: {whole:.3f} CPU-µs per sample = {1 / whole:.3f} Msamples per "
          f"CPU-second, {1 / np.median(wall[:, -1]):.3f} per wall second")
    full_exe, full_args = programs[-1]
    print("full program:", hlo_stats(full_exe.as_text()))
    ms, total = scoped_profile(scene, est)
    print(f"\nKernel time of one traced full render by stage ({total:.0f} ms of kernels; "
          "CPU-µs scaled to the paired full-render median)\n")
    print("| stage (scope of the kernel's root op) | µs per sample | share |\n|---|---:|---:|")
    for label, v in sorted(ms.items(), key=lambda kv: -kv[1]):
        print(f"| {label} | {v / total * whole:.3f} | {v / total:.0%} |")
    if a.trace:
        print("\n| kernel (one full render) | calls | ms |\n|---|---:|---:|")
        for name, c, ms in kernel_trace(full_exe, full_args):
            print(f"| {name} | {c} | {ms:.1f} |")


if __name__ == "__main__":
    main()
