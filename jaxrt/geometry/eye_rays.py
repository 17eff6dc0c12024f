"""Closest hit for a batch of rays that share their origin: a pinhole camera's primary rays.

Every camera ray starts at the eye ``o``. A triangle seen from ``o`` is three planes through
``o`` (one per edge) and the plane of the triangle, and those do not depend on the ray: the
edge normals ``N_ab = (a − o) × (b − o)`` and the volume ``V = (v0 − o) · N_12`` are formed
once per batch of rays (:func:`origin_planes`; under ``vmap`` an unbatched origin leaves them
unbatched, so XLA computes them once per step, not once per lane), or once per scene on the
host (:func:`eye_planes`, which :class:`~jaxrt.scene.container.Scene` carries for its camera: the
render pass then compiles none of the table's ten kernels), and each triangle test is
then four dot products and six comparisons (:func:`closest_hit_from_origin`), where the
watertight test permutes, shears and bounds every triangle for every ray. On the 256²
Cornell box the camera rays' loop costs about half the watertight one and the MIS pass runs
~1.1× as fast per CPU-second; storing ``n / V`` so that the loop keeps the largest
``1/t = d · (n / V)`` (no division per triangle, ``t_max`` applied to the winner) gives a few
per cent more (benchmarks/README.md#eye-planes).

The vertices come in the canonical order of :func:`jaxrt.geometry.triangle.canonical_vertices`, so
two triangles that share an edge hold the same ``N`` for it, and the table is one
elementwise expression over every edge.

For a ray ``o + t d``:

- the edge functions are ``s_ab = d · N_ab``; the ray passes inside iff ``s_12``, ``−s_02``
  and ``s_01`` share a sign, up to their rounding error (below);
- their sum is ``det = d · n`` with ``n = (v1 − v0) × (v2 − v0)`` (the three ``N`` sum to
  ``n``), and the hit distance is ``t = V / det`` (the plane ``(p − v0) · n = 0``; ``V`` is
  ``(v0 − o) · n`` since ``(v0 − o) · N_01 = (v0 − o) · N_20 = 0``), in units of ``‖d‖``;
  the loop forms ``1/t = d · (n / V)`` from the stored ``n / V`` and keeps the largest;
- the barycentrics are ``b1 = −s_02 / det`` and ``b2 = s_01 / det``, as in the watertight
  test (:mod:`jaxrt.geometry.triangle` recomputes the winner's from its own frame).

Why it is watertight: each edge function is computed from a normal rounded on its own, so
near a vertex, where every edge through it is within rounding of the ray, exact negation of
shared edges is not enough: the rounded planes of a fan of triangles leave slivers between
them, and rays aimed exactly at a closed mesh's vertices escaped (4 of 642 from the centre of
an icosphere). The inside test is therefore conservative: the rounding error of ``d · N`` is at
most ``m = ‖d‖₁ γ₈ ‖|a| ×ₐ |b|‖₂`` (``×ₐ`` the cross product of absolute values, which bounds
``|N|`` componentwise; ``a = v_a − o``, ``b = v_b − o`` rounded once each, two roundings in
each component of the cross product, two in the dot product, with margin), and an edge
function within ``m`` of the right sign counts as right. A ray inside a triangle's cone in
exact arithmetic is then inside it in floats, so a closed mesh around the origin has no
crack; a ray within ``m`` of an edge may hit both neighbours (the nearer wins), a few ulp
outside one of them (:func:`jaxrt.geometry.triangle.winner_hit` computes the point from the winner's
barycentrics).

Why the hit is in front: ``V`` has an error bound ``γ₁₀ |v0 − o| · (|v1 − o| ×ₐ |v2 − o|)``,
and for a ray in the triangle's cone ``d = Σ λ_k (v_k − o)`` with ``λ_k ≥ 0``, so
``det = V Σ λ_k`` and ``|det| ≥ |V| ‖d‖ / max_k ‖v_k − o‖``. A triangle whose ``|V|`` exceeds
its own bound plus ``2 γ₁₀ max_k ‖v_k − o‖ Σ_edges ‖|a| ×ₐ |b|‖₂`` (which covers the rounding
of ``det``, and of ``d · (n / V)``, at most ``γ₄ ‖d‖ ‖n‖ / |V|``) therefore gets ``1/t`` with
its exact sign; any other has the origin nearly in its plane (an edge-on view from the eye: at
distance 1, a triangle of size 0.01 is seen edge-on within ~4e-4 rad) and is never hit
(``n / V`` is stored as 0), as the watertight test's ``δt`` rejects grazing hits.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import device_array
from jaxrt.geometry.triangle import (
    TriangleHit,
    TriangleSet,
    closest_loop,
    finish_hit,
    gamma,
    ray_frame,
)


def origin_planes(geometry: TriangleSet, origin: Array, xp=jnp) -> Array:
    """Each triangle's edge planes through ``origin`` and its volume seen from it.

    Args:
        geometry: the triangles (their canonically sorted vertices, padded as the loops read
            them: :meth:`~jaxrt.geometry.triangle.TriangleSet.loop_tables`).
        origin: (3,) the rays' common origin; the table is formed in its dtype.
        xp: ``jax.numpy`` (in a program) or ``numpy`` (on the host, :func:`eye_planes`): the
            same expression; numpy rounds every operation once, XLA may contract products
            into FMAs (fewer roundings), and the margins bound either.
    Returns:
        (F', 15): per triangle ``N_12``, ``N_02``, ``N_01`` (3 components each), the three
        edges' rounding margins for a direction of unit ``‖d‖₁``, and ``n / V`` (3); ``n / V``
        is 0 for a zero-area or padding triangle and for one whose plane passes too close to
        the origin to tell its side (never hit; see the module notes).
    """
    dtype = origin.dtype
    verts, valid = geometry.loop_tables(dtype, xp)
    rel = verts - origin  # (F', 3, 3): v_k − o, each vertex of each triangle
    # edges (v1, v2), (v0, v2), (v0, v1): the earlier vertex first in the canonical order
    a, b = rel[:, xp.array([1, 0, 0])], rel[:, xp.array([2, 2, 1])]  # (F', 3 edges, 3)
    # one elementwise expression for every edge of every triangle (watertight: module notes)
    normals = xp.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                        a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)
    # |N| ≤ |a| ×ₐ |b| componentwise: bounds each normal and the rounding of its computation
    aa, bb = xp.abs(a), xp.abs(b)
    n_abs = xp.stack([aa[..., 1] * bb[..., 2] + aa[..., 2] * bb[..., 1],
                      aa[..., 2] * bb[..., 0] + aa[..., 0] * bb[..., 2],
                      aa[..., 0] * bb[..., 1] + aa[..., 1] * bb[..., 0]], axis=-1)
    norm_abs = xp.sqrt(xp.sum(n_abs * n_abs, axis=-1))  # (F', 3 edges)
    # |d · N − d · N_exact| ≤ ‖d‖₁ · γ₈ ‖|a| ×ₐ |b|‖₂ (module notes); the loop's directions
    # have ‖d‖₁ = 1
    margin = gamma(8, dtype) * norm_abs
    v0, n12 = rel[:, 0], normals[:, 0]
    volume = xp.sum(v0 * n12, axis=-1)
    # V's own rounding, and room for det's: a ray in the triangle's cone has
    # |det| ≥ |V| ‖d‖ / max_k ‖v_k − o‖, more than det's rounding beyond this (module notes)
    reach = xp.sqrt(xp.max(xp.sum(rel * rel, axis=-1), axis=-1))
    bound = gamma(10, dtype) * (xp.sum(xp.abs(v0) * n_abs[:, 0], axis=-1)
                                + 2 * reach * xp.sum(norm_abs, axis=-1))
    keep = valid & (xp.abs(volume) > bound)
    # n / V with n = Σ N (rounded as the loop's det would be): then 1 / t = d · (n / V)
    n = (normals[:, 0] + normals[:, 2]) - normals[:, 1]
    inv = xp.where(keep[:, None], n / xp.where(keep, volume, 1)[:, None], 0)
    return xp.concatenate([normals.reshape(-1, 9), margin, inv], axis=1)


def eye_planes(geometry, camera) -> Array | None:
    """:func:`origin_planes` of a brute-force scene seen from its camera's eye, formed on the
    host (numpy) as :class:`~jaxrt.scene.container.Scene` is built or given a new camera or
    geometry.

    The render pass then reads the table as an input instead of forming it per pass: ten fewer
    distinct kernels to compile, a shorter XLA compile (benchmarks/README.md#eye-planes). Returns
    (F', 15) in the vertices' dtype, or None for a BVH or for arrays traced by a transformation (the
    program then forms it: the same triangles hit but for rays within rounding of an edge).
    """
    if not isinstance(geometry, TriangleSet):
        return None
    if any(isinstance(a, jax.core.Tracer)
           for a in (geometry.sorted_vertices, geometry.valid, camera.eye)):
        return None
    dtype = np.asarray(geometry.sorted_vertices).dtype
    return device_array(origin_planes(geometry, np.asarray(camera.eye, dtype), np))


def closest_hit_from_origin(geometry: TriangleSet, origin: Array, direction: Array,
                            t_max: Array, planes: Array | None = None) -> TriangleHit:
    """Nearest hit with ``0 < t ≤ t_max`` of one ray, tested by its origin's edge planes.

    The same query as :meth:`jaxrt.geometry.triangle.TriangleSet.closest_hit` (ties keep the lowest
    index, the :class:`~jaxrt.geometry.triangle.Hit` of the winner is built the same way), for rays
    that share ``origin``: batched with ``vmap`` over ``direction`` and ``t_max`` only, the
    per-triangle planes are formed once per batch (module notes). A batched ``origin`` gives
    the same hits at the cost of forming them per ray.

    Args:
        geometry: a brute-force :class:`~jaxrt.geometry.triangle.TriangleSet`.
        origin: (3,) ray origin; direction: (3,) any non-zero length; t_max: () (may be inf).
        planes: ``origin_planes(geometry, origin)`` when formed already (a scene's
            :func:`eye_planes`); formed here when None or of another dtype than ``direction``.
    Returns:
        :class:`~jaxrt.geometry.triangle.Hit` (``t = inf``, ``prim = −1`` on a miss).
    """
    dtype = direction.dtype
    origin = jnp.asarray(origin, dtype)
    table = (planes if planes is not None and planes.dtype == dtype
             else origin_planes(geometry, origin))
    inf = jnp.asarray(jnp.inf, dtype)
    # the edge functions' rounding scales with ‖d‖: the loop reads d / ‖d‖₁ (‖d‖₁ ≥ ‖d‖₂,
    # no sqrt), so each margin is the table's (the same direction for every triangle)
    scale = jnp.abs(direction[0]) + jnp.abs(direction[1]) + jnp.abs(direction[2])
    # per component: a (3,) quotient would be an (N, 3) array under vmap, sliced per use
    inv_scale = 1 / jnp.where(scale > 0, scale, 1)
    dx, dy, dz = direction[0] * inv_scale, direction[1] * inv_scale, direction[2] * inv_scale

    def minus_inv_t(i):
        r = table[i]
        s0 = dx * r[0] + dy * r[1] + dz * r[2]
        s1c = dx * r[3] + dy * r[4] + dz * r[5]
        s2 = dx * r[6] + dy * r[7] + dz * r[8]
        # inside iff s_12, −s_02, s_01 share a sign up to their rounding margin: an edge
        # within rounding of the ray counts for both its triangles (module notes)
        inside = (((s0 + r[9] >= 0) & (r[10] - s1c >= 0) & (s2 + r[11] >= 0))
                  | ((s0 - r[9] <= 0) & (s1c + r[10] >= 0) & (s2 - r[11] <= 0)))
        # 1/t = det / V > 0 (in front); 0 where V was dropped; false for NaN
        inv_t = dx * r[12] + dy * r[13] + dz * r[14]
        return jnp.where(inside & (inv_t > 0), -inv_t, inf)

    # the largest 1/t is the nearest hit: the loop keeps the smallest −1/t (ties: lowest
    # index); inf as a value of the ray, batched under vmap from the start (closest_loop)
    best, prim = closest_loop(minus_inv_t, table.shape[0], jnp.where(jnp.isnan(dx), inf, inf))
    t = -1 / (best * scale)
    # the nearest hit beyond t_max: none in range (t_max decided on t itself, to the ulp)
    prim = jnp.where((prim >= 0) & (t <= jnp.asarray(t_max, dtype)), prim, -1)
    return finish_hit(geometry, ray_frame(origin, direction), t, prim)
