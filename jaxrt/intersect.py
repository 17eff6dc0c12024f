"""Watertight ray–triangle intersection and brute-force closest-hit / any-hit queries.

Everything is written for ONE ray (origin ``(3,)``, direction ``(3,)``, scalar ``t_max``) and
batched with ``jax.vmap``. Distances ``t`` are in units of ``‖direction‖`` (the direction need
not be unit length); ``t = +inf`` means a miss.

The intersection is the watertight algorithm of Woop, Benthin & Wald 2013, "Watertight
Ray/Triangle Intersection" (JCGT 2(1)), as written in pbrt-v4 §6.5.3: translate the triangle to
the ray origin, permute axes so the largest ``|d|`` component is z, shear so the ray becomes
+z, and decide inside/outside with 2D edge functions in that frame.

Floating-point notes (why this is watertight under XLA):

- XLA:CPU contracts ``a*b - c*d`` into a fused multiply-add (measured: 25% of random float32
  inputs round differently from the two-rounding form), so the plain edge function of an
  edge shared by two triangles is *not* the exact negation of its neighbour's, and a ray
  through the edge could miss both. pbrt falls back to double when an edge function is 0;
  under JAX without x64 there is no double.
- We instead evaluate every edge function from an error-free split of its operands:
  ``a = a_hi + a_lo`` by masking the low half of the significand (bit operations, no
  arithmetic that contraction could change), so all partial products are exact in float32
  (12-bit × 12-bit significands) and every rounding step is a sum or difference, which is
  exactly antisymmetric. The result has the sign of the exact real edge function unless
  ``|e| ≲ 2^-35 · |a b|`` (about what pbrt's double fallback gives), and the two triangles that
  share an edge compute exact negations, so a ray through an edge is never lost.
  In float64 the same split is exact but for ``a_lo·b_lo`` (rounded at 2^-106 relative).
- Hits with ``t ≤ 0`` are rejected by pbrt's conservative bound ``δt`` on the rounding error of
  ``t`` (pbrt-v4 §6.8.4), not by a fixed epsilon; degenerate (zero-area) triangles never hit.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array, lax

from jaxrt.vecmath import cross, dot


def gamma(n: int, dtype) -> Array:
    """pbrt's ``γ_n = n ε / (1 − n ε)`` with ``ε`` half the machine epsilon of ``dtype``.

    Bounds the relative error of ``n`` successive roundings (pbrt-v4 §6.8.1).
    """
    eps = jnp.asarray(jnp.finfo(dtype).eps / 2, dtype)
    n = jnp.asarray(n, dtype)
    return n * eps / (1 - n * eps)


class Hit(NamedTuple):
    """Closest intersection of one ray (batched Hits carry leading batch axes).

    Attributes:
        t: () hit distance in units of ``‖direction‖``; ``+inf`` on a miss.
        prim: () int32 index of the triangle hit; ``-1`` on a miss.
        b1, b2: () barycentrics of ``v1`` and ``v2``, ``p = (1−b1−b2) v0 + b1 v1 + b2 v2``;
            0 on a miss.
        ng: (3,) unit geometric normal ``normalize((v1 − v0) × (v2 − v0))`` (not flipped
            towards the ray); zero on a miss.
    """

    t: Array
    prim: Array
    b1: Array
    b2: Array
    ng: Array


class RayFrame(NamedTuple):
    """Per-ray part of the watertight test, computed once and reused for every triangle.

    Attributes:
        origin: (3,) ray origin.
        kz: () int32 axis of the largest ``|d|`` component (becomes z); kx = kz+1, ky = kz+2 mod 3.
        shear: (3,) ``(S_x, S_y, S_z) = (−d_x/d_z, −d_y/d_z, 1/d_z)`` in the permuted frame.
        valid: () bool, False for a zero (or non-finite) direction, which hits nothing.
    """

    origin: Array
    kz: Array
    shear: Array
    valid: Array


def _permute(v: Array, kz: Array) -> Array:
    """Components ``(v[kx], v[ky], v[kz])`` with ``kx = kz+1, ky = kz+2 (mod 3)``; no gather."""
    # selects instead of indexing: under vmap a per-ray gather is much slower than two selects
    return jnp.where(kz == 0, v[jnp.array([1, 2, 0])],
                     jnp.where(kz == 1, v[jnp.array([2, 0, 1])], v))


def ray_frame(origin: Array, direction: Array) -> RayFrame:
    """Permutation and shear that map ray ``direction`` to +z (pbrt-v4 §6.5.3).

    Args:
        origin: (3,) ray origin.
        direction: (3,) ray direction, any non-zero length.
    Returns:
        The :class:`RayFrame`; ``valid`` is False when ``direction`` is zero or not finite.
    """
    a = jnp.abs(direction)
    # pbrt's MaxComponentIndex: ties resolved the same way for every triangle
    kz = jnp.where(a[0] > a[1], jnp.where(a[0] > a[2], 0, 2),
                   jnp.where(a[1] > a[2], 1, 2)).astype(jnp.int32)
    d = _permute(direction, kz)
    valid = (d[2] != 0) & jnp.all(jnp.isfinite(direction))
    # the largest |component| is non-zero for any non-zero direction: no division by zero
    dz = jnp.where(valid, d[2], jnp.ones_like(d[2]))
    shear = jnp.stack([-d[0] / dz, -d[1] / dz, 1 / dz])
    return RayFrame(origin, kz, shear, valid)


def _split(a: Array) -> tuple[Array, Array]:
    """Error-free split ``a = hi + lo`` with hi, lo holding about half the significand each.

    ``hi`` is ``a`` with the low half of its stored significand bits cleared (12 of 23 in
    float32, 27 of 52 in float64); ``lo = a − hi`` is exact (Sterbenz). Pure bit masking, so
    no compiler contraction can alter it (unlike Dekker's ``c − (c − a)`` split).
    """
    if a.dtype == jnp.float64:
        bits = lax.bitcast_convert_type(a, jnp.uint64)
        hi_bits = bits & jnp.asarray(0xFFFFFFFFF8000000, jnp.uint64)
    else:
        bits = lax.bitcast_convert_type(a, jnp.uint32)
        hi_bits = bits & jnp.asarray(0xFFFFF000, jnp.uint32)
    hi = lax.bitcast_convert_type(hi_bits, a.dtype)
    return hi, a - hi


def _edge(ax: tuple, ay: tuple, bx: tuple, by: tuple) -> Array:
    """2D edge function ``a_x b_y − a_y b_x`` from split operands, exactly antisymmetric.

    All partial products are exact; the three brackets and the final sum round, each in a way
    that satisfies ``fl(−x) = −fl(x)``, so ``_edge(b, a) == −_edge(a, b)`` bit for bit.
    """
    (axh, axl), (ayh, ayl), (bxh, bxl), (byh, byl) = ax, ay, bx, by
    high = axh * byh - ayh * bxh
    mid = (axh * byl + axl * byh) - (ayh * bxl + ayl * bxh)
    low = axl * byl - ayl * bxl
    return (high + mid) + low


def _sheared(v: Array, frame: RayFrame) -> Array:
    """Vertex ``v`` in the ray's sheared frame: ``(x + S_x z, y + S_y z, z)`` (z not yet scaled)."""
    p = _permute(v - frame.origin, frame.kz)
    return jnp.stack([p[0] + frame.shear[0] * p[2], p[1] + frame.shear[1] * p[2], p[2]])


def intersect_triangle_frame(frame: RayFrame, v0: Array, v1: Array, v2: Array,
                             t_max: Array) -> tuple[Array, Array, Array]:
    """:func:`intersect_triangle` for a ray already set up by :func:`ray_frame`.

    The brute-force and BVH loops call this so that the per-ray permutation and shear are
    computed once, not once per triangle. Degenerate triangles are *not* rejected here beyond
    ``det == 0`` (a sheared sliver can have ``det ≠ 0``); callers that precompute a
    per-triangle validity flag (``TriangleSet``) reject them with it.
    """
    dtype = frame.shear.dtype
    zero = jnp.zeros((), dtype)
    inf = jnp.asarray(jnp.inf, dtype)
    p0, p1, p2 = _sheared(v0, frame), _sheared(v1, frame), _sheared(v2, frame)
    # 2D edge functions, each from the same split coordinates whichever triangle shares the edge
    s0 = (_split(p0[0]), _split(p0[1]))
    s1 = (_split(p1[0]), _split(p1[1]))
    s2 = (_split(p2[0]), _split(p2[1]))
    e0 = _edge(s1[0], s1[1], s2[0], s2[1])
    e1 = _edge(s2[0], s2[1], s0[0], s0[1])
    e2 = _edge(s0[0], s0[1], s1[0], s1[1])
    # inside iff all edge functions share a sign (zeros count as either: edges are shared)
    inside = ~(((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0)))
    det = e0 + e1 + e2
    # scaled hit distance, compared against t_max without dividing
    z0, z1, z2 = frame.shear[2] * p0[2], frame.shear[2] * p1[2], frame.shear[2] * p2[2]
    t_scaled = e0 * z0 + e1 * z1 + e2 * z2
    in_range = jnp.where(det < 0, (t_scaled < 0) & (t_scaled >= t_max * det),
                         (t_scaled > 0) & (t_scaled <= t_max * det))
    safe_det = jnp.where(det != 0, det, jnp.ones_like(det))
    inv_det = 1 / safe_det
    t = t_scaled * inv_det
    # conservative rounding-error bound δt on t (pbrt-v4 §6.8.4): reject t ≤ δt, not t ≤ ε
    max_zt = jnp.maximum(jnp.maximum(jnp.abs(z0), jnp.abs(z1)), jnp.abs(z2))
    max_xt = jnp.maximum(jnp.maximum(jnp.abs(p0[0]), jnp.abs(p1[0])), jnp.abs(p2[0]))
    max_yt = jnp.maximum(jnp.maximum(jnp.abs(p0[1]), jnp.abs(p1[1])), jnp.abs(p2[1]))
    delta_z = gamma(3, dtype) * max_zt
    delta_x = gamma(5, dtype) * (max_xt + max_zt)
    delta_y = gamma(5, dtype) * (max_yt + max_zt)
    delta_e = 2 * (gamma(2, dtype) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt)
    max_e = jnp.maximum(jnp.maximum(jnp.abs(e0), jnp.abs(e1)), jnp.abs(e2))
    delta_t = 3 * (gamma(3, dtype) * max_e * max_zt + delta_e * max_zt
                   + delta_z * max_e) * jnp.abs(inv_det)
    hit = frame.valid & inside & (det != 0) & in_range & (t > delta_t)
    return (jnp.where(hit, t, inf), jnp.where(hit, e1 * inv_det, zero),
            jnp.where(hit, e2 * inv_det, zero))


def intersect_triangle(origin: Array, direction: Array, v0: Array, v1: Array, v2: Array,
                       t_max: Array) -> tuple[Array, Array, Array]:
    """Watertight intersection of one ray with one triangle (Woop et al. 2013; pbrt-v4 §6.5.3).

    Solves ``o + t d = (1 − b1 − b2) v0 + b1 v1 + b2 v2`` for ``0 < t ≤ t_max``,
    ``b1, b2 ≥ 0, b1 + b2 ≤ 1``, deciding inside/outside with sign-consistent edge functions so
    that a ray through an edge or vertex shared by two triangles hits at least one of them.

    Args:
        origin: (3,) ray origin.
        direction: (3,) ray direction (any non-zero length; components may be exactly 0).
        v0, v1, v2: (3,) triangle vertices.
        t_max: () largest accepted distance (may be ``inf``), in units of ``‖direction‖``.
    Returns:
        ``(t, b1, b2)``: scalars; ``t = +inf`` and ``b1 = b2 = 0`` on a miss. Zero-area
        triangles (``(v1 − v0) × (v2 − v0) = 0``) and hits with ``t ≤ δt`` (the conservative
        error bound on ``t``) are misses; no NaN for any finite input.
    """
    origin, direction, v0, v1, v2 = jnp.broadcast_arrays(origin, direction, v0, v1, v2)
    t_max = jnp.asarray(t_max, direction.dtype)
    t, b1, b2 = intersect_triangle_frame(ray_frame(origin, direction), v0, v1, v2, t_max)
    n = cross(v1 - v0, v2 - v0)
    # a zero-area triangle has no interior: reject before its sheared sliver can produce det ≠ 0
    degenerate = dot(n, n) == 0
    zero = jnp.zeros_like(t)
    return (jnp.where(degenerate, jnp.asarray(jnp.inf, t.dtype), t),
            jnp.where(degenerate, zero, b1), jnp.where(degenerate, zero, b2))
