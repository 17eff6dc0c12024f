"""A room under a ceiling of many small lamps: where choosing a light by power alone fails.

A 4 × 4 m room (floor, back wall, two side walls) and a glossy floor with two blocks on it,
lit by ``rows × rows`` small square lamps on the ceiling (two triangles each: 1 152 emissive
triangles at the default 24 × 24). The lamps' radiances span two orders of magnitude, the
brightest along the far wall: power selection sends most shadow rays there, wherever the
shading point is, though the lamps overhead contribute most to it. The light BVH
(``light_selection="bvh"``) weighs lamps by their distance and orientation at the point.
The camera looks down at the floor: the lamps themselves are out of view (their pixels'
own footprint noise would hide the light selection's). Resampled importance
sampling (``estimator="ris"``) chooses among several candidates by what they contribute.
"""

from __future__ import annotations

import numpy as np

from jaxrt.scene import camera as cm
from jaxrt.scene import materials as mt
from jaxrt.scene.container import build_scene, mesh

ROOM = 2.0  # half-width of the room (m); the floor is y = 0, the ceiling y = 2.5
CEILING = 2.5
COLOURS = ([1.0, 0.85, 0.6], [0.6, 0.8, 1.0], [1.0, 1.0, 1.0])


def _quad(v) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(v, np.float64), np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def _box(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float64)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [3, 7, 6], [3, 6, 2], [0, 4, 7], [0, 7, 3], [1, 2, 6], [1, 6, 5]], np.int32)
    return v, f


def lamp_grid(width: int = 256, height: int = 192, rows: int = 24, glossy: bool = True,
              **options):
    """The room under ``rows × rows`` ceiling lamps (``2 rows²`` emissive triangles).

    ``glossy``: a Phong floor and a GGX metal block (the default); ``False`` makes both
    diffuse, so that which lamps matter at a point depends on where it is, not on its BSDF.

    Lamp ``(i, j)`` (``i`` from the camera's side to the far wall) has radiance
    ``0.25 · 100^(i/(rows−1))`` in one of three colours, so the far row is 100× the near one.
    ``options`` go to :func:`jaxrt.scene.container.build_scene` (BVH by default here).
    """
    if rows < 1:
        raise ValueError(f"rows must be >= 1, got {rows}")
    r, c = ROOM, CEILING
    meshes = [
        mesh(*_quad([[-r, 0, -r], [-r, 0, r], [r, 0, r], [r, 0, -r]]),
             mt.phong([0.35, 0.35, 0.35], 0.25, 40.0) if glossy else mt.diffuse(0.5),
             name="floor"),
        mesh(*_quad([[-r, 0, -r], [r, 0, -r], [r, c, -r], [-r, c, -r]]), mt.diffuse(0.6),
             name="back wall"),
        mesh(*_quad([[-r, 0, -r], [-r, c, -r], [-r, c, r], [-r, 0, r]]),
             mt.diffuse([0.6, 0.2, 0.2]), name="left wall"),
        mesh(*_quad([[r, 0, -r], [r, 0, r], [r, c, r], [r, c, -r]]),
             mt.diffuse([0.2, 0.6, 0.2]), name="right wall"),
        mesh(*_box([-0.9, 0.0, -0.8], [-0.2, 0.9, -0.1]), mt.diffuse(0.7), name="tall block"),
        mesh(*_box([0.3, 0.0, 0.0], [0.9, 0.45, 0.6]),
             mt.conductor(0.2, [0.9, 0.7, 0.5]) if glossy else mt.diffuse([0.9, 0.7, 0.5]),
             name="short block"),
    ]
    pitch = 2 * r / rows
    half = 0.3 * pitch
    centres = -r + pitch * (np.arange(rows) + 0.5)
    by_lamp = {}
    for i, z in enumerate(centres[::-1]):  # i = 0 nearest the camera (z = +r)
        for j, x in enumerate(centres):
            colour = COLOURS[(i + j) % len(COLOURS)]
            # facing down: wound so that the normal points to −y
            v = [[x - half, c - 1e-3, z - half], [x + half, c - 1e-3, z - half],
                 [x + half, c - 1e-3, z + half], [x - half, c - 1e-3, z + half]]
            by_lamp.setdefault((i, tuple(colour)), []).append(v)
    for (i, colour), quads in by_lamp.items():
        radiance = 0.25 * 100.0 ** (i / max(rows - 1, 1))
        v = np.concatenate([np.asarray(q, np.float64) for q in quads])
        f = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]], np.int32) + 4 * k
                            for k in range(len(quads))])
        meshes.append(mesh(v, f, mt.diffuse(0.0), emission=[radiance * ch for ch in colour],
                           name=f"lamps row {i}"))
    cam = cm.look_at(eye=[0.0, 1.3, 1.95], target=[0.0, 0.25, -1.0], up=[0, 1, 0],
                     fov_deg=60, width=width, height=height)
    options.setdefault("accel", "bvh")
    return build_scene(meshes, cam, **options)
