"""Delta lights: point, spot and directional.

A delta light reaches a shading point ``p`` along exactly one direction, so "sampling" it is
deterministic: the density is a Dirac delta, reported as ``pdf = 1`` (times the selection pmf)
with ``is_delta = True``, and ``li`` carries the radiance-like value that makes the usual
estimator ``f · li · |cos θ| / pdf`` correct (PBR book 4th ed., §12.1–12.4):

- point:        ``li = I / d²``
- spot:         ``li = I · smoothstep(cos θ; cos θ_outer, cos θ_inner) / d²``
- directional:  ``li = E`` (irradiance on a surface facing the light), ``dist = inf``.

Units: point and spot lights by intensity ``I`` (W/sr per RGB channel), directional lights by
irradiance ``E``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import dot
from jaxrt.scene.lights.records import (
    KindSample,
    as_rows,
    check_emission,
    check_finite,
    luminance_np,
    safe_div,
    to_device,
    unit_rows,
)


class PointLights(NamedTuple):
    """Isotropic point lights. position (N, 3); intensity (N, 3) RGB, W/sr."""

    position: Array
    intensity: Array


class SpotLights(NamedTuple):
    """Spot lights with a smoothstep falloff between two cones about ``axis``.

    position (N, 3); axis (N, 3) unit, the direction the spot points to; intensity (N, 3);
    cos_inner, cos_outer (N,): full intensity inside the inner cone, zero outside the outer one.
    """

    position: Array
    axis: Array
    intensity: Array
    cos_inner: Array
    cos_outer: Array


class DirectionalLights(NamedTuple):
    """Lights at infinity. direction (N, 3) unit, from the scene *towards* the light;
    irradiance (N, 3)."""

    direction: Array
    irradiance: Array


# ---------------------------------------------------------------------------------------------
# Host constructors (validate, then store in the default float dtype).


def point_light(position, intensity) -> PointLights:
    """Point light(s) at ``position`` ((3,) or (N, 3)) with RGB ``intensity`` ((3,) or (N, 3)).

    Raises ``ValueError`` for a non-finite position or a negative / non-finite intensity.
    """
    pos = as_rows(position, 3, None, "point light position")
    inten = as_rows(intensity, 3, pos.shape[0], "point light intensity")
    check_finite(pos, "point light position")
    check_emission(inten, "point light intensity")
    return PointLights(to_device(pos), to_device(inten))


def spot_light(position, axis, intensity, inner_angle, outer_angle) -> SpotLights:
    """One spot light at ``position`` pointing along ``axis`` (need not be unit).

    ``inner_angle`` and ``outer_angle`` are half-angles in radians with
    ``0 ≤ inner_angle ≤ outer_angle ≤ π``: full intensity within the inner cone, a smoothstep
    in ``cos θ`` down to zero at the outer cone (pbrt-v4's ``SpotLight``).
    """
    pos = as_rows(position, 3, 1, "spot light position")
    ax = unit_rows(as_rows(axis, 3, 1, "spot light axis"), "spot light axis")
    inten = as_rows(intensity, 3, 1, "spot light intensity")
    check_finite(pos, "spot light position")
    check_emission(inten, "spot light intensity")
    inner, outer = float(inner_angle), float(outer_angle)
    ok = np.isfinite(inner) and np.isfinite(outer) and 0 <= inner <= outer <= np.pi
    if not (ok and outer > 0):
        raise ValueError(
            "spot light cone angles must satisfy 0 <= inner_angle <= outer_angle <= pi and "
            f"outer_angle > 0; got inner_angle={inner}, outer_angle={outer}"
        )
    return SpotLights(to_device(pos), to_device(ax), to_device(inten),
                      to_device(np.array([np.cos(inner)])), to_device(np.array([np.cos(outer)])))


def directional_light(direction, irradiance) -> DirectionalLights:
    """Directional light(s); ``direction`` points from the scene towards the light (normalised)."""
    d = unit_rows(as_rows(direction, 3, None, "directional light direction"),
                  "directional light direction")
    e = as_rows(irradiance, 3, d.shape[0], "directional light irradiance")
    check_emission(e, "directional light irradiance")
    return DirectionalLights(to_device(d), to_device(e))


# ---------------------------------------------------------------------------------------------
# Power (host, luminance): drives power-proportional light selection.


def point_power(t: PointLights) -> np.ndarray:
    """``Φ = 4π I`` (luminance) per light, shape (N,)."""
    return 4 * np.pi * luminance_np(np.asarray(t.intensity))


def spot_power(t: SpotLights) -> np.ndarray:
    """``Φ ≈ 2π I (1 − (cos θ_inner + cos θ_outer)/2)`` (pbrt-v3's approximation), shape (N,)."""
    ci = np.asarray(t.cos_inner, np.float64)
    co = np.asarray(t.cos_outer, np.float64)
    return 2 * np.pi * luminance_np(np.asarray(t.intensity)) * (1 - 0.5 * (ci + co))


def directional_power(t: DirectionalLights, scene_radius: float) -> np.ndarray:
    """``Φ = π r² E``: the irradiance through the disk that bounds a scene of radius ``r``."""
    return np.pi * scene_radius**2 * luminance_np(np.asarray(t.irradiance))


# ---------------------------------------------------------------------------------------------
# Kernels (one shading point).


def smoothstep(x: Array, a: Array, b: Array) -> Array:
    """Hermite ``t²(3 − 2t)``, ``t = clamp((x − a)/(b − a), 0, 1)``; a step if ``a == b``."""
    width = b - a
    t = jnp.clip(safe_div(x - a, width), 0, 1)
    soft = t * t * (3 - 2 * t)
    return jnp.where(width > 0, soft, jnp.where(x >= a, jnp.ones_like(x), jnp.zeros_like(x)))


def _towards(position: Array, p: Array) -> tuple[Array, Array, Array]:
    """Unit direction, distance and squared distance from ``p`` to ``position``."""
    v = position - p
    d2 = dot(v, v)
    d = jnp.sqrt(d2)
    wi = v / jnp.where(d > 0, d, jnp.ones_like(d))
    return wi, d, d2


def sample_point(t: PointLights, j: Array, p: Array, u: Array) -> KindSample:
    """Point light ``j`` seen from ``p`` (``u`` unused): ``li = I / d²``, ``pdf = 1`` (delta)."""
    del u
    pos, inten = t.position[j].astype(p.dtype), t.intensity[j].astype(p.dtype)
    wi, d, d2 = _towards(pos, p)
    return KindSample(wi, d, safe_div(inten, d2), jnp.ones_like(d))


def spot_falloff(t: SpotLights, j: Array, wi: Array) -> Array:
    """Smoothstep falloff of spot ``j`` for a receiver in direction ``-wi`` from the light."""
    cos_theta = -dot(wi, t.axis[j].astype(wi.dtype))
    return smoothstep(cos_theta, t.cos_outer[j].astype(wi.dtype), t.cos_inner[j].astype(wi.dtype))


def sample_spot(t: SpotLights, j: Array, p: Array, u: Array) -> KindSample:
    """Spot light ``j`` seen from ``p``: ``li = I · falloff / d²``, ``pdf = 1`` (delta)."""
    del u
    wi, d, d2 = _towards(t.position[j].astype(p.dtype), p)
    li = safe_div(t.intensity[j].astype(p.dtype) * spot_falloff(t, j, wi), d2)
    return KindSample(wi, d, li, jnp.ones_like(d))


def sample_directional(t: DirectionalLights, j: Array, p: Array, u: Array) -> KindSample:
    """Directional light ``j``: ``wi`` its direction, ``li = E``, ``dist = inf``, ``pdf = 1``."""
    del u
    wi = t.direction[j].astype(p.dtype)
    one = jnp.ones_like(p[0])
    return KindSample(wi, jnp.full_like(one, jnp.inf), t.irradiance[j].astype(p.dtype), one)


def delta_pdf(p: Array) -> Array:
    """Solid-angle pdf of a delta light for any direction a BSDF could sample: 0."""
    return jnp.zeros_like(p[0])
