"""Ray queries over a whole scene, for one ray: closest hit, shadow test, emission.

:func:`intersect` finds the closest triangle or sphere light along a ray (by the scene's
BVH, its convex bodies and triangles, or for camera rays by the planes through the eye) and
returns a :class:`SurfaceHit`; :func:`unoccluded` tests a shadow segment; :func:`emitted`
is the radiance an emitter sends back along a hit ray. Batch them with ``jax.vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import dot, normalize
from jaxrt.geometry.convex import convex_any_hit, convex_closest_hit
from jaxrt.geometry.eye_rays import closest_hit_from_origin
from jaxrt.geometry.spawn import short_of
from jaxrt.geometry.triangle import TriangleSet, any_hit, closest_hit, gamma, miss_hit
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx
from jaxrt.scene.container import Scene

MISS, TRIANGLE, SPHERE = 0, 1, 2  # what a ray hit (SurfaceHit.kind)

class SurfaceHit(NamedTuple):
    """What a ray hit: a triangle, a sphere light, or nothing (``kind == MISS``).

    t: () distance (inf on a miss); p: (3,) hit point (from barycentrics on triangles);
    p_error: (3,) bound on the rounding error of p (:func:`jaxrt.geometry.triangle.surface_point`);
    ng: (3,) unit geometric normal (unflipped; outward on spheres); kind: () int32 MISS,
    TRIANGLE or SPHERE; prim: () int32 triangle index (−1 otherwise); material: () int32;
    light: () int32 global light index of an emitter (−1 if the surface does not emit).
    """

    t: Array
    p: Array
    p_error: Array
    ng: Array
    kind: Array
    prim: Array
    material: Array
    light: Array


def intersect(scene: Scene, o: Array, d: Array, t_max: Array, shared_origin: bool = False,
              emission_only: bool = False) -> SurfaceHit:
    """Closest hit of the ray ``o + t d``, ``0 < t < t_max``, against triangles and spheres.

    On a miss, ``light`` is the environment's global index (−1 without an environment).
    The convex bodies of a brute-force scene (``scene.convex``, :mod:`jaxrt.geometry.convex`) are
    clipped against their face planes instead of testing their triangles: the hit is then
    the face's (``p = o + t d`` with its error bound off the face's plane, the face's normal,
    ``prim`` a triangle of that face). Not for ``shared_origin`` rays, whose triangle tests
    cost less than the planes (clipping its camera rays slows the MIS pass).
    Two static options specialise the query without changing what the caller uses of it:

    - ``shared_origin``: every ray of the batch starts at ``o``, the camera's eye (``o``
      unbatched under ``vmap``), so brute-force triangles are tested by their edge
      planes through it (:mod:`jaxrt.geometry.eye_rays`: ``scene.eye_planes``, or formed in the
      program); a BVH ignores it.
    - ``emission_only``: the caller (a direct estimator's BSDF ray from a surface point)
      uses only the emitter the ray reaches: the emitted radiance, the light and its point.
      Then only the triangles that can block a shadow ray (``scene.occluders``) and the
      emissive ones are tested, and the convex bodies (``scene.convex``) between the origin
      and the emitter found (stopping short of it by the shadow rays' relative margin). Exact
      but for that margin: a left-out face is a hull face, beyond whose plane
      nothing lies, or lies in the plane of every light end, which the ray crosses once;
      either way no emitter lies past it (:mod:`jaxrt.geometry.occluders`), so the ray that meets
      it first reaches no emitter (``light`` −1; ``p``, ``prim`` and ``t`` may then be of
      another non-emissive triangle, or a miss). None of them: every triangle is tested.
    """
    geometry, prims, bodies = scene.geometry, None, None
    if emission_only and scene.occluders is not None:
        parts = [scene.occluders.astype(jnp.int32)]
        if scene.lights.structure.count("triangle"):
            parts.append(scene.lights.table("triangle").prim.astype(jnp.int32))
        # an emissive triangle among the occluders is tested twice (ties keep the first)
        prims = jnp.concatenate(parts)
    elif not shared_origin and scene.convex is not None and scene.convex.others.shape[0]:
        prims, bodies = scene.convex.others, scene.convex  # the bodies by their planes
    if prims is not None:  # the rows tested, gathered once per batch of rays
        geometry = jax.tree.map(lambda a: a[prims], geometry)
    if prims is not None and prims.shape[0] == 0:
        # nothing can block or emit (a lone plane under delta lights): the ray reaches none
        hit = miss_hit(o.dtype)
    elif shared_origin and isinstance(geometry, TriangleSet):
        hit = closest_hit_from_origin(geometry, o, d, t_max, scene.eye_planes)
    else:  # a hit shading continues from (not the eye's, not an emitter's): see winner_hit
        hit = closest_hit(geometry, o, d, t_max,
                          stored_barycentrics=not (emission_only or shared_origin))
    if prims is not None and prims.shape[0]:  # back to the scene's triangle indices
        prim = jnp.where(hit.prim >= 0, prims[jnp.maximum(hit.prim, 0)], -1)
        if emission_only and scene.convex is not None:
            # a convex body before the emitter: the ray reaches none (stopping short of the
            # emitter by the shadow rays' relative margin, as spawn_ray_to does)
            prim = jnp.where(convex_any_hit(scene.convex, o, d, short_of(hit.t)), -1, prim)
        hit = hit._replace(prim=prim)
    if bodies is not None:  # a face of a body before the closest triangle
        face = convex_closest_hit(bodies, o, d, jnp.minimum(hit.t, t_max))
        on_face = face.prim >= 0
        hit = hit._replace(**{k: jnp.where(on_face, getattr(face, k), getattr(hit, k))
                              for k in ("t", "prim", "ng", "p", "p_error")})
    tri_hit = hit.prim >= 0
    prim = jnp.maximum(hit.prim, 0)
    # the winner's point, error bound and normal come with the hit (no (3, 3) gather here);
    # a miss keeps a unit normal so that shading code masked by ``kind`` stays finite
    p, p_error = hit.p, hit.p_error
    ng = jnp.where(tri_hit, hit.ng, jnp.asarray([0, 0, 1], o.dtype))
    kind = jnp.where(tri_hit, TRIANGLE, MISS).astype(jnp.int32)
    t = jnp.where(tri_hit, hit.t, jnp.inf).astype(o.dtype)
    env = lt.environment_light_index(scene.lights)
    light = jnp.where(tri_hit, scene.prim_light[prim], env)
    if scene.lights.structure.count("sphere"):
        ts, js = lt.intersect_spheres(scene.lights, o, d, jnp.minimum(t, t_max))
        sph = ts < t
        c = scene.lights.sphere.center[_local_index(scene.lights.structure, "sphere", js)[0]]
        p_s = o + ts * d
        kind = jnp.where(sph, SPHERE, kind)
        t = jnp.where(sph, ts, t)
        p = jnp.where(sph, p_s, p)
        # a sphere hit's error grows with |p| and with the distance travelled
        p_error = jnp.where(sph, _sphere_point_error(p_s, o, ts * d), p_error)
        ng = jnp.where(sph, normalize(p_s - c), ng)
        light = jnp.where(sph, js, light)
    return SurfaceHit(t=t, p=p, p_error=p_error, ng=ng, kind=kind,
                      prim=jnp.where(tri_hit, hit.prim, -1),
                      material=jnp.where(tri_hit, scene.prim_material[prim], 0),
                      light=light.astype(jnp.int32))


def _sphere_point_error(p: Array, o: Array, td: Array) -> Array:
    """Conservative error of ``p = o + t d`` on a sphere: γ₅ (|o| + |t d|) per component."""
    eps = jnp.finfo(p.dtype).eps / 2
    g5 = 5 * eps / (1 - 5 * eps)
    return g5 * (jnp.abs(o) + jnp.abs(td)) + g5 * jnp.abs(p)


def unoccluded(scene: Scene, o: Array, d: Array, t_max: Array) -> Array:
    """True when nothing blocks ``o + t d`` for ``0 < t < t_max`` (a shadow ray, any hit)."""
    geometry = scene.geometry
    if scene.occluders is None:
        blocked = any_hit(geometry, o, d, t_max)
    elif scene.occluders.shape[0]:
        # the triangles that can block (jaxrt.geometry.occluders), gathered once per batch of rays
        blocked = any_hit(jax.tree.map(lambda a: a[scene.occluders], geometry), o, d, t_max)
    else:  # nothing in the scene can block a shadow ray
        blocked = jnp.zeros(jnp.shape(t_max), bool)
    if scene.convex is not None:
        blocked = blocked | convex_any_hit(scene.convex, o, d, t_max)
    if scene.lights.structure.count("sphere"):
        ts, _ = lt.intersect_spheres(scene.lights, o, d, t_max)
        blocked = blocked | (ts < t_max)
    return ~blocked


def emitted(scene: Scene, hit: SurfaceHit, wo: Array) -> Array:
    """Radiance ``le`` leaving the hit surface towards ``wo`` (3,); the environment on a miss.

    ``wo`` points from the hit back to the ray's origin (so a miss looks up ``−wo``).
    """
    lights = scene.lights
    le = jnp.where(hit.kind == TRIANGLE, lt.le_triangle(lights, hit.light, wo, hit.p), 0)
    if lights.structure.count("sphere"):
        le = jnp.where(hit.kind == SPHERE, lt.le_sphere(lights, hit.light, wo, hit.p), le)
    if lights.structure.environment != "none":
        le = jnp.where(hit.kind == MISS, lt.le_environment(lights, -wo), le)
    return le


def light_normal(scene: Scene, light: Array, q: Array) -> Array:
    """Unit surface normal of the light ``light`` at its point ``q`` (zero for lights without
    a surface: point, spot, directional, environment). Used to offset shadow-ray targets."""
    lights = scene.lights
    s = lights.structure
    n = jnp.zeros_like(q)
    if s.count("triangle"):
        j, mine = _local_index(s, "triangle", light)
        # one gather per component from the (3, L) table: under vmap each is a contiguous
        # vector, where gathering (3,) rows cost a (…, 3) kernel of its own
        n = jnp.where(mine, lights.triangle.normal[j].astype(q.dtype), n)
    if s.count("sphere"):
        j, mine = _local_index(s, "sphere", light)
        n = jnp.where(mine, normalize(q - lights.sphere.center[j]), n)
    return n


def light_point_error(scene: Scene, light: Array, p: Array, q: Array) -> Array:
    """Error bound (3,) of a light point ``q`` sampled from the shading point ``p``.

    A shadow ray from ``p`` must stop short of the light's own surface by more than the
    intersection test's error in ``t`` there. The watertight test works on the vertices
    relative to the ray origin, so that error grows with the light's extent seen from ``p``,
    not with ``|q|``: ``γ₇ max_i ‖v_i − p‖_∞`` in every component for a triangle (a unit
    triangle 1e-4 above ``p``, steep rays of length 3e-4: ``t`` off by 1.5e-4 relative, and
    11 % of the shadow rays re-hit the light with ``γ₇|q|`` alone), bounded from above by
    ``‖q − p‖_∞ + diameter`` (precomputed per light, so no vertex is gathered per sample);
    ``γ₇ (‖c − p‖_∞ + r)`` for
    a sphere; plus ``γ₇|q|`` for ``q``'s own rounding. Lights without a surface: ``γ₇|q|``.
    """
    lights = scene.lights
    s = lights.structure
    g = gamma(7, q.dtype)
    err = g * jnp.abs(q)
    if s.count("triangle"):
        j, mine = _local_index(s, "triangle", light)
        # max_i ‖v_i − p‖_∞ ≤ ‖q − p‖_∞ + diameter (q lies on the triangle): no vertex gather
        extent = jnp.max(jnp.abs(q - p)) + lights.triangle.diameter[j].astype(q.dtype)
        err = jnp.where(mine, err + g * extent, err)
    if s.count("sphere"):
        j, mine = _local_index(s, "sphere", light)
        c = lights.sphere.center[j].astype(q.dtype)
        extent = jnp.max(jnp.abs(c - p)) + lights.sphere.radius[j].astype(q.dtype)
        err = jnp.where(mine, err + g * extent, err)
    return err


def _local_index(structure, kind: str, light: Array) -> tuple[Array, Array]:
    """Index within the ``kind`` table (clamped) and whether global ``light`` is of that kind."""
    off, cnt = structure.offset(kind), structure.count(kind)
    return jnp.clip(light - off, 0, cnt - 1), (light >= off) & (light < off + cnt)


def material_at(scene: Scene, hit: SurfaceHit) -> mt.Material:
    """The material row of a hit (one gather per field), its textured fields looked up at the
    hit's texture coordinates (:func:`jaxrt.scene.textures.textured_material`; only in a
    scene with textures: without, no texture code is traced)."""
    m = jax.tree.map(lambda a: a[hit.material], scene.materials)
    if scene.textures is None:
        return m
    return tx.textured_material(scene.textures, m, hit.material, hit.prim, hit.p)


def shading_normal(ng: Array, wo: Array) -> Array:
    """The geometric normal flipped to the viewer's side (two-sided reflection)."""
    return jnp.where(dot(ng, wo) < 0, -ng, ng)
