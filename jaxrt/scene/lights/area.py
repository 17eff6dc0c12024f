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

Emission textures: a triangle may emit ``L ⊙ T(uv(y))``, its radiance scaled by an image
looked up at the emitting point's texture coordinates (:class:`EmissionTextures`, the
lookup of :mod:`jaxrt.scene.textures`). Sampling stays uniform on the triangle (or its
spherical triangle), as in pbrt-v4's image area lights: the texture enters the sample's
radiance, and light selection by power uses the texture's mean over each triangle
(:func:`emission_scale`). A table without textures has ``emission = None`` and compiles no
lookup.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import area_to_solid_angle_pdf, device_array, dot, dot_components, length
from jaxrt.sampling.warp import (
    square_to_spherical_triangle,
    square_to_spherical_triangle_pdf,
    square_to_uniform_triangle,
)
from jaxrt.scene import textures as tx
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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EmissionTextures:
    """Images that scale the radiance of triangle lights (a pytree, one per light table).

    Attributes:
        texels: tuple of (H_k, W_k, 3) linear texel arrays (traced: ``jax.grad`` w.r.t. them
            works).
        uv_map: (N, 11) per light, the affine UV map of its triangle
            (:func:`jaxrt.scene.textures.uv_gradients`).
        index: (N,) int32, the texture of each light, −1 for an untextured one.
        mean: (N, 3) host-side mean texel value over each triangle
            (:func:`emission_scale`), for light selection by power only.
        modes: static tuple of ``(wrap, filter)`` per texture.
    """

    texels: tuple
    uv_map: Array
    index: Array
    mean: Array
    modes: tuple = dataclasses.field(metadata=dict(static=True))


class TriangleLights(NamedTuple):
    """Emissive triangles. vertices (N, 3, 3); radiance (N, 3); two_sided (N,) bool;
    prim (N,) int32, the index of each triangle in the scene geometry.

    Precomputed once on the host (float64, then stored in JAX's float), so that the kernels
    that only need them gather a row, not the vertices: normal (N, 3) unit
    ``(v1 − v0) × (v2 − v0)``; area (N,); diameter (N,) ``max_{i,j} ‖v_i − v_j‖_∞`` (bounds
    ``‖v_i − q‖_∞`` for every point ``q`` of the triangle). emission: the
    :class:`EmissionTextures` scaling ``radiance``, or None (constant radiance per light).
    """

    vertices: Array
    radiance: Array
    two_sided: Array
    prim: Array
    normal: Array
    area: Array
    diameter: Array
    emission: EmissionTextures | None = None


def triangle_lights(vertices, radiance, prims, two_sided=False, uv=None,
                    texture=None) -> TriangleLights:
    """Emissive triangles from host arrays.

    Args:
      vertices: (N, 3, 3) world-space vertices (or (3, 3) for one triangle).
      radiance: (N, 3) or (3,) RGB radiance, non-negative.
      prims: (N,) int, index of each triangle in the scene's triangle list (for the estimator's
        "which light did the BSDF ray hit" lookup).
      two_sided: bool or (N,) bool.
      uv, texture: an emission texture (:func:`jaxrt.scene.textures.texture`; colour, so
        8-bit images are sRGB-decoded under ``encoding="auto"``) and the (N, 3, 2) texture
        coordinates of the vertices: the triangles emit ``radiance ⊙ T(uv(y))`` at ``y``.

    Raises ``ValueError`` for non-finite vertices, zero-area triangles, negative or non-finite
    radiance, mismatched lengths, or a texture without (finite, (N, 3, 2)) UVs.
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
    emission = None if texture is None else _emission_textures(v, uv, texture)
    return TriangleLights(to_device(v), to_device(rad), device_array(two),
                          device_array(prim, jnp.int32), to_device(cross64 / twice_area[:, None]),
                          to_device(0.5 * twice_area), to_device(diameter), emission)


def _emission_textures(v: np.ndarray, uv, texture) -> EmissionTextures:
    """The :class:`EmissionTextures` of ``N`` triangles ``v`` sharing one texture."""
    if not isinstance(texture, tx.Texture):
        raise ValueError(f"triangle light texture: expected a jaxrt.scene.textures.texture(...), "
                         f"got a {type(texture).__name__}")
    uv = None if uv is None else np.asarray(uv, np.float64)
    if uv is None or uv.shape != (len(v), 3, 2) or not np.all(np.isfinite(uv)):
        raise ValueError(f"triangle light texture {texture.name!r}: needs finite uv of shape "
                         f"({len(v)}, 3, 2), got {None if uv is None else uv.shape}")
    texels = tx.decoded(texture, "emission")
    mean = emission_scale(texels, uv, texture.wrap, texture.filter)
    return EmissionTextures((to_device(np.ascontiguousarray(texels)),),
                            to_device(tx.uv_gradients(v, uv)),
                            device_array(np.zeros(len(v)), jnp.int32), to_device(mean),
                            ((texture.wrap, texture.filter),))


def emission_scale(texels: np.ndarray, uv: np.ndarray, wrap: str,
                   filter: str = "bilinear") -> np.ndarray:
    """Mean texel value (N, 3) over each triangle (``uv`` (N, 3, 2) its vertices' UVs): the
    lookup averaged over the centroids of the ``m²`` congruent sub-triangles of a regular
    subdivision (the midpoint rule, exact for an affine texture), ``m`` twice the triangle's
    extent in texels (4 … 64).

    An estimate of the triangle's mean emission, for light selection only (the sampled
    radiance is looked up exactly; a light it misses keeps the selection floor's share).
    """
    h, w = texels.shape[:2]
    out = np.empty((len(uv), texels.shape[2]))
    for k, (a, b, c) in enumerate(np.asarray(uv, np.float64)):
        span = np.ptp(np.stack([a, b, c]) * [w, h], axis=0).max()
        m = int(np.clip(2 * np.ceil(span) + 2, 4, 64))
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        up = i + j <= m - 1
        down = i + j <= m - 2
        s = np.concatenate([(i[up] + 1 / 3) / m, (i[down] + 2 / 3) / m])
        t = np.concatenate([(j[up] + 1 / 3) / m, (j[down] + 2 / 3) / m])
        points = a + s[:, None] * (b - a) + t[:, None] * (c - a)
        out[k] = _lookup_np(texels, points, wrap, filter).mean(axis=0)
    return out


def _lookup_np(texels: np.ndarray, uv: np.ndarray, wrap: str, filter: str) -> np.ndarray:
    """Host lookups (P, C) at ``uv`` (P, 2), by :func:`jaxrt.scene.textures.bilinear`'s or
    :func:`~jaxrt.scene.textures.nearest`'s rule."""
    h, w = texels.shape[:2]
    x, y = uv[:, 0] * w - 0.5, (1 - uv[:, 1]) * h - 0.5

    def fold(i, n):
        return np.mod(i, n) if wrap == "repeat" else np.clip(i, 0, n - 1)

    if filter == "nearest":
        i, j = np.floor(y + 0.5).astype(int), np.floor(x + 0.5).astype(int)
        return texels[fold(i, h), fold(j, w)]
    x0, y0 = np.floor(x), np.floor(y)
    a, b = (x - x0)[:, None], (y - y0)[:, None]
    j0, i0 = x0.astype(int), y0.astype(int)
    j0, j1, i0, i1 = fold(j0, w), fold(j0 + 1, w), fold(i0, h), fold(i0 + 1, h)
    top = texels[i0, j0] * (1 - a) + texels[i0, j1] * a
    return top * (1 - b) + (texels[i1, j0] * (1 - a) + texels[i1, j1] * a) * b


def concat_triangle_lights(tables: list[TriangleLights]) -> TriangleLights:
    """Concatenate triangle tables (host): their arrays in order, and their emission textures
    (untextured tables' lights get index −1, zero UV maps and a unit mean)."""
    def cat(xs):
        return device_array(np.concatenate([np.asarray(x) for x in xs]), xs[0].dtype)

    plain = [t._replace(emission=None) for t in tables]
    out = jax.tree.map(lambda *xs: cat(xs), *plain)
    if all(t.emission is None for t in tables):
        return out
    texels, modes, uv_map, index, mean = [], [], [], [], []
    for t in tables:
        n, e = int(t.vertices.shape[0]), t.emission
        if e is None:
            uv_map.append(np.zeros((n, 11)))
            index.append(np.full(n, -1))
            mean.append(np.ones((n, 3)))
            continue
        idx = np.asarray(e.index)
        index.append(np.where(idx >= 0, idx + len(texels), -1))
        texels += list(e.texels)
        modes += list(e.modes)
        uv_map.append(np.asarray(e.uv_map))
        mean.append(np.asarray(e.mean))
    return out._replace(emission=EmissionTextures(
        tuple(texels), to_device(np.concatenate(uv_map)),
        device_array(np.concatenate(index), jnp.int32), to_device(np.concatenate(mean)),
        tuple(modes)))


def triangle_power(t: TriangleLights) -> np.ndarray:
    """``Φ = π A L`` (luminance), doubled for two-sided triangles; shape (N,)."""
    v = np.asarray(t.vertices, np.float64)
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=-1)
    sides = np.where(np.asarray(t.two_sided), 2.0, 1.0)
    radiance = np.asarray(t.radiance, np.float64)
    if t.emission is not None:  # the texture's mean over each triangle (emission_scale)
        radiance = radiance * np.asarray(t.emission.mean, np.float64)
    return np.pi * area * luminance_np(radiance) * sides


# ---------------------------------------------------------------------------------------------
# Kernels (one shading point).


def _geometry(t: TriangleLights, j: Array, dtype) -> tuple[Array, Array, Array]:
    """Vertices of triangle ``j``, its unit geometric normal and its area."""
    return t.vertices[j].astype(dtype), t.normal[j].astype(dtype), t.area[j].astype(dtype)


def _emitted(t: TriangleLights, j: Array, n: Array, wo_light: Array, y) -> Array:
    """Radiance leaving triangle ``j`` at ``y`` along ``wo_light``: ``L`` (times the emission
    texture at ``y``) on the lit side, else 0."""
    facing = (dot(n, wo_light) > 0) | t.two_sided[j]
    rad = t.radiance[j].astype(wo_light.dtype)
    if t.emission is not None:
        rad = rad * emission_texture(t.emission, j, y)
    return jnp.where(facing, rad, jnp.zeros_like(rad))


def emission_texture(e: EmissionTextures, j: Array, y: Array) -> Array:
    """The emission texture's value (3,) of light ``j`` at its point ``y`` (3,); 1 for an
    untextured light. One lookup per texture (static), selected by ``e.index[j]``."""
    uv = tx.uv_of_row(e.uv_map[j], y)
    value = jnp.ones_like(y)
    for k, (wrap, filter) in enumerate(e.modes):
        looked = tx.lookup(e.texels[k], uv, wrap, filter).astype(y.dtype)
        value = jnp.where(e.index[j] == k, looked, value)
    return value


def le_triangle_local(t: TriangleLights, j: Array, wo_light: Array,
                      p_light: Array | None = None) -> Array:
    """Emitted radiance of triangle ``j`` (index in the triangle table) at its point
    ``p_light`` (3,) towards ``wo_light``.

    ``wo_light``: (3,) direction leaving the light (towards the viewer / shading point), any
    length. ``p_light`` is needed only by textured tables (``t.emission``).
    """
    if t.emission is not None and p_light is None:
        raise ValueError("a textured triangle light's radiance depends on the point: "
                         "pass p_light")
    return _emitted(t, j, t.normal[j].astype(wo_light.dtype), wo_light, p_light)


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
    return KindSample(wi, d, _emitted(t, j, n, -wi, y), pdf)


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
    y = None if t.emission is None else p + d * wi
    li = jnp.where(pdf > 0, _emitted(t, j, n, -wi, y), jnp.zeros_like(p))
    return KindSample(wi, d, li, pdf)


def pdf_triangle_solid_angle(t: TriangleLights, j: Array, p: Array, wi: Array,
                             p_light: Array) -> Array:
    """Density of :func:`sample_triangle_solid_angle` for ``wi`` that hit triangle ``j``
    (``p_light`` unused). The hit is trusted: the inside test is not repeated from the
    un-offset ``p`` (1e5 from the origin it said "no" near the edges: MIS weight 1, +92 %)."""
    del p_light
    v, _, _ = _geometry(t, j, p.dtype)
    return square_to_spherical_triangle_pdf(wi, v[0] - p, v[1] - p, v[2] - p, assume_inside=True)
