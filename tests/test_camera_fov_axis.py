"""``look_at(..., fov_axis=)``: the field of view measured across x, y, the diagonal, the
smaller or the larger side, so that Mitsuba 3 (``fov_axis``) and pbrt-v4 (shorter side)
cameras carry over."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.camera import FOV_AXES, generate_ray, look_at
from jaxrt.scene_file import load_scene


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
