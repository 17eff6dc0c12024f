"""The terms every estimator is built of: sample streams, shading points, MIS weights, and the
light- and BSDF-sampling terms with the rays they trace.

The direct estimators (:mod:`jaxrt.integrators.direct`) combine these terms at one shading point;
the path tracer (:mod:`jaxrt.integrators.path`) at every vertex of a path. Every sampled direction
and point, every pdf and every MIS weight is detached (``lax.stop_gradient``): see
:mod:`jaxrt.integrators.direct`, "Derivatives".
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array, lax

from jaxrt.core.vecmath import computed_once, to_local, to_world
from jaxrt.geometry.spawn import spawn_ray, spawn_ray_to
from jaxrt.sampling import sampler as smp
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.camera import generate_ray
from jaxrt.scene.container import Scene
from jaxrt.scene.queries import (
    SurfaceHit,
    emitted,
    intersect,
    light_normal,
    light_point_error,
    material_at,
    shading_normal,
    unoccluded,
)


class Stream(NamedTuple):
    """The sample stream of one camera sample: ``u(dim)`` for a fixed (seed, pixel, index).

    It holds the pixel's key, :func:`jaxrt.sampling.sampler.pixel_key` of the seed and the pixel,
    rather than the two: a loop over a pixel's samples forms the key once, outside the loop
    (:func:`of` forms it for one stream). The variates are
    :func:`jaxrt.sampling.sampler.sample_1d`'s.
    """

    sampler: str  # one of jaxrt.sampling.sampler.SAMPLERS
    key: Array
    index: Array
    spp: int

    @classmethod
    def of(cls, sampler: str, seed, pixel, index, spp: int) -> Stream:
        """The stream of sample ``index`` of ``pixel`` for ``seed``."""
        return cls(sampler, smp.pixel_key(seed, pixel), index, spp)

    def u1(self, dim: int) -> Array:
        return smp.keyed_1d(self.sampler, self.key, self.index, dim, self.spp)

    def u2(self, dim) -> Array:
        return smp.keyed_2d(self.sampler, self.key, self.index, dim, self.spp)


class ShadingPoint(NamedTuple):
    """A surface point ready for shading: position, viewer-facing normal, local wo, material."""

    hit: SurfaceHit
    n: Array  # (3,) geometric normal flipped towards the viewer
    wo_local: Array  # (3,) wo in the frame of n
    material: mt.Material


# ---------------------------------------------------------------------------------------------
# MIS weights
# ---------------------------------------------------------------------------------------------


def mis_weight(heuristic: str, n_f: Array, pdf_f: Array, n_g: Array, pdf_g: Array) -> Array:
    """Weight of a sample of technique f against technique g (Veach 1997, §9.2).

    balance: ``n_f p_f / (n_f p_f + n_g p_g)``; power (β = 2):
    ``(n_f p_f)² / ((n_f p_f)² + (n_g p_g)²)``. ``n_f``, ``n_g`` are the sample counts; the
    weights of the two techniques sum to one wherever either pdf is positive; 0 where both
    vanish. No derivative flows through a weight (``stop_gradient``): it sums to one with
    its partner at every sample whatever the parameters.
    """
    a = n_f * pdf_f
    b = n_g * pdf_g
    if heuristic == "power":
        a, b = a * a, b * b
    s = a + b
    # weights of detached pdfs carry no derivative (module notes): say so where they are made
    return lax.stop_gradient(jnp.where(s > 0, a / jnp.where(s > 0, s, 1), 0))


def _div(num: Array, den: Array) -> Array:
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1), 0)


# ---------------------------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------------------------


class Arrival(NamedTuple):
    """What a ray from a shading point finds: the emission along it, the hit, and the
    density with which light sampling at the origin would have chosen its direction."""

    le: Array  # (3,) L_e(r(o, d), −d) (environment on a miss)
    hit: SurfaceHit
    pdf_light: Array  # () solid-angle pdf of d under light sampling at p (detached)


def receiver_normal(scene: Scene, n: Array) -> Array | None:
    """``n`` where the scene's light selection depends on the receiver normal (the light
    BVH), else ``None``: the other selections carry no normal through their pdfs."""
    return n if scene.lights.structure.selection == "bvh" else None


def trace_from(scene: Scene, p: Array, o: Array, d: Array,
               emission_only: bool = False, n: Array | None = None) -> Arrival:
    """Trace ``o + t d`` (``o``: ``p`` offset off its surface, ``d`` unit) to its emitter.

    ``emission_only`` (static): the caller uses only ``le`` and ``pdf_light`` (a direct
    estimator), not the surface hit: fewer triangles are tested
    (:func:`jaxrt.scene.queries.intersect`). ``n``: the normal at ``p`` light sampling was
    given there (:func:`receiver_normal`), for ``pdf_light``."""
    h = intersect(scene, o, d, jnp.asarray(jnp.inf, o.dtype), emission_only=emission_only)
    pdf_light = lax.stop_gradient(lt.pdf_li(scene.lights, p, d, h.light, h.p, n))
    return Arrival(emitted(scene, h, -d), h, pdf_light)


def _trace_emission(scene: Scene, x: ShadingPoint, wi: Array) -> Array:
    """``L_e(r(x, wi), −wi)``: the emitted radiance found along wi (environment on a miss)."""
    o, d = spawn_ray(x.hit.p, x.n, wi, x.hit.p_error)
    return trace_from(scene, x.hit.p, o, d, emission_only=True,
                      n=receiver_normal(scene, x.n)).le


def direction_sample(scene: Scene, x: ShadingPoint, wi_local: Array, pdf: Array) -> Array:
    """``f · L_e · cos θi / p`` for a direction sampled in the hemispherical form."""
    wi = to_world(wi_local, x.n)
    le = _trace_emission(scene, x, wi)
    f = mt.bsdf_eval(x.material, x.wo_local, wi_local, scene.material_kinds)
    return _div(f * le * jnp.abs(wi_local[2]), pdf)


class _LightTerm(NamedTuple):
    value: Array  # (3,) f · li · |cos θi| · V / pdf_light (unweighted)
    pdf_light: Array
    pdf_bsdf: Array
    is_delta: Array


class LightCandidate(NamedTuple):
    """A light sample at a shading point and what it would contribute, before any shadow ray."""

    sample: lt.LightSample  # its wi and pdf detached (module notes)
    wi_local: Array  # (3,) wi in the shading frame
    unshadowed: Array  # (3,) f · li · |cos θi|, carrying the derivative of f and li


def light_candidate(scene: Scene, x: ShadingPoint, u_point: Array,
                    u_select: Array) -> LightCandidate:
    """Sample a light from ``u_select`` (choice) and ``u_point`` (2,), and evaluate the BSDF
    towards it: light sampling's integrand without the visibility (also RIS's candidates)."""
    u = jnp.concatenate([u_select[None], u_point])
    ls = lt.sample_li(scene.lights, x.hit.p, x.n, u)
    # sampling detached: only f and li carry derivatives (module notes)
    ls = ls._replace(wi=lax.stop_gradient(ls.wi), pdf=lax.stop_gradient(ls.pdf))
    wi_local = to_local(ls.wi, x.n)
    f = mt.bsdf_eval(x.material, x.wo_local, wi_local, scene.material_kinds)
    return LightCandidate(ls, wi_local, f * ls.li * jnp.abs(wi_local[2]))


def light_term(scene: Scene, x: ShadingPoint, u_point: Array, u_select: Array) -> _LightTerm:
    """Sample a light, test visibility, and form the light-sampling estimate and both pdfs."""
    c = light_candidate(scene, x, u_point, u_select)
    visible = light_visible(scene, x, c.sample)
    value = jnp.where(visible, _div(c.unshadowed, c.sample.pdf), 0)
    pdf_bsdf = lax.stop_gradient(mt.bsdf_pdf(x.material, x.wo_local, c.wi_local,
                                             scene.material_kinds))
    return _LightTerm(value, c.sample.pdf, pdf_bsdf, c.sample.is_delta)


def light_visible(scene: Scene, x: ShadingPoint, ls: lt.LightSample) -> Array:
    """Shadow ray from x to the sampled light point (or towards an infinitely far light).

    The target's error bound is :func:`jaxrt.scene.queries.light_point_error` (the light's extent
    seen from ``p``, not only ``|q|``).
    """
    finite = jnp.isfinite(ls.dist)
    dist = jnp.where(finite, ls.dist, 1)
    q = x.hit.p + dist * ls.wi
    n_q = light_normal(scene, ls.light, q)
    q_error = light_point_error(scene, ls.light, x.hit.p, q)
    o_f, d_f, t_f = spawn_ray_to(x.hit.p, x.n, q, n_q, x.hit.p_error, q_error)
    o_i, d_i = spawn_ray(x.hit.p, x.n, ls.wi, x.hit.p_error)
    o = jnp.where(finite, o_f, o_i)
    d = jnp.where(finite, d_f, d_i)
    t_max = jnp.where(finite, t_f, jnp.inf)
    return unoccluded(scene, o, d, t_max)


class _BSDFTerm(NamedTuple):
    value: Array  # (3,) weight · L_e (unweighted)
    pdf_bsdf: Array
    pdf_light: Array
    is_delta: Array


class BSDFDirection(NamedTuple):
    """A BSDF sample at a shading point, in world space, with its sampling detached."""

    weight: Array  # (3,) f |cos θi| / p (derivative at the fixed wi: materials.detached_weight)
    pdf: Array  # () solid-angle density (detached)
    is_delta: Array  # () bool
    o: Array  # (3,) the ray's origin, offset off the surface
    wi: Array  # (3,) unit world direction


def bsdf_direction(scene: Scene, x: ShadingPoint, u: Array) -> BSDFDirection:
    """Sample the BSDF at ``x`` from ``u`` (2,) and spawn the ray that leaves along it."""
    s = mt.bsdf_sample(x.material, x.wo_local, u, scene.material_kinds)
    # sampling detached: the weight's derivative is that of f cos / p at a fixed wi
    weight = mt.detached_weight(x.material, x.wo_local, s, scene.material_kinds)
    # used by the spawn offset, the ray's traversal and (in a path) the next shading frame
    wi = computed_once(to_world(lax.stop_gradient(s.wi), x.n))
    o, _ = spawn_ray(x.hit.p, x.n, wi, x.hit.p_error)
    return BSDFDirection(weight, lax.stop_gradient(s.pdf), s.is_delta, o, wi)


def bsdf_term(scene: Scene, x: ShadingPoint, u: Array) -> _BSDFTerm:
    """Sample the BSDF, trace to the emitter found, and form its estimate and both pdfs."""
    b = bsdf_direction(scene, x, u)
    a = trace_from(scene, x.hit.p, b.o, b.wi, emission_only=True,
                   n=receiver_normal(scene, x.n))
    return _BSDFTerm(b.weight * a.le, b.pdf, a.pdf_light, b.is_delta)


def shading_point(scene: Scene, hit: SurfaceHit, wo: Array) -> ShadingPoint:
    """The hit made ready for shading: normal flipped towards ``wo``, ``wo`` in its frame,
    its material row."""
    n = shading_normal(hit.ng, wo)
    return ShadingPoint(hit, n, to_local(wo, n), material_at(scene, hit))


def camera_ray(scene: Scene, pixel: Array, s: Stream,
               stored: bool = False) -> tuple[Array, Array]:
    """The camera ray ``(o, d)`` (d unit) through flat pixel ``pixel``, jittered by dims 0–1
    (``stored``: see :func:`~jaxrt.scene.camera.generate_ray`)."""
    xy = jnp.stack([pixel % scene.width, pixel // scene.width]).astype(jnp.int32)
    return generate_ray(scene.camera, xy, s.u2(0), stored)
