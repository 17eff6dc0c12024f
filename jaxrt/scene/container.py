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
    from jaxrt.scene import container as scene
    from jaxrt.scene import materials
    from jaxrt.scene import lights
    from jaxrt.scene import camera
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

from jaxrt.core.autodiff import nondifferentiable
from jaxrt.core.vecmath import device_array
from jaxrt.geometry.accel import build_geometry
from jaxrt.geometry.eye_rays import eye_planes
from jaxrt.geometry.occluders import shadow_blockers
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx


class Mesh(NamedTuple):
    """A triangle mesh with one material, and optionally emission (a host-side record).

    vertices: (V, 3) float; faces: (F, 3) int; material: a :class:`jaxrt.scene.materials.Material`;
    emission: (3,) radiance or None (not a light), scaled by an ``"emission"`` texture if
    one is bound; a declared emission, even 0, makes the mesh a light, so the static structure
    follows what was declared, not the values;
    two_sided_emission: emit on both sides; uv: (V, 2) texture coordinates per vertex or None;
    textures: ``(field, texture)`` pairs (:mod:`jaxrt.scene.textures`), empty if untextured.
    """

    vertices: np.ndarray
    faces: np.ndarray
    material: mt.Material
    emission: np.ndarray | None = None
    two_sided_emission: bool = False
    name: str = "mesh"
    uv: np.ndarray | None = None
    textures: tuple = ()


#: The material kinds that use each textured field.
_FIELD_KINDS = {"kd": (mt.DIFFUSE, mt.PHONG), "ks": (mt.PHONG, mt.CONDUCTOR, mt.MIRROR),
                "alpha": (mt.CONDUCTOR,)}


def mesh(vertices, faces, material: mt.Material, emission=None, two_sided_emission=False,
         name="mesh", uv=None, textures=None) -> Mesh:
    """Validate and wrap a mesh: finite vertices, integer faces inside the vertex array.

    ``uv``: (V, 2) per-vertex texture coordinates (``u`` along an image's width, ``v`` up its
    height); ``textures``: a dict ``{field: texture}`` binding material fields ``"kd"``,
    ``"ks"`` or ``"alpha"`` to :func:`jaxrt.scene.textures.texture` images (these override the
    material's value of the field), and ``"emission"`` of an emissive mesh to an image that
    scales ``emission``: it emits ``emission ⊙ T(uv)``. Raises ValueError naming the mesh and
    the problem (non-finite vertices, faces out of range, wrong shapes, negative or
    non-finite emission; a textured mesh without UVs, a field its material does not use,
    texels out of range, an emission texture on a mesh that does not emit).
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
    uv, bound = _mesh_textures(name, v, material, uv, textures, e is not None)
    return Mesh(v, f.astype(np.int32), material, e, bool(two_sided_emission), name, uv, bound)


def _mesh_textures(name: str, v: np.ndarray, material: mt.Material, uv, textures,
                   emissive: bool):
    """Validated ``(uv, ((field, texture), ...))`` of :func:`mesh`."""
    if uv is not None:
        uv = np.asarray(uv, np.float64)
        if uv.shape != (len(v), 2) or not np.all(np.isfinite(uv)):
            raise ValueError(f"mesh {name!r}: uv must be finite with shape ({len(v)}, 2) (one "
                             f"pair per vertex), got shape {uv.shape}")
    bound = tuple(sorted(dict(textures or {}).items()))
    if bound and uv is None:
        raise ValueError(f"mesh {name!r} is textured ({', '.join(f for f, _ in bound)}) but "
                         "has no UVs: give uv= (a mesh file's vt / uv / TEXCOORD_0)")
    kind = int(np.asarray(material.kind))
    for field, tex in bound:
        if field not in tx.FIELDS and field != tx.EMISSION:
            raise ValueError(f"mesh {name!r}: cannot texture {field!r}; textured fields: "
                             f"{', '.join([*tx.FIELDS, tx.EMISSION])}")
        if not isinstance(tex, tx.Texture):
            raise ValueError(f"mesh {name!r}: textures[{field!r}] is a {type(tex).__name__}, "
                             "expected a jaxrt.scene.textures.texture(...)")
        if field == tx.EMISSION:
            if not emissive:
                raise ValueError(f"mesh {name!r}: an emission texture needs an emissive mesh "
                                 "(give emission=, the radiance the texture scales)")
            continue
        if kind not in _FIELD_KINDS[field]:
            raise ValueError(f"mesh {name!r}: a {mt.KIND_NAMES[kind]} material has no "
                             f"{field!r} to texture")
        top = float(np.max(tx.decoded(tex, field)))
        rest = 0.0
        if kind == mt.PHONG:  # kd + ks ≤ 1 wherever the texture reaches
            other = "ks" if field == "kd" else "kd"
            rest = float(np.max(np.asarray(getattr(material, other))))
        if top + rest > 1:
            raise ValueError(f"mesh {name!r}: texture {tex.name!r} for {field!r} reaches "
                             f"{top:.4g}{' + ' + f'{rest:.4g}' if rest else ''} > 1")
    return uv, bound


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scene:
    """Everything a render needs. Arrays are traced; fields marked static are compile-time.

    Attributes:
        geometry: a triangle set or BVH (:mod:`jaxrt.geometry.accel`) over all F triangles.
        triangles: (F, 3, 3) vertices, in the geometry's primitive order.
        prim_material: (F,) int32 material index per triangle.
        prim_light: (F,) int32 global light index of an emissive triangle, −1 otherwise.
        materials: material table, leading (M,) axis (:func:`jaxrt.scene.materials.material_table`).
        lights: the light table (:mod:`jaxrt.scene.lights`).
        camera: the camera (:mod:`jaxrt.scene.camera`); its width and height are static.
        material_kinds: static sorted tuple of the BSDF kinds present.
        occluders: the triangles a shadow ray tests one by one
            (:func:`jaxrt.geometry.occluders.shadow_blockers`), or None for all of ``geometry``.
        convex: the convex bodies shadow rays and closest hits test by their face planes
            (:class:`jaxrt.geometry.convex.ConvexBodies`, whose triangles ``occluders`` and closest
            hits leave out), or None.
        eye_planes: the brute-force triangles' edge planes through the camera's eye, which the
            camera rays are tested by (:func:`jaxrt.geometry.eye_rays.eye_planes`, formed on the
            host), or None (a BVH, or arrays traced when the scene was made: the program forms
            them).
        textures: the image textures (:class:`jaxrt.scene.textures.TextureTable`: texels traced,
            which field of which material each drives static), or None: a scene without
            textures compiles no texture code.

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
    textures: Any = None

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
        (:func:`jaxrt.geometry.occluders.shadow_blockers`; None, every triangle tested, when the new
        arrays are traced) unless ``occluders`` is given too (``convex`` then stays unless
        given: a body tested as planes and as triangles is still right).
        """
        new = dataclasses.replace(self, **changes)
        if "occluders" not in changes and {"geometry", "triangles", "lights",
                                           "prim_material"} & set(changes):
            occluders, convex = shadow_blockers(new.geometry, new.triangles, new.lights,
                                                _face_materials(new.prim_material, new.textures))
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

        A program's entry calls it (:class:`jaxrt.rendering.passes.RenderPass`,
        :func:`guard_geometry`), so that a copy made with ``dataclasses.replace`` or rebuilt from
        its leaves, which keeps its original's derived fields, still renders right: with the
        original camera's plane table most of the pixels would be wrong, with the original
        blocks' convex planes moved blocks would cast the old shadows. ~7 ms of numpy for the
        Cornell box, only for such copies.
        """
        if getattr(self, _FORMED, False) or any(
                isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(self)):
            return self
        occluders, convex = shadow_blockers(self.geometry, self.triangles, self.lights,
                                            _face_materials(self.prim_material, self.textures))
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
                f"materials [{kinds}], lights: {describe_lights(self.lights)}"
                + ("" if self.textures is None else
                   f", textures: {len(self.textures.texels)} images driving "
                   + ", ".join(f"{b.field} of material {b.material}"
                               for b in self.textures.bindings)))


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
    from ``Mesh.emission``, times its ``"emission"`` texture if it has one).
    ``extra_lights``: light records from :mod:`jaxrt.scene.lights` (point,
    spot, directional, sphere, environment). ``accel``: "auto" | "brute" | "bvh".
    ``triangle_sampling``: how every light-sampling estimator (MIS included) samples triangle
    lights, "area" (uniform on the triangle) or "solid_angle" (uniform in the spherical
    triangle); ``light_area`` / ``light_solid_angle`` override it. The default "area" is
    chosen by measurement (MIS, 1 + 1 samples, efficiency 1 / (variance × CPU time), paired):
    on the Cornell box the variance is the same and area sampling 1.46× cheaper; with the
    light 10× smaller 1.55× more efficient; with it 3.5× larger (12× the area, close to the
    walls) solid angle has 1.5× less variance and the two are even (0.96×) — see
    benchmarks/README.md#light-sampling.
    ``light_selection``: "uniform" | "power" | "bvh" (a light BVH: each light chosen by its
    importance at the shading point, for scenes of many lights; :mod:`jaxrt.scene.lights.bvh`).

    With no light at all the scene renders black: a warning says so.
    """
    if len(meshes) == 0:
        raise ValueError("build_scene needs at least one mesh")
    tris, mat_idx, mats, uvs, bindings = [], [], [], [], []
    emissive = []  # (first prim, count, radiance, two_sided) per emissive mesh
    offset = 0
    for i, m in enumerate(meshes):
        if not isinstance(m, Mesh):
            raise TypeError(f"meshes[{i}] is a {type(m).__name__}, expected a "
                            "jaxrt Mesh (build one with jaxrt.mesh)")
        t = m.vertices[m.faces]  # (F, 3, 3)
        tris.append(t)
        mat_idx.append(np.full(len(t), i, np.int32))
        mats.append(m.material)
        material_textures = [(f, tex) for f, tex in m.textures if f != tx.EMISSION]
        uvs.append(m.uv[m.faces] if material_textures else np.zeros((len(t), 3, 2)))
        bindings += [(i, field, tex) for field, tex in material_textures]
        if m.emission is not None:
            glow = dict(m.textures).get(tx.EMISSION)
            emissive.append((offset, t, m.emission, m.two_sided_emission, m.name,
                             None if glow is None else (m.uv[m.faces], glow)))
        offset += len(t)
    triangles = np.concatenate(tris)
    prim_material = np.concatenate(mat_idx)
    table, kinds = mt.material_table(mats)
    textures = tx.texture_table(bindings, triangles, np.concatenate(uvs))

    light_list = list(extra_lights)
    for first, t, e, two, name, glow in emissive:
        area2 = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        keep = area2 > 0
        if not np.all(keep):
            warnings.warn(f"mesh {name!r}: {int((~keep).sum())} zero-area emissive triangles "
                          "do not emit (they have no area to sample)", stacklevel=2)
        prims = first + np.flatnonzero(keep)
        if prims.size:
            uv, tex = (None, None) if glow is None else (glow[0][keep], glow[1])
            light_list.append(lt.triangle_lights(t[keep], np.broadcast_to(e, (prims.size, 3)),
                                                 prims.astype(np.int32), two_sided=two,
                                                 uv=uv, texture=tex))
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
        **dict(zip(("occluders", "convex"),
                   shadow_blockers(geometry, stored, light_table,
                                   _face_materials(prim_material, textures)), strict=True)),
        eye_planes=eye_planes(geometry, camera),
        textures=textures,
    ))


def _face_materials(prim_material, textures):
    """What a convex body's face must share (:func:`shadow_blockers`): the material, and on a
    textured material the triangle itself (a closest hit on a face knows one of its
    triangles, whose UV map would be extrapolated over the others')."""
    if textures is None or isinstance(prim_material, jax.core.Tracer):
        return prim_material
    pm = np.asarray(prim_material)
    own = np.isin(pm, sorted(tx.bound_rows(textures.bindings)))
    return np.where(own, pm.max() + 1 + np.arange(len(pm)), pm)


def shading_scene(material: mt.Material, lights: Sequence[Any], occluders: Sequence[Mesh] = (),
                  **options) -> Scene:
    """A scene for shading one point (``jaxrt.integrators.point.estimate_at``): no mesh or camera
    needed.

    ``material`` is material row 0 (shade with ``material=0``); ``lights`` are light records
    (:mod:`jaxrt.scene.lights`); ``occluders`` optional meshes (emissive ones are lights too).
    Without occluders nothing blocks any ray: the geometry is one zero-area triangle, which is
    never hit. ``options`` go to :func:`build_scene` (``triangle_sampling``, ...); the camera
    is a 1×1 placeholder.
    """
    from jaxrt.scene.camera import look_at

    # collinear, so zero area (flagged invalid, never hit), and a scene radius of 1 for the
    # power of directional and environment lights
    segment = np.array([[-1.0, 0, 0], [0, 0, 0], [1, 0, 0]])
    placeholder = mesh(segment, [[0, 1, 2]], material, name="shading point")
    cam = look_at(eye=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0], fov_deg=1, width=1, height=1)
    return build_scene([placeholder, *occluders], cam, lights, **options)


def _bounding_radius(triangles: np.ndarray) -> float:
    lo, hi = triangles.reshape(-1, 3).min(0), triangles.reshape(-1, 3).max(0)
    return float(0.5 * np.linalg.norm(hi - lo))


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
    glow = lights.triangle.emission if lights.triangle is not None else None
    textured = ("" if glow is None else
                f", {int(np.sum(np.asarray(glow.index) >= 0))} with "
                f"{len(glow.texels)} emission textures")
    return (f"{', '.join(parts)} (selection {s.selection}, triangles by "
            f"{s.triangle_sampling}{textured})")


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
    unchanged); used by :func:`jaxrt.rendering.differentiable.estimate_image` and
    :func:`jaxrt.integrators.point.estimate_at`.
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
    glow = lights.triangle.emission if lights.triangle is not None else None
    if glow is not None:
        tables["triangle"] = tables["triangle"]._replace(emission=dataclasses.replace(
            glow, uv_map=guard(glow.uv_map, "the emission texture coordinates")))
    cam = scene.camera
    camera = dataclasses.replace(cam, **{f: guard(getattr(cam, f), f"the camera's {f}")
                                         for f in ("eye", "frame", "tan_half_fov", "aspect")})
    return scene.replace(
        occluders=scene.occluders,  # the same triangles and lights, guarded
        eye_planes=scene.eye_planes,  # and the same camera
        geometry=jax.tree.map(lambda a: guard(a, "the scene geometry (acceleration structure)"),
                              scene.geometry),
        triangles=guard(scene.triangles, "the scene's triangle vertices"),
        lights=dataclasses.replace(lights, **tables), camera=camera,
        textures=None if scene.textures is None else dataclasses.replace(
            scene.textures, uv_map=guard(scene.textures.uv_map, "the texture coordinates")))
