"""What a texture costs: the Cornell box against the same box with a constant back-wall texture.

    python benchmarks/textures.py [--size 256] [--spp 16] [--rounds 8] [--estimator mis]
    python benchmarks/textures.py --field emission   # a constant emission texture on the light

Two scenes of one geometry: the built-in box (texture-free: no texture code is compiled) and
the box whose back wall's albedo is a constant 8 × 8 texture of the same value (the same
image, bit for bit: the bilinear lookup of a constant is exact; checked here), so the
difference is the lookup alone: the hit's UVs from its triangle's affine map (11 numbers
gathered per shading point), four texel gathers and the lerps, and a select per binding.
``--field emission`` textures the light instead (a constant 1 times its radiance): then
every light sample, BSDF hit of the light and camera hit of it looks the texture up.
Both passes are compiled apart (``RenderPass.compile``, reported), then timed in
interleaved rounds (A B, B A, …) in this process, per wall second and per CPU-second of the
process (``time.process_time``), with the load average before and after. Prints samples/s
of each, the per-round CPU ratios and the XLA kernels of each compiled program.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


def scenes(size: int, field: str = "kd"):
    """``(plain, textured)``: the box, and the box with a constant texture on its back wall's
    albedo (``field="kd"``) or on its light's emission (``field="emission"``)."""
    import jaxrt
    from jaxrt.scene.builtin.cornell import WHITE, cornell_box, cornell_camera, cornell_meshes

    meshes = []
    for m in cornell_meshes():
        if m.name == ("back" if field == "kd" else "light"):
            lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
            axes = [0, 1] if field == "kd" else [0, 2]
            uv = (m.vertices[:, axes] - lo[axes]) / (hi[axes] - lo[axes])
            value = WHITE if field == "kd" else 1.0
            m = jaxrt.mesh(m.vertices, m.faces, m.material, emission=m.emission, name=m.name,
                           uv=uv, textures={field: jaxrt.texture(
                               np.broadcast_to(value, (8, 8, 3)).astype(np.float64))})
        meshes.append(m)
    return cornell_box(size, size), jaxrt.build_scene(meshes, cornell_camera(size, size))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel per pass")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--estimator", default="mis")
    parser.add_argument("--field", choices=("kd", "emission"), default="kd")
    a = parser.parse_args(argv)

    import jax

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.rendering.passes import RenderPass

    est = make_estimator(a.estimator)
    static = dict(est=est, sampler="independent", spp_total=1 << 20, batch_size=64)
    device = jax.devices()[:1]
    runs, compile_s, carries, images = {}, {}, {}, {}
    for name, scene in zip(("plain", "textured"), scenes(a.size, a.field), strict=True):
        run = RenderPass(prepare_scene(scene, est), 0, device, 256, **static)
        compile_s[name] = run.compile(a.spp)
        carries[name] = run(run.zeros(), 0, a.spp)  # warm-up
        images[name] = np.asarray(carries[name].s1)
        runs[name] = run
    same = np.array_equal(images["plain"], images["textured"])
    done = a.spp
    times = {"plain": [], "textured": []}
    load_start = os.getloadavg()
    for r in range(a.rounds):
        for name in ("plain", "textured") if r % 2 == 0 else ("textured", "plain"):
            w0, c0 = time.perf_counter(), time.process_time()
            carries[name] = runs[name](carries[name], done, a.spp)
            times[name].append((time.perf_counter() - w0, time.process_time() - c0))
        done += a.spp
    load_end = os.getloadavg()
    n = a.size * a.size * a.spp
    for name, t in times.items():
        wall, cpu = np.array(t).T
        print(f"{name:8s}: {n / np.median(wall) / 1e6:.3f} Msamples/wall-s, "
              f"{n / np.median(cpu) / 1e6:.3f} Msamples/CPU-s, "
              f"{np.median(cpu) / n * 1e9:.1f} CPU-ns/sample (medians of {len(t)}); "
              f"compile {compile_s[name]:.2f} s")
    pair = [p[1] / t[1] for p, t in zip(times["plain"], times["textured"], strict=True)]
    print(f"textured / plain cost per sample (CPU, per round): median {1 / np.median(pair):.4f} "
          f"({1 / max(pair):.4f} … {1 / min(pair):.4f}); first-pass sums equal bit for bit: "
          f"{same}; load {load_start} -> {load_end}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
