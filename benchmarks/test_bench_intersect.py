"""Ray-casting throughput: brute force vs BVH vs Embree, coherent and incoherent rays.

Run: ``pytest benchmarks/test_bench_intersect.py --benchmark-enable`` (add ``-k 80k`` etc. to
select sizes). Each case records ``mrays_per_s``, ``compile_s`` (``.lower().compile()``) and
for the BVH ``build_s`` in ``benchmark.extra_info``. Queries are compiled with jaxrt's
``compiler_options()`` (as the renderer's programs are); Embree (``pip install embreex``) is
timed in the same run and its ratio recorded. Results: benchmarks/README.md#results-intersection.
"""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxrt.core.xla import compiler_options
from jaxrt.geometry.bvh import build_bvh
from jaxrt.geometry.triangle import any_hit, closest_hit, triangle_set

try:
    import embreex.mesh_construction as embree_mesh
    import embreex.rtcore_scene as embree_scene
except ImportError:  # optional "bench" extra
    embree_mesh = embree_scene = None

N_RAYS = 1 << 14
# Brute force costs F tests per ray: beyond ~20k triangles one batch takes minutes.
BRUTE_MAX = 25_000


def _box(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    p = [[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return [[p[f[0]], p[f[k]], p[f[k + 1]]] for f in faces for k in (1, 2)]


def _mesh(name):
    """Triangles (F, 3, 3) float32: a 36-triangle Cornell-like box or an icosphere."""
    if name == "36":
        tri = _box((-1, -1, -1), (1, 1, 1)) + _box((-0.6, -1, -0.5), (-0.1, 0.2, 0)) + _box(
            (0.1, -1, 0.1), (0.6, -0.4, 0.6))
        return np.asarray(tri, np.float32)
    sub = {"1k": 3, "20k": 5, "80k": 6, "1M": 8}[name]
    return trimesh.creation.icosphere(subdivisions=sub).triangles.astype(np.float32)


def _rays(kind, n=N_RAYS, seed=0):
    """Coherent: pinhole camera at z = −3 looking at the origin; incoherent: random origins
    inside the unit ball's bounds and uniform random directions."""
    rng = np.random.default_rng(seed)
    if kind == "coherent":
        side = int(np.sqrt(n))
        u, v = np.meshgrid(np.linspace(-0.5, 0.5, side), np.linspace(-0.5, 0.5, side))
        d = np.stack([u.ravel(), v.ravel(), np.ones(side * side)], axis=1)
        o = np.broadcast_to([0.0, 0.0, -3.0], d.shape)
    else:
        o = rng.uniform(-0.5, 0.5, (n, 3))
        d = rng.normal(size=(n, 3))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32)


_CACHE = {}


def _geometry(name, accel):
    key = (name, accel)
    if key not in _CACHE:
        tri = _mesh(name)
        t0 = time.perf_counter()
        geo = build_bvh(tri) if accel == "bvh" else triangle_set(tri)
        jax.block_until_ready(geo)
        _CACHE[key] = (tri, geo, time.perf_counter() - t0)
    return _CACHE[key]


def _query_fn(query):
    """The per-ray query vmapped over the batch, as the renderer calls it (either accel).

    Closest hit returns the whole TriangleHit (t, prim, barycentrics, normal), as Embree does."""
    return jax.vmap(closest_hit if query == "closest" else any_hit, (None, 0, 0, 0))


def _embree_rate(tri, o, d, query):
    """Embree (embreex, 1 call per batch) Mrays/s on the same rays, or None."""
    if embree_scene is None:
        return None
    scene = embree_scene.EmbreeScene()
    embree_mesh.TriangleMesh(scene, tri.astype(np.float32))
    o, d = np.asarray(o, np.float32), np.asarray(d, np.float32)
    mode = "INTERSECT" if query == "closest" else "OCCLUDED"
    scene.run(o, d, query=mode)
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        scene.run(o, d, query=mode)
        best = min(best, time.perf_counter() - t0)
    return len(o) / best / 1e6


@pytest.mark.parametrize("query", ["closest", "any"])
@pytest.mark.parametrize("kind", ["coherent", "incoherent"])
@pytest.mark.parametrize("accel", ["brute", "bvh"])
@pytest.mark.parametrize("name", ["36", "1k", "20k", "80k", "1M"])
def test_intersect_throughput(benchmark, name, accel, kind, query):
    tri = _mesh(name) if accel == "brute" else None
    if accel == "brute" and len(tri) > BRUTE_MAX:
        pytest.skip(f"brute force over {len(tri)} triangles: minutes per batch, not sensible")
    tri, geo, build_s = _geometry(name, accel)
    o, d = _rays(kind)
    t_max = jnp.full((o.shape[0],), jnp.inf, jnp.float32)
    t0 = time.perf_counter()
    # compiled as jaxrt compiles its own render programs (512-bit vectors: ~1.7x here)
    fn = jax.jit(_query_fn(query)).lower(geo, o, d, t_max).compile(compiler_options())
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(fn(geo, o, d, t_max))  # warm-up
    benchmark.pedantic(lambda: jax.block_until_ready(fn(geo, o, d, t_max)), rounds=5,
                       iterations=1)
    rate = o.shape[0] / benchmark.stats.stats.min / 1e6
    info = dict(triangles=len(tri), mrays_per_s=rate, compile_s=compile_s, rays=o.shape[0])
    if accel == "bvh":
        info["build_s"] = build_s
    embree = _embree_rate(tri, o, d, query)
    if embree is not None:
        info["embree_mrays_per_s"] = embree
        info["ratio_to_embree"] = rate / embree
    benchmark.extra_info.update(info)
    print(f"\n{name:>4} {accel:5} {kind:10} {query:7} {rate:8.3f} Mrays/s  compile "
          f"{compile_s:5.1f}s" + (f"  embree {embree:.2f}" if embree else ""))
