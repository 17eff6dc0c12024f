"""Which triangles can block a shadow ray: the scene's own hull faces cannot.

A shadow ray runs from a point on the scene's surfaces to a point a light sampled. When every
point a light can sample lies in the scene, both ends are convex combinations of the scene's
vertices or lie inside its walls. A triangle whose plane has every vertex and every light on
one side (closed) — a wall of a room, the floor under everything, a face of the convex hull —
then meets such a segment only at an end (``t ≈ 0`` or ``t ≈ t_max``, which the any-hit test
excludes: the δt bound and the light end's offset) or along its plane (parallel: never a hit).
So shadow rays need not test it: on the Cornell box 10 of 32 triangles (the five walls), and an
any-hit loop over the other 22 (padded to 24) makes the 256² MIS pass up to 1.17× and the path pass
~1.06× as fast per CPU-second, images bit-identical (benchmarks/README.md#shadow-occluders). Nor
need they test a triangle in the plane of every point the lights sample (:func:`coplanar_faces`: the
Cornell box's light quad), which the segment meets only at its light end: 20 tests left. Those 20
are the two blocks, which :func:`shadow_blockers` then hands to :mod:`jaxrt.geometry.convex`: a
closed convex body is tested by its face planes (five per block), not by its triangles.

Only which triangles are tested changes; every test is the full watertight one. Lights that
sample points outside the scene (directional lights, environments) make every triangle a
possible occluder: then no triangle is left out. Point and spot lights and sphere lights
count as scene points (a sphere by its whole ball). The side test runs in float64 with a
tolerance of 64 float64 ulps of the scene's extent: a vertex that pokes through a wall by less
than that is taken as on the wall, ~10⁶ times below float32's resolution of the same extent.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from jaxrt.core.vecmath import device_array
from jaxrt.geometry.convex import SIDE_TOL, ConvexBodies, convex_bodies
from jaxrt.geometry.triangle import TriangleSet

#: Above this many triangles no list is made (the side test is an F × 3F float64 matrix on the
#: host, 6 MB at 512, run again by every Scene.replace of geometry or lights; brute
#: force is chosen automatically below 96 triangles).
MAX_TRIANGLES = 512


def one_sided_faces(triangles: np.ndarray, points: np.ndarray | None = None,
                    balls: np.ndarray | None = None) -> np.ndarray:
    """(F,) bool: triangles whose plane has every vertex, point and ball on one side (closed).

    Args:
        triangles: (F, 3, 3) vertices (host).
        points: (P, 3) more points that must lie on the same side (point and spot lights);
            None for none.
        balls: (B, 4) ``(centre, radius)`` of balls that must lie wholly on that side.
    Returns:
        True for each triangle of non-zero area whose plane ``n·x = n·v₀`` satisfies
        ``n·(x − v₀) ≤ τ`` for every vertex and point x (and ``n·(c − v₀) + r |n| ≤ τ`` for
        every ball), or the same with every sign reversed; ``τ`` = 64 float64 ulps of
        ``|n|`` times the scene's extent.
    """
    tri = np.asarray(triangles, np.float64)
    points = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64)
    v = np.concatenate([tri.reshape(-1, 3), points.reshape(-1, 3)])
    balls = np.zeros((0, 4)) if balls is None else np.asarray(balls, np.float64).reshape(-1, 4)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    extent = np.max(np.abs(np.concatenate([v, balls[:, :3] + balls[:, 3:]])))
    tol = SIDE_TOL * norm * max(extent, np.finfo(np.float64).tiny)
    s = n @ v.T - np.sum(n * tri[:, 0], axis=1)[:, None]  # (F, V) signed distances × |n|
    c = n @ balls[:, :3].T - np.sum(n * tri[:, 0], axis=1)[:, None]
    r = norm[:, None] * balls[:, 3][None, :]
    below = np.all(s <= tol[:, None], axis=1) & np.all(c + r <= tol[:, None], axis=1)
    above = np.all(s >= -tol[:, None], axis=1) & np.all(c - r >= -tol[:, None], axis=1)
    return (norm > 0) & (below | above)


def coplanar_faces(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(F,) bool: triangles whose plane holds every one of ``points`` (P, 3), P ≥ 1.

    A shadow ray ends at a point a light sampled. When every such point lies in one plane
    (a quad light, coplanar triangle lights, point lights on it), a triangle in that plane
    meets the segment only at its light end, which the any-hit test excludes, or along the
    plane (parallel: never a hit); on the Cornell box, the light's own two triangles. Same
    float64 tolerance as :func:`one_sided_faces`.
    """
    tri = np.asarray(triangles, np.float64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    extent = max(np.max(np.abs(tri)), np.max(np.abs(pts), initial=0.0),
                 np.finfo(np.float64).tiny)
    tol = SIDE_TOL * norm * extent
    s = n @ pts.T - np.sum(n * tri[:, 0], axis=1)[:, None]  # (F, P) signed distances × |n|
    return (norm > 0) & (pts.shape[0] > 0) & np.all(np.abs(s) <= tol[:, None], axis=1)


def shadow_occluders(geometry: Any, triangles: Any, lights: Any):
    """(K,) int32 indices of the triangles a shadow ray must test, or None for all of them.

    A device array (as :class:`jaxrt.scene.container.Scene` holds it); :func:`_occluder_indices` is
    the host computation.
    """
    found = _occluder_indices(geometry, triangles, lights)
    return None if found is None else device_array(found)


def _occluder_indices(geometry: Any, triangles: Any, lights: Any) -> np.ndarray | None:
    """The host part of :func:`shadow_occluders` (numpy indices or None).

    ``lights`` is the scene's light table (:func:`jaxrt.scene.lights.light_table`). Brute-force
    scenes of at most :data:`MAX_TRIANGLES` only (a BVH already skips what a ray cannot
    reach). None when a light samples points outside the scene (directional, environment),
    when no triangle can be left out, or when the arrays are traced (inside ``jit``: nothing
    to read). :func:`jaxrt.scene.queries.unoccluded` gathers these rows of the ``TriangleSet`` once
    per ray batch (its loop pads them to a multiple of its unroll factor); K may be 0.
    """
    s = lights.structure
    if (not isinstance(geometry, TriangleSet) or s.count("directional")
            or s.count("environment") or np.shape(triangles)[0] > MAX_TRIANGLES):
        return None
    arrays = [triangles] + [getattr(lights.table(k), f) for k, f in (
        ("point", "position"), ("spot", "position"), ("sphere", "center"), ("sphere", "radius"),
        ("triangle", "prim"))
        if s.count(k)]
    if any(isinstance(a, jax.core.Tracer) for a in arrays):
        return None
    points, balls = _light_points(lights)
    skip = one_sided_faces(np.asarray(triangles), points, balls)
    if not s.count("sphere"):  # every light end in one plane?
        # triangle lights by the emitters' own rows of `triangles`
        prims = np.asarray(lights.table("triangle").prim) if s.count("triangle") else []
        ends = np.asarray(triangles, np.float64)[prims].reshape(-1, 3)
        skip |= coplanar_faces(np.asarray(triangles), np.concatenate([ends, points]))
    if not np.any(skip):
        return None
    return np.flatnonzero(~skip).astype(np.int32)


def _light_points(lights: Any) -> tuple[np.ndarray, np.ndarray]:
    """(Q, 3) point and spot light positions and (S, 4) sphere lights ``(centre, radius)``;
    triangle lights are scene triangles (among the vertices already)."""
    s = lights.structure
    points = [np.asarray(lights.table(k).position, np.float64).reshape(-1, 3)
              for k in ("point", "spot") if s.count(k)]
    balls = []
    if s.count("sphere"):
        sph = lights.table("sphere")
        balls.append(np.concatenate([np.asarray(sph.center, np.float64).reshape(-1, 3),
                                     np.asarray(sph.radius, np.float64).reshape(-1, 1)], 1))
    return (np.concatenate(points or [np.zeros((0, 3))]),
            np.concatenate(balls or [np.zeros((0, 4))]))


def shadow_blockers(geometry: Any, triangles: Any, lights: Any,
                    prim_material: Any) -> tuple[Any, Any]:
    """``(occluders, convex)``: what a shadow ray tests, as triangles and as convex bodies.

    :func:`shadow_occluders`, then the convex bodies among those triangles
    (:func:`jaxrt.geometry.convex.convex_bodies`; ``prim_material`` (F,): a body's face has one
    material), which are tested by their face planes and so leave the list: ``occluders``
    (K,) int32 indices of the triangles still tested one by one (None: all of them),
    ``convex`` a :class:`~jaxrt.geometry.convex.ConvexBodies` or None (no body; always None when
    ``occluders`` is None or ``prim_material`` is traced). Closest hits test the bodies by
    their planes too (:func:`jaxrt.scene.queries.intersect`).
    """
    occluders = _occluder_indices(geometry, triangles, lights)
    if occluders is None:
        return None, None
    if isinstance(prim_material, jax.core.Tracer):
        return device_array(occluders), None
    tri = np.asarray(triangles)
    emissive = np.zeros(len(tri), bool)
    if lights.structure.count("triangle"):
        emissive[np.asarray(lights.table("triangle").prim)] = True
    points, balls = _light_points(lights)
    found = convex_bodies(tri, np.asarray(occluders), emissive, points, balls,
                          np.asarray(prim_material))
    if not len(found.planes):
        return device_array(occluders), None
    others = np.setdiff1d(np.arange(len(tri)), found.members)
    bodies = ConvexBodies(*(device_array(a.astype(tri.dtype))
                            for a in (found.planes, found.origin, found.caps)),
                          *(device_array(a.astype(np.int32))
                            for a in (found.faces, found.members, others)))
    return device_array(found.kept.astype(np.int32)), bodies
