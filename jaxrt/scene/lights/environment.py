"""Environment lights at infinity: constant radiance, or an importance-sampled lat-long map.

Lat-long convention (environment frame, +z up, as pbrt-v3's ``InfiniteAreaLight``): image
column ``x ∈ [0, 1)`` ↦ azimuth ``φ = 2π x``, row ``y ∈ [0, 1)`` (top row first) ↦ polar angle
``θ = π y``, direction ``(sin θ cos φ, sin θ sin φ, cos θ)``; world direction = ``R ·`` local,
with ``R`` the (3, 3) ``rotation`` (world from environment). Radiance is piecewise constant
per texel (nearest lookup), so the sampling density matches the integrand exactly.

Sampling the map draws ``(x, y)`` from a piecewise-constant 2D distribution with weights
``∝ luminance · sin θ`` (texel centres), then changes measure from the unit square to solid
angle: ``dω = sin θ dθ dφ = 2π² sin θ dx dy`` so ``p_ω = p_xy / (2π² sin θ)`` (PBR book 3rd ed.
§14.2.4). The constant environment is sampled uniformly on the sphere, ``p_ω = 1/4π``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import spherical_direction, spherical_phi, spherical_theta
from jaxrt.sampling.distributions import pc2d_from_values, pc2d_pdf, pc2d_sample
from jaxrt.sampling.warp import square_to_uniform_sphere
from jaxrt.scene.lights.records import (
    KindSample,
    as_rows,
    check_emission,
    luminance_np,
    safe_div,
    to_device,
)

#: Share of the environment map's sampling spread uniformly in solid angle (see environment_map).
TEXEL_FLOOR = 0.01


class ConstantEnvironment(NamedTuple):
    """Radiance ``L`` (3,) arriving from every direction."""

    radiance: Array


class EnvironmentMap(NamedTuple):
    """Lat-long environment map.

    image (H, W, 3) RGB radiance; distribution: the 2D piecewise-constant distribution of
    :mod:`jaxrt.sampling.distributions` over (x, y) ∈ [0, 1)² with weights ``luminance · sin θ``;
    rotation (3, 3) world-from-environment; mean_radiance (3,) the solid-angle average of the
    map (for power estimates).
    """

    image: Array
    distribution: object
    rotation: Array
    mean_radiance: Array


def constant_environment(radiance) -> ConstantEnvironment:
    """Uniform environment of RGB ``radiance`` (3,); negative or non-finite values are errors."""
    rad = as_rows(radiance, 3, 1, "environment radiance")
    check_emission(rad, "environment radiance")
    return ConstantEnvironment(to_device(rad[0]))


def environment_map(image, rotation=None) -> EnvironmentMap:
    """Environment light from an (H, W, 3) lat-long RGB radiance ``image`` (host array).

    ``rotation``: optional (3, 3) orthonormal world-from-environment matrix (identity: the map's
    +z is the world's +z). Texels are drawn with probability ∝ (luminance + TEXEL_FLOOR · mean
    luminance) · sin θ, so a black texel is still drawn (its derivative needs samples). A map
    of zero luminance everywhere gets a sin θ-only distribution (its ``li`` is then 0).
    """
    img = np.asarray(image, np.float64)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError("environment map: expected an (H, W, 3) image, "
                         f"got shape {np.shape(image)}")
    h, w, _ = img.shape
    bad = ~np.isfinite(img) | (img < 0)
    if bad.any():
        r, c, k = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"environment map texel (row {r}, column {c}, channel {k}) is negative "
                         f"or not finite: {img[r, c, k]}")
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise ValueError("environment map rotation must be a (3, 3) orthonormal matrix")
    sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
    lum = luminance_np(img)
    weights = lum * sin_theta[:, None]
    if not weights.sum() > 0:
        # A black map: keep a valid (solid-angle uniform) distribution; li is 0 anyway.
        weights = np.broadcast_to(sin_theta[:, None], (h, w))
    else:
        # every texel keeps a share (as lights do: table.SELECTION_FLOOR), so that the
        # derivative w.r.t. a black texel has samples of it
        weights = weights + TEXEL_FLOOR * np.mean(weights) * sin_theta[:, None]
    # Texel solid angle ∝ (cos θ_top − cos θ_bottom); used for the map's mean radiance.
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    texel_omega = (edges[:-1] - edges[1:]) * (2 * np.pi / w)
    mean = np.einsum("hwc,h->c", img, texel_omega) / (4 * np.pi)
    dist = pc2d_from_values(to_device(weights))
    return EnvironmentMap(to_device(img), dist, to_device(rot), to_device(mean))


def environment_power(env, scene_radius: float) -> np.ndarray:
    """Power proxy ``Φ = π · 4π r² · L̄`` (luminance of the mean radiance ``L̄``), shape (1,).

    The power an environment delivers depends on the scene; following pbrt-v4 we use the flux
    through a sphere of the scene's bounding radius ``r``.
    """
    mean = env.radiance if isinstance(env, ConstantEnvironment) else env.mean_radiance
    return np.array([4 * np.pi**2 * scene_radius**2 * float(luminance_np(np.asarray(mean)))])


# ---------------------------------------------------------------------------------------------
# Kernels.


def _texel(env: EnvironmentMap, x: Array, y: Array) -> Array:
    """Nearest-texel radiance at (x, y) ∈ [0, 1)² (clamped at the borders)."""
    h, w = env.image.shape[0], env.image.shape[1]
    col = jnp.clip(jnp.floor(x * w).astype(jnp.int32), 0, w - 1)
    row = jnp.clip(jnp.floor(y * h).astype(jnp.int32), 0, h - 1)
    return env.image[row, col]


def _to_square(env: EnvironmentMap, d: Array) -> tuple[Array, Array, Array]:
    """World direction → lat-long (x, y) and sin θ in the environment frame."""
    local = env.rotation.astype(d.dtype).T @ d
    theta = spherical_theta(local)
    x = spherical_phi(local) / (2 * jnp.pi)
    y = theta / jnp.pi
    # Wrap the φ = 2π edge back into [0, 1).
    x = jnp.where(x >= 1, x - 1, x)
    return x, y, jnp.sin(theta)


def le_constant(env: ConstantEnvironment, d: Array) -> Array:
    """Radiance arriving along ``d`` (pointing away from the scene) from a constant environment."""
    return env.radiance.astype(d.dtype) + jnp.zeros_like(d)


def le_map(env: EnvironmentMap, d: Array) -> Array:
    """Radiance arriving along unit ``d`` (world, pointing away from the scene) from the map."""
    x, y, _ = _to_square(env, d)
    return _texel(env, x, y).astype(d.dtype)


def sample_constant(env: ConstantEnvironment, j: Array, p: Array, u: Array) -> KindSample:
    """Uniform direction on the sphere: ``p_ω = 1/4π``, ``li = L``, ``dist = inf``."""
    del j
    wi = square_to_uniform_sphere(u.astype(p.dtype))
    one = jnp.ones_like(p[0])
    return KindSample(wi, jnp.full_like(one, jnp.inf), le_constant(env, wi),
                      one / (4 * jnp.pi))


def pdf_constant(env: ConstantEnvironment, j: Array, p: Array, wi: Array, p_light: Array) -> Array:
    """Density of :func:`sample_constant`: ``1/4π`` for every direction."""
    del env, j, wi, p_light
    return jnp.ones_like(p[0]) / (4 * jnp.pi)


def sample_map(env: EnvironmentMap, j: Array, p: Array, u: Array) -> KindSample:
    """Importance-sample the map: ``(x, y) ~ p_xy``, then ``p_ω = p_xy / (2π² sin θ)``."""
    del j
    xy, pdf_xy = pc2d_sample(env.distribution, u)
    xy = xy.astype(p.dtype)
    theta = jnp.pi * xy[1]
    phi = 2 * jnp.pi * xy[0]
    sin_theta = jnp.sin(theta)
    local = spherical_direction(sin_theta, jnp.cos(theta), phi)
    wi = env.rotation.astype(p.dtype) @ local
    pdf = safe_div(pdf_xy.astype(p.dtype), 2 * jnp.pi**2 * sin_theta)
    li = _texel(env, xy[0], xy[1]).astype(p.dtype)
    return KindSample(wi, jnp.full_like(pdf, jnp.inf), li, pdf)


def pdf_map(env: EnvironmentMap, j: Array, p: Array, wi: Array, p_light: Array) -> Array:
    """Density of :func:`sample_map` for direction ``wi`` (``p``, ``p_light`` unused)."""
    del j, p_light
    x, y, sin_theta = _to_square(env, wi.astype(p.dtype))
    pdf_xy = pc2d_pdf(env.distribution, jnp.stack([x, y])).astype(p.dtype)
    return safe_div(pdf_xy, 2 * jnp.pi**2 * sin_theta)

