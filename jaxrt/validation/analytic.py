"""Closed-form irradiance and reflected radiance: the oracles every estimator is tested against.

For a receiver at point ``p`` with unit normal ``n``, irradiance is the cosine-weighted
integral of incident radiance over the upper hemisphere,

    E(p, n) = ∫_{H²(n)} L_i(p, ω) max(0, n·ω) dω,

and for a Lambertian receiver of albedo ρ the reflected radiance is ``L_r = ρ E / π``
(the same in every outgoing direction). All functions are written for one receiver (vmap to
batch), take arrays of any float dtype and return that dtype.

Oracles (each verified against numerical quadrature in ``tests/validation/test_analytic.py``):

- :func:`polygon_irradiance`: a uniformly emitting polygon, Lambert's formula (1760) for the
  projected solid angle, after clipping the polygon to the receiver's horizon.
- :func:`point_light_irradiance`: ``E = I max(0, cos θ) / d²``.
- :func:`sphere_light_irradiance`: a uniformly emitting sphere, including the case where it
  is partly below the horizon (Snyder 1996, "Area light sources for real-time graphics").
- :func:`constant_environment_irradiance`: ``E = π L``.

Float32 stability (measured in the tests): Lambert's formula sums edge terms of size ℓ/d that
cancel to a result of size (ℓ/d)², so its relative error grows like ε·d/ℓ (ε = 6e-8 in float32):
about 1e-4 at d/ℓ = 1e3 and 1e-3 at d/ℓ = 1e4; beyond d/ℓ ≈ 1e5 float32 is useless and the
far-field :func:`polygon_irradiance_far` (point-source approximation, relative error
O((ℓ/d)²)) or float64 should be used. The sphere and point formulas have no cancellation.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array, lax

from jaxrt.core.vecmath import cross, dot, length, normalize, safe_sqrt


def _edge_angle(a: Array, b: Array) -> Array:
    """Angle between two (non-normalised) vectors, ``atan2(‖a×b‖, a·b)``: accurate at 0 and π."""
    return jnp.arctan2(length(cross(a, b)), dot(a, b))


def clip_polygon_to_plane(vertices: Array, p: Array, n: Array) -> tuple[Array, Array]:
    """Clip a convex or simple polygon to the half-space ``n·(x − p) ≥ 0`` (Sutherland–Hodgman).

    Args:
        vertices: (K, 3) polygon vertices in order.
        p, n: (3,) a point on the plane and its unit normal (the kept side).

    Returns:
        ``(clipped, valid)``: (2K, 3) vertices and a (2K,) boolean mask. Invalid slots repeat
        the previous valid vertex, so the closed polygon ``clipped`` (with its degenerate
        zero-length edges) has the same edge sums as the compact clipped polygon.
    """
    k = vertices.shape[0]
    d = dot(vertices - p, n)  # signed heights above the plane
    nxt = jnp.roll(vertices, -1, axis=0)
    d_nxt = jnp.roll(d, -1)
    inside = d >= 0
    inside_nxt = d_nxt >= 0
    # intersection of edge (v_k, v_k+1) with the plane, where the edge crosses it
    denom = d - d_nxt
    s = jnp.where(denom != 0, d / jnp.where(denom != 0, denom, 1), 0)
    x = vertices + s[:, None] * (nxt - vertices)
    # per edge: emit v_k if inside, then the crossing point if the edge crosses
    out = jnp.stack([vertices, x], axis=1).reshape(2 * k, 3)
    ok = jnp.stack([inside, inside != inside_nxt], axis=1).reshape(2 * k)
    # compact: fill invalid slots with the last valid vertex seen before them (or the first valid)
    idx = jnp.arange(2 * k)
    last_valid = lax.cummax(jnp.where(ok, idx, -1), axis=0)
    first_valid = jnp.argmax(ok)
    src = jnp.where(last_valid >= 0, last_valid, first_valid)
    return out[src], ok


def polygon_projected_solid_angle(vertices: Array, p: Array, n: Array) -> Array:
    """Projected solid angle ``∫ max(0, n·ω) dω`` of a planar polygon seen from ``p``.

    Lambert's formula after clipping to the horizon: with ``r_k = v_k − p``,

        Φ = ½ |Σ_k θ_k n·γ_k|,   θ_k = ∠(r_k, r_{k+1}),   γ_k = (r_k × r_{k+1}) / ‖r_k × r_{k+1}‖.

    The absolute value makes the result independent of the winding. Args: ``vertices`` (K, 3),
    ``p`` (3,), unit ``n`` (3,). Returns a scalar in steradians (projected measure), in [0, π].
    """
    clipped, ok = clip_polygon_to_plane(vertices, p, n)
    r = clipped - p
    r_nxt = jnp.roll(r, -1, axis=0)
    theta = _edge_angle(r, r_nxt)
    gamma = normalize(cross(r, r_nxt))
    total = 0.5 * jnp.sum(theta * dot(gamma, n))
    any_inside = jnp.any(ok)
    return jnp.where(any_inside, jnp.abs(total), jnp.zeros_like(total))


def polygon_irradiance(vertices: Array, radiance: Array, p: Array, n: Array) -> Array:
    """Irradiance at ``(p, n)`` from a polygon of uniform radiance ``radiance`` (3,) facing p.

    ``E = L · Φ`` with Φ from :func:`polygon_projected_solid_angle` (Lambert's formula, clipped
    to the horizon). The polygon is assumed to face the receiver (for a one-sided emitter
    facing away, the irradiance is zero: check the orientation yourself). Returns (3,).
    """
    return radiance * polygon_projected_solid_angle(vertices, p, n)


def polygon_irradiance_far(vertices: Array, radiance: Array, p: Array, n: Array) -> Array:
    """Far-field irradiance of a small planar polygon: ``E ≈ L · A |cos θ_l| max(0, cos θ) / d²``.

    Treats the polygon as a point source at its centroid; the relative error is O((ℓ/d)²) for a
    polygon of size ℓ at distance d, so it complements Lambert's formula where float32
    cancellation makes that one inaccurate (d/ℓ ≳ 1e4). ``vertices`` (K, 3) of a convex polygon.
    """
    c = jnp.mean(vertices, axis=0)
    v0 = vertices[0]
    # area vector of a planar polygon by a fan of triangles
    area_vec = 0.5 * jnp.sum(cross(vertices - v0, jnp.roll(vertices, -1, axis=0) - v0), axis=0)
    w = c - p
    d2 = dot(w, w)
    wn = normalize(w)
    cos_l = jnp.abs(dot(area_vec, wn))  # = A |cos θ_l|
    cos_r = jnp.maximum(dot(n, wn), 0)
    return radiance * cos_l * cos_r / d2


def point_light_irradiance(position: Array, intensity: Array, p: Array, n: Array) -> Array:
    """Irradiance from an isotropic point light: ``E = I · max(0, n·ω) / d²`` (3,)."""
    w = position - p
    d2 = dot(w, w)
    cos = jnp.maximum(dot(n, normalize(w)), 0)
    return intensity * cos / d2


def sphere_light_irradiance(center: Array, radius: Array, radiance: Array, p: Array,
                            n: Array) -> Array:
    """Irradiance from a sphere of uniform radiance, also when it is partly below the horizon.

    With ``sin²α = r²/d²`` (α the half-angle of the cone the sphere subtends) and ``cos ω = n·ĉ``
    (ĉ towards the centre):

    - fully above the horizon (ω ≤ π/2 − α): ``E = π L sin²α cos ω``;
    - fully below (ω ≥ π/2 + α): ``E = 0``;
    - straddling: the exact projected solid angle of the cap clipped by the horizon,
      ``E = L [ (cos ω · acos y − x sin ω √(1 − y²)) sin²α + atan(sin ω √(1 − y²) / x) ]``
      with ``x = √(1/sin²α − 1) = cos α / sin α`` and ``y = −x cos ω / sin ω``
      (Snyder 1996; the form used in Lagarde & de Rousiers 2014, eq. 19).

    Receivers inside the sphere see radiance L over the whole hemisphere: ``E = π L``.
    Returns (3,).
    """
    w = center - p
    d2 = dot(w, w)
    r2 = radius * radius
    inside = d2 <= r2
    sin2a = jnp.where(inside, jnp.ones_like(d2), r2 / jnp.where(inside, 1, d2))
    cos_w = jnp.clip(dot(n, normalize(w)), -1, 1)
    sin_w = safe_sqrt(1 - cos_w * cos_w)
    pi = jnp.asarray(jnp.pi, d2.dtype)
    above = cos_w * cos_w > sin2a
    full = pi * sin2a * jnp.maximum(cos_w, 0)
    # straddling the horizon
    x = safe_sqrt(1 / sin2a - 1)
    safe_sin_w = jnp.where(sin_w > 0, sin_w, 1)
    y = jnp.clip(-x * cos_w / safe_sin_w, -1, 1)
    s = sin_w * safe_sqrt(1 - y * y)
    part = (cos_w * jnp.arccos(y) - x * s) * sin2a + jnp.arctan2(s, x)
    e = jnp.where(above, full, jnp.maximum(part, 0))
    e = jnp.where(inside, pi, e)
    return radiance * e


def constant_environment_irradiance(radiance: Array) -> Array:
    """Irradiance under a constant environment of radiance L: ``E = ∫_{H²} L cos θ dω = π L``."""
    return jnp.pi * radiance


def lambertian_radiance(albedo: Array, irradiance: Array) -> Array:
    """Radiance reflected by a Lambertian surface, ``L_r = ρ E / π``, in every direction."""
    return albedo * irradiance / jnp.pi


def polygon_lamp_grid(k: int = 4, size: float = 0.12, height: float = 1.0,
                      spread: float = 1.6):
    """A many-light case with a closed form: ``k × k`` square lamps of half-width ``size``
    facing down (−z) at ``height``, centres on the grid ``[−spread, spread]²``, radiance
    ``1 … 40`` increasing across the grid (the bright ones far off to one side of the origin).

    Returns host arrays ``(quads (k², 4, 3), radiance (k²,))``; the reflection of a receiver
    below them is :func:`polygons_lambertian_radiance`.
    """
    import numpy as np

    xs = np.linspace(-spread, spread, k)
    quads, radiance = [], []
    for i, x in enumerate(xs):
        for j, y in enumerate(xs):
            radiance.append(1.0 + 39.0 * (i * k + j) / max(k * k - 1, 1))
            quads.append([[x - size, y - size, height], [x - size, y + size, height],
                          [x + size, y + size, height], [x + size, y - size, height]])
    return np.asarray(quads, np.float64), np.asarray(radiance, np.float64)


def polygons_lambertian_radiance(quads, radiance, albedo: float, p, n) -> float:
    """``L_r = ρ/π Σ_i L_i Ω⊥_i``: a Lambertian receiver at ``p`` (normal ``n``) under
    uniformly emitting polygons none of which occludes another, in float64 (Lambert's formula
    per polygon, :func:`polygon_projected_solid_angle`). ``quads`` (N, V, 3), ``radiance`` (N,)."""
    import jax
    import numpy as np

    with jax.enable_x64(True):
        psa = jax.vmap(polygon_projected_solid_angle, (0, None, None))(
            jnp.asarray(np.asarray(quads, np.float64)), jnp.asarray(np.asarray(p, np.float64)),
            jnp.asarray(np.asarray(n, np.float64)))
        return float(albedo / np.pi * np.sum(np.asarray(radiance) * np.asarray(psa)))
