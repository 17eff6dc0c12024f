"""The Cornell box, from the measured data published by the Cornell Program of Computer Graphics.

Coordinates are the published millimetres divided by 1000 (metres); the camera is the
published one (position (278, 273, −800) mm looking along +z, 35 mm focal length on a 25 mm
film: vertical field of view 2·atan(12.5/35) ≈ 39.3°). Quads are split into two triangles
and oriented to face the inside of the box (walls) or the outside of the blocks, the light
faces down. Reflectances are the usual RGB fits of the measured spectra.
"""

from __future__ import annotations

import numpy as np

from jaxrt.scene import camera as cm
from jaxrt.scene import materials as mt
from jaxrt.scene.container import build_scene, mesh

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_RADIANCE = (18.387, 13.9873, 6.75357)
FOV_DEG = float(np.degrees(2 * np.arctan(12.5 / 35.0)))

_MM = 1e-3
FLOOR = [[552.8, 0, 0], [0, 0, 0], [0, 0, 559.2], [549.6, 0, 559.2]]
CEILING = [[556, 548.8, 0], [556, 548.8, 559.2], [0, 548.8, 559.2], [0, 548.8, 0]]
BACK = [[549.6, 0, 559.2], [0, 0, 559.2], [0, 548.8, 559.2], [556, 548.8, 559.2]]
GREEN_WALL = [[0, 0, 559.2], [0, 0, 0], [0, 548.8, 0], [0, 548.8, 559.2]]
RED_WALL = [[552.8, 0, 0], [549.6, 0, 559.2], [556, 548.8, 559.2], [556, 548.8, 0]]
LIGHT = [[343, 548.8, 227], [343, 548.8, 332], [213, 548.8, 332], [213, 548.8, 227]]
LIGHT_Y = 548.8 - 0.1  # just below the ceiling so the two never coincide
SHORT_BLOCK = [
    [[130, 165, 65], [82, 165, 225], [240, 165, 272], [290, 165, 114]],
    [[290, 0, 114], [290, 165, 114], [240, 165, 272], [240, 0, 272]],
    [[130, 0, 65], [130, 165, 65], [290, 165, 114], [290, 0, 114]],
    [[82, 0, 225], [82, 165, 225], [130, 165, 65], [130, 0, 65]],
    [[240, 0, 272], [240, 165, 272], [82, 165, 225], [82, 0, 225]],
]
TALL_BLOCK = [
    [[423, 330, 247], [265, 330, 296], [314, 330, 456], [472, 330, 406]],
    [[423, 0, 247], [423, 330, 247], [472, 330, 406], [472, 0, 406]],
    [[472, 0, 406], [472, 330, 406], [314, 330, 456], [314, 0, 456]],
    [[314, 0, 456], [314, 330, 456], [265, 330, 296], [265, 0, 296]],
    [[265, 0, 296], [265, 330, 296], [423, 330, 247], [423, 0, 247]],
]
BOX_CENTRE = np.array([278.0, 274.4, 279.6]) * _MM


def _quads(quads, facing_point, outward: bool):
    """Vertices and faces of quads split in two triangles, wound so normals face the right way.

    ``outward=False``: normals point towards ``facing_point`` (walls seen from inside);
    ``outward=True``: normals point away from it (a block seen from outside).
    """
    verts, faces = [], []
    for q in quads:
        q = np.asarray(q, np.float64) * _MM
        n = np.cross(q[1] - q[0], q[2] - q[0])
        towards = np.dot(n, facing_point - q.mean(0)) > 0
        if towards == outward:
            q = q[::-1]
        base = len(verts) * 4
        verts.append(q)
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return np.concatenate(verts), np.asarray(faces, np.int32)


def _light_quad(scale: float):
    q = np.asarray(LIGHT, np.float64)
    q[:, 1] = LIGHT_Y
    c = q.mean(0)
    q = (c + (q - c) * scale) * _MM
    # wind so that the normal points down (-y): the light is one-sided
    if np.cross(q[1] - q[0], q[2] - q[0])[1] > 0:
        q = q[::-1]
    return q, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def _block_centre(quads):
    return np.asarray(quads, np.float64).reshape(-1, 3).mean(0) * _MM


def cornell_meshes(light_scale: float = 1.0, light_radiance=LIGHT_RADIANCE, glossy=False):
    """The box as a list of :class:`jaxrt.scene.container.Mesh` (walls, blocks, light)."""
    white = mt.diffuse(WHITE)
    floor_mat = mt.phong(kd=np.multiply(WHITE, 0.5), ks=0.4, exponent=60.0) if glossy else white
    tall_mat = mt.conductor(alpha=0.08, ks=(0.95, 0.64, 0.54)) if glossy else white
    short_mat = mt.mirror(0.9) if glossy else white
    meshes = []
    for name, quads, mat in [("floor", [FLOOR], floor_mat), ("ceiling", [CEILING], white),
                             ("back", [BACK], white), ("green_wall", [GREEN_WALL],
                                                       mt.diffuse(GREEN)),
                             ("red_wall", [RED_WALL], mt.diffuse(RED))]:
        v, f = _quads(quads, BOX_CENTRE, outward=False)
        meshes.append(mesh(v, f, mat, name=name))
    for name, quads, mat in [("short_block", SHORT_BLOCK, short_mat),
                             ("tall_block", TALL_BLOCK, tall_mat)]:
        v, f = _quads(quads, _block_centre(quads), outward=True)
        meshes.append(mesh(v, f, mat, name=name))
    lv, lf = _light_quad(light_scale)
    radiance = np.asarray(light_radiance, np.float64) / light_scale**2
    meshes.append(mesh(lv, lf, mt.diffuse(0.0), emission=radiance, name="light"))
    return meshes


def cornell_camera(width: int = 256, height: int = 256):
    """The published camera: from (0.278, 0.273, −0.8) m along +z, vertical fov ≈ 39.3°."""
    return cm.look_at(eye=[0.278, 0.273, -0.8], target=[0.278, 0.273, 0.0], up=[0, 1, 0],
                      fov_deg=FOV_DEG, width=width, height=height)


def cornell_box(width: int = 256, height: int = 256, **options):
    """The classic Cornell box (diffuse only; one quad light of radiance ``LIGHT_RADIANCE``).

    ``options`` go to :func:`jaxrt.scene.container.build_scene` (accel, triangle_sampling,
    light_selection). 32 triangles: brute-force intersection under ``accel="auto"``.
    """
    return build_scene(cornell_meshes(), cornell_camera(width, height), **options)


def cornell_box_small(width: int = 256, height: int = 256, light_scale: float = 0.1,
                      **options):
    """The box lit by a light ``light_scale`` times the size and 1/scale² brighter (same power)."""
    return build_scene(cornell_meshes(light_scale=light_scale), cornell_camera(width, height),
                       **options)


def cornell_box_glossy(width: int = 256, height: int = 256, **options):
    """Phong floor, rough GGX copper tall block, mirror short block: all four BSDF kinds."""
    return build_scene(cornell_meshes(glossy=True), cornell_camera(width, height), **options)
