"""Image textures: per-vertex UVs, bilinear lookup, sRGB decoding, and the scene's texture table.

A texture binds one material field of one mesh — the diffuse albedo ``kd``, the specular
albedo ``ks`` (Phong's, a conductor's F0, a mirror's reflectance) or the GGX roughness
``alpha`` — to an image, looked up at the hit's texture coordinates ``(u, v)``.

Conventions:

- ``(u, v)`` are interpolated from per-vertex UVs with the hit's barycentrics; ``u`` runs
  along the image's width, ``v`` up its height (OBJ's and OpenGL's convention): ``v = 0`` is
  the image's bottom row, ``v = 1`` its top (row 0 of the file).
- Texel ``(i, j)`` (row, column) is centred at ``u = (j + ½)/W``, ``v = 1 − (i + ½)/H``;
  :func:`bilinear` is exact there and linear in between.
- ``wrap="repeat"`` tiles the image (``u`` and ``u + 1`` look up the same value);
  ``wrap="clamp"`` repeats the border texels outwards (clamp to edge).
- Colour maps (``kd``, ``ks``) of 8-bit images are sRGB-encoded and decoded to linear
  (:func:`srgb_to_linear`) when the scene is built; float images (EXR, float arrays) are
  linear; ``encoding`` overrides. Roughness maps are linear, and a colour image bound to
  ``alpha`` gives its luminance.

Model only what a scene requires: a scene without textures has ``Scene.textures = None``
and compiles no texture code. With textures, :class:`TextureTable` holds the decoded texels
(traced leaves: differentiable, ``jax.grad`` w.r.t. them works) and a per-triangle affine
UV map, and which material is bound to which texture, field, wrap and filter is its static
aux data (:class:`Binding`), part of the compiled program.
"""

from __future__ import annotations

import dataclasses
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import device_array
from jaxrt.scene import materials as mt

WRAPS = ("repeat", "clamp")
FILTERS = ("bilinear", "nearest")
ENCODINGS = ("auto", "srgb", "linear")
#: Material fields a texture can drive, and the channels each takes.
FIELDS = {"kd": 3, "ks": 3, "alpha": 1}
#: The field of an emissive mesh's radiance (its triangle lights':
#: :class:`jaxrt.scene.lights.area.EmissionTextures`), a colour.
EMISSION = "emission"
#: Fields that hold colours (sRGB-decoded when the image is 8-bit and ``encoding="auto"``).
COLOUR_FIELDS = ("kd", "ks", EMISSION)
_CHANNELS = {**FIELDS, EMISSION: 3}


def srgb_to_linear(c, xp=jnp):
    """The sRGB electro-optical transfer function (IEC 61966-2-1), elementwise.

    ``c_lin = c / 12.92`` for ``c ≤ 0.04045``, else ``((c + 0.055) / 1.055)^2.4``; maps [0, 1]
    onto [0, 1], continuous and increasing. ``xp``: ``jax.numpy`` (default) or ``numpy`` (the
    host decodes 8-bit images in float64 with it).
    """
    c = xp.asarray(c)
    lo = c / 12.92
    hi = ((xp.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4
    return xp.where(c <= 0.04045, lo, hi)


# ---------------------------------------------------------------------------------------------
# Host-side records
# ---------------------------------------------------------------------------------------------


class Texture(NamedTuple):
    """An image to bind to a material field (a host-side record, see :func:`texture`).

    texels: (H, W, C) float64, the stored values (8-bit images scaled to [0, 1], not decoded);
    eight_bit: whether they came from 8-bit data; wrap, filter, encoding, name: see
    :func:`texture`.
    """

    texels: np.ndarray
    eight_bit: bool
    wrap: str
    filter: str
    encoding: str
    name: str


def texture(image, wrap: str = "repeat", filter: str = "bilinear", encoding: str = "auto",
            name: str = "texture") -> Texture:
    """Validate an image as a texture.

    Args:
        image: (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) array (alpha channels are dropped);
            uint8 values are 8-bit (scaled by 1/255), floats taken as given (finite, ≥ 0).
        wrap: "repeat" (tile) or "clamp" (clamp to edge), outside ``[0, 1]²``.
        filter: "bilinear" (the four nearest texel centres, :func:`bilinear`) or "nearest".
        encoding: "auto" (8-bit colour maps are sRGB, everything else linear), "srgb" or
            "linear".
    Raises ValueError naming the texture for a bad shape, value, wrap, filter or encoding.
    """
    if wrap not in WRAPS:
        raise ValueError(f"texture {name!r}: wrap must be one of {WRAPS}, got {wrap!r}")
    if filter not in FILTERS:
        raise ValueError(f"texture {name!r}: filter must be one of {FILTERS}, got {filter!r}")
    if encoding not in ENCODINGS:
        raise ValueError(f"texture {name!r}: encoding must be one of {ENCODINGS}, got "
                         f"{encoding!r}")
    a = np.asarray(image)
    eight_bit = a.dtype == np.uint8
    t = a.astype(np.float64) / 255.0 if eight_bit else a.astype(np.float64)
    if t.ndim == 2:
        t = t[..., None]
    if t.ndim != 3 or t.shape[2] not in (1, 3, 4) or t.shape[0] < 1 or t.shape[1] < 1:
        raise ValueError(f"texture {name!r}: image must have shape (H, W), (H, W, 1), (H, W, 3) "
                         f"or (H, W, 4), got {a.shape}")
    t = t[..., :3] if t.shape[2] == 4 else t
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError(f"texture {name!r}: texel values must be finite and >= 0")
    return Texture(t, bool(eight_bit), wrap, filter, encoding, str(name))


def load_texture(path: str | os.PathLike, wrap: str = "repeat", filter: str = "bilinear",
                 encoding: str = "auto") -> Texture:
    """A :func:`texture` from an 8-bit PNG (:func:`jaxrt.scene.images.read_png`) or an OpenEXR
    file (:func:`jaxrt.scene.images.read_exr`, linear float RGB). Raises FileNotFoundError for a
    missing file, ValueError for an unknown suffix or anything :func:`texture` rejects."""
    from jaxrt.scene.images import read_exr, read_png

    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in (".png", ".exr"):
        raise ValueError(f"{path}: textures are read from .png or .exr files, got {suffix!r}")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: texture file not found")
    image = read_png(path) if suffix == ".png" else read_exr(path)[0]
    return texture(image, wrap=wrap, filter=filter, encoding=encoding,
                   name=os.path.basename(path))


def decoded(tex: Texture, field: str) -> np.ndarray:
    """The linear texels (H, W, FIELDS[field]) a binding of ``tex`` to ``field`` looks up.

    Colour fields: sRGB-decoded if ``encoding == "srgb"``, or "auto" and 8-bit; a one-channel
    image is grey. ``alpha``: linear (decoded only if ``encoding == "srgb"``), a colour
    image's Rec. 709 luminance. ``field`` may also be :data:`EMISSION` (a colour).
    """
    from jaxrt.scene.lights.records import luminance_np

    t = tex.texels
    srgb = tex.encoding == "srgb" or (tex.encoding == "auto" and tex.eight_bit
                                      and field in COLOUR_FIELDS)
    t = srgb_to_linear(t, xp=np) if srgb else t
    if _CHANNELS[field] == 1:
        return t if t.shape[2] == 1 else luminance_np(t)[..., None]
    return np.broadcast_to(t, t.shape[:2] + (3,))


class Binding(NamedTuple):
    """Static: material row ``material``'s field ``field`` is looked up in texture ``texture``."""

    material: int
    field: str
    texture: int
    wrap: str
    filter: str


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TextureTable:
    """The scene's textures (a pytree; built by :func:`texture_table`).

    Attributes:
        texels: tuple of (H_k, W_k, C_k) arrays, linear texel values (traced, differentiable).
        uv_map: (F, 11) per triangle: the UV ``uv0`` (2) of its vertex ``v0``, ``v0`` (3), and
            the gradient ``G`` (3, 2) of ``(u, v)`` in world space, so that on the triangle
            ``uv(p) = uv0 + (p − v0) G`` (zero rows for untextured triangles). Formed from the
            triangles when the scene is built: a scene given other triangles
            (``Scene.replace(triangles=...)``) keeps it, right only for the same triangles.
            Geometry: derivatives w.r.t. it raise (:func:`jaxrt.scene.container.guard_geometry`).
        bindings: static tuple of :class:`Binding`.
    """

    texels: tuple
    uv_map: Array
    bindings: tuple = dataclasses.field(metadata=dict(static=True))


def uv_gradients(triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The affine UV map of each triangle, as ``(uv0, v0, G)`` rows (F, 11), in float64.

    With edges ``e1 = v1 − v0``, ``e2 = v2 − v0`` and ``n = e1 × e2``, a point
    ``p = v0 + b1 e1 + b2 e2`` of the triangle's plane has barycentrics
    ``b1 = (p − v0)·(e2 × n)/|n|²`` and ``b2 = (p − v0)·(n × e1)/|n|²``, so
    ``uv(p) = uv0 + b1 (uv1 − uv0) + b2 (uv2 − uv0) = uv0 + (p − v0) G`` with
    ``G = (e2 × n)(uv1 − uv0)ᵀ/|n|² + (n × e1)(uv2 − uv0)ᵀ/|n|²`` (3, 2). A point off the plane
    is projected onto it along ``n``. Zero-area triangles get ``G = 0`` (``uv = uv0``).

    Args: triangles (F, 3, 3) vertices; uv (F, 3, 2) their UVs.
    """
    tri, uv = np.asarray(triangles, np.float64), np.asarray(uv, np.float64)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    nn = np.sum(n * n, axis=1, keepdims=True)
    inv = np.where(nn > 0, 1.0 / np.where(nn > 0, nn, 1.0), 0.0)
    g1, g2 = np.cross(e2, n) * inv, np.cross(n, e1) * inv
    du1, du2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    grad = g1[:, :, None] * du1[:, None, :] + g2[:, :, None] * du2[:, None, :]  # (F, 3, 2)
    return np.concatenate([uv[:, 0], v0, grad.reshape(-1, 6)], axis=1)


def texture_table(bindings: list[tuple[int, str, Texture]], triangles: np.ndarray,
                  uv: np.ndarray) -> TextureTable | None:
    """Build the :class:`TextureTable` of a scene (host), or None without bindings.

    ``bindings``: (material row, field, texture) triples; a texture bound to two fields
    that decode alike is stored once (textures are compared by identity). ``triangles``
    (F, 3, 3) and ``uv`` (F, 3, 2) the scene's triangles and their vertices' UVs (zeros on
    untextured meshes).
    """
    if not bindings:
        return None
    dt = jax.dtypes.canonicalize_dtype(jnp.float64)
    arrays, index, out = [], {}, []
    for material, field, tex in bindings:
        if field not in FIELDS:
            raise ValueError(f"texture {tex.name!r}: cannot drive material field {field!r}; "
                             f"textured fields: {', '.join(FIELDS)}")
        key = (id(tex), FIELDS[field], field in COLOUR_FIELDS)
        if key not in index:
            index[key] = len(arrays)
            arrays.append(device_array(np.ascontiguousarray(decoded(tex, field)), dt))
        out.append(Binding(int(material), field, index[key], tex.wrap, tex.filter))
    return TextureTable(tuple(arrays), device_array(uv_gradients(triangles, uv), dt),
                        tuple(out))


# ---------------------------------------------------------------------------------------------
# Lookup (traced, for one point)
# ---------------------------------------------------------------------------------------------


def _wrap_index(i: Array, n: int, wrap: str) -> Array:
    """Integer texel index ``i`` folded into ``[0, n)``: modulo (repeat) or clipped (clamp)."""
    return jnp.mod(i, n) if wrap == "repeat" else jnp.clip(i, 0, n - 1)


def texel_coordinates(texels: Array, uv: Array) -> tuple[Array, Array]:
    """Continuous texel coordinates ``(x, y)`` of ``uv``, texel centres at integers.

    ``x = u W − ½`` along a row, ``y = (1 − v) H − ½`` down the columns (row 0 is ``v = 1``).
    Non-finite UVs map to 0 so that the indices stay defined.
    """
    h, w = texels.shape[0], texels.shape[1]
    dt = texels.dtype
    u, v = uv[0].astype(dt), uv[1].astype(dt)
    x, y = u * w - 0.5, (1 - v) * h - 0.5
    return jnp.where(jnp.isfinite(x), x, 0), jnp.where(jnp.isfinite(y), y, 0)


def bilinear(texels: Array, uv: Array, wrap: str = "repeat") -> Array:
    """Bilinear lookup of a (H, W, C) texture at ``uv`` (2,), returning (C,).

    With ``(x, y)`` = :func:`texel_coordinates`, ``j = ⌊x⌋``, ``i = ⌊y⌋``, ``a = x − j``,
    ``b = y − i``::

        T(u, v) = (1−a)(1−b) T[i, j] + a (1−b) T[i, j+1] + (1−a) b T[i+1, j] + a b T[i+1, j+1]

    with indices folded by ``wrap`` (static): "repeat" modulo the size, "clamp" into the
    image. The weights are non-negative and sum to one, and ``T`` is linear in ``x`` (and
    ``y``) between texel centres. Evaluated as two lerps ``t0 + a (t1 − t0)``, so that it is
    exact in floating point where it should be: a constant texture gives the constant bit for
    bit (a textured material renders as the untextured one), and a texel centre (``a = b =
    0``) its texel. Differentiable in the texels (a linear combination of four of them).
    """
    h, w = texels.shape[0], texels.shape[1]
    x, y = texel_coordinates(texels, uv)
    x0, y0 = jnp.floor(x), jnp.floor(y)
    a, b = (x - x0)[None], (y - y0)[None]
    j0, i0 = x0.astype(jnp.int32), y0.astype(jnp.int32)
    j0, j1 = _wrap_index(j0, w, wrap), _wrap_index(j0 + 1, w, wrap)
    i0, i1 = _wrap_index(i0, h, wrap), _wrap_index(i0 + 1, h, wrap)
    t00, t01 = texels[i0, j0], texels[i0, j1]
    t10, t11 = texels[i1, j0], texels[i1, j1]
    top = t00 + a * (t01 - t00)
    bottom = t10 + a * (t11 - t10)
    return top + b * (bottom - top)


def nearest(texels: Array, uv: Array, wrap: str = "repeat") -> Array:
    """Nearest-texel lookup ``T[⌊y + ½⌋, ⌊x + ½⌋]`` (indices folded by ``wrap``), (C,)."""
    h, w = texels.shape[0], texels.shape[1]
    x, y = texel_coordinates(texels, uv)
    j = _wrap_index(jnp.floor(x + 0.5).astype(jnp.int32), w, wrap)
    i = _wrap_index(jnp.floor(y + 0.5).astype(jnp.int32), h, wrap)
    return texels[i, j]


def lookup(texels: Array, uv: Array, wrap: str, filter: str) -> Array:
    """:func:`bilinear` or :func:`nearest` (``filter``, static)."""
    return (bilinear if filter == "bilinear" else nearest)(texels, uv, wrap)


def uv_at(table: TextureTable, prim: Array, p: Array) -> Array:
    """Texture coordinates (2,) of the point ``p`` (3,) on triangle ``prim`` (its affine map,
    :func:`uv_gradients`; ``p − v0`` first, so that precision does not depend on where the
    scene lies)."""
    return uv_of_row(table.uv_map[jnp.maximum(prim, 0)], p)


def uv_of_row(row: Array, p: Array) -> Array:
    """``uv0 + (p − v0) G`` (2,) of one (11,) row of an affine UV map (:func:`uv_gradients`)."""
    row = row.astype(p.dtype)
    d = p - row[2:5]
    g = row[5:11].reshape(3, 2)
    return row[0:2] + d[0] * g[0] + d[1] * g[1] + d[2] * g[2]


def textured_material(table: TextureTable, m: mt.Material, material: Array, prim: Array,
                      p: Array) -> mt.Material:
    """The material row ``m`` of material index ``material`` with its textured fields looked up
    at the hit ``(prim, p)``: one lookup per static binding, selected where the hit's material
    is the binding's. ``alpha`` is raised to :data:`jaxrt.scene.materials.ALPHA_MIN`."""
    uv = uv_at(table, prim, p)
    fields = {}
    for b in table.bindings:
        value = lookup(table.texels[b.texture], uv, b.wrap, b.filter).astype(p.dtype)
        if b.field == "alpha":
            value = jnp.maximum(value[0], jnp.asarray(mt.ALPHA_MIN, p.dtype))
        old = fields.get(b.field, getattr(m, b.field))
        fields[b.field] = jnp.where(material == b.material, value, old.astype(p.dtype))
    return m._replace(**fields)


def bound_rows(bindings: tuple[Binding, ...]) -> set[int]:
    """The material rows a texture drives."""
    return {b.material for b in bindings}
