"""Pinhole perspective camera and primary-ray generation with a box pixel filter.

Conventions:

- Camera space is right-handed: +x to the right of the image, +y up, and the camera looks
  along **−z** (OpenGL's convention), so +z points backwards.
- Raster space: column ``x ∈ [0, width)`` grows to the right, row ``y ∈ [0, height)`` grows
  DOWNWARDS; row 0 is the top of the image. Pixel ``(x, y)`` covers ``[x, x+1) × [y, y+1)``.
- ``tan_half_fov`` is ``tan(fov_y / 2)`` for the VERTICAL field of view, measured between the
  top and bottom image edges; the horizontal one follows from ``aspect = width / height``:
  ``tan(fov_x / 2) = aspect · tan(fov_y / 2)``.

:class:`Camera` is a pytree: its pose and field of view are traced arrays (a new pose
compiles nothing), while ``width`` and ``height`` are static Python ints (they fix array
shapes), stored as metadata of the registered dataclass.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import computed_once, device_array


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Fields (traced): ``eye`` (3,) centre of projection in world space; ``frame`` (3, 3) whose
    rows are the world-space camera axes ``right`` (+x), ``up`` (+y) and ``back`` (+z, the
    opposite of the viewing direction); ``tan_half_fov`` () = ``tan(fov_y / 2)``;
    ``aspect`` () = ``width / height``. Static: ``width``, ``height`` (pixels, Python ints).
    """

    eye: Array
    frame: Array
    tan_half_fov: Array
    aspect: Array
    width: int
    height: int


jax.tree_util.register_dataclass(
    Camera, data_fields=["eye", "frame", "tan_half_fov", "aspect"],
    meta_fields=["width", "height"])


def _vec3(name: str, v) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"look_at: {name} must be a 3-vector, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"look_at: {name} must be finite, got {a.tolist()}")
    return a


def _size(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
        raise ValueError(f"look_at: {name} must be a positive int, got {v!r}")
    return int(v)


#: The image extents a field of view can be measured across (Mitsuba 3's ``fov_axis``):
#: horizontal, vertical, diagonal, the smaller or the larger of width and height.
FOV_AXES = ("x", "y", "diagonal", "smaller", "larger")


def tan_half_fov_y(tan_half: float, fov_axis: str, aspect: float) -> float:
    """``tan(fov_y / 2)`` from ``tan(fov / 2)`` measured across ``fov_axis``.

    The image plane at distance 1 spans ``(±a·t_y, ±t_y)`` with ``a = width / height``, so
    across x the half-extent is ``a·t_y``, across the diagonal ``t_y·√(a² + 1)``.
    """
    if fov_axis not in FOV_AXES:
        raise ValueError(f"look_at: fov_axis must be one of {FOV_AXES}, got {fov_axis!r}")
    if fov_axis == "smaller":
        fov_axis = "y" if aspect >= 1 else "x"
    elif fov_axis == "larger":
        fov_axis = "x" if aspect >= 1 else "y"
    scale = {"x": aspect, "y": 1.0, "diagonal": float(np.hypot(aspect, 1.0))}[fov_axis]
    return tan_half / scale


def look_at(eye, target, up, fov_deg, width: int, height: int, fov_axis: str = "y") -> Camera:
    """Camera at ``eye`` looking at ``target``, with ``up`` giving the image's upward side.

    ``fov_deg``: field of view in degrees, in (0, 180), measured across ``fov_axis``: "y"
    (VERTICAL, the default, as pbrt's ``fov`` for a landscape image), "x" (horizontal),
    "diagonal", "smaller" or "larger" of the two image sides (Mitsuba 3's ``fov_axis``;
    pbrt-v4's ``fov`` is across the shorter side, "smaller"). The frame is
    ``back = (eye − target)/‖·‖``, ``right = normalize(up × back)``, ``up' = back × right``
    (Gram–Schmidt; ``up`` need not be orthogonal to the view direction). Built on the host in
    float64 and stored in the default float dtype (float32, or float64 under x64).

    Raises ValueError when an input is non-finite, ``eye == target``, ``up`` is zero or
    parallel to the viewing direction, the field of view is outside (0, 180), or the image
    size is not a positive int.
    """
    eye, target, up = _vec3("eye", eye), _vec3("target", target), _vec3("up", up)
    width, height = _size("width", width), _size("height", height)
    fov = float(fov_deg)
    if not np.isfinite(fov) or not 0 < fov < 180:
        raise ValueError(f"look_at: fov_deg must lie in (0, 180), got {fov_deg}")
    view = target - eye
    dist = np.linalg.norm(view)
    if dist == 0 or dist <= 1e-12 * max(np.linalg.norm(eye), np.linalg.norm(target)):
        raise ValueError(f"look_at: eye and target coincide ({eye.tolist()})")
    back = -view / dist
    up_len = np.linalg.norm(up)
    side = np.cross(up, back)
    # |up × back| = sin of the angle between up and the view direction
    if up_len == 0 or np.linalg.norm(side) <= 1e-6 * up_len:
        raise ValueError(f"look_at: up {up.tolist()} is zero or parallel to the view direction")
    right = side / np.linalg.norm(side)
    frame = np.stack([right, np.cross(back, right), back])
    dt = jax.dtypes.canonicalize_dtype(jnp.float64)
    return Camera(eye=device_array(eye, dt), frame=device_array(frame, dt),
                  tan_half_fov=device_array(tan_half_fov_y(np.tan(np.radians(fov) / 2),
                                                           fov_axis, width / height), dt),
                  aspect=device_array(width / height, dt), width=width, height=height)


def generate_ray(camera: Camera, pixel_xy: Array, u: Array,
                 stored: bool = False) -> tuple[Array, Array]:
    """Primary ray through pixel ``(x, y) = (column, row)`` jittered by ``u`` (box filter).

    The film point is ``(x + u₀, y + u₁)`` in raster space; its camera-space direction is
    ``d = (a t (2 s_x − 1), t (1 − 2 s_y), −1)`` with ``s = (x + u₀, y + u₁)/(W, H)``,
    ``t = tan(fov_y/2)`` and ``a`` the aspect (row 0 at the top, hence ``1 − 2 s_y``).
    Args: ``pixel_xy`` (2,) int32, ``u`` (2,) in [0, 1)²; ``stored`` (static): keep the film
    point and the normalisation as stored scalars (:func:`~jaxrt.core.vecmath.computed_once`), for
    a caller whose (3,) direction feeds a select: XLA:CPU computes each element of a (…, 3)
    output on its own, so the path pass's regeneration select would compute the sampler's
    hash and the film point three times per lane and step (stored, the path pass runs
    faster; the MIS pass's camera ray, which feeds no select, runs slower stored).
    Returns ``(origin, direction)``: the eye (3,) and the unit world direction (3,), in the
    dtype of ``u``.
    """
    dt = u.dtype
    sx = (pixel_xy[0].astype(dt) + u[0]) / jnp.asarray(camera.width, dt)
    sy = (pixel_xy[1].astype(dt) + u[1]) / jnp.asarray(camera.height, dt)
    t = camera.tan_half_fov.astype(dt)
    keep = computed_once if stored else (lambda x: x)
    cx, cy = keep(camera.aspect.astype(dt) * t * (2 * sx - 1)), keep(t * (1 - 2 * sy))
    # camera → world: cx·right + cy·up − back, per component (under vmap each is one
    # contiguous vector; a (3,) @ (3, 3) product is a dot kernel and a stack of its own)
    f = camera.frame.astype(dt)
    d = [cx * f[0, k] + cy * f[1, k] - f[2, k] for k in range(3)]
    inv = keep(1 / jnp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))  # ≥ 1: never zero
    return camera.eye.astype(dt), jnp.stack([d[0] * inv, d[1] * inv, d[2] * inv])


def project(camera: Camera, p: Array) -> tuple[Array, Array]:
    """Raster position of world point ``p``, inverse of :func:`generate_ray`.

    Returns ``(raster_xy (2,), depth ())``: continuous ``(column, row)`` such that a ray
    through that film point passes through ``p``, and the depth of ``p`` along the viewing
    direction (positive in front of the camera; the raster position is meaningless if not).
    """
    q = camera.frame.astype(p.dtype) @ (p - camera.eye.astype(p.dtype))
    depth = -q[2]
    safe = jnp.where(depth != 0, depth, jnp.ones_like(depth))
    t = camera.tan_half_fov.astype(p.dtype)
    ndc_x = q[0] / (safe * t * camera.aspect.astype(p.dtype))
    ndc_y = q[1] / (safe * t)
    raster = jnp.stack([(ndc_x + 1) / 2 * camera.width, (1 - ndc_y) / 2 * camera.height])
    return raster, depth


def pixel_coordinates(width: int, height: int) -> Array:
    """All pixels in row-major order as (height·width, 2) int32 ``(column, row)`` pairs."""
    ys, xs = jnp.meshgrid(jnp.arange(height, dtype=jnp.int32),
                          jnp.arange(width, dtype=jnp.int32), indexing="ij")
    return jnp.stack([xs.ravel(), ys.ravel()], axis=-1)


def view_direction(camera: Camera) -> Array:
    """Unit world-space viewing direction (camera −z)."""
    return -camera.frame[2]


__all__ = ["FOV_AXES", "Camera", "generate_ray", "look_at", "pixel_coordinates", "project",
           "view_direction"]
