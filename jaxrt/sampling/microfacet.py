"""Microfacet normal distributions (GGX, Beckmann): NDFs, Smith masking, and their warps.

All functions take ONE microfacet normal ``h`` (or direction ``w``) in the local frame with
+z as the macro-surface normal and an isotropic roughness ``α`` (1e-3 … 1). Trigonometry is
written in terms of ``x² + y²`` (= sin²θ for a unit vector) rather than ``1 − z²`` so that
very smooth surfaces (α = 1e-3, normals within 1e-3 rad of +z) stay exact in float32.

Re-exported from :mod:`jaxrt.sampling.warp`. References: Walter et al. 2007, "Microfacet models for
refraction through rough surfaces"; Heitz 2014, "Understanding the masking-shadowing
function"; Heitz 2018, "Sampling the GGX distribution of visible normals" (JCGT 7(4)).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import (
    cos_sin_turn,
    cross,
    dot,
    normalize,
    spherical_direction_turn,
    spherical_phi,
)


def _sin2(h: Array) -> Array:
    """``sin²θ = x² + y²`` of a unit local vector (no cancellation near the pole)."""
    return h[0] * h[0] + h[1] * h[1]


def _azimuth_to_square(v: Array) -> Array:
    """``φ / 2π`` in [0, 1)."""
    u = spherical_phi(v) / (2 * jnp.pi)
    return jnp.where(u >= 1, jnp.zeros_like(u), u)


# ------------------------------------------------------------------------------- GGX


def ggx_d(h: Array, alpha: Array) -> Array:
    """GGX (Trowbridge–Reitz) normal distribution ``D(h)``, per steradian of normals.

    ``D = α² / (π cos⁴θ (α² + tan²θ)²) = α² / (π (sin²θ + α² cos²θ)²)`` for ``cos θ > 0``,
    0 otherwise; normalised as ``∫ D cos θ dω = 1``. ``h``: unit (3,); ``alpha`` scalar.
    """
    a2 = alpha * alpha
    denom = _sin2(h) + a2 * h[2] * h[2]
    pos = (h[2] > 0) & (denom > 0)
    safe = jnp.where(pos, denom, jnp.ones_like(denom))
    return jnp.where(pos, a2 / (jnp.pi * safe * safe), jnp.zeros_like(denom))


def square_to_ggx(u: Array, alpha: Array) -> Array:
    """Microfacet normal distributed as ``D(h) cos θh`` (GGX), by inversion.

    ``tan²θ = α² u₀ / (1 − u₀)``, written as ``cos²θ = (1 − u₀)/(1 − u₀ + α² u₀)`` and
    ``sin²θ = α² u₀/(1 − u₀ + α² u₀)`` so neither cancels; ``φ = 2π u₁``.
    Args: ``u`` (2,), ``alpha`` scalar. Returns unit (3,). Walter et al. 2007, eq. 35–36.
    """
    a2u = alpha * alpha * u[0]
    denom = (1 - u[0]) + a2u
    cos_t = jnp.sqrt((1 - u[0]) / denom)
    sin_t = jnp.sqrt(a2u / denom)
    return spherical_direction_turn(sin_t, cos_t, u[1])


def square_to_ggx_pdf(h: Array, alpha: Array) -> Array:
    """Density ``D(h) cos θh`` per steradian of normals (GGX), 0 below the horizon."""
    return ggx_d(h, alpha) * jnp.maximum(h[2], jnp.zeros_like(h[2]))


def ggx_to_square(h: Array, alpha: Array) -> Array:
    """Inverse of :func:`square_to_ggx`: ``u₀ = tan²θ/(α² + tan²θ) = sin²/(sin² + α² cos²)``."""
    s2 = _sin2(h)
    denom = s2 + alpha * alpha * h[2] * h[2]
    safe = jnp.where(denom > 0, denom, jnp.ones_like(denom))
    u0 = jnp.where(denom > 0, s2 / safe, jnp.zeros_like(denom))
    return jnp.stack([jnp.clip(u0, 0, 1), _azimuth_to_square(h)])


def ggx_lambda(w: Array, alpha: Array) -> Array:
    """Smith's ``Λ(w)`` for GGX: ``(√(1 + α² tan²θ) − 1) / 2``.

    Written as ``a / (2 (√(1 + a) + 1))`` with ``a = α² tan²θ`` (no cancellation for smooth
    surfaces); ``+∞`` at grazing (``z = 0``) and for ``z < 0`` (back-facing). Heitz 2014 eq. 72.
    """
    z2 = w[2] * w[2]
    pos = w[2] > 0
    a = alpha * alpha * _sin2(w) / jnp.where(pos, z2, jnp.ones_like(z2))
    lam = a / (2 * (jnp.sqrt(1 + a) + 1))
    return jnp.where(pos, lam, jnp.full_like(lam, jnp.inf))


def ggx_g1(w: Array, alpha: Array) -> Array:
    """Smith masking ``G1(w) = 1 / (1 + Λ(w))`` for GGX; 0 for ``z ≤ 0``."""
    return 1 / (1 + ggx_lambda(w, alpha))


def square_to_ggx_visible(u: Array, wo: Array, alpha: Array) -> Array:
    """GGX microfacet normal visible from ``wo``, by Heitz's 2018 method.

    Stretch ``wo`` to the hemisphere configuration (α = 1), sample a point of the projected
    hemisphere (a disk whose far half is squashed by ``(1 + cos θo)/2``), lift it to the
    hemisphere and unstretch. Density :func:`square_to_ggx_visible_pdf`
    ``= G1(wo) max(0, wo·h) D(h) / cos θo``. Args: ``u`` (2,), ``wo`` unit (3,) with
    ``wo_z > 0``, ``alpha`` scalar. Returns unit (3,). Heitz 2018, JCGT 7(4), listing 1.
    """
    one = jnp.ones_like(u[0])
    zero = jnp.zeros_like(u[0])
    # stretch the view vector into the hemisphere (α = 1) configuration
    vh = normalize(jnp.stack([alpha * wo[0], alpha * wo[1], wo[2]]))
    # orthonormal basis around vh; any tangent when vh = +z
    lensq = vh[0] * vh[0] + vh[1] * vh[1]
    safe = jnp.sqrt(jnp.where(lensq > 0, lensq, one))
    t1 = jnp.where(lensq > 0, jnp.stack([-vh[1], vh[0], zero]) / safe,
                   jnp.stack([one, zero, zero]))
    t2 = cross(vh, t1)
    # uniform point of the unit disk (polar map)
    r = jnp.sqrt(u[0])
    c, s = cos_sin_turn(u[1])
    p1, p2 = r * c, r * s
    # squash the far half of the disk onto the projected hemisphere
    s = (1 + vh[2]) / 2
    p2 = (1 - s) * jnp.sqrt(jnp.maximum(1 - p1 * p1, zero)) + s * p2
    # lift to the hemisphere, then unstretch back to roughness α
    pz = jnp.sqrt(jnp.maximum(1 - p1 * p1 - p2 * p2, zero))
    nh = p1 * t1 + p2 * t2 + pz * vh
    return normalize(jnp.stack([alpha * nh[0], alpha * nh[1], jnp.maximum(nh[2], zero)]))


def square_to_ggx_visible_pdf(h: Array, wo: Array, alpha: Array) -> Array:
    """Density of visible normals, ``G1(wo) max(0, wo·h) D(h) / cos θo``, per steradian.

    0 where ``wo_z ≤ 0`` (no visible normals) or ``h`` is back-facing. Heitz 2018, eq. 3.
    """
    cos_o = wo[2]
    pos = cos_o > 0
    safe = jnp.where(pos, cos_o, jnp.ones_like(cos_o))
    pdf = ggx_g1(wo, alpha) * jnp.maximum(dot(wo, h), 0 * cos_o) * ggx_d(h, alpha) / safe
    return jnp.where(pos, pdf, jnp.zeros_like(pdf))


# -------------------------------------------------------------------------- Beckmann


def beckmann_d(h: Array, alpha: Array) -> Array:
    """Beckmann normal distribution ``D(h) = exp(−tan²θ/α²) / (π α² cos⁴θ)`` per steradian.

    Evaluated as ``exp(−tan²θ/α² − 4 log cos θ) / (π α²)`` so that grazing normals give 0
    rather than ``0/0``; 0 for ``cos θ ≤ 0``. Normalised as ``∫ D cos θ dω = 1``.
    """
    z = h[2]
    pos = z > 0
    safe_z = jnp.where(pos, z, jnp.ones_like(z))
    tan2 = _sin2(h) / (safe_z * safe_z)
    log_d = -tan2 / (alpha * alpha) - 4 * jnp.log(safe_z)
    return jnp.where(pos, jnp.exp(log_d) / (jnp.pi * alpha * alpha), jnp.zeros_like(z))


def square_to_beckmann(u: Array, alpha: Array) -> Array:
    """Microfacet normal distributed as ``D(h) cos θh`` (Beckmann), by inversion.

    ``tan²θ = −α² log(1 − u₀)`` (``log1p`` keeps small u₀ exact), ``φ = 2π u₁``.
    Args: ``u`` (2,), ``alpha`` scalar. Returns unit (3,). Walter et al. 2007, eq. 28–29.
    """
    tan2 = -alpha * alpha * jnp.log1p(-u[0])
    cos_t = 1 / jnp.sqrt(1 + tan2)
    sin_t = jnp.sqrt(tan2 / (1 + tan2))
    return spherical_direction_turn(sin_t, cos_t, u[1])


def square_to_beckmann_pdf(h: Array, alpha: Array) -> Array:
    """Density ``D(h) cos θh`` per steradian of normals (Beckmann), 0 below the horizon."""
    return beckmann_d(h, alpha) * jnp.maximum(h[2], jnp.zeros_like(h[2]))


def beckmann_to_square(h: Array, alpha: Array) -> Array:
    """Inverse of :func:`square_to_beckmann`: ``u₀ = 1 − exp(−tan²θ/α²)``."""
    z = h[2]
    pos = z > 0
    safe_z = jnp.where(pos, z, jnp.ones_like(z))
    tan2 = jnp.where(pos, _sin2(h) / (safe_z * safe_z), jnp.full_like(z, jnp.inf))
    u0 = -jnp.expm1(-tan2 / (alpha * alpha))
    return jnp.stack([jnp.clip(u0, 0, 1), _azimuth_to_square(h)])
