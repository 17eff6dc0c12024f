"""Pinhole camera: orientation, field of view, jitter footprint, dtypes, validation.

The second part tests ``look_at(..., fov_axis=)``: the field of view measured across x, y, the
diagonal, the smaller or the larger side, so that Mitsuba 3 (``fov_axis``) and pbrt-v4 (shorter
side) cameras carry over.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.scene.camera import (
    FOV_AXES,
    Camera,
    generate_ray,
    look_at,
    pixel_coordinates,
    project,
    view_direction,
)
from jaxrt.scene.file import load_scene

EYE, TARGET, UP = [1.0, 2.0, 5.0], [0.5, 1.5, -3.0], [0.1, 1.0, 0.0]
W, H = 64, 48

ray = jax.jit(generate_ray)
rays = jax.jit(jax.vmap(generate_ray, in_axes=(None, 0, 0)))
projects = jax.jit(jax.vmap(project, in_axes=(None, 0)))


def _angle(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def _cam(width=W, height=H, fov=40.0):
    return look_at(EYE, TARGET, UP, fov, width, height)


@pytest.mark.parametrize("width, height", [(W, H), (65, 49)])
def test_centre_ray_hits_target(width, height, x64):
    dt = jnp.float64 if x64 else jnp.float32
    cam = _cam(width, height)
    # the image centre: pixel corner (W/2, H/2) if even, centre of pixel (W//2, H//2) if odd
    u = jnp.asarray([0.0 if width % 2 == 0 else 0.5, 0.0 if height % 2 == 0 else 0.5], dt)
    o, d = ray(cam, jnp.asarray([width // 2, height // 2], jnp.int32), u)
    want = np.subtract(TARGET, EYE) / np.linalg.norm(np.subtract(TARGET, EYE))
    # float32 round-off on a unit vector (x64: double round-off)
    np.testing.assert_allclose(d, want, atol=1e-12 if x64 else 1e-6)
    np.testing.assert_allclose(o, EYE, rtol=1e-7 if x64 else 1e-6)
    np.testing.assert_allclose(view_direction(cam), want, atol=1e-12 if x64 else 1e-6)
    assert o.dtype == d.dtype == dt


@pytest.mark.parametrize("fov", [10.0, 40.0, 90.0, 150.0])
def test_field_of_view_at_image_edges(fov):
    with jax.enable_x64(True):  # measure the angles without float32 noise
        cam = _cam(fov=fov)
        xs = jnp.asarray([[W // 2, 0], [W // 2, H - 1], [0, H // 2], [W - 1, H // 2]], jnp.int32)
        us = jnp.asarray([[0.0, 0.0], [0.0, 1.0], [0.0, 0.0], [1.0, 0.0]])
        _, d = rays(cam, xs, us)
    # top edge of row 0 to bottom edge of row H−1: exactly the vertical fov
    np.testing.assert_allclose(_angle(d[0], d[1]), fov, rtol=1e-10)
    # left edge of column 0 to right edge of column W−1: 2 atan(aspect tan(fov/2))
    fov_x = 2 * np.degrees(np.arctan(W / H * np.tan(np.radians(fov) / 2)))
    np.testing.assert_allclose(_angle(d[2], d[3]), fov_x, rtol=1e-10)


def test_orientation():
    cam = _cam()
    up, right = cam.frame[1], cam.frame[0]
    # a point above the target is imaged in the upper half (row < H/2), one to the right in
    # the right half (column > W/2); the frame is right-handed with back = right × up
    (col, row), depth = project(cam, jnp.asarray(TARGET) + 0.5 * up)
    assert float(row) < H / 2 and float(depth) > 0
    (col, row), _ = project(cam, jnp.asarray(TARGET) + 0.5 * right)
    assert float(col) > W / 2
    np.testing.assert_allclose(jnp.cross(right, up), cam.frame[2], atol=1e-6)
    # the world up vector points to the image's top half
    (col, row), _ = project(cam, jnp.asarray(TARGET) + jnp.asarray(UP))
    assert float(row) < H / 2
    # frame is orthonormal to float32 round-off
    np.testing.assert_allclose(cam.frame @ cam.frame.T, np.eye(3), atol=1e-6)


def test_jitter_stays_in_pixel_footprint(x64):
    dt = jnp.float64 if x64 else jnp.float32
    cam = _cam()
    n = 4096
    key1, key2 = jax.random.split(jax.random.PRNGKey(0))
    pix = jnp.stack([jax.random.randint(key1, (n,), 0, W), jax.random.randint(key2, (n,), 0, H)],
                    axis=-1).astype(jnp.int32)
    u = jax.random.uniform(jax.random.PRNGKey(1), (n, 2), dt)
    u = u.at[0].set(0).at[1].set(1 - jnp.finfo(dt).epsneg)  # the footprint's extreme corners
    o, d = rays(cam, pix, u)
    raster, depth = projects(cam, o + d)
    # the ray's film point is (x + u0, y + u1): inside [x, x+1) × [y, y+1) up to round-off
    tol = 1e-9 if x64 else 2e-4
    np.testing.assert_allclose(raster, pix + u, atol=tol)
    assert np.all(np.asarray(depth) > 0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=10 * tol)
    assert d.dtype == dt


def test_float32_preserved():
    cam = _cam()
    o, d = generate_ray(cam, jnp.asarray([3, 4], jnp.int32), jnp.asarray([0.2, 0.7], jnp.float32))
    assert o.dtype == d.dtype == jnp.float32
    assert cam.eye.dtype == jnp.float32 and cam.frame.shape == (3, 3)


def test_pose_change_does_not_recompile():
    f = jax.jit(lambda c, p, u: generate_ray(c, p, u))  # a fresh cache
    p, u = jnp.asarray([1, 2], jnp.int32), jnp.asarray([0.5, 0.5])
    f(_cam(), p, u)
    f(look_at([0.0, 0, 0], [0.0, 0, -1], [0, 1, 0], 60.0, W, H), p, u)
    assert f._cache_size() == 1  # pose and fov are traced; only the size is static
    f(_cam(32, 32), p, u)
    assert f._cache_size() == 2


def test_camera_is_a_pytree_with_static_size():
    cam = _cam()
    leaves, tree = jax.tree.flatten(cam)
    assert len(leaves) == 4
    again = jax.tree.unflatten(tree, leaves)
    assert isinstance(again, Camera) and (again.width, again.height) == (W, H)


def test_pixel_coordinates():
    p = pixel_coordinates(3, 2)
    np.testing.assert_array_equal(p, [[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]])
    assert p.dtype == jnp.int32


@pytest.mark.parametrize("kwargs, match", [
    (dict(target=EYE), "coincide"),
    (dict(up=[1.0, 1.0, 16.0]), "parallel"),
    (dict(up=[0.0, 0.0, 0.0]), "parallel"),
    (dict(fov=0.0), "fov"),
    (dict(fov=180.0), "fov"),
    (dict(fov=-10.0), "fov"),
    (dict(fov=float("nan")), "fov"),
    (dict(width=0), "width"),
    (dict(height=-3), "height"),
    (dict(width=64.0), "width"),
    (dict(eye=[0.0, np.inf, 0.0]), "finite"),
    (dict(eye=[0.0, 1.0]), "3-vector"),
])
def test_look_at_rejects(kwargs, match):
    args = dict(eye=EYE, target=TARGET, up=UP, fov=40.0, width=W, height=H) | kwargs
    with pytest.raises(ValueError, match=match):
        look_at(args["eye"], args["target"], args["up"], args["fov"], args["width"],
                args["height"])


# ---------------------------------------------------------------------------------------------
# The field of view along an axis: ``look_at(..., fov_axis=)``
# ---------------------------------------------------------------------------------------------


def _angle_deg(cam, raster_xy) -> float:
    """Angle between the view direction and the ray through a raster point (film edge)."""
    px = jnp.floor(jnp.asarray(raster_xy, jnp.float32))
    u = jnp.asarray(raster_xy, jnp.float32) - px
    _, d = generate_ray(cam, px.astype(jnp.int32), u)
    view = -np.asarray(cam.frame[2], np.float64)
    return float(np.degrees(np.arccos(np.clip(np.dot(np.asarray(d, np.float64), view), -1, 1))))


@pytest.mark.parametrize("width, height", [(200, 100), (100, 200)])
@pytest.mark.parametrize("axis", FOV_AXES)
def test_half_fov_is_the_angle_to_that_edge(axis, width, height):
    cam = look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 50.0, width, height, fov_axis=axis)
    landscape = width >= height
    edge = {"x": "x", "y": "y", "diagonal": "diagonal",
            "smaller": "y" if landscape else "x", "larger": "x" if landscape else "y"}[axis]
    # a point at the middle of the right edge, of the top edge, or the top-right corner
    point = {"x": (width - 1e-4, height / 2), "y": (width / 2, 0.0),
             "diagonal": (width - 1e-4, 0.0)}[edge]
    assert _angle_deg(cam, point) == pytest.approx(25.0, abs=2e-3)


def test_default_is_vertical_and_unchanged():
    a = look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 40.0, 64, 48)
    b = look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 40.0, 64, 48, fov_axis="y")
    assert float(a.tan_half_fov) == float(b.tan_half_fov) == pytest.approx(np.tan(np.radians(20)))


def test_bad_axis():
    with pytest.raises(ValueError, match="fov_axis must be one of"):
        look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 40.0, 64, 48, fov_axis="z")


def test_scene_file_fov_axis(tmp_path):
    doc = {"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "fov": 60, "fov_axis": "x",
                      "width": 40, "height": 20},
           "materials": {"m": {"type": "diffuse", "albedo": 0.5}},
           "meshes": [{"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]],
                       "material": "m"}],
           "lights": [{"type": "point", "position": [0, 2, 0], "intensity": 1}]}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    cam = load_scene(path).camera
    # tan(fov_x / 2) = aspect · tan(fov_y / 2)
    assert 2 * float(cam.tan_half_fov) == pytest.approx(np.tan(np.radians(30)), rel=1e-6)
