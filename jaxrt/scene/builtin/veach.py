"""A Veach-style multiple-importance-sampling scene (Veach 1997, fig. 9.2).

Four glossy plates, from rough (top of the image) to nearly smooth (bottom), reflect four
sphere lights of equal power whose radii span two orders of magnitude. Light sampling wins
on rough plates and small lights; BSDF sampling on smooth plates and large lights; MIS gets
both. Each plate is tilted so that its mirror direction links the camera to the lights.
"""

from __future__ import annotations

import numpy as np

from jaxrt.scene import camera as cm
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.container import build_scene, mesh

PLATE_ROUGHNESS = (0.35, 0.15, 0.05, 0.01)  # GGX α, top plate first
LIGHT_RADII = (0.9, 0.3, 0.1, 0.03)  # left to right
LIGHT_POWER_RADIANCE = 0.8  # radiance × r² (same power for every light)
EYE = np.array([0.0, 2.0, 15.0])
TARGET = np.array([0.0, 0.0, 2.5])
LIGHT_Y, LIGHT_Z = 4.0, -2.0
FOV_DEG = 40.0  # vertical: the four lights (16° above the view axis) and all plates in frame


def _plate(centre: np.ndarray, half_width: float, half_depth: float):
    """A rectangle centred at ``centre`` whose normal bisects the directions to eye and lights."""
    to_eye = EYE - centre
    to_light = np.array([0.0, LIGHT_Y, LIGHT_Z]) - centre
    n = to_eye / np.linalg.norm(to_eye) + to_light / np.linalg.norm(to_light)
    n /= np.linalg.norm(n)
    x = np.array([1.0, 0, 0])
    y = np.cross(n, x)
    w, h = half_width * x, half_depth * y
    v = np.stack([centre - w - h, centre + w - h, centre + w + h, centre - w + h])
    if np.dot(np.cross(v[1] - v[0], v[2] - v[0]), n) < 0:
        v = v[::-1]
    return v, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def veach_mis(width: int = 384, height: int = 256, **options):
    """Four plates (GGX α = 0.35, 0.15, 0.05, 0.01) under four equal-power sphere lights.

    ``options`` go to :func:`jaxrt.scene.container.build_scene`.
    """
    meshes = []
    for k, alpha in enumerate(PLATE_ROUGHNESS):
        centre = np.array([0.0, 0.4 - 0.9 * k, 0.8 + 1.3 * k])
        v, f = _plate(centre, 4.0, 0.55)
        meshes.append(mesh(v, f, mt.conductor(alpha=alpha, ks=0.8), name=f"plate{k}"))
    # a dark diffuse back wall and floor, so the lights do not float in the void
    wall = np.array([[-10, -4, -4], [10, -4, -4], [10, 10, -4], [-10, 10, -4]], np.float64)
    floor = np.array([[-10, -4, -4], [-10, -4, 16], [10, -4, 16], [10, -4, -4]], np.float64)
    quad = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    meshes.append(mesh(wall, quad, mt.diffuse(0.1), name="back_wall"))
    meshes.append(mesh(floor, quad, mt.diffuse(0.1), name="floor"))
    spheres = [lt.sphere_light([x, LIGHT_Y, LIGHT_Z], r, [LIGHT_POWER_RADIANCE / r**2] * 3)
               for x, r in zip((-3.75, -1.25, 1.25, 3.75), LIGHT_RADII, strict=True)]
    cam = cm.look_at(eye=EYE, target=TARGET, up=[0, 1, 0], fov_deg=FOV_DEG, width=width,
                     height=height)
    return build_scene(meshes, cam, spheres, **options)
