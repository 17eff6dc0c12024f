"""Warps from the unit square to rendering domains, each with its density and inverse.

Every warp follows the Nori/Mitsuba triad

- ``square_to_X(u, *params) -> x``: maps ONE point ``u`` of [0, 1)^2 to the domain;
- ``square_to_X_pdf(x, *params) -> ()``: density of ``x`` in the domain's own measure
  (area on the disk, the triangle's barycentric plane and the square; solid angle on the
  sphere, hemisphere and cone), 0 outside the support;
- ``X_to_square(x, *params) -> u``: the inverse, where one exists in closed form.

Kernels are written for one sample and batched with ``jax.vmap``; constants take the
dtype of the input so float32 stays float32 and the same code is exact under x64. Local
frames have +z as the pole (the shading normal).

Microfacet normals live in :mod:`jaxrt.sampling.microfacet`, spherical triangles in
:mod:`jaxrt.sampling.spherical_triangle`; both are re-exported here. :data:`REGISTRY` lists every
warp with its domain and test parameters and drives the contract test suite.

References: Shirley & Chiu 1997 (concentric map); PBR book 3rd ed. §13.6; Mitsuba 3
``warp.h``; Nori ``warp.cpp``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import cos_sin_octant, cos_sin_turn, spherical_direction_turn, spherical_phi
from jaxrt.sampling.microfacet import (
    beckmann_d,
    beckmann_to_square,
    ggx_d,
    ggx_g1,
    ggx_lambda,
    ggx_to_square,
    square_to_beckmann,
    square_to_beckmann_pdf,
    square_to_ggx,
    square_to_ggx_pdf,
    square_to_ggx_visible,
    square_to_ggx_visible_pdf,
)
from jaxrt.sampling.spherical_triangle import (
    SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE,
    spherical_triangle_solid_angle,
    spherical_triangle_to_square,
    square_to_spherical_triangle,
    square_to_spherical_triangle_pdf,
)

__all__ = [
    "REGISTRY",
    "SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE",
    "WarpSpec",
    "beckmann_d",
    "beckmann_to_square",
    "cosine_hemisphere_to_square",
    "ggx_d",
    "ggx_g1",
    "ggx_lambda",
    "ggx_to_square",
    "phong_lobe_to_square",
    "spherical_triangle_solid_angle",
    "spherical_triangle_to_square",
    "square_to_beckmann",
    "square_to_beckmann_pdf",
    "square_to_cosine_hemisphere",
    "square_to_cosine_hemisphere_pdf",
    "square_to_ggx",
    "square_to_ggx_pdf",
    "square_to_ggx_visible",
    "square_to_ggx_visible_pdf",
    "square_to_phong_lobe",
    "square_to_phong_lobe_pdf",
    "square_to_spherical_triangle",
    "square_to_spherical_triangle_pdf",
    "square_to_tent",
    "square_to_tent_2d",
    "square_to_tent_2d_pdf",
    "square_to_tent_pdf",
    "square_to_uniform_cone",
    "square_to_uniform_cone_pdf",
    "square_to_uniform_cone_sin2",
    "square_to_uniform_cone_sin2_pdf",
    "square_to_uniform_disk",
    "square_to_uniform_disk_concentric",
    "square_to_uniform_disk_concentric_pdf",
    "square_to_uniform_disk_pdf",
    "square_to_uniform_hemisphere",
    "square_to_uniform_hemisphere_pdf",
    "square_to_uniform_sphere",
    "square_to_uniform_sphere_pdf",
    "square_to_uniform_triangle",
    "square_to_uniform_triangle_pdf",
    "tent_2d_to_square",
    "tent_to_square",
    "uniform_cone_sin2_to_square",
    "uniform_cone_to_square",
    "uniform_disk_concentric_to_square",
    "uniform_disk_to_square",
    "uniform_hemisphere_to_square",
    "uniform_sphere_to_square",
    "uniform_triangle_to_square",
]


def _azimuth_to_square(v: Array) -> Array:
    """``φ / 2π`` in [0, 1) for a local direction (inverse of ``φ = 2π u``)."""
    u = spherical_phi(v) / (2 * jnp.pi)
    # φ just below 2π can round to exactly 1 in float32; keep the result in [0, 1)
    return jnp.where(u >= 1, jnp.zeros_like(u), u)


def _one_minus_cos(v: Array) -> Array:
    """``1 − cos θ`` of a unit local direction, without cancellation near the pole.

    ``1 − z = (x² + y²) / (1 + z)`` for ``z > ½``: exact where ``z`` itself has rounded to 1.
    Below, ``1 − z`` directly (no cancellation there), which also keeps the result below 1 for
    every ``z > 0`` when ``v`` is a few ulps off unit length (``x² + y²`` can then exceed
    ``1 − z²``, and ``log1p(−(1 − cos θ))`` in the Phong pdf would be NaN).
    """
    s2 = v[0] * v[0] + v[1] * v[1]
    near_pole = v[2] > 0.5
    safe = jnp.where(near_pole, 1 + v[2], jnp.ones_like(v[2]))
    return jnp.where(near_pole, s2 / safe, 1 - v[2])


# ----------------------------------------------------------------------------- disks


def square_to_uniform_disk(u: Array) -> Array:
    """Uniform point on the unit disk by the polar map.

    ``r = √u₀, φ = 2π u₁``; the area element ``r dr dφ = π du₀ du₁/…`` gives density ``1/π``.
    Distorts strata near the centre (see the concentric map). Args: ``u`` (2,) in [0, 1)^2.
    Returns (2,) point ``(r cos φ, r sin φ)``. PBR 3rd ed. §13.6.2.
    """
    r = jnp.sqrt(u[0])
    c, s = cos_sin_turn(u[1])
    return jnp.stack([r * c, r * s])


def square_to_uniform_disk_pdf(p: Array) -> Array:
    """Density ``1/π`` per unit area inside the unit disk, 0 outside. ``p``: (2,)."""
    inside = p[0] * p[0] + p[1] * p[1] <= 1
    return jnp.where(inside, 1 / jnp.asarray(jnp.pi, p.dtype), jnp.zeros_like(p[0]))


def uniform_disk_to_square(p: Array) -> Array:
    """Inverse of :func:`square_to_uniform_disk`: ``(r², φ/2π)``. ``p``: (2,) → (2,)."""
    r2 = p[0] * p[0] + p[1] * p[1]
    u1 = _azimuth_to_square(jnp.stack([p[0], p[1], jnp.zeros_like(p[0])]))
    return jnp.stack([jnp.minimum(r2, jnp.ones_like(r2)), u1])


def square_to_uniform_disk_concentric(u: Array) -> Array:
    """Uniform point on the unit disk by Shirley & Chiu's concentric map.

    Maps concentric squares of ``[-1, 1]^2`` to concentric circles: for ``|a| > |b|``,
    ``r = a, φ = π/4 · b/a``, else ``r = b, φ = π/2 − π/4 · a/b`` (``a, b = 2u − 1``). Area
    preserving up to the constant ``π/4``, so the density is ``1/π`` and strata stay compact.
    Args: ``u`` (2,). Returns (2,). Shirley & Chiu 1997, "A low distortion map between disk
    and square"; PBR 3rd ed. §13.6.2.
    """
    a = 2 * u[0] - 1
    b = 2 * u[1] - 1
    one = jnp.ones_like(a)
    horizontal = jnp.abs(a) > jnp.abs(b)
    # NaN-safe ratios: the unused branch never divides by zero
    b_over_a = b / jnp.where(a != 0, a, one)
    a_over_b = a / jnp.where(b != 0, b, one)
    r = jnp.where(horizontal, a, b)
    # φ = π/4 · b/a, or π/2 − π/4 · a/b whose cosine and sine are those of π/4 · a/b swapped
    c, s = cos_sin_octant(jnp.where(horizontal, b_over_a, a_over_b))
    return jnp.stack([r * jnp.where(horizontal, c, s), r * jnp.where(horizontal, s, c)])


def square_to_uniform_disk_concentric_pdf(p: Array) -> Array:
    """Density ``1/π`` per unit area inside the unit disk (same as the polar map)."""
    return square_to_uniform_disk_pdf(p)


def uniform_disk_concentric_to_square(p: Array) -> Array:
    """Inverse of the concentric map: find the octant from ``φ`` and undo ``r, φ → a, b``.

    ``p``: (2,) on the unit disk. Returns (2,) in [0, 1]^2. Mitsuba 3 ``warp.h``.
    """
    x, y = p[0], p[1]
    r = jnp.sqrt(x * x + y * y)
    phi = jnp.arctan2(y, x)
    quarter_pi = jnp.asarray(jnp.pi / 4, x.dtype)
    # shift φ to [−π/4, 7π/4) so each quarter of the square is one interval
    phi = jnp.where(phi < -quarter_pi, phi + 8 * quarter_pi, phi)
    t = phi / quarter_pi
    q = jnp.floor((phi + quarter_pi) / (2 * quarter_pi))
    a = jnp.select([q <= 0, q == 1, q == 2], [r, -(t - 2) * r, -r], -(t - 6) * -r)
    b = jnp.select([q <= 0, q == 1, q == 2], [t * r, r, (t - 4) * -r], -r)
    u = jnp.stack([(a + 1) / 2, (b + 1) / 2])
    return jnp.clip(u, 0, 1)


# ------------------------------------------------------------------ spheres, hemispheres


def square_to_uniform_sphere(u: Array) -> Array:
    """Uniform direction on the unit sphere (Archimedes' hat-box projection).

    ``cos θ = 1 − 2u₀, φ = 2π u₁``; ``sin θ = 2√(u₀(1 − u₀))`` avoids cancellation at the
    poles. Density ``1/4π`` per steradian. Args: ``u`` (2,). Returns unit (3,).
    """
    cos_t = 1 - 2 * u[0]
    sin_t = 2 * jnp.sqrt(jnp.maximum(u[0] * (1 - u[0]), jnp.zeros_like(u[0])))
    return spherical_direction_turn(sin_t, cos_t, u[1])


def square_to_uniform_sphere_pdf(v: Array) -> Array:
    """Density ``1/4π`` per steradian everywhere on the sphere. ``v``: unit (3,)."""
    return jnp.ones_like(v[0]) / (4 * jnp.pi)


def uniform_sphere_to_square(v: Array) -> Array:
    """Inverse of :func:`square_to_uniform_sphere`: ``((1 − cos θ)/2, φ/2π)``."""
    return jnp.stack([jnp.clip((1 - v[2]) / 2, 0, 1), _azimuth_to_square(v)])


def square_to_uniform_hemisphere(u: Array) -> Array:
    """Uniform direction on the upper (+z) hemisphere.

    ``cos θ = u₀, φ = 2π u₁``, so ``dω = d(cos θ) dφ = 2π du``: density ``1/2π`` per
    steradian. Args: ``u`` (2,). Returns unit (3,) with ``z ≥ 0``.
    """
    cos_t = u[0]
    sin_t = jnp.sqrt(jnp.maximum((1 - cos_t) * (1 + cos_t), jnp.zeros_like(cos_t)))
    return spherical_direction_turn(sin_t, cos_t, u[1])


def square_to_uniform_hemisphere_pdf(v: Array) -> Array:
    """Density ``1/2π`` per steradian for ``z ≥ 0``, 0 below the horizon. ``v``: unit (3,)."""
    return jnp.where(v[2] >= 0, jnp.ones_like(v[2]) / (2 * jnp.pi), jnp.zeros_like(v[2]))


def uniform_hemisphere_to_square(v: Array) -> Array:
    """Inverse of :func:`square_to_uniform_hemisphere`: ``(cos θ, φ/2π)``."""
    return jnp.stack([jnp.clip(v[2], 0, 1), _azimuth_to_square(v)])


def square_to_cosine_hemisphere(u: Array) -> Array:
    """Cosine-weighted direction on the +z hemisphere by Malley's method.

    A uniform point of the disk (concentric map) lifted vertically onto the hemisphere,
    ``z = √(1 − x² − y²)``: the projected-solid-angle measure ``cos θ dω`` is the disk's
    area, so the density is ``cos θ / π`` per steradian (Nusselt's analog read backwards).
    Args: ``u`` (2,). Returns unit (3,). PBR 3rd ed. §13.6.3.
    """
    d = square_to_uniform_disk_concentric(u)
    z = jnp.sqrt(jnp.maximum(1 - d[0] * d[0] - d[1] * d[1], jnp.zeros_like(d[0])))
    return jnp.stack([d[0], d[1], z])


def square_to_cosine_hemisphere_pdf(v: Array) -> Array:
    """Density ``cos θ / π`` per steradian, 0 for ``z ≤ 0``. ``v``: unit (3,)."""
    return jnp.maximum(v[2], jnp.zeros_like(v[2])) / jnp.pi


def cosine_hemisphere_to_square(v: Array) -> Array:
    """Inverse of :func:`square_to_cosine_hemisphere`: project to the disk, undo the map."""
    return uniform_disk_concentric_to_square(v[:2])


# ----------------------------------------------------------------------------- cones


def _one_minus_cos_from_sin2(sin2_max: Array) -> Array:
    """``1 − cos θ = sin²θ / (1 + cos θ)`` for ``θ ≤ π/2``: exact for tiny caps."""
    return sin2_max / (1 + jnp.sqrt(jnp.maximum(1 - sin2_max, jnp.zeros_like(sin2_max))))


def _cone_sample(u: Array, one_minus_cos_max: Array) -> Array:
    """Uniform cone sample parametrised by ``1 − cos θmax`` (no cancellation for tiny caps)."""
    # 1 − cos θ is uniform on [0, 1 − cos θmax]
    om = u[0] * one_minus_cos_max
    sin_t = jnp.sqrt(jnp.maximum(om * (2 - om), jnp.zeros_like(om)))
    return spherical_direction_turn(sin_t, 1 - om, u[1])


def _cone_pdf(v: Array, one_minus_cos_max: Array) -> Array:
    """``1 / (2π (1 − cos θmax))`` inside the cap, 0 outside."""
    om = one_minus_cos_max
    # relative slack of a few ulps: samples at u₀ → 1 round onto the rim from either side
    eps = jnp.finfo(v.dtype).eps
    inside = (_one_minus_cos(v) <= om * (1 + 16 * eps)) & (om > 0)
    safe = jnp.where(om > 0, om, jnp.ones_like(om))
    return jnp.where(inside, 1 / (2 * jnp.pi * safe), jnp.zeros_like(om))


def _cone_to_square(v: Array, one_minus_cos_max: Array) -> Array:
    """Inverse of the cone sample: ``((1 − cos θ)/(1 − cos θmax), φ/2π)``."""
    om = one_minus_cos_max
    safe = jnp.where(om > 0, om, jnp.ones_like(om))
    u0 = jnp.where(om > 0, _one_minus_cos(v) / safe, jnp.zeros_like(om))
    return jnp.stack([jnp.clip(u0, 0, 1), _azimuth_to_square(v)])


def square_to_uniform_cone(u: Array, cos_max: Array) -> Array:
    """Uniform direction in the cone ``θ ≤ θmax`` about +z.

    ``1 − cos θ = u₀ (1 − cos θmax), φ = 2π u₁``; density ``1 / (2π (1 − cos θmax))`` per
    steradian (:func:`square_to_uniform_cone_pdf`). ``cos_max`` ∈ [−1, 1).

    Precision: a caller holding only ``cos θmax`` in float32 has already lost tiny caps
    (``cos 1e-4 == 1`` in float32, so the cap is empty). Callers that know ``sin²θmax`` (a
    sphere light seen from distance d: ``sin²θmax = r²/d²``) should use
    :func:`square_to_uniform_cone_sin2`, which is exact down to ``θmax ~ 1e-18``.
    Args: ``u`` (2,), ``cos_max`` scalar. Returns unit (3,). PBR 3rd ed. §13.6.4.
    """
    return _cone_sample(u, 1 - cos_max)


def square_to_uniform_cone_pdf(v: Array, cos_max: Array) -> Array:
    """Density ``1 / (2π (1 − cos θmax))`` per steradian inside the cone, 0 outside."""
    return _cone_pdf(v, 1 - cos_max)


def uniform_cone_to_square(v: Array, cos_max: Array) -> Array:
    """Inverse of :func:`square_to_uniform_cone`."""
    return _cone_to_square(v, 1 - cos_max)


def square_to_uniform_cone_sin2(u: Array, sin2_max: Array) -> Array:
    """Uniform direction in the cone about +z given ``sin²θmax`` (``θmax ≤ π/2``).

    Same distribution as :func:`square_to_uniform_cone` but parametrised so that tiny caps
    stay exact in float32: ``1 − cos θmax = sin²θmax / (1 + cos θmax)``. For a sphere light
    of radius r at distance d, ``sin²θmax = r²/d²``. Args: ``u`` (2,), ``sin2_max`` ∈ [0, 1].
    Returns unit (3,); density :func:`square_to_uniform_cone_sin2_pdf`.
    """
    return _cone_sample(u, _one_minus_cos_from_sin2(sin2_max))


def square_to_uniform_cone_sin2_pdf(v: Array, sin2_max: Array) -> Array:
    """Density ``1 / (2π (1 − cos θmax))`` per steradian inside the cone given ``sin²θmax``."""
    return _cone_pdf(v, _one_minus_cos_from_sin2(sin2_max))


def uniform_cone_sin2_to_square(v: Array, sin2_max: Array) -> Array:
    """Inverse of :func:`square_to_uniform_cone_sin2`."""
    return _cone_to_square(v, _one_minus_cos_from_sin2(sin2_max))


# ------------------------------------------------------------------------- triangle


def square_to_uniform_triangle(u: Array) -> Array:
    """Uniform barycentrics ``(b1, b2)`` on a triangle.

    ``b1 = 1 − √u₀, b2 = u₁ √u₀`` (PBR 3rd ed. §13.6.5). The density is 2 per unit area of
    the barycentric (b1, b2) triangle, whose area is 1/2; on the actual triangle (vertices
    p0, p1, p2) the point ``b0 p0 + b1 p1 + b2 p2`` has density ``1 / area``.
    Args: ``u`` (2,). Returns (2,).
    """
    su0 = jnp.sqrt(u[0])
    return jnp.stack([1 - su0, u[1] * su0])


def square_to_uniform_triangle_pdf(b: Array) -> Array:
    """Density 2 in the barycentric (b1, b2) plane inside the triangle, 0 outside."""
    # slack of a few ulps on the hypotenuse, where b1 + b2 rounds above 1
    eps = jnp.finfo(b.dtype).eps
    inside = (b[0] >= 0) & (b[1] >= 0) & (b[0] + b[1] <= 1 + 4 * eps)
    return jnp.where(inside, 2 * jnp.ones_like(b[0]), jnp.zeros_like(b[0]))


def uniform_triangle_to_square(b: Array) -> Array:
    """Inverse of :func:`square_to_uniform_triangle`: ``((1 − b1)², b2 / (1 − b1))``."""
    su0 = 1 - b[0]
    safe = jnp.where(su0 > 0, su0, jnp.ones_like(su0))
    u1 = jnp.where(su0 > 0, b[1] / safe, jnp.zeros_like(su0))
    return jnp.clip(jnp.stack([su0 * su0, u1]), 0, 1)


# ----------------------------------------------------------------------------- tents


def square_to_tent(u: Array) -> Array:
    """1D tent on [−1, 1] by inversion: density ``1 − |x|``.

    ``x = −1 + √(2u)`` for ``u < 1/2``, ``x = 1 − √(2 − 2u)`` otherwise. ``u``: scalar.
    Returns a scalar. PBR 3rd ed. §7.8.2 (the tent filter).
    """
    left = u < 0.5
    return jnp.where(left, -1 + jnp.sqrt(2 * u), 1 - jnp.sqrt(jnp.maximum(2 - 2 * u, 0 * u)))


def square_to_tent_pdf(x: Array) -> Array:
    """Density ``1 − |x|`` per unit length on [−1, 1], 0 outside."""
    return jnp.maximum(1 - jnp.abs(x), jnp.zeros_like(x))


def tent_to_square(x: Array) -> Array:
    """Inverse of :func:`square_to_tent`: ``(1 + x)²/2`` left of 0, ``1 − (1 − x)²/2`` right."""
    x = jnp.clip(x, -1, 1)
    return jnp.where(x < 0, (1 + x) * (1 + x) / 2, 1 - (1 - x) * (1 - x) / 2)


def square_to_tent_2d(u: Array) -> Array:
    """Separable 2D tent on [−1, 1]^2: density ``(1 − |x|)(1 − |y|)``. ``u`` (2,) → (2,)."""
    return jnp.stack([square_to_tent(u[0]), square_to_tent(u[1])])


def square_to_tent_2d_pdf(p: Array) -> Array:
    """Density ``(1 − |x|)(1 − |y|)`` per unit area on [−1, 1]^2, 0 outside."""
    return square_to_tent_pdf(p[0]) * square_to_tent_pdf(p[1])


def tent_2d_to_square(p: Array) -> Array:
    """Inverse of :func:`square_to_tent_2d`, coordinate by coordinate."""
    return jnp.stack([tent_to_square(p[0]), tent_to_square(p[1])])


# ----------------------------------------------------------------------------- Phong


def square_to_phong_lobe(u: Array, exponent: Array) -> Array:
    """Normalised cosine-power (Phong) lobe about +z.

    Density ``(n + 1)/(2π) cosⁿθ`` per steradian; its CDF in ``cos θ`` gives
    ``cos θ = u₀^{1/(n+1)}``. Computed as ``1 − cos θ = −expm1(log u₀ / (n + 1))`` so that
    ``sin θ`` stays accurate for sharp lobes (n up to 1e4 in float32).
    Args: ``u`` (2,), ``exponent`` n ≥ 0. Returns unit (3,). Lafortune & Willems 1994.
    """
    one_minus_cos = -jnp.expm1(jnp.log(u[0]) / (exponent + 1))
    sin_t = jnp.sqrt(jnp.maximum(one_minus_cos * (2 - one_minus_cos), 0 * one_minus_cos))
    return spherical_direction_turn(sin_t, 1 - one_minus_cos, u[1])


def _cos_power(v: Array, n: Array) -> Array:
    """``cosⁿθ = exp(n log cos θ)`` for ``z > 0``: no underflow-to-NaN, exact at n=0.

    ``log cos θ = log1p(−(1 − cos θ))`` near the pole (accurate for sharp lobes) and ``log z``
    below ``z = ½`` (finite for every ``z > 0``, even when ``1 − z`` rounds to 1).
    """
    om = _one_minus_cos(v)
    pos = v[2] > 0
    near_pole = v[2] > 0.5
    log_cos = jnp.where(near_pole, jnp.log1p(-jnp.where(near_pole, om, jnp.zeros_like(om))),
                        jnp.log(jnp.where(pos, v[2], jnp.ones_like(v[2]))))
    return jnp.where(pos, jnp.exp(n * log_cos), jnp.where(n == 0, 1 + 0 * om, 0 * om))


def square_to_phong_lobe_pdf(v: Array, exponent: Array) -> Array:
    """Density ``(n + 1)/(2π) cosⁿθ`` per steradian for ``z ≥ 0``, 0 below the horizon."""
    pdf = (exponent + 1) / (2 * jnp.pi) * _cos_power(v, exponent)
    return jnp.where(v[2] >= 0, pdf, jnp.zeros_like(pdf))


def phong_lobe_to_square(v: Array, exponent: Array) -> Array:
    """Inverse of :func:`square_to_phong_lobe`: ``(cos^{n+1}θ, φ/2π)``."""
    return jnp.stack([jnp.clip(_cos_power(v, exponent + 1), 0, 1), _azimuth_to_square(v)])


# -------------------------------------------------------------------------- registry


class WarpSpec(NamedTuple):
    """One warp for the contract suite and the chi-square harness.

    ``sample(u, *params)``, ``pdf(x, *params)`` and ``inverse(x, *params)`` (or None) are
    the public functions; ``domain`` names the chi-square harness domain
    (:mod:`jaxrt.validation.domains`), or ``("interval", lo, hi)`` / ``("square", lo, hi)`` for
    the tents on [−1, 1] and [−1, 1]^2; ``params`` is a tuple of
    parameter tuples (plain floats or nested float tuples, converted to arrays of the test
    dtype); ``dim`` is the output size (1 for the scalar tent).
    """

    name: str
    sample: Callable
    pdf: Callable
    inverse: Callable | None
    domain: str
    params: tuple
    dim: int


_NO_PARAMS = ((),)
# α = 1e-3 is too peaked for a chi-square grid; tests/sampling/test_warp.py checks it radially
_ALPHAS = ((0.1,), (0.5,), (1.0,))
# visible-normal parameters: (wo, α) with wo at normal incidence, 60° and grazing 85°
_WO_60 = (0.75, 0.0, 0.5)
_WO_85 = (0.0, 0.9961947, 0.0871557)
# spherical triangles relative to the shading point (vertex lengths deliberately uneven):
# two whose edges run along the chi-square grid (meridians and the equator, so no grid cell
# is cut by an edge), a generic one, one near a hemisphere, and a far tiny one (Ω < 1e-6 →
# the area-sampling fallback)
_TRI_OCTANT = ((0.0, 0.0, 2.0), (0.5, 0.0, 0.0), (0.0, 3.0, 0.0))
_TRI_WEDGE = ((0.0, 0.0, 0.7), (1.0, 0.0, 0.0), (-1.4142135, 1.4142135, 0.0))
_TRI_GENERIC = ((-0.5, -0.3, 1.0), (0.8, -0.2, 1.2), (0.1, 0.7, 0.9))
_TRI_LARGE = ((-3.0, -2.0, 0.05), (3.0, -2.0, 0.05), (0.0, 4.0, 0.05))
_TRI_TINY = ((0.0, 0.0, 1000.0), (0.5, 0.0, 1000.0), (0.0, 0.5, 1000.2))

REGISTRY: tuple[WarpSpec, ...] = (
    WarpSpec("uniform_disk", square_to_uniform_disk, square_to_uniform_disk_pdf,
             uniform_disk_to_square, "disk", _NO_PARAMS, 2),
    WarpSpec("uniform_disk_concentric", square_to_uniform_disk_concentric,
             square_to_uniform_disk_concentric_pdf, uniform_disk_concentric_to_square,
             "disk", _NO_PARAMS, 2),
    WarpSpec("uniform_sphere", square_to_uniform_sphere, square_to_uniform_sphere_pdf,
             uniform_sphere_to_square, "sphere", _NO_PARAMS, 3),
    WarpSpec("uniform_hemisphere", square_to_uniform_hemisphere,
             square_to_uniform_hemisphere_pdf, uniform_hemisphere_to_square, "hemisphere",
             _NO_PARAMS, 3),
    WarpSpec("cosine_hemisphere", square_to_cosine_hemisphere,
             square_to_cosine_hemisphere_pdf, cosine_hemisphere_to_square, "hemisphere",
             _NO_PARAMS, 3),
    WarpSpec("uniform_cone", square_to_uniform_cone, square_to_uniform_cone_pdf,
             uniform_cone_to_square, "sphere", ((0.5,), (0.9,), (-0.5,)), 3),
    WarpSpec("uniform_cone_sin2", square_to_uniform_cone_sin2,
             square_to_uniform_cone_sin2_pdf, uniform_cone_sin2_to_square, "sphere",
             ((0.75,), (0.19,), (1.0,)), 3),
    WarpSpec("uniform_triangle", square_to_uniform_triangle, square_to_uniform_triangle_pdf,
             uniform_triangle_to_square, "triangle", _NO_PARAMS, 2),
    WarpSpec("tent", square_to_tent, square_to_tent_pdf, tent_to_square, ("interval", -1.0, 1.0),
             _NO_PARAMS, 1),
    WarpSpec("tent_2d", square_to_tent_2d, square_to_tent_2d_pdf, tent_2d_to_square,
             ("square", -1.0, 1.0), _NO_PARAMS, 2),
    WarpSpec("phong_lobe", square_to_phong_lobe, square_to_phong_lobe_pdf,
             phong_lobe_to_square, "hemisphere", ((0.0,), (1.0,), (10.0,), (100.0,)), 3),
    WarpSpec("ggx", square_to_ggx, square_to_ggx_pdf, ggx_to_square, "hemisphere",
             _ALPHAS, 3),
    WarpSpec("beckmann", square_to_beckmann, square_to_beckmann_pdf, beckmann_to_square,
             "hemisphere", _ALPHAS, 3),
    WarpSpec("ggx_visible", square_to_ggx_visible, square_to_ggx_visible_pdf, None,
             "hemisphere", (((0.0, 0.0, 1.0), 0.5), (_WO_60, 0.3), (_WO_85, 0.8),
                            (_WO_60, 1.0)), 3),
    WarpSpec("spherical_triangle", square_to_spherical_triangle,
             square_to_spherical_triangle_pdf, spherical_triangle_to_square, "sphere",
             (_TRI_OCTANT, _TRI_WEDGE, _TRI_GENERIC, _TRI_LARGE, _TRI_TINY), 3),
)
