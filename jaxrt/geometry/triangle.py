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
- We instead evaluate every edge in ONE canonical order: the loops intersect each triangle
  with its vertices sorted lexicographically by their coordinates (:func:`canonical_vertices`,
  done once on the host), and the edge functions are ``E(v1, v2)``, ``−E(v0, v2)`` and
  ``E(v0, v1)`` with ``E(a, b) = a_x b_y − a_y b_x`` and ``a`` before ``b`` in that order. Two
  triangles that share an edge therefore evaluate the *same* expression on the *same* sheared
  coordinates, whatever XLA contracts into FMAs, and differ only in the sign they give it:
  the neighbours' edge functions are exact negations, so a ray through an edge is never lost.
  Coincident vertices of different meshes sort the same way (the order is by coordinates,
  not by index). It is cheaper than an error-free split of every operand into 12-bit halves
  (four exact partial products per term, ~45 more operations per ray and triangle).
- Hits with ``t ≤ 0`` are rejected by pbrt's conservative bound ``δt`` on the rounding error of
  ``t`` (pbrt-v4 §6.8.4), not by a fixed epsilon; degenerate (zero-area) triangles never hit.
  One correction to pbrt: the shear error ``δx, δy`` uses the raw (world-unit) z, not z scaled
  by ``1/d_z``; pbrt's form is right only for ``|d_z| ≈ 1`` and rejects genuine hits of a
  1e-8-thin slab along an unnormalised shadow ray of length 2e-4.

Brute-force form (on the 36-triangle box, 2^16 rays; benchmarks/README.md#brute-force-loop): a
``fori_loop`` over triangles of a per-ray kernel whose body has ONE output (the hit distance) beats
``vmap`` over triangles + ``argmin`` (~2× slower) and loops over blocks of 8/16 triangles (~8×
slower); an SoA vertex layout makes no difference beyond noise, and a ``while_loop`` with early exit
makes any-hit ~3× slower than the ``fori_loop``. The winner's barycentrics and normal are recovered
after the loop. Work on ``(N, 3)`` arrays sliced along the minor axis is ~100× slower under
``vmap``, hence the scalar-component kernel.

Closest hit carries ``(t, prim)`` as ONE complex number ``t + i·prim`` (prim exact as a float
below 2^24 triangles): the loop body then has one output and compiles to one kernel per
triangle, as any-hit does. With two carries XLA:CPU runs the test plus two update kernels and
three copies per triangle (and fuses the test into each update, three tests per triangle,
unless the loop is software-pipelined; ``optimization_barrier`` is removed by XLA's
``cse_barrier_expander`` before fusion, jax 0.10.2): one carry brings the closest hit close
to the cost of the test alone, images bit-identical.

Camera rays, which share their origin, have a cheaper query of their own on brute-force
scenes (:mod:`jaxrt.geometry.eye_rays`: the triangles' edge planes through the eye, formed once
per batch); it shares :func:`closest_loop` and :func:`finish_hit` with the loop here.

Four triangles per loop iteration (``unroll=4``): each iteration also runs a few tiny kernels
(the counter's copy and increment, the condition), so fewer iterations pay: the 256² MIS render
1.08× as fast per CPU-second as without unrolling (unroll 2: 1.03×), images bit-identical
(benchmarks/README.md#brute-force-loop).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.vecmath import computed_once, cross, device_array, dot
from jaxrt.geometry.bvh_build import validate_triangles


def gamma(n: int, dtype) -> np.generic:
    """pbrt's ``γ_n = n ε / (1 − n ε)`` with ``ε`` half the machine epsilon of ``dtype``.

    Bounds the relative error of ``n`` successive roundings (pbrt-v4 §6.8.1). A numpy scalar
    of ``dtype``, each operation rounded in ``dtype`` (the value XLA folded the same
    expression to when a program computed it): in a program it is a literal, not four
    operations traced per use (29 uses in the MIS pass).
    """
    eps, n = np.asarray(jnp.finfo(dtype).eps / 2, dtype), np.asarray(n, dtype)
    return (n * eps / (1 - n * eps))[()]


class TriangleHit(NamedTuple):
    """Closest intersection of one ray (batched Hits carry leading batch axes).

    Attributes:
        t: () hit distance in units of ``‖direction‖``; ``+inf`` on a miss.
        prim: () int32 index of the triangle hit; ``-1`` on a miss.
        b1, b2: () barycentrics of ``v1`` and ``v2``, ``p = (1−b1−b2) v0 + b1 v1 + b2 v2``;
            0 on a miss.
        ng: (3,) unit geometric normal ``normalize((v1 − v0) × (v2 − v0))`` (not flipped
            towards the ray); zero on a miss.
        p: (3,) hit point from the barycentrics, ``p_error`` (3,) a bound on its rounding
            error (:func:`surface_point`); zero on a miss.
    """

    t: Array
    prim: Array
    b1: Array
    b2: Array
    ng: Array
    p: Array
    p_error: Array


def surface_point(v0: tuple, v1: tuple, v2: tuple, b1: Array,
                  b2: Array) -> tuple[tuple, tuple]:
    """Point of a triangle from barycentrics, with a conservative bound on its rounding error.

    ``p = b0 v0 + b1 v1 + b2 v2`` with ``b0 = 1 − b1 − b2``, and per component
    ``p_error = γ₇ (|b0 v0| + |b1 v1| + |b2 v2|) + γ₂ (1 + |b1| + |b2|) |v0|``: pbrt's bound
    (pbrt-v4 §6.8.5) plus the rounding of ``b0``, which pbrt takes from the intersection test.

    Args:
        v0, v1, v2: the vertices as 3-tuples of scalars (components, so that under ``vmap``
            every operand is one contiguous vector and no (N, 3) array is formed).
        b1, b2: () barycentrics of ``v1`` and ``v2``.
    Returns:
        ``(p, p_error)``, each a 3-tuple of scalars; ``p_error ≥ 0`` bounds ``|p − p_exact|``
        componentwise.
    """
    b0 = 1 - b1 - b2
    dtype = b0.dtype
    g7, g2 = gamma(7, dtype), gamma(2, dtype)
    b0_scale = g2 * (1 + jnp.abs(b1) + jnp.abs(b2))
    p, err = [], []
    for k in range(3):
        a, b, c = b0 * v0[k], b1 * v1[k], b2 * v2[k]
        p.append(a + b + c)
        err.append(g7 * (jnp.abs(a) + jnp.abs(b) + jnp.abs(c)) + b0_scale * jnp.abs(v0[k]))
    return tuple(p), tuple(err)


def winner_hit(frame: RayFrame, t: Array, prim: Array, v: list, ng: Array,
               stored_barycentrics: bool = False) -> TriangleHit:
    """The :class:`TriangleHit` of the closest triangle, from its 9 vertex components ``v`` and
    normal.

    ``prim`` < 0 is a miss. Barycentrics and the hit point are computed for the winner only,
    once per ray, from values the loop's caller has already gathered.

    ``stored_barycentrics`` (static): store ``b1``, ``b2``
    (:func:`~jaxrt.core.vecmath.computed_once`) before the point is formed from them. For a hit that
    shading continues from (a path's next vertex): XLA:CPU computes each element of a (…, 3) output
    on its own, so the kernel that forms ``p`` (fused with the convex faces' select,
    :func:`jaxrt.scene.queries.intersect`) would evaluate the barycentrics, two divisions among
    them, once per component; stored, the path pass runs ~1.2× as fast per CPU-second
    (benchmarks/README.md#winner-record). Not for the camera's and the BSDF ray's emitter
    hits of the direct estimators, whose points have few consumers (storing does not pay).
    """
    hit = prim >= 0
    v0, v1, v2 = tuple(v[0:3]), tuple(v[3:6]), tuple(v[6:9])
    b1, b2 = barycentrics_frame(frame, v0, v1, v2)
    zero = jnp.zeros_like(t)
    keep = computed_once if stored_barycentrics else (lambda x: x)
    b1, b2 = keep(jnp.where(hit, b1, zero)), keep(jnp.where(hit, b2, zero))
    p, p_error = surface_point(v0, v1, v2, b1, b2)
    zero3 = jnp.zeros(3, t.dtype)
    return TriangleHit(t=jnp.where(hit, t, jnp.asarray(jnp.inf, t.dtype)),
               prim=jnp.where(hit, prim, -1).astype(jnp.int32), b1=b1, b2=b2,
               ng=jnp.where(hit, ng, zero3), p=jnp.where(hit, jnp.stack(p), zero3),
               p_error=jnp.where(hit, jnp.stack(p_error), zero3))


def miss_hit(dtype) -> TriangleHit:
    """The :class:`TriangleHit` of a ray that meets nothing (``t = inf``, ``prim = −1``, zeros)."""
    zero, zero3 = jnp.zeros((), dtype), jnp.zeros(3, dtype)
    return TriangleHit(t=jnp.asarray(jnp.inf, dtype), prim=jnp.int32(-1), b1=zero, b2=zero,
                       ng=zero3, p=zero3, p_error=zero3)


class RayFrame(NamedTuple):
    """Per-ray part of the watertight test, computed once and reused for every triangle.

    All fields are scalars (shape ``()``), so that under ``vmap`` each is one contiguous
    vector: XLA:CPU is ~100× slower on ``(N, 3)`` arrays sliced along the minor axis.

    Attributes:
        ox, oy, oz: ray origin permuted to ``(o[kx], o[ky], o[kz])``.
        sx, sy, sz: shear ``(−d_x/d_z, −d_y/d_z, 1/d_z)`` in the permuted frame.
        kz0, kz1: bool, ``kz == 0`` and ``kz == 1`` (``kz`` the axis of the largest ``|d|``;
            kx = kz+1, ky = kz+2 mod 3).
        valid: bool, False for a zero or non-finite direction, which hits nothing.
    """

    ox: Array
    oy: Array
    oz: Array
    sx: Array
    sy: Array
    sz: Array
    kz0: Array
    kz1: Array
    valid: Array


def _permute(x: Array, y: Array, z: Array, kz0: Array, kz1: Array) -> tuple[Array, Array, Array]:
    """Components ``(v[kx], v[ky], v[kz])`` with ``kx = kz+1, ky = kz+2 (mod 3)``, by selects."""
    # selects, not a gather: under vmap a per-ray gather is far slower than two selects
    return (jnp.where(kz0, y, jnp.where(kz1, z, x)),
            jnp.where(kz0, z, jnp.where(kz1, x, y)),
            jnp.where(kz0, x, jnp.where(kz1, y, z)))


def ray_frame(origin: Array, direction: Array) -> RayFrame:
    """Permutation and shear that map ray ``direction`` to +z (pbrt-v4 §6.5.3).

    Args:
        origin: (3,) ray origin.
        direction: (3,) ray direction, any non-zero length.
    Returns:
        The :class:`RayFrame`; ``valid`` is False when ``direction`` is zero or not finite.
    """
    ax, ay, az = jnp.abs(direction[0]), jnp.abs(direction[1]), jnp.abs(direction[2])
    # pbrt's MaxComponentIndex: ties resolved the same way for every triangle
    kz0 = (ax > ay) & (ax > az)
    kz1 = ~kz0 & (ay > az)
    dx, dy, dz = _permute(direction[0], direction[1], direction[2], kz0, kz1)
    ox, oy, oz = _permute(origin[0], origin[1], origin[2], kz0, kz1)
    valid = (dz != 0) & jnp.all(jnp.isfinite(direction))
    # the largest |component| is non-zero for any non-zero direction: no division by zero
    dz = jnp.where(valid, dz, jnp.ones_like(dz))
    return RayFrame(ox, oy, oz, -dx / dz, -dy / dz, 1 / dz, kz0, kz1, valid)


def _edge(ax: Array, ay: Array, bx: Array, by: Array) -> Array:
    """2D edge function ``a_x b_y − a_y b_x`` of the edge from ``a`` to ``b``.

    One expression for every edge, so that an edge shared by two triangles (whose vertices
    come in the canonical order) rounds identically in both, however it is contracted.
    """
    return ax * by - ay * bx


def _sheared(v: Array, f: RayFrame) -> tuple[Array, Array, Array]:
    """Vertex ``v`` in the ray's sheared frame: ``(x + S_x z, y + S_y z, z)`` (z not yet scaled)."""
    x, y, z = _permute(v[0], v[1], v[2], f.kz0, f.kz1)
    x, y, z = x - f.ox, y - f.oy, z - f.oz
    return x + f.sx * z, y + f.sy * z, z


def _max3(a: Array, b: Array, c: Array) -> Array:
    return jnp.maximum(jnp.maximum(a, b), c)


class _Raw(NamedTuple):
    """Unmasked results of the watertight test (internal)."""

    hit: Array
    t: Array
    b1: Array
    b2: Array


def _intersect_raw(frame: RayFrame, v0: Array, v1: Array, v2: Array, t_max: Array) -> _Raw:
    """The watertight test; ``b1, b2, t`` are valid only where ``hit`` (never NaN)."""
    dtype = frame.sz.dtype
    (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = (_sheared(v0, frame), _sheared(v1, frame),
                                                _sheared(v2, frame))
    # 2D edge functions, each edge evaluated from its earlier vertex in the canonical order
    # (watertight when the vertices come sorted, see the module notes); e1 = −e1c
    e0 = _edge(x1, y1, x2, y2)
    e1c = _edge(x0, y0, x2, y2)
    e2 = _edge(x0, y0, x1, y1)
    # inside iff all edge functions share a sign (zeros count as either: edges are shared)
    inside = ~(((e0 < 0) | (e1c > 0) | (e2 < 0)) & ((e0 > 0) | (e1c < 0) | (e2 > 0)))
    det = (e0 + e2) - e1c
    # the shear's rounding scales with the raw z (world units), not with z scaled to t units
    max_z_raw = _max3(jnp.abs(z0), jnp.abs(z1), jnp.abs(z2))
    # scaled hit distance, compared against t_max without dividing
    z0, z1, z2 = frame.sz * z0, frame.sz * z1, frame.sz * z2
    t_scaled = (e0 * z0 + e2 * z2) - e1c * z1
    in_range = jnp.where(det < 0, (t_scaled < 0) & (t_scaled >= t_max * det),
                         (t_scaled > 0) & (t_scaled <= t_max * det))
    # conservative rounding-error bound δt on t (pbrt-v4 §6.8.4): reject t ≤ δt, not t ≤ ε
    # = max |z_k| of the scaled z, exactly: rounding is monotone and symmetric in sign
    max_zt = jnp.abs(frame.sz) * max_z_raw
    max_xt = _max3(jnp.abs(x0), jnp.abs(x1), jnp.abs(x2))
    max_yt = _max3(jnp.abs(y0), jnp.abs(y1), jnp.abs(y2))
    delta_z = gamma(3, dtype) * max_zt
    # pbrt writes max_zt (scaled) here, which is the raw z only for |d_z| = 1: too loose for
    # short directions (rejects real hits) and too tight for long ones (unnormalised shadow rays)
    delta_x = gamma(5, dtype) * (max_xt + max_z_raw)
    delta_y = gamma(5, dtype) * (max_yt + max_z_raw)
    delta_e = 2 * (gamma(2, dtype) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt)
    max_e = _max3(jnp.abs(e0), jnp.abs(e1c), jnp.abs(e2))
    # pbrt's δt = bound · |1/det|; in_range gives t_scaled the sign of det, so t > δt is
    # |t_scaled| > bound: no division in the hit decision (any-hit loops need none at all)
    bound = 3 * (gamma(3, dtype) * max_e * max_zt + delta_e * max_zt + delta_z * max_e)
    hit = frame.valid & inside & (det != 0) & in_range & (jnp.abs(t_scaled) > bound)
    inv_det = 1 / jnp.where(det != 0, det, jnp.ones_like(det))
    return _Raw(hit, t_scaled * inv_det, -e1c * inv_det, e2 * inv_det)


def intersect_triangle_frame(frame: RayFrame, v0: Array, v1: Array, v2: Array,
                             t_max: Array) -> tuple[Array, Array, Array]:
    """:func:`intersect_triangle` for a ray already set up by :func:`ray_frame`.

    The brute-force and BVH loops use this so that the per-ray permutation and shear are
    computed once, not once per triangle. Degenerate triangles are *not* rejected here beyond
    ``det == 0`` (a sheared sliver of a zero-area triangle can have ``det ≠ 0``); callers
    reject them with a per-triangle flag precomputed on the host (``TriangleSet.valid``).
    Returns ``(t, b1, b2)``, ``t = inf`` and ``b1 = b2 = 0`` on a miss.
    """
    r = _intersect_raw(frame, v0, v1, v2, t_max)
    zero = jnp.zeros_like(r.t)
    return (jnp.where(r.hit, r.t, jnp.asarray(jnp.inf, r.t.dtype)),
            jnp.where(r.hit, r.b1, zero), jnp.where(r.hit, r.b2, zero))


def intersect_triangle_t(frame: RayFrame, v0: Array, v1: Array, v2: Array,
                         t_max: Array) -> Array:
    """TriangleHit distance only (``inf`` on a miss): the form for loops over many triangles.

    A loop body with one output compiles to one fused kernel; returning ``b1, b2`` too makes
    XLA:CPU duplicate the whole test into one fusion per output (4–7× slower).
    Recover the barycentrics of the winner afterwards with :func:`intersect_triangle_frame`.
    """
    r = _intersect_raw(frame, v0, v1, v2, t_max)
    return jnp.where(r.hit, r.t, jnp.asarray(jnp.inf, r.t.dtype))


def intersect_triangle_hit(frame: RayFrame, v0: Array, v1: Array, v2: Array,
                           t_max: Array) -> Array:
    """Whether the ray hits the triangle with ``δt < t ≤ t_max``: the any-hit form.

    The same decision as ``intersect_triangle_t(...) < inf``, computed without ``t`` (no
    division), so an any-hit loop body is the inside and range tests only.
    """
    return _intersect_raw(frame, v0, v1, v2, t_max).hit


def barycentrics_frame(frame: RayFrame, v0: Array, v1: Array, v2: Array) -> tuple[Array, Array]:
    """Barycentrics ``(b1, b2)`` of the ray's crossing of the triangle's plane, no inside test.

    Used after a loop has chosen the closest triangle, so that the winner's barycentrics
    exist even if a recompilation rounds its inside test differently; 0 when ``det == 0``.
    """
    r = _intersect_raw(frame, v0, v1, v2, jnp.asarray(jnp.inf, frame.sz.dtype))
    return r.b1, r.b2


def intersect_triangle(origin: Array, direction: Array, v0: Array, v1: Array, v2: Array,
                       t_max: Array) -> tuple[Array, Array, Array]:
    """Watertight intersection of one ray with one triangle (Woop et al. 2013; pbrt-v4 §6.5.3).

    Solves ``o + t d = (1 − b1 − b2) v0 + b1 v1 + b2 v2`` for ``0 < t ≤ t_max``,
    ``b1, b2 ≥ 0, b1 + b2 ≤ 1``, deciding inside/outside with sign-consistent edge functions so
    that a ray through an edge or vertex shared by two triangles hits at least one of them.
    That holds for the vertices in any order: they are tested sorted by ``(x, y, z)``, as the
    brute-force and BVH loops test them, so two triangles sharing an edge evaluate it by one
    expression (the module notes); hit or miss and ``t`` do not depend on the order given.

    Args:
        origin: (3,) ray origin.
        direction: (3,) ray direction (any non-zero length; components may be exactly 0).
        v0, v1, v2: (3,) triangle vertices, in any order; ``b1, b2`` refer to them as given.
        t_max: () largest accepted distance (may be ``inf``), in units of ``‖direction‖``.
    Returns:
        ``(t, b1, b2)``: scalars; ``t = +inf`` and ``b1 = b2 = 0`` on a miss. Zero-area
        triangles (``(v1 − v0) × (v2 − v0) = 0``) and hits with ``t ≤ δt`` (the conservative
        error bound on ``t``) are misses; no NaN for any finite input.
    """
    origin, direction, v0, v1, v2 = jnp.broadcast_arrays(origin, direction, v0, v1, v2)
    t_max = jnp.asarray(t_max, direction.dtype)
    # tested with the vertices in the canonical order, as the loops test them (the module
    # notes): a ray through an edge shared with a neighbour then hits one of the two
    given = jnp.stack([v0, v1, v2])
    order = canonical_order(given, jnp)
    s0, s1, s2 = given[order]
    t, c1, c2 = intersect_triangle_frame(ray_frame(origin, direction), s0, s1, s2, t_max)
    # the sorted vertices' weights (1 − c1 − c2, c1, c2) back to the vertices as given
    weights = jnp.stack([jnp.where(t < jnp.inf, 1 - c1 - c2, 0), c1, c2])
    b1, b2 = jnp.zeros_like(weights).at[order].set(weights)[1:]
    n = cross(v1 - v0, v2 - v0)
    # a zero-area triangle has no interior: reject before its sheared sliver can produce det ≠ 0
    degenerate = dot(n, n) == 0
    zero = jnp.zeros_like(t)
    return (jnp.where(degenerate, jnp.asarray(jnp.inf, t.dtype), t),
            jnp.where(degenerate, zero, b1), jnp.where(degenerate, zero, b2))


#: Brute-force sets hold fewer triangles than this: the closest-hit loop carries the index in a
#: float32 (exact below 2^24).
MAX_BRUTE_FORCE = 2**24

#: Triangles per brute-force loop iteration (``fori_loop`` unroll factor; see the module notes).
UNROLL = 4


class TriangleSet(NamedTuple):
    """A flat set of triangles, intersected by brute force; a pytree built by :func:`triangle_set`.

    Attributes:
        vertices: (F, 3, 3) the raw vertices ``v0, v1, v2`` of each triangle (world space).
        ng: (F, 3) unit geometric normals ``normalize((v1 − v0) × (v2 − v0))``; zero if degenerate.
        valid: (F,) bool, False for zero-area triangles, which are never hit.
        sorted_vertices: (F, 3, 3) the same vertices in the canonical order the loops test
            them in (:func:`canonical_vertices`; the hit's barycentrics refer to ``vertices``).
        columns: twelve (F,) arrays, the winner's record one scalar per array: ``v0``, ``v1``,
            ``v2`` (x, y, z each) and ``ng`` (:func:`finish_hit` gathers each at the winner).
    """

    vertices: Array
    ng: Array
    valid: Array
    sorted_vertices: Array
    columns: tuple

    @property
    def num_triangles(self) -> int:
        """Number of triangles ``F`` (static)."""
        return self.vertices.shape[0]

    def closest_hit(self, origin: Array, direction: Array, t_max: Array,
                    stored_barycentrics: bool = False) -> TriangleHit:
        """Nearest hit with ``0 < t ≤ t_max`` of one ray; see :func:`closest_hit`."""
        frame = ray_frame(origin, direction)
        dtype = frame.sz.dtype
        inf = jnp.asarray(jnp.inf, dtype)
        verts, valid = self.loop_tables(dtype)
        t_max = jnp.asarray(t_max, dtype)

        def t_of(i):
            v = verts[i]
            return jnp.where(valid[i], intersect_triangle_t(frame, v[0], v[1], v[2], t_max), inf)

        # the carry starts as a value of the ray (inf wherever it is valid or not), so that
        # under vmap it is batched from the start and JAX batches the body once, not twice
        t, prim = closest_loop(t_of, verts.shape[0], jnp.where(frame.valid, inf, inf))
        return finish_hit(self, frame, t, prim, stored_barycentrics)

    def any_hit(self, origin: Array, direction: Array, t_max: Array) -> Array:
        """Whether one ray hits any triangle with ``0 < t ≤ t_max``; see :func:`any_hit`."""
        frame = ray_frame(origin, direction)
        dtype = frame.sz.dtype
        verts, valid = self.loop_tables(dtype)
        t_max = jnp.asarray(t_max, dtype)

        def body(i, found):
            v = verts[i]
            return found | (valid[i] & intersect_triangle_hit(frame, v[0], v[1], v[2], t_max))

        # a value of the ray (False), batched under vmap from the start, as in closest_hit
        return lax.fori_loop(0, verts.shape[0], body, frame.valid & False,
                             unroll=loop_unroll(verts.shape[0]))

    def loop_tables(self, dtype, xp=jnp) -> tuple[Array, Array]:
        """Sorted vertices (F', 3, 3) and validity (F',) as the loops read them, padded with
        never-hit triangles to a multiple of the unroll factor ``F' = 4 ⌈F/4⌉`` (``xp``:
        ``jax.numpy`` in a program, ``numpy`` on the host).

        A remainder after the unrolled iterations costs more than whole iterations in the
        render: shadow rays over 22 triangles run the 256² MIS pass slower than over 32, and
        over the same 22 padded to 24 faster.
        """
        verts, valid = xp.asarray(self.sorted_vertices).astype(dtype), xp.asarray(self.valid)
        pad = -verts.shape[0] % UNROLL
        if pad:
            verts = xp.concatenate([verts, xp.zeros((pad, 3, 3), dtype)])
            valid = xp.concatenate([valid, xp.zeros(pad, valid.dtype)])
        return verts, valid


def closest_loop(t_of, count: int, start: Array) -> tuple[Array, Array]:
    """Smallest ``t_of(i)`` over ``i < count`` and the first index reaching it (−1: none < start).

    The brute-force closest-hit loop: ``t_of(i)`` is triangle i's hit distance (inf on a
    miss, which already rejects ``t > t_max``). The carry is ONE complex number
    ``t + i·prim`` (see the module notes), ``UNROLL`` tests per iteration; strictly closer
    wins, so ties keep the lowest index. ``start`` is the ray's ``inf``, a value of the ray
    so that under ``vmap`` the carry is batched from the start and the body batched once.
    """
    dtype = start.dtype

    def body(i, best):
        ti, t = t_of(i), jnp.real(best)
        return lax.complex(jnp.minimum(ti, t), jnp.where(ti < t, i.astype(dtype), jnp.imag(best)))

    best = lax.fori_loop(0, count, body, lax.complex(start, jnp.asarray(-1, dtype)),
                         unroll=loop_unroll(count))
    return jnp.real(best), jnp.imag(best).astype(jnp.int32)


def loop_unroll(count: int) -> int:
    """``UNROLL``, or 1 for a loop of at most ``UNROLL`` iterations, so that it stays a loop.

    A loop of one (unrolled) iteration is inlined by XLA, and its tests are then fused into
    every consumer of its result, per element: the TriangleHit's twelve gathers, (…, 3) selects.
    A direct BSDF ray's two emitters (padded to four) tested that way make the MIS pass several
    times slower; stored instead (:func:`~jaxrt.core.vecmath.computed_once`), the tests run in a
    scalar reduction kernel.
    """
    return UNROLL if count > UNROLL else 1


def finish_hit(geometry: TriangleSet, frame: RayFrame, t: Array, prim: Array,
               stored_barycentrics: bool = False) -> TriangleHit:
    """Build the :class:`TriangleHit` of triangle ``prim`` (−1: miss) at distance ``t`` (for
    ``stored_barycentrics`` see :func:`winner_hit`)."""
    k = jnp.maximum(prim, 0)
    # one gather per scalar component, each from an (F,) array of its own: under vmap each
    # is a contiguous (N,) vector (gathering (3, 3) rows makes this step cost more than the
    # whole loop), and the twelve are one kernel to XLA:CPU, which compiles a kernel once
    # however many identical copies a program holds (rows of one (12, F) table would be
    # twelve, a row offset apiece). Each is stored (computed_once): fused into their consumers
    # as XLA chooses, the BSDF ray's winner can be evaluated differently in a one-sample pass
    # (whose loop XLA inlines) than in longer ones, an ulp apart; stored, the 256² MIS pass
    # also runs faster (benchmarks/README.md#winner-record)
    c = [computed_once(column[k].astype(t.dtype)) for column in geometry.columns]
    return winner_hit(frame, t, prim, c[0:9], jnp.stack(c[9:12]), stored_barycentrics)


def host_triangles(triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate triangles and derive, on the host, what the intersection kernels store.

    Args:
        triangles: (F, 3, 3) array-like, ``triangles[f, k]`` the k-th vertex of triangle f.
    Returns:
        ``(stored, ng, valid)``: the vertices (F, 3, 3) in the dtype the device holds them in
        (float32 unless x64), the unit geometric normals ``(v1 − v0) × (v2 − v0) / ‖…‖`` (F, 3)
        in that dtype (formed in float64), and (F,) bool, False for zero area (a zero cross
        product in the input's precision; such triangles are never hit). Shared by
        :func:`triangle_set` and :func:`jaxrt.geometry.bvh.bvh_from_flat`, which need no device copy
        to compute them.
    Raises:
        ValueError: wrong shape, no triangles, or a non-finite vertex (names the triangle).
    """
    tri = validate_triangles(triangles)
    stored = tri.astype(jax.dtypes.canonicalize_dtype(tri.dtype))
    tri64 = tri.astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    valid = np.any(n != 0, axis=1)
    n64 = np.cross(tri64[:, 1] - tri64[:, 0], tri64[:, 2] - tri64[:, 0])
    length = np.linalg.norm(n64, axis=1, keepdims=True)
    ng = np.where(valid[:, None], n64 / np.where(length > 0, length, 1.0), 0.0)
    return stored, ng.astype(stored.dtype), valid


def triangle_set(triangles) -> TriangleSet:
    """Validate triangles on the host and pack them for brute-force intersection.

    Args:
        triangles: (F, 3, 3) array-like (numpy or jax), ``triangles[f, k]`` the k-th vertex of
            triangle f. Kept in its floating dtype (float32 unless x64 float64 is given).
    Returns:
        A :class:`TriangleSet`. Zero-area triangles are kept (indices stay those of the input)
        but flagged invalid and never hit.
    Raises:
        ValueError: wrong shape, no triangles, 2^24 or more (the closest-hit loop carries
            the index as a float32; build a BVH), or a non-finite vertex (names the triangle).
    """
    tri = np.asarray(triangles)
    if tri.ndim == 3 and tri.shape[0] >= MAX_BRUTE_FORCE:
        raise ValueError(f"{tri.shape[0]} triangles are too many to test by brute force "
                         f"(at most {MAX_BRUTE_FORCE - 1}); use a BVH (accel='bvh')")
    stored, ng, valid = host_triangles(tri)
    vertices = device_array(stored)
    record = np.concatenate([stored.reshape(-1, 9), ng], axis=1)  # finish_hit's columns
    # sorted as stored (float64 input may be stored as float32: two vertices that round to the
    # same float32 must sort alike in every triangle that shares them)
    return TriangleSet(vertices, device_array(ng), device_array(valid),
                       device_array(canonical_vertices(stored)),
                       tuple(device_array(np.ascontiguousarray(c)) for c in record.T))


def canonical_vertices(triangles: np.ndarray) -> np.ndarray:
    """Each triangle's vertices sorted lexicographically by ``(x, y, z)`` (host, any dtype).

    The order in which the intersection loops evaluate edge functions: two triangles that
    share an edge (or coincident vertices of different meshes) meet it in the same order, so
    their edge functions are exact negations (see the module notes). Shape (F, 3, 3) in,
    (F, 3, 3) out; the set of vertices, hence the triangle, is unchanged.
    """
    t = np.asarray(triangles)
    return np.take_along_axis(t, canonical_order(t)[..., None], axis=1)


def canonical_order(triangles, xp=np):
    """Indices that sort each triangle's vertices by ``(x, y, z)``: shape (…, 3, 3) in, (…, 3)
    out (``xp``: ``numpy`` on the host, ``jax.numpy`` in a program; a stable sort, so both
    give the same order)."""
    # lexsort keys: last is primary
    return xp.lexsort((triangles[..., 2], triangles[..., 1], triangles[..., 0]), axis=-1)


def closest_hit(geometry, origin: Array, direction: Array, t_max: Array,
                stored_barycentrics: bool = False) -> TriangleHit:
    """Nearest intersection of one ray with a geometry (``TriangleSet``, BVH, ...).

    Dispatches to ``geometry.closest_hit``, so any pytree class with that method plugs in.
    Finds the hit ``o + t d`` with the smallest ``t`` in ``(δt, t_max]`` (watertight; δt the
    rounding-error bound). Ties keep the lowest triangle index.

    Args:
        origin: (3,) ray origin.
        direction: (3,) direction, any non-zero length; ``t`` is in units of ``‖direction‖``.
        t_max: () upper bound on ``t`` (``inf`` for none).
        stored_barycentrics: (static) for a hit that shading continues from; see
            :func:`winner_hit`. Passed on only when True, so a geometry class without it
            serves the other queries.
    Returns:
        :class:`TriangleHit` (``t = inf``, ``prim = −1`` on a miss).
    """
    if stored_barycentrics:
        return geometry.closest_hit(origin, direction, t_max, stored_barycentrics=True)
    return geometry.closest_hit(origin, direction, t_max)


def any_hit(geometry, origin: Array, direction: Array, t_max: Array) -> Array:
    """Whether one ray hits anything with ``0 < t ≤ t_max`` (shadow/visibility rays).

    Dispatches to ``geometry.any_hit``. Equivalent to ``closest_hit(...).t <= t_max`` but
    cheaper: no barycentrics, no ordering.

    Returns:
        () bool.
    """
    return geometry.any_hit(origin, direction, t_max)
