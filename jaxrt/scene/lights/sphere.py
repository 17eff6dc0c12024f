"""Spherical area lights: sampled by the cone they subtend, intersected analytically.

A sphere of centre ``c`` and radius ``r`` emits constant radiance ``L`` outwards. Seen from a
point ``p`` outside it (distance ``d = ‖c − p‖ > r``) it subtends a cone of half-angle
``θ_max`` with ``sin² θ_max = r²/d²``; every direction in that cone hits the sphere, so uniform
cone sampling is exact and ``p_ω = 1 / (2π (1 − cos θ_max))`` (PBR book 4th ed. §6.2.4).
``1 − cos θ_max`` is computed as ``sin² θ_max / (1 + cos θ_max)`` so a sphere subtending 1e-7 sr
keeps its density in float32.

From inside the sphere (``d ≤ r``) every direction hits its inner side, which does not emit:
directions are then sampled uniformly on the unit sphere (``p_ω = 1/4π``) with ``li = 0``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import dot, length, safe_sqrt, to_world
from jaxrt.sampling.warp import (
    square_to_uniform_cone_sin2,
    square_to_uniform_cone_sin2_pdf,
    square_to_uniform_sphere,
)
from jaxrt.scene.lights.records import (
    KindSample,
    as_rows,
    check_emission,
    check_finite,
    luminance_np,
    safe_div,
    to_device,
)


class SphereLights(NamedTuple):
    """Emissive spheres. center (N, 3); radius (N,); radiance (N, 3) RGB, emitted outwards."""

    center: Array
    radius: Array
    radiance: Array


def sphere_light(center, radius, radiance) -> SphereLights:
    """Sphere light(s): ``center`` (3,) or (N, 3), ``radius`` scalar or (N,) > 0, ``radiance`` RGB.

    Raises ``ValueError`` for a radius ≤ 0 or non-finite, a non-finite centre, or a negative /
    non-finite radiance.
    """
    c = as_rows(center, 3, None, "sphere light center")
    n = c.shape[0]
    r = np.broadcast_to(np.asarray(radius, np.float64).reshape(-1), (n,)).copy()
    check_finite(c, "sphere light center")
    bad = ~(np.isfinite(r) & (r > 0))
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise ValueError(f"sphere light {i} has radius {r[i]}; the radius must be finite and > 0")
    rad = as_rows(radiance, 3, n, "sphere light radiance")
    check_emission(rad, "sphere light radiance")
    return SphereLights(to_device(c), to_device(r), to_device(rad))


def sphere_power(t: SphereLights) -> np.ndarray:
    """``Φ = π · 4π r² · L`` (luminance), shape (N,)."""
    r = np.asarray(t.radius, np.float64)
    return np.pi * 4 * np.pi * r**2 * luminance_np(np.asarray(t.radiance))


# ---------------------------------------------------------------------------------------------
# Kernels (one shading point / one ray).


def ray_sphere(o: Array, d: Array, center: Array, radius: Array) -> tuple[Array, Array, Array]:
    """Both roots ``t0 ≤ t1`` of ``‖o + t d − c‖ = r`` and whether the line hits.

    Numerically stable form of Haines et al. 2019 ("Precision improvements for ray/sphere
    intersection", Ray Tracing Gems ch. 7): the discriminant is ``a(r² − ‖f − (b/a) d‖²)`` with
    ``f = o − c``, ``b = f·d``, ``a = d·d``, which stays accurate for small or far spheres, and the
    roots are ``c/q`` and ``q/a`` with ``q = −(b + sign(b)√Δ)`` (no cancellation).
    ``d`` need not be unit. On a miss the roots are those of the tangent (Δ clamped to 0).
    """
    f = o - center
    a = dot(d, d)
    b = dot(f, d)
    safe_a = jnp.where(a > 0, a, jnp.ones_like(a))
    ell = f - (b / safe_a) * d
    disc = a * (radius * radius - dot(ell, ell))
    hit = (disc >= 0) & (a > 0)
    fl = length(f)
    # c = |f|² − r² as a product, so it keeps its relative precision when r ≪ |f|.
    c = (fl - radius) * (fl + radius)
    one = jnp.ones_like(b)
    q = -(b + jnp.where(b >= 0, one, -one) * safe_sqrt(disc))
    r0 = safe_div(c, jnp.abs(q)) * jnp.sign(q)
    r1 = q / safe_a
    return jnp.minimum(r0, r1), jnp.maximum(r0, r1), hit


def _cone(t: SphereLights, j: Array, p: Array):
    """Axis, distance and sin² θ_max of the cone sphere ``j`` subtends at ``p``."""
    center = t.center[j].astype(p.dtype)
    r = t.radius[j].astype(p.dtype)
    v = center - p
    d = length(v)
    axis = v / jnp.where(d > 0, d, jnp.ones_like(d))
    sin2_max = jnp.clip(safe_div(r * r, d * d), 0, 1)
    return center, r, axis, d, sin2_max


def _cone_pdf(sin2_max: Array) -> Array:
    """``1 / (2π (1 − cos θ_max))`` (the warp's density on its axis, always inside the cone)."""
    z = jnp.zeros_like(sin2_max)
    return square_to_uniform_cone_sin2_pdf(jnp.stack([z, z, z + 1]), sin2_max)


def sample_sphere(t: SphereLights, j: Array, p: Array, u: Array) -> KindSample:
    """Sample sphere ``j`` from ``p``: uniform in its cone outside; uniform sphere inside (li 0)."""
    center, r, axis, d, sin2_max = _cone(t, j, p)
    outside = d > r
    # Outside: a uniform direction in the cone about the axis towards the centre.
    w_cone = to_world(square_to_uniform_cone_sin2(u, jnp.where(outside, sin2_max, 0.5)), axis)
    w_inside = square_to_uniform_sphere(u)
    wi = jnp.where(outside, w_cone, w_inside)
    t0, t1, _ = ray_sphere(p, wi, center, r)
    # Outside the near root is the visible point; inside, the only positive root is the far one.
    dist = jnp.where(outside, jnp.maximum(t0, jnp.zeros_like(t0)), t1)
    pdf = jnp.where(outside, _cone_pdf(sin2_max), jnp.full_like(d, 1 / (4 * np.pi)))
    rad = t.radiance[j].astype(p.dtype)
    li = jnp.where(outside, rad, jnp.zeros_like(rad))
    return KindSample(wi, dist, li, pdf)


def pdf_sphere(t: SphereLights, j: Array, p: Array, wi: Array, p_light: Array) -> Array:
    """Density of :func:`sample_sphere` for a ``wi`` that hits sphere ``j`` (``p_light`` unused)."""
    del wi, p_light
    _, r, _, d, sin2_max = _cone(t, j, p)
    return jnp.where(d > r, _cone_pdf(sin2_max), jnp.full_like(d, 1 / (4 * np.pi)))


def le_sphere_local(t: SphereLights, j: Array, wo_light: Array, p_light: Array) -> Array:
    """Radiance leaving sphere ``j`` at ``p_light`` along ``wo_light``: ``L`` outwards, else 0."""
    n = p_light.astype(wo_light.dtype) - t.center[j].astype(wo_light.dtype)
    rad = t.radiance[j].astype(wo_light.dtype)
    return jnp.where(dot(n, wo_light) > 0, rad, jnp.zeros_like(rad))


def intersect_sphere_table(t: SphereLights, o: Array, d: Array, t_max: Array,
                           t_min: Array) -> tuple[Array, Array]:
    """Closest root in ``(t_min, t_max)`` over all spheres: ``(t, j)``, ``(inf, -1)`` on a miss."""

    def one(center, radius):
        t0, t1, hit = ray_sphere(o, d, center.astype(o.dtype), radius.astype(o.dtype))
        t_hit = jnp.where(t0 > t_min, t0, t1)
        ok = hit & (t_hit > t_min) & (t_hit < t_max)
        return jnp.where(ok, t_hit, jnp.full_like(t_hit, jnp.inf))

    ts = jax.vmap(one)(t.center, t.radius)
    j = jnp.argmin(ts).astype(jnp.int32)
    t_best = ts[j]
    return t_best, jnp.where(jnp.isfinite(t_best), j, jnp.int32(-1))
