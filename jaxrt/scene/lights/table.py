"""The ``Lights`` pytree: per-kind tables, light selection, and kind dispatch.

Global light index. Lights are concatenated in a fixed kind order,

    point, spot, directional, triangle, sphere, environment,

so light ``i`` is entry ``i − offset(kind)`` of its kind's table, where ``offset`` sums the
counts of the kinds before it. Counts are *static* (part of the pytree's aux data): a kind with
no lights compiles no code, and a scene of the same structure compiles nothing new.

Selection. ``sample_li`` picks a light with ``u[0]`` from a discrete distribution — uniform
(pmf ``1/N``) or proportional to power (luminance; see each kind's ``*_power``) — and samples
it with ``u[1:3]``. The returned ``pdf`` is the light's solid-angle density times the pmf (the
pmf alone for delta lights); ``pdf_li`` returns the same product for a given direction, so the
pair can be used for multiple importance sampling (Veach 1997, ch. 9). Uniform and power
selection ignore the receiver normal; the light BVH (selection ``"bvh"``) weighs lights by
it, so ``pdf_li`` takes the normal ``sample_li`` was given.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import device_array
from jaxrt.sampling.distributions import discrete_from_weights, discrete_pmf, discrete_sample
from jaxrt.scene.lights import area, bvh, bvh_build, delta, environment, sphere
from jaxrt.scene.lights.records import LightSample

KINDS = ("point", "spot", "directional", "triangle", "sphere", "environment")
DELTA_KINDS = ("point", "spot", "directional")
_TABLE_TYPES = {
    delta.PointLights: "point",
    delta.SpotLights: "spot",
    delta.DirectionalLights: "directional",
    area.TriangleLights: "triangle",
    sphere.SphereLights: "sphere",
    environment.ConstantEnvironment: "environment",
    environment.EnvironmentMap: "environment",
}

#: Power-based selection draws light i with pmf ∝ power_i + SELECTION_FLOOR · mean power. The
#: floor keeps every light reachable: a derivative w.r.t. the power of a light that is never
#: sampled would be 0 (its estimator's support would miss the light), so an optimiser could
#: not light a light that starts black (d/dI of a black point light beside a lit one: 0, for
#: 0.065). Lights of equal power keep the uniform pmf; others lose at most 1 % of the samples.
SELECTION_FLOOR = 0.01

#: The light selections: uniform, by power, by a light BVH's importance at the shading point.
SELECTIONS = ("uniform", "power", "bvh")


@dataclasses.dataclass(frozen=True)
class LightsStructure:
    """Static (hashable) description of a light table: what code the kernels compile."""

    counts: tuple[int, ...]  # one per kind, in KINDS order
    environment: Literal["none", "constant", "map"] = "none"
    triangle_sampling: Literal["area", "solid_angle"] = "area"
    selection: Literal["uniform", "power", "bvh"] = "power"
    bvh_depth: int = 0  # the light BVH's depth (selection "bvh"): the descent's length

    def count(self, kind: str) -> int:
        """Number of lights of ``kind``."""
        return self.counts[KINDS.index(kind)]

    def offset(self, kind: str) -> int:
        """Global index of the first light of ``kind``."""
        return sum(self.counts[: KINDS.index(kind)])

    @property
    def num_lights(self) -> int:
        """Total number of lights."""
        return sum(self.counts)

    @property
    def unpositioned(self) -> np.ndarray:
        """Global indices of the lights without a position (directional, then environment)."""
        idx = [self.offset("directional") + k for k in range(self.count("directional"))]
        if self.count("environment"):
            idx.append(self.offset("environment"))
        return np.asarray(idx, np.int32)


@dataclasses.dataclass(frozen=True)
class Lights:
    """All lights of a scene: per-kind tables (``None`` for absent kinds), the selection
    distribution over global indices, and the static :class:`LightsStructure`.

    Fields: point, spot, directional (:mod:`.delta` tables), triangle (:class:`.TriangleLights`),
    sphere (:class:`.SphereLights`), environment (:class:`.ConstantEnvironment` or
    :class:`.EnvironmentMap`), selection (a ``jaxrt.sampling.distributions`` discrete distribution),
    structure (static).
    """

    point: delta.PointLights | None
    spot: delta.SpotLights | None
    directional: delta.DirectionalLights | None
    triangle: area.TriangleLights | None
    sphere: sphere.SphereLights | None
    environment: environment.ConstantEnvironment | environment.EnvironmentMap | None
    selection: object  # a Discrete (uniform, power) or a bvh.LightBVH (bvh)
    structure: LightsStructure

    def table(self, kind: str):
        """The table of ``kind`` (``None`` if the scene has none)."""
        return getattr(self, kind)


jax.tree_util.register_dataclass(Lights, data_fields=[*KINDS, "selection"],
                                 meta_fields=["structure"])


def _concat(tables):
    """Concatenate same-kind tables along their leading (light) axis."""
    # on the host: jnp.concatenate would compile a program per field
    return jax.tree.map(lambda *xs: device_array(np.concatenate([np.asarray(x) for x in xs])),
                        *tables)


def light_powers(lights: Lights, scene_radius: float = 1.0) -> np.ndarray:
    """Power (luminance, host float64) of every light, in global-index order, shape (N,).

    Directional and environment lights need a scene radius ``r`` (see
    :func:`.delta.directional_power` and :func:`.environment.environment_power`).
    """
    parts = []
    for kind in KINDS:
        t = lights.table(kind)
        if t is None:
            continue
        if kind == "point":
            parts.append(delta.point_power(t))
        elif kind == "spot":
            parts.append(delta.spot_power(t))
        elif kind == "directional":
            parts.append(delta.directional_power(t, scene_radius))
        elif kind == "triangle":
            parts.append(area.triangle_power(t))
        elif kind == "sphere":
            parts.append(sphere.sphere_power(t))
        else:
            parts.append(environment.environment_power(t, scene_radius))
    return np.concatenate(parts)


def light_table(lights, *, triangle_sampling: str = "area", selection: str = "power",
                scene_radius: float = 1.0) -> Lights:
    """Collect light records (:func:`point_light`, :func:`triangle_lights`, ...) into ``Lights``.

    Args:
      lights: iterable of per-kind tables; several of the same kind are concatenated in order.
        At most one environment.
      triangle_sampling: ``"area"`` (uniform on the triangle) or ``"solid_angle"`` (spherical
        triangle); static.
      selection: ``"uniform"`` (pmf 1/N), ``"power"`` (pmf ∝ luminance power plus
        :data:`SELECTION_FLOOR` times the mean power, so that no light has pmf 0) or ``"bvh"``
        (a light BVH over the lights with a position, whose pmf depends on the shading point:
        :mod:`jaxrt.scene.lights.bvh`); static. If every light has zero power, power
        selection falls back to uniform.
      scene_radius: radius of the scene's bounding sphere, for the power of directional and
        environment lights.
    """
    if triangle_sampling not in ("area", "solid_angle"):
        raise ValueError("triangle_sampling must be 'area' or 'solid_angle', "
                         f"got {triangle_sampling!r}")
    if selection not in SELECTIONS:
        raise ValueError(f"selection must be one of {', '.join(map(repr, SELECTIONS))}, "
                         f"got {selection!r}")
    if not (np.isfinite(scene_radius) and scene_radius > 0):
        raise ValueError(f"scene_radius must be finite and > 0, got {scene_radius}")
    by_kind: dict[str, list] = {k: [] for k in KINDS}
    for rec in lights:
        kind = _TABLE_TYPES.get(type(rec))
        if kind is None:
            raise TypeError(f"not a light table: {type(rec).__name__}")
        by_kind[kind].append(rec)
    if len(by_kind["environment"]) > 1:
        raise ValueError("at most one environment light per scene")
    env = by_kind["environment"][0] if by_kind["environment"] else None
    tables = {k: (None if not v or k == "environment" else
                  area.concat_triangle_lights(v) if k == "triangle" else _concat(v))
              for k, v in by_kind.items()}
    tables["environment"] = env
    counts = tuple(0 if tables[k] is None else
                   (1 if k == "environment" else int(tables[k][0].shape[0])) for k in KINDS)
    if sum(counts) == 0:
        raise ValueError("light_table needs at least one light")
    env_kind = ("none" if env is None else
                "constant" if isinstance(env, environment.ConstantEnvironment) else "map")
    structure = LightsStructure(counts, env_kind, triangle_sampling, selection)
    draft = Lights(**tables, selection=None, structure=structure)
    if selection == "bvh":
        tree, depth = bvh_build.build_light_bvh(draft, light_powers(draft, scene_radius),
                                          SELECTION_FLOOR)
        return dataclasses.replace(draft, selection=tree,
                                   structure=dataclasses.replace(structure, bvh_depth=depth))
    weights = np.ones(sum(counts))
    if selection == "power":
        power = light_powers(draft, scene_radius)
        # every light keeps a share: derivatives w.r.t. a dark light's power need samples of it
        weights = power + SELECTION_FLOOR * power.mean() if power.sum() > 0 else weights
    return dataclasses.replace(draft, selection=discrete_from_weights(weights))


# ---------------------------------------------------------------------------------------------
# Kind dispatch: every present kind is evaluated, the selected one kept (a select, as vmap
# would turn a switch into anyway); absent kinds compile nothing.


def _samplers(structure: LightsStructure):
    tri = (area.sample_triangle_area if structure.triangle_sampling == "area"
           else area.sample_triangle_solid_angle)
    env = (environment.sample_constant if structure.environment == "constant"
           else environment.sample_map)
    return {"point": delta.sample_point, "spot": delta.sample_spot,
            "directional": delta.sample_directional, "triangle": tri,
            "sphere": sphere.sample_sphere, "environment": env}


def _pdfs(structure: LightsStructure):
    tri = (area.pdf_triangle_area if structure.triangle_sampling == "area"
           else area.pdf_triangle_solid_angle)
    env = environment.pdf_constant if structure.environment == "constant" else environment.pdf_map
    return {"triangle": tri, "sphere": sphere.pdf_sphere, "environment": env}


def _local(structure: LightsStructure, kind: str, light: Array) -> tuple[Array, Array]:
    """(index within ``kind``'s table clamped to range, whether ``light`` is of ``kind``)."""
    off, cnt = structure.offset(kind), structure.count(kind)
    j = jnp.clip(light - off, 0, cnt - 1).astype(jnp.int32)
    return j, (light >= off) & (light < off + cnt)


def sample_li(lights: Lights, p: Array, n: Array, u: Array) -> LightSample:
    """Pick a light and sample a direction towards it from shading point ``p``.

    Args:
      lights: the light table.
      p: (3,) shading point, world frame.
      n: (3,) receiver normal: the light BVH weighs lights by it
        (:mod:`jaxrt.scene.lights.bvh`); uniform and power selection ignore it. No light is
        culled for being behind the receiver.
      u: (3,) uniform variates: ``u[0]`` selects the light, ``u[1:3]`` sample it.

    Returns a :class:`LightSample` whose ``pdf`` is the solid-angle density including the
    selection pmf (pmf alone for delta lights).
    """
    s = lights.structure
    light, pmf = select_light(lights, p, n, u[0])
    u2 = u[1:3].astype(p.dtype)
    samplers = _samplers(s)
    out = None
    is_delta = jnp.zeros((), bool)
    for kind in KINDS:
        if s.count(kind) == 0:
            continue
        j, mine = _local(s, kind, light)
        rec = samplers[kind](lights.table(kind), j, p, u2)
        out = rec if out is None else jax.tree.map(
            lambda a, b, m=mine: jnp.where(m, a, b), rec, out)
        if kind in DELTA_KINDS:
            is_delta = is_delta | mine
    pdf = out.pdf * pmf.astype(p.dtype)
    return LightSample(out.wi, out.dist, out.li, pdf, is_delta, light)


def pdf_li(lights: Lights, p: Array, wi: Array, light: Array, p_light: Array,
           n: Array | None = None) -> Array:
    """Solid-angle density with which :func:`sample_li` produces ``wi`` towards ``light``.

    Args:
      p: (3,) shading point; wi: (3,) unit direction towards the light.
      light: () int32 global light index (e.g. from the BSDF ray's hit).
      p_light: (3,) where the ray along ``wi`` hit the light's surface (triangles sampled by
        area need it; spheres and environments ignore it).
      n: (3,) the receiver normal :func:`sample_li` was given (the light BVH's pmf depends on
        it; ``None``: no receiver factor).

    Returns ``pmf(light) · p_ω(wi)``; 0 for delta lights (a BSDF sample never hits them).
    The caller guarantees that ``wi`` does hit ``light`` (this is not re-checked).
    """
    s = lights.structure
    light = jnp.asarray(light, jnp.int32)
    pdfs = _pdfs(s)
    total = jnp.zeros_like(p[0])
    for kind in ("triangle", "sphere", "environment"):
        if s.count(kind) == 0:
            continue
        j, mine = _local(s, kind, light)
        val = pdfs[kind](lights.table(kind), j, p, wi, p_light)
        total = jnp.where(mine, val, total)
    return total * selection_pmf(lights, p, light, n)


def select_light(lights: Lights, p: Array, n: Array | None,
                 u: Array) -> tuple[Array, Array]:
    """Choose a light for shading point ``p`` (3,) with receiver normal ``n`` (3,) (or ``None``)
    from ``u`` ∈ [0, 1): (global index () int32, its pmf ()). Uniform and power selection
    ignore ``p`` and ``n``; the light BVH weighs each light by its importance there."""
    s = lights.structure
    if s.selection == "bvh":
        return bvh.bvh_select(lights.selection, s.bvh_depth, s.unpositioned, p, n, u)
    light, pmf, _ = discrete_sample(lights.selection, u)
    return light.astype(jnp.int32), pmf.astype(p.dtype)


def selection_pmf(lights: Lights, p: Array, light: Array, n: Array | None = None) -> Array:
    """Probability that :func:`select_light` at ``(p, n)`` chooses ``light`` (global index); 0
    for an index out of range."""
    s = lights.structure
    if s.selection == "bvh":
        return bvh.bvh_pmf(lights.selection, s.bvh_depth, p, n, light)
    return discrete_pmf(lights.selection, light).astype(p.dtype)


def le_triangle(lights: Lights, light: Array, wo_light: Array,
                p_light: Array | None = None) -> Array:
    """Radiance emitted by triangle light ``light`` (global index) at its point ``p_light``
    (3,) along ``wo_light`` (3,).

    ``wo_light`` leaves the light (towards the receiver). One-sided triangles emit only on the
    side of ``cross(v1 − v0, v2 − v0)``. Returns 0 if ``light`` is not a triangle light.
    ``p_light`` matters (and is required) only where triangles have emission textures.
    """
    s = lights.structure
    if s.count("triangle") == 0:
        return jnp.zeros_like(wo_light)
    j, mine = _local(s, "triangle", jnp.asarray(light, jnp.int32))
    le = area.le_triangle_local(lights.triangle, j, wo_light, p_light)
    return jnp.where(mine, le, jnp.zeros_like(le))


def le_sphere(lights: Lights, light: Array, wo_light: Array, p_light: Array) -> Array:
    """Radiance emitted by sphere light ``light`` (global index) at ``p_light`` along ``wo_light``.

    Spheres emit outwards only. Returns 0 if ``light`` is not a sphere light.
    """
    s = lights.structure
    if s.count("sphere") == 0:
        return jnp.zeros_like(wo_light)
    j, mine = _local(s, "sphere", jnp.asarray(light, jnp.int32))
    le = sphere.le_sphere_local(lights.sphere, j, wo_light, p_light)
    return jnp.where(mine, le, jnp.zeros_like(le))


def le_environment(lights: Lights, d: Array) -> Array:
    """Radiance arriving from the environment along ``d`` (3,), the escaping ray's direction.

    0 when the scene has no environment light.
    """
    kind = lights.structure.environment
    if kind == "none":
        return jnp.zeros_like(d)
    if kind == "constant":
        return environment.le_constant(lights.environment, d)
    return environment.le_map(lights.environment, d)


def environment_light_index(lights: Lights) -> int:
    """Global index of the environment light (static; -1 if there is none)."""
    s = lights.structure
    return s.offset("environment") if s.count("environment") else -1


def triangle_light_index(lights: Lights, j: Array) -> Array:
    """Global index of entry ``j`` of the triangle table (whose primitive is ``prim[j]``)."""
    return jnp.asarray(j, jnp.int32) + lights.structure.offset("triangle")


def intersect_spheres(lights: Lights, o: Array, d: Array, t_max: Array,
                      t_min: Array | float = 0.0) -> tuple[Array, Array]:
    """Closest hit of the ray ``o + t d`` with the sphere lights, ``t ∈ (t_min, t_max)``.

    Returns ``(t, light)``: the hit distance (in units of ``‖d‖``) and the GLOBAL light index of
    the sphere hit, or ``(inf, -1)`` on a miss or when the scene has no sphere lights. Uses the
    stable quadratic of :func:`.sphere.ray_sphere`. Offset ``o`` (or pass ``t_min > 0``) when
    the ray starts on a sphere.
    """
    s = lights.structure
    t_max = jnp.asarray(t_max, o.dtype)
    if s.count("sphere") == 0:
        return jnp.full_like(t_max, jnp.inf), jnp.int32(-1)
    t, j = sphere.intersect_sphere_table(lights.sphere, o, d, t_max, jnp.asarray(t_min, o.dtype))
    return t, jnp.where(j >= 0, j + jnp.int32(s.offset("sphere")), jnp.int32(-1))
