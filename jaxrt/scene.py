"""The ``Scene`` pytree: geometry, materials, lights and camera, with its builder and validation.

A scene is arrays (traced: vertices, albedos, radiances, the camera pose) plus *static*
structure (hashable, part of the compiled program): the BSDF kinds present, the light kinds
and counts, the acceleration structure's class, the image size. ``jax.jit`` therefore
specialises to what the scene contains — a diffuse-only scene compiles no glossy code, a
scene with only point lights no area-light sampling — and a scene of the same structure with
new numbers (another albedo, another radiance) compiles nothing.

Surface conventions:

- Triangles are *two-sided for reflection*: the shading normal is the geometric normal
  ``normalize((v1 − v0) × (v2 − v0))`` flipped to the side of the viewer ``wo``, so meshes
  with inconsistent winding still shade. BSDFs themselves are one-sided about that normal.
- Emission is one-sided by default: an emissive triangle emits on the side of its geometric
  normal only (``two_sided_emission=True`` emits on both sides).
- Sphere lights are pure emitters (they occlude and emit, but reflect nothing).

Build a scene from numpy arrays in a few lines::

    import numpy as np
    from jaxrt import scene, materials, lights, camera
    quad = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
    floor = scene.mesh(quad, [[0, 1, 2], [0, 2, 3]], materials.diffuse(0.5))
    cam = camera.look_at(eye=[0, 1, 3], target=[0, 0, 0], up=[0, 1, 0], fov_deg=40,
                         width=64, height=48)
    s = scene.build_scene([floor], cam, [lights.point_light([0, 2, 0], 10.0)])
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt import lights as lt
from jaxrt import materials as mt
from jaxrt.accel import build_geometry
from jaxrt.convex import convex_any_hit, convex_closest_hit
from jaxrt.derivatives import nondifferentiable
from jaxrt.intersect import TriangleSet, any_hit, closest_hit, gamma, miss_hit
from jaxrt.occluders import shadow_blockers
from jaxrt.shared_origin import closest_hit_from_origin, eye_planes
from jaxrt.spawn import short_of
from jaxrt.vecmath import device_array, dot, normalize

MISS, TRIANGLE, SPHERE = 0, 1, 2  # what a ray hit (SurfaceHit.kind)


class Mesh(NamedTuple):
    """A triangle mesh with one material, and optionally uniform emission (a host-side record).

    vertices: (V, 3) float; faces: (F, 3) int; material: a :class:`jaxrt.materials.Material`;
    emission: (3,) radiance or None (not a light); a declared emission, even 0, makes the mesh
    a light, so the static structure follows what was declared, not the values;
    two_sided_emission: emit on both sides.
    """

    vertices: np.ndarray
    faces: np.ndarray
    material: mt.Material
    emission: np.ndarray | None = None
    two_sided_emission: bool = False
    name: str = "mesh"


def mesh(vertices, faces, material: mt.Material, emission=None, two_sided_emission=False,
         name="mesh") -> Mesh:
    """Validate and wrap a mesh: finite vertices, integer faces inside the vertex array.

    Raises ValueError naming the mesh and the problem (non-finite vertices, faces out of
    range, wrong shapes, negative or non-finite emission).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"mesh {name!r}: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ValueError(f"mesh {name!r}: faces must have shape (F, 3) with F > 0, got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.equal(np.mod(f, 1), 0)):
            raise ValueError(f"mesh {name!r}: face indices must be integers")
        f = f.astype(np.int64)
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if bad.size:
        raise ValueError(f"mesh {name!r}: non-finite vertex coordinates at vertex {int(bad[0])}"
                         f" ({bad.size} vertices in all)")
    out = np.flatnonzero(np.any((f < 0) | (f >= len(v)), axis=1))
    if out.size:
        raise ValueError(f"mesh {name!r}: face {int(out[0])} = {f[out[0]].tolist()} indexes "
                         f"outside the vertex array of {len(v)} vertices")
    e = None
    if emission is not None:
        e = np.broadcast_to(np.asarray(emission, np.float64), (3,)).copy()
        if not np.all(np.isfinite(e)) or np.any(e < 0):
            raise ValueError(f"mesh {name!r}: emission must be finite and >= 0, got {e.tolist()}")
        # a declared emission stays a light even at 0: the scene's static structure follows
        # what was declared, not the values, so a sweep of radiance through 0 compiles once
    return Mesh(v, f.astype(np.int32), material, e, bool(two_sided_emission), name)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scene:
    """Everything a render needs. Arrays are traced; fields marked static are compile-time.

    geometry: a triangle set or BVH (:mod:`jaxrt.accel`) over all F triangles.
    triangles: (F, 3, 3) vertices, in the geometry's primitive order.
    prim_material: (F,) int32 material index per triangle.
    prim_light: (F,) int32 global light index of an emissive triangle, −1 otherwise.
    materials: material table, leading (M,) axis (:func:`jaxrt.materials.material_table`).
    lights: the light table (:mod:`jaxrt.lights`).
    camera: the camera (:mod:`jaxrt.camera`); its width and height are static.
    material_kinds: static sorted tuple of the BSDF kinds present.
    occluders: the triangles a shadow ray tests one by one
        (:func:`jaxrt.occluders.shadow_blockers`), or None for all of ``geometry``.
    convex: the convex bodies shadow rays and closest hits test by their face planes
        (:class:`jaxrt.convex.ConvexBodies`, whose triangles ``occluders`` and closest hits
        leave out), or None.
    eye_planes: the brute-force triangles' edge planes through the camera's eye, which the
        camera rays are tested by (:func:`jaxrt.shared_origin.eye_planes`, formed on the
        host), or None (a BVH, or arrays traced when the scene was made: the program forms
        them).

    ``occluders``, ``convex`` and ``eye_planes`` are derived from the other fields: change
    the scene with :meth:`replace`, which forms them again (or keeps what it is given). A
    copy made otherwise (``dataclasses.replace``, or rebuilt from its leaves by
    ``jax.tree.map``) has them formed again by each program's entry,
    :meth:`with_own_derived_state`, so it renders right too.
    """

    geometry: Any
    triangles: Array
    prim_material: Array
    prim_light: Array
    materials: mt.Material
    lights: Any
    camera: Any
    material_kinds: tuple[int, ...] = dataclasses.field(metadata=dict(static=True))
    occluders: Any = None
    convex: Any = None
    eye_planes: Any = None

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def num_triangles(self) -> int:
        return int(self.triangles.shape[0])

    def replace(self, **changes) -> Scene:
        """A copy with some fields replaced (e.g. a new camera or new materials).

        ``eye_planes`` are formed again for a new ``camera`` or ``geometry`` unless given.

        ``occluders`` and ``convex`` belong to the scene's triangles, materials and lights: a
        copy with new ``geometry``, ``triangles``, ``prim_material`` or ``lights`` finds them
        again
        (:func:`jaxrt.occluders.shadow_blockers`; None, every triangle tested, when the new
        arrays are traced) unless ``occluders`` is given too (``convex`` then stays unless
        given: a body tested as planes and as triangles is still right).
        """
        new = dataclasses.replace(self, **changes)
        if "occluders" not in changes and {"geometry", "triangles", "lights",
                                           "prim_material"} & set(changes):
            occluders, convex = shadow_blockers(new.geometry, new.triangles, new.lights,
                                                new.prim_material)
            new = dataclasses.replace(new, occluders=occluders, convex=convex)
        if "eye_planes" not in changes and {"geometry", "camera"} & set(changes):
            new = dataclasses.replace(new, eye_planes=eye_planes(new.geometry, new.camera))
        return _formed(new)

    def with_own_derived_state(self) -> Scene:
        """This scene with ``occluders``, ``convex`` and ``eye_planes`` formed again from its own
        geometry, triangles, materials, lights and camera, unless they are known to belong to
        them: a scene made by :func:`build_scene` or :meth:`replace` (which honours derived
        fields it is given, e.g. ``replace(occluders=None)``, every triangle tested) is
        returned as it is, and so is one with traced arrays (a jit argument: nothing can be
        formed from tracers, so the fields are kept, unchecked, as passed in).

        A program's entry calls it (:class:`jaxrt.passes.RenderPass`, :func:`guard_geometry`),
        so that a copy made with ``dataclasses.replace`` or rebuilt from its leaves, which keeps
        its original's derived fields, still renders right: with the old camera's plane table
        78 % of a 24² image's pixels were wrong, with the old blocks' convex planes the moved
        blocks cast the old shadows. ~7 ms of numpy for the Cornell box, only for such copies.
        """
        if getattr(self, _FORMED, False) or any(
                isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(self)):
            return self
        occluders, convex = shadow_blockers(self.geometry, self.triangles, self.lights,
                                            self.prim_material)
        return _formed(dataclasses.replace(self, occluders=occluders, convex=convex,
                                           eye_planes=eye_planes(self.geometry, self.camera)))

    def summary(self) -> str:
        """A few lines describing the scene's structure (what the compiled kernel contains)."""
        kinds = ", ".join(mt.KIND_NAMES[k] for k in self.material_kinds)
        shadow = ("" if self.occluders is None else
                  f", shadow rays test {self.occluders.shape[0]} of them")
        if self.convex is not None:
            planes = int(np.sum(np.any(np.asarray(self.convex.planes)[..., :3] != 0, -1)))
            shadow += f" and {self.convex.count} convex bodies ({planes} planes)"
        return (f"Scene: {self.width}x{self.height} camera, {self.num_triangles} triangles "
                f"({type(self.geometry).__name__}){shadow}, {self.materials.kind.shape[0]} "
                f"materials [{kinds}], lights: {describe_lights(self.lights)}")


#: Set on a scene made by :func:`build_scene` or :meth:`Scene.replace`: its derived fields
#: (``occluders``, ``convex``, ``eye_planes``) belong to its other fields. Not a dataclass
#: field, so a copy made with ``dataclasses.replace`` or unflattened from its leaves lacks it.
_FORMED = "_derived_state_formed"


def _formed(scene: Scene) -> Scene:
    object.__setattr__(scene, _FORMED, True)
    return scene


def build_scene(meshes: Sequence[Mesh], camera, extra_lights: Sequence[Any] = (), *,
                accel: str = "auto", triangle_sampling: str = "area",
                light_selection: str = "power") -> Scene:
    """Assemble a :class:`Scene` from meshes, a camera and non-mesh lights.

    Emissive meshes become triangle lights automatically (one light per triangle, radiance
    from ``Mesh.emission``). ``extra_lights``: light records from :mod:`jaxrt.lights` (point,
    spot, directional, sphere, environment). ``accel``: "auto" | "brute" | "bvh".
    ``triangle_sampling``: how every light-sampling estimator (MIS included) samples triangle
    lights, "area" (uniform on the triangle) or "solid_angle" (uniform in the spherical
    triangle); ``light_area`` / ``light_solid_angle`` override it. The default "area" is
    chosen by measurement (MIS, 1 + 1 samples, efficiency 1 / (variance × CPU time), paired):
    on the Cornell box the variance is the same and area sampling 1.46× cheaper; with the
    light 10× smaller 1.55× more efficient; with it 3.5× larger (12× the area, close to the
    walls) solid angle has 1.5× less variance and the two are even (0.96×) — see
    benchmarks/README.md, "light sampling".
    ``light_selection``: "uniform" | "power".

    With no light at all the scene renders black: a warning says so.
    """
    if len(meshes) == 0:
        raise ValueError("build_scene needs at least one mesh")
    tris, mat_idx, mats = [], [], []
    emissive = []  # (first prim, count, radiance, two_sided) per emissive mesh
    offset = 0
    for i, m in enumerate(meshes):
        if not isinstance(m, Mesh):
            raise TypeError(f"meshes[{i}] is a {type(m).__name__}, expected jaxrt.scene.Mesh "
                            "(build one with jaxrt.scene.mesh)")
        t = m.vertices[m.faces]  # (F, 3, 3)
        tris.append(t)
        mat_idx.append(np.full(len(t), i, np.int32))
        mats.append(m.material)
        if m.emission is not None:
            emissive.append((offset, t, m.emission, m.two_sided_emission, m.name))
        offset += len(t)
    triangles = np.concatenate(tris)
    prim_material = np.concatenate(mat_idx)
    table, kinds = mt.material_table(mats)

    light_list = list(extra_lights)
    for first, t, e, two, name in emissive:
        area2 = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        keep = area2 > 0
        if not np.all(keep):
            warnings.warn(f"mesh {name!r}: {int((~keep).sum())} zero-area emissive triangles "
                          "do not emit (they have no area to sample)", stacklevel=2)
        prims = first + np.flatnonzero(keep)
        if prims.size:
            light_list.append(lt.triangle_lights(t[keep], np.broadcast_to(e, (prims.size, 3)),
                                                 prims.astype(np.int32), two_sided=two))
    if not light_list:
        # a black environment keeps every kernel well defined; the image is black
        warnings.warn("the scene has no lights: every image of it is black", stacklevel=2)
        light_list = [lt.constant_environment([0.0] * 3)]
    light_table = lt.light_table(light_list, triangle_sampling=triangle_sampling,
                                 selection=light_selection,
                                 scene_radius=_bounding_radius(triangles))
    prim_light = np.full(len(triangles), -1, np.int32)
    if light_table.triangle is not None:
        prims = np.asarray(light_table.triangle.prim)
        prim_light[prims] = light_table.structure.offset("triangle") + np.arange(len(prims))

    # primitive indices of hits always refer to this (mesh) order, whatever the accelerator
    geometry = build_geometry(triangles, accel=accel)
    dt = jax.dtypes.canonicalize_dtype(jnp.float64)
    stored = device_array(triangles, dt)  # what the kernels read; occluders are found in it
    return _formed(Scene(
        geometry=geometry,
        triangles=stored,
        prim_material=device_array(prim_material),
        prim_light=device_array(prim_light),
        materials=table,
        lights=light_table,
        camera=camera,
        material_kinds=kinds,
        **dict(zip(("occluders", "convex"), shadow_blockers(geometry, stored, light_table,
                                                                    prim_material),
                   strict=True)),
        eye_planes=eye_planes(geometry, camera),
    ))


def shading_scene(material: mt.Material, lights: Sequence[Any], occluders: Sequence[Mesh] = (),
                  **options) -> Scene:
    """A scene for shading one point (``jaxrt.estimators.estimate_at``): no mesh or camera needed.

    ``material`` is material row 0 (shade with ``material=0``); ``lights`` are light records
    (:mod:`jaxrt.lights`); ``occluders`` optional meshes (emissive ones are lights too).
    Without occluders nothing blocks any ray: the geometry is one zero-area triangle, which is
    never hit. ``options`` go to :func:`build_scene` (``triangle_sampling``, ...); the camera
    is a 1×1 placeholder.
    """
    from jaxrt.camera import look_at

    # collinear, so zero area (flagged invalid, never hit), and a scene radius of 1 for the
    # power of directional and environment lights
    segment = np.array([[-1.0, 0, 0], [0, 0, 0], [1, 0, 0]])
    placeholder = mesh(segment, [[0, 1, 2]], material, name="shading point")
    cam = look_at(eye=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0], fov_deg=1, width=1, height=1)
    return build_scene([placeholder, *occluders], cam, lights, **options)


def _bounding_radius(triangles: np.ndarray) -> float:
    lo, hi = triangles.reshape(-1, 3).min(0), triangles.reshape(-1, 3).max(0)
    return float(0.5 * np.linalg.norm(hi - lo))


# ---------------------------------------------------------------------------------------------
# Ray queries over the whole scene (triangles and sphere lights), for one ray
# ---------------------------------------------------------------------------------------------


class SurfaceHit(NamedTuple):
    """What a ray hit: a triangle, a sphere light, or nothing (``kind == MISS``).

    t: () distance (inf on a miss); p: (3,) hit point (from barycentrics on triangles);
    p_error: (3,) bound on the rounding error of p (:func:`jaxrt.spawn.hit_point`);
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
    The convex bodies of a brute-force scene (``scene.convex``, :mod:`jaxrt.convex`) are
    clipped against their face planes instead of testing their triangles: the hit is then
    the face's (``p = o + t d`` with its error bound off the face's plane, the face's normal,
    ``prim`` a triangle of that face). Not for ``shared_origin`` rays, whose triangle tests
    cost less than the planes (the MIS pass ran 0.88× as fast with its camera rays clipped).
    Two static options specialise the query without changing what the caller uses of it:

    - ``shared_origin``: every ray of the batch starts at ``o``, the camera's eye (``o``
      unbatched under ``vmap``), so brute-force triangles are tested by their edge
      planes through it (:mod:`jaxrt.shared_origin`: ``scene.eye_planes``, or formed in the
      program); a BVH ignores it.
    - ``emission_only``: the caller (a direct estimator's BSDF ray from a surface point)
      uses only the emitter the ray reaches: the emitted radiance, the light and its point.
      Then only the triangles that can block a shadow ray (``scene.occluders``) and the
      emissive ones are tested, and the convex bodies (``scene.convex``) between the origin
      and the emitter found (stopping short of it by the shadow rays' relative margin). Exact
      but for that margin: a left-out face is a hull face, beyond whose plane
      nothing lies, or lies in the plane of every light end, which the ray crosses once;
      either way no emitter lies past it (:mod:`jaxrt.occluders`), so the ray that meets
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
        # the triangles that can block (jaxrt.occluders), gathered once per batch of rays
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
    le = jnp.where(hit.kind == TRIANGLE, lt.le_triangle(lights, hit.light, wo), 0)
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


def with_triangle_sampling(lights, mode: str):
    """The same lights with triangle lights sampled by ``mode`` ("area" | "solid_angle").

    Only the static structure changes (no array is copied); the estimator chooses the mode.
    """
    if mode not in ("area", "solid_angle"):
        raise ValueError(f"triangle sampling must be 'area' or 'solid_angle', got {mode!r}")
    return dataclasses.replace(lights, structure=dataclasses.replace(lights.structure,
                                                                     triangle_sampling=mode))


def describe_lights(lights) -> str:
    """E.g. ``"2 triangle, 1 point (selection power, triangles by solid_angle)"``."""
    s = lights.structure
    parts = [f"{c} {k}" for k, c in zip(lt.KINDS, s.counts, strict=True) if c]
    return (f"{', '.join(parts)} (selection {s.selection}, triangles by "
            f"{s.triangle_sampling})")


def material_at(scene: Scene, hit: SurfaceHit) -> mt.Material:
    """The material row of a hit (one gather per field)."""
    return jax.tree.map(lambda a: a[hit.material], scene.materials)


def shading_normal(ng: Array, wo: Array) -> Array:
    """The geometric normal flipped to the viewer's side (two-sided reflection)."""
    return jnp.where(dot(ng, wo) < 0, -ng, ng)


#: Fields of each light table that are geometry: :func:`guard_geometry` refuses their derivatives.
LIGHT_GEOMETRY_FIELDS = {
    "point": ("position",), "spot": ("position", "axis"), "directional": ("direction",),
    "triangle": ("vertices", "normal", "area", "diameter"), "sphere": ("center", "radius"),
    "environment": ("rotation",),
}


def guard_geometry(scene: Scene) -> Scene:
    """The same scene whose geometric arrays refuse derivatives (:func:`nondifferentiable`).

    Geometry: the triangles and the acceleration structure, the camera (pose, field of view,
    aspect), light positions, axes, directions, triangle-light vertices (and their derived
    normal, area, diameter), sphere centres and radii, and the environment map's rotation.
    Visibility makes the image discontinuous in all of them, so plain autodiff would miss the
    boundary terms; differentiating through the guarded scene w.r.t. any of them raises a
    ``ValueError`` naming the array. An identity in the primal (the compiled program is
    unchanged); used by :func:`jaxrt.differentiable.estimate_image` and
    :func:`jaxrt.estimators.estimate_at`.
    """
    def guard(a, what):
        a = jnp.asarray(a)
        return nondifferentiable(a, what) if jnp.issubdtype(a.dtype, jnp.floating) else a

    scene = scene.with_own_derived_state()
    lights = scene.lights
    tables = {}
    for kind, fields in LIGHT_GEOMETRY_FIELDS.items():
        t = lights.table(kind)
        if t is not None:
            tables[kind] = t._replace(**{f: guard(getattr(t, f), f"{kind} light {f}")
                                         for f in fields if f in t._fields})
    cam = scene.camera
    camera = dataclasses.replace(cam, **{f: guard(getattr(cam, f), f"the camera's {f}")
                                         for f in ("eye", "frame", "tan_half_fov", "aspect")})
    return scene.replace(
        occluders=scene.occluders,  # the same triangles and lights, guarded
        eye_planes=scene.eye_planes,  # and the same camera
        geometry=jax.tree.map(lambda a: guard(a, "the scene geometry (acceleration structure)"),
                              scene.geometry),
        triangles=guard(scene.triangles, "the scene's triangle vertices"),
        lights=dataclasses.replace(lights, **tables), camera=camera)
