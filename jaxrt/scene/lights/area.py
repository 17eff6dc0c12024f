"""Emissive triangles (diffuse area lights), sampled by area or by solid angle.

A triangle ``(v0, v1, v2)`` emits constant radiance ``L`` on the side of its geometric normal
``n = (v1 − v0) × (v2 − v0)`` (right-hand rule), or on both sides if ``two_sided``.

Two samplers, chosen by the static ``triangle_sampling`` of the light table:

- ``"area"``: a uniform point ``y`` on the triangle (density ``1/A`` per unit area), converted
  to solid angle at ``p``: ``p_ω = ‖y − p‖² / (A |cos θ_y|)`` (PBR book §12.2.3).
- ``"solid_angle"``: a uniform direction in the spherical triangle the light subtends at ``p``
  (Arvo 1995), ``p_ω = 1 / Ω`` (with the warp's own consistent fallback for tiny Ω).

Both sample every direction that hits the (front or back of the) triangle; a one-sided light
seen from behind returns ``li = 0`` with the true, non-zero density, so ``pdf_li`` and
``sample_li`` always agree.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import area_to_solid_angle_pdf, device_array, dot, dot_components, length
from jaxrt.sampling.warp import (
    square_to_spherical_triangle,
    square_to_spherical_triangle_pdf,
    square_to_uniform_triangle,
)
from jaxrt.scene.lights.records import (
    KindSample,
    check_emission,
    check_finite,
    luminance_np,
    safe_div,
    to_device,
)

# Triangles with |e1 × e2| below this fraction of |e1|·|e2| are rejected as degenerate.
MIN_RELATIVE_AREA = 1e-9


class TriangleLights(NamedTuple):
    """Emissive triangles. vertices (N, 3, 3); radiance (N, 3); two_sided (N,) bool;
    prim (N,) int32, the index of each triangle in the scene geometry.

    Precomputed once on the host (float64, then stored in JAX's float), so that the kernels
    that only need them gather a row, not the vertices: normal (N, 3) unit
    ``(v1 − v0) × (v2 − v0)``; area (N,); diameter (N,) ``max_{i,j} ‖v_i − v_j‖_∞`` (bounds
    ``‖v_i − q‖_∞`` for every point ``q`` of the triangle).
    """

    vertices: Array
    radiance: Array
    two_sided: Array
    prim: Array
    normal: Array
    area: Array
    diameter: Array


def triangle_lights(vertices, radiance, prims, two_sided=False) -> TriangleLights:
    """Emissive triangles from host arrays.

    Args:
      vertices: (N, 3, 3) world-space vertices (or (3, 3) for one triangle).
      radiance: (N, 3) or (3,) RGB radiance, non-negative.
      prims: (N,) int, index of each triangle in the scene's triangle list (for the estimator's
        "which light did the BSDF ray hit" lookup).
      two_sided: bool or (N,) bool.

    Raises ``ValueError`` for non-finite vertices, zero-area triangles, negative or non-finite
    radiance, or mismatched lengths.
    """
    v = np.asarray(vertices, np.float64)
    if v.ndim == 2:
        v = v[None]
    if v.ndim != 3 or v.shape[1:] != (3, 3):
        raise ValueError("triangle light vertices: expected shape (N, 3, 3), "
                         f"got {np.shape(vertices)}")
    n = v.shape[0]
    check_finite(v.reshape(n, 9), "triangle light vertices")
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=-1)
    scale = np.linalg.norm(e1, axis=-1) * np.linalg.norm(e2, axis=-1)
    bad = ~(twice_area > MIN_RELATIVE_AREA * scale) | (twice_area == 0)
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise ValueError(f"triangle light {i} has zero area (degenerate vertices {v[i].tolist()})")
    rad = np.asarray(radiance, np.float64)
    rad = np.broadcast_to(rad, (n, 3)) if rad.shape in ((3,), (1, 3)) else rad
    if rad.shape != (n, 3):
        raise ValueError(f"triangle light radiance: expected shape ({n}, 3) or (3,), "
                         f"got {np.shape(radiance)}")
    check_emission(rad, "triangle light radiance")
    prim = np.asarray(prims)
    prim = np.broadcast_to(prim, (n,)) if prim.ndim == 0 else prim
    if prim.shape != (n,) or not np.issubdtype(prim.dtype, np.integer):
        raise ValueError(f"triangle light prims: expected ({n},) integers, "
                         f"got {np.shape(prims)} {prim.dtype}")
    two = np.broadcast_to(np.asarray(two_sided, bool), (n,))
    cross64 = np.cross(e1, e2)
    diameter = np.max(np.abs(v[:, :, None, :] - v[:, None, :, :]), axis=(1, 2, 3))
    return TriangleLights(to_device(v), to_device(rad), device_array(two),
                          device_array(prim, jnp.int32), to_device(cross64 / twice_area[:, None]),
                          to_device(0.5 * twice_area), to_device(diameter))


def triangle_power(t: TriangleLights) -> np.ndarray:
    """``Φ = π A L`` (luminance), doubled for two-sided triangles; shape (N,)."""
    v = np.asarray(t.vertices, np.float64)
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=-1)
    sides = np.where(np.asarray(t.two_sided), 2.0, 1.0)
    return np.pi * area * luminance_np(np.asarray(t.radiance)) * sides


# ---------------------------------------------------------------------------------------------
# Kernels (one shading point).


def _geometry(t: TriangleLights, j: Array, dtype) -> tuple[Array, Array, Array]:
    """Vertices of triangle ``j``, its unit geometric normal and its area."""
    return t.vertices[j].astype(dtype), t.normal[j].astype(dtype), t.area[j].astype(dtype)


def _emitted(t: TriangleLights, j: Array, n: Array, wo_light: Array) -> Array:
    """Radiance leaving triangle ``j`` along ``wo_light``: ``L`` on the lit side, else 0."""
    facing = (dot(n, wo_light) > 0) | t.two_sided[j]
    rad = t.radiance[j].astype(wo_light.dtype)
    return jnp.where(facing, rad, jnp.zeros_like(rad))


def le_triangle_local(t: TriangleLights, j: Array, wo_light: Array) -> Array:
    """Emitted radiance of triangle ``j`` (index in the triangle table) towards ``wo_light``.

    ``wo_light``: (3,) direction leaving the light (towards the viewer / shading point), any length.
    """
    return _emitted(t, j, t.normal[j].astype(wo_light.dtype), wo_light)


def sample_triangle_area(t: TriangleLights, j: Array, p: Array, u: Array) -> KindSample:
    """Uniform point on triangle ``j`` by area; ``pdf = ‖y − p‖² / (A |n·wi|)`` per steradian."""
    v, n, area = _geometry(t, j, p.dtype)
    b = square_to_uniform_triangle(u)
    # Barycentric interpolation in the triangle's own frame keeps y on the triangle.
    y = v[0] + b[0] * (v[1] - v[0]) + b[1] * (v[2] - v[0])
    to_y = y - p
    d2 = dot(to_y, to_y)
    d = jnp.sqrt(d2)
    wi = to_y / jnp.where(d > 0, d, jnp.ones_like(d))
    cos_light = dot(n, -wi)
    pdf = area_to_solid_angle_pdf(safe_div(jnp.ones_like(area), area), d2, cos_light)
    return KindSample(wi, d, _emitted(t, j, n, -wi), pdf)


def pdf_triangle_area(t: TriangleLights, j: Array, p: Array, wi: Array, p_light: Array) -> Array:
    """Density of :func:`sample_triangle_area` for ``wi`` hitting triangle ``j`` at ``p_light``.

    Both inner products are :func:`~jaxrt.core.vecmath.dot_components`, not
    :func:`~jaxrt.core.vecmath.dot`'s reduction: ``p_light`` is a hit point stacked from three
    components, and under ``vmap`` XLA:CPU fuses the stack, its transpose and the reduction
    over the axis of 3 into the kernel of the MIS weight, which then runs ~10× slower per lane
    (benchmarks/README.md#vector-type). The light sample's side
    (:func:`sample_triangle_area`) keeps the reduction: there the same rewrite is slower.
    """
    n, area = t.normal[j].astype(p.dtype), t.area[j].astype(p.dtype)
    to_y = [p_light[k].astype(p.dtype) - p[k] for k in range(3)]
    return area_to_solid_angle_pdf(safe_div(jnp.ones_like(area), area),
                                   dot_components(to_y, to_y), dot_components(n, wi))


def sample_triangle_solid_angle(t: TriangleLights, j: Array, p: Array, u: Array) -> KindSample:
    """Uniform direction in the spherical triangle that triangle ``j`` subtends at ``p``.

    ``pdf = 1/Ω`` per steradian (the warp's area fallback for tiny ``Ω``), without re-testing
    that its own sample lies inside (see ``assume_inside`` of the warp's pdf).
    """
    v, n, _ = _geometry(t, j, p.dtype)
    a, b, c = v[0] - p, v[1] - p, v[2] - p
    wi = square_to_spherical_triangle(u, a, b, c)
    # Distance along wi to the triangle's plane: (n·(v0 − p)) / (n·wi).
    cos_wi = dot(n, wi)
    d = jnp.abs(safe_div(dot(n, a), jnp.abs(cos_wi)))
    # Grazing rays: the plane distance is ill-conditioned; fall back to the nearest vertex.
    d = jnp.where((jnp.abs(cos_wi) > 0) & jnp.isfinite(d), d,
                  jnp.minimum(jnp.minimum(length(a), length(b)), length(c)))
    pdf = square_to_spherical_triangle_pdf(wi, a, b, c, assume_inside=True)
    li = jnp.where(pdf > 0, _emitted(t, j, n, -wi), jnp.zeros_like(p))
    return KindSample(wi, d, li, pdf)


def pdf_triangle_solid_angle(t: TriangleLights, j: Array, p: Array, wi: Array,
                             p_light: Array) -> Array:
    """Density of :func:`sample_triangle_solid_angle` for ``wi`` that hit triangle ``j``
    (``p_light`` unused). The hit is trusted: the inside test is not repeated from the
    un-offset ``p`` (1e5 from the origin it said "no" near the edges: MIS weight 1, +92 %)."""
    del p_light
    v, _, _ = _geometry(t, j, p.dtype)
    return square_to_spherical_triangle_pdf(wi, v[0] - p, v[1] - p, v[2] - p, assume_inside=True)
