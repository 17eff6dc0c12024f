"""Brute force vs BVH by triangle count: the measurement behind ``AUTO_BVH_THRESHOLD``.

    python benchmarks/crossover.py            # ~3 min on the 2-core machine

Incoherent rays (random origins in [-0.5, 0.5]^3, uniform directions, 2^14 per batch, the
vmapped per-ray queries the renderer uses) against the 36-triangle box of
``test_bench_intersect.py``, icospheres of 80 … 5 120 triangles and a 192-triangle UV sphere.
Both structures of a mesh are timed alternately in the same rounds (paired), best of 5; the
table gives Mrays/s and the BVH / brute-force ratio for closest and any hit.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from test_bench_intersect import _mesh, _rays  # noqa: E402

from jaxrt.geometry.accel import AUTO_BVH_THRESHOLD, build_geometry  # noqa: E402
from jaxrt.geometry.triangle import any_hit, closest_hit  # noqa: E402

ROUNDS = 5


def meshes():
    yield "box", _mesh("36")
    for sub in (1, 2, 3, 4):  # 80, 320, 1 280, 5 120 triangles
        yield f"icosphere {sub}", trimesh.creation.icosphere(subdivisions=sub).triangles.astype(
            np.float32)
        if sub == 1:  # 192 triangles, between 80 and 320
            yield "uv sphere 8×8", trimesh.creation.uv_sphere(count=(8, 8)).triangles.astype(
                np.float32)


def main():
    o, d = _rays("incoherent")
    t_max = jnp.full((o.shape[0],), jnp.inf, jnp.float32)
    queries = {"closest": closest_hit, "any": any_hit}
    print(f"AUTO_BVH_THRESHOLD = {AUTO_BVH_THRESHOLD}; {o.shape[0]} incoherent rays")
    print("| mesh | triangles | query | brute Mrays/s | BVH Mrays/s | BVH / brute |")
    print("|---|---:|---|---:|---:|---:|")
    for name, tri in meshes():
        geo = {a: build_geometry(tri, accel=a) for a in ("brute", "bvh")}
        for q, fn in queries.items():
            run = {a: jax.jit(jax.vmap(fn, (None, 0, 0, 0))).lower(g, o, d, t_max).compile()
                   for a, g in geo.items()}
            best = dict.fromkeys(run, np.inf)
            for _ in range(ROUNDS):
                for a, f in run.items():
                    t0 = time.perf_counter()
                    jax.block_until_ready(f(geo[a], o, d, t_max))
                    best[a] = min(best[a], time.perf_counter() - t0)
            rate = {a: o.shape[0] / best[a] / 1e6 for a in run}
            print(f"| {name} | {len(tri)} | {q} | {rate['brute']:.2f} | {rate['bvh']:.2f} | "
                  f"{rate['bvh'] / rate['brute']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
