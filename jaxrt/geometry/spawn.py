"""Robust spawning of secondary and shadow rays from surface points (pbrt-v4 §6.8.5–6.8.6).

A hit point computed from barycentrics is off the true surface by a rounding error that grows
with the coordinates' magnitude. A ray leaving it can therefore re-hit its own triangle
("surface acne") or, offset by a fixed epsilon, leak through thin geometry at some scale and
self-intersect at another. Following pbrt, each hit point carries a conservative per-component
error bound ``p_error``; a ray origin is pushed along the geometric normal just past the box
``p ± p_error`` on the side the ray leaves to, and rounded one more float away. No fixed
epsilon appears anywhere, so the same code works for scenes of size 1e-4 … 1e5 placed up to
1e5 from the origin.

All functions are for one point (shapes ``(3,)``); batch with ``jax.vmap``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import dot
from jaxrt.geometry.triangle import gamma

#: Relative margin by which a shadow ray stops short of its (already offset) target:
#: ``t_max = 1 − SHADOW_EPSILON`` (pbrt-v4's ``ShadowEpsilon``).
SHADOW_EPSILON = 1e-4


def short_of(t: Array, shadow_epsilon: float = SHADOW_EPSILON) -> Array:
    """``t (1 − shadow_epsilon)``: a ray's parameter stopped a relative margin short of ``t``
    (a shadow ray's ``t_max`` for its target at ``t``; :func:`spawn_ray_to` has ``t = 1``)."""
    t = jnp.asarray(t)
    return t * (1 - jnp.asarray(shadow_epsilon, t.dtype))


def default_point_error(p: Array) -> Array:
    """Fallback error bound ``γ₇ |p|`` for a point given without one.

    Equals :func:`jaxrt.geometry.triangle.surface_point`'s bound when the triangle is small compared
    with its distance from the origin; prefer passing the real ``p_error`` (a huge triangle
    straddling the origin has a much larger error than ``|p|`` suggests).
    """
    return gamma(7, p.dtype) * jnp.abs(p)


def offset_ray_origin(p: Array, p_error: Array, n: Array, w: Array) -> Array:
    """Ray origin pushed off a surface past its error box, on the side ``w`` points to.

    ``d = |n| · p_error`` is the distance along ``n`` to the farthest corner of the box
    ``p ± p_error``; the origin is ``p ± d n`` (sign of ``w · n``), each component then moved
    one float further away from ``p`` (by adding ``max(⅝ ε |po|, tiny)``, which rounds to the
    next float) so the rounding of the sum cannot pull it back (pbrt-v4 §6.8.6,
    ``OffsetRayOrigin`` with ``NextFloatUp``/``Down``).

    Args:
        p: (3,) point on the surface.
        p_error: (3,) its error bound (:func:`~jaxrt.geometry.triangle.surface_point`).
        n: (3,) unit geometric normal (either orientation); zero for points not on a surface.
        w: (3,) direction the ray will leave in (any length).
    Returns:
        (3,) the offset origin.
    """
    d = dot(jnp.abs(n), p_error)
    offset = d * n
    offset = jnp.where(dot(w, n) < 0, -offset, offset)
    po = p + offset
    # exactly one more float away from p on each perturbed axis: for |po| in [2^e, 2^(e+1))
    # the step |po|·⅝ε lies in (½, 1¼] ulp (ε the machine epsilon), so po ± step rounds to the
    # neighbouring float, also across a binade edge; a zero moves by the smallest normal.
    # Five operations where jnp.nextafter takes ~17 per component (spawn kernels are a
    # noticeable part of a render).
    finfo = jnp.finfo(po.dtype)
    step = jnp.maximum(jnp.abs(po) * jnp.asarray(0.625 * finfo.eps, po.dtype),
                       jnp.asarray(finfo.tiny, po.dtype))
    return jnp.where(offset > 0, po + step, jnp.where(offset < 0, po - step, po))


def spawn_ray(p: Array, n: Array, w: Array, p_error: Array | None = None) -> tuple[Array, Array]:
    """Ray leaving surface point ``p`` in direction ``w`` without re-hitting its own surface.

    Args:
        p: (3,) surface point; n: (3,) unit geometric normal; w: (3,) direction (any length,
            returned unchanged, so ``t`` stays in units of ``‖w‖``).
        p_error: (3,) error bound of ``p`` from :func:`~jaxrt.geometry.triangle.surface_point`;
        default
            :func:`default_point_error`.
    Returns:
        ``(origin, direction)``, both (3,); trace it with ``t_max = inf``.
    """
    if p_error is None:
        p_error = default_point_error(p)
    return offset_ray_origin(p, p_error, n, w), w


def spawn_ray_to(p: Array, n: Array, q: Array, n_q: Array, p_error: Array | None = None,
                 q_error: Array | None = None,
                 shadow_epsilon: float = SHADOW_EPSILON) -> tuple[Array, Array, Array]:
    """Shadow (visibility) ray between two surface points, robust at both ends.

    The origin is ``p`` offset towards ``q`` and the target is ``q`` offset towards that origin
    (pbrt-v4 ``SpawnRayTo`` with two interactions); the direction is the **unnormalised**
    ``target − origin``, so ``t = 1`` is the target, and ``t_max = 1 − shadow_epsilon`` stops a
    relative margin short of it. ``any_hit(geometry, origin, direction, t_max)`` is then the
    occlusion test and never reports the endpoints' own triangles.

    Args:
        p, q: (3,) the two points; n, n_q: (3,) their unit geometric normals (zero for a point
            light or camera, which need no offset).
        p_error, q_error: (3,) error bounds from :func:`~jaxrt.geometry.triangle.surface_point`;
        default
            :func:`default_point_error`.
        shadow_epsilon: relative margin (pbrt's ShadowEpsilon).
    Returns:
        ``(origin, direction, t_max)``: (3,), (3,) unnormalised, () scalar.
    """
    if p_error is None:
        p_error = default_point_error(p)
    if q_error is None:
        q_error = default_point_error(q)
    origin = offset_ray_origin(p, p_error, n, q - p)
    target = offset_ray_origin(q, q_error, n_q, origin - q)
    return origin, target - origin, short_of(jnp.ones((), p.dtype), shadow_epsilon)
