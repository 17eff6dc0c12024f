"""Global illumination: a unidirectional path tracer with next-event estimation and MIS.

The rendering equation replaces the emitted radiance of the reflection equation by all the
radiance arriving at x,

    L(x, wo) = L_e(x, wo) + ∫_{H²} f(x, wi, wo) L(r(x, wi), −wi) |cos θi| dwi,

and its Neumann series sums paths x₀ (camera) → x₁ → … → x_D of D segments. The estimator
walks one path per camera sample. At every surface vertex x_k it

1. samples a light (``jaxrt.estimators._light_term``: one light sample, light chosen by the
   scene's selection pmf) and adds ``β · w_l · f L_e |cos θi| / p_l`` when the shadow ray is
   free (next-event estimation, NEE);
2. samples the BSDF (``_bsdf_term``), multiplies the throughput ``β`` by ``f |cos θi| / p_b``
   and traces the ray: the emitter it finds adds ``β · w_b · L_e``; the surface it hits is
   the next vertex.

``w_l``, ``w_b`` are the MIS weights of the two techniques (``heuristic``: balance or power,
one sample each), exactly as in the ``mis`` estimator: the direct light at each vertex is the
``mis`` estimate, with the throughput of the path before it. Delta lights are reached only
by NEE (weight 1); a delta BSDF lobe (mirror) gives NEE nothing (f = 0 off the mirror
direction) and its BSDF sample weight 1; point, spot and directional lights are never hit.
Environment light is found by rays that escape (and sampled by NEE). Sphere lights emit
and end the path (they do not reflect).

Depth convention (Mitsuba 3's ``path`` integrator, so ``max_depth`` compares one for one):
``max_depth`` is the largest number of path segments, the camera ray included.
``max_depth = 1``: emitters seen by the camera only; ``2``: plus direct illumination (the
``mis`` estimator with one light and one BSDF sample); ``D``: light reflected up to D − 1
times; ``−1``: unbounded. Inside a closed furnace of albedo ρ whose walls emit L_e, a path of
at most D segments sees ``L_e (1 − ρ^D) / (1 − ρ)``.

Russian roulette (Mitsuba 3's rule): after the BSDF sample of the k-th vertex (k = 1 at the
first surface the camera sees), if ``k ≥ rr_depth`` the path survives with probability
``q = min(max_c β_c, 0.95)`` and ``β`` is divided by q: unbiased, since E[1{u < q}/q] = 1.
q is computed from the throughput *after* the BSDF weight, so paths whose throughput is
small stop early; the clamp at 0.95 keeps every path finite (the expected length is at most
``rr_depth + 20``). q carries no derivative (it is a sampling decision).

Random dimensions: vertex k (from 1) uses ``b = 2 + 6 (k − 1)``: the pair (b, b+1) for the
point on the light, b+2 to choose the light, b+3 for the roulette, the pair (b+4, b+5) for
the BSDF. The first vertex's light and BSDF dimensions are those of ``mis`` (2–4 and 6–7),
so ``max_depth=2`` renders the ``mis`` image from the same random numbers.

Batching: one camera sample's path is a ``lax.while_loop`` over vertices; vmapped over the
lanes of a pass it runs until the longest path of the batch ends, lanes whose paths have
ended masked (the fraction of useful lane-steps is measured in benchmarks/README.md).

Derivatives: as for the direct estimators (sampling detached: every sampled direction, pdf,
MIS weight and roulette probability is held fixed, ``β`` carries the derivative of
``f |cos θi| / p`` at the fixed direction): forward mode (``jax.jvp``,
:func:`jaxrt.differentiable.derivative_at`) works at any depth. Reverse mode
(``jax.grad``/``jax.vjp``, :func:`jaxrt.differentiable.gradient`) does not go through a
``while_loop`` in JAX and is refused before any work.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array, lax

from jaxrt.estimators import (
    Estimator,
    ShadingPoint,
    Stream,
    _bsdf_term,
    _light_term,
    mis_weight,
    shading_point,
)
from jaxrt.scene import TRIANGLE, Scene

#: Random dimensions per path vertex (see the module notes).
DIMS_PER_VERTEX = 6
#: Largest survival probability of Russian roulette (Mitsuba 3 and pbrt-v4 use the same).
MAX_SURVIVAL = 0.95


def path_dims(max_depth: int) -> int | None:
    """Random dimensions of one camera sample of a path of at most ``max_depth`` segments
    (None when unbounded): 2 for the pixel, :data:`DIMS_PER_VERTEX` per scattering vertex."""
    if max_depth < 0:
        return None
    return 2 + DIMS_PER_VERTEX * max(max_depth - 1, 0)


class PathState(NamedTuple):
    """One path between vertices: where it is, what it carries, what it has gathered."""

    x: ShadingPoint  # the current vertex (valid while ``active``)
    beta: Array  # (3,) throughput: Π f |cos θi| / p over the segments so far (/ q for RR)
    radiance: Array  # (3,) light gathered so far (emission at x₀…x_k excluded: see path)
    vertex: Array  # () int32: k, the index of the current vertex (1 = first surface)
    active: Array  # () bool: the path continues from x


def path(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Radiance reflected at the first vertex ``x`` towards the camera (3,): the sum over
    path lengths 2 … max_depth of NEE and BSDF-sampled emission, MIS-weighted (module notes).

    The emission of ``x`` itself is not included (``camera_sample`` adds the emitter the
    camera sees); 0 when ``max_depth == 1``.
    """
    dtype = x.hit.p.dtype
    max_depth, rr_depth = est.max_depth, est.rr_depth

    def can_scatter(hit, vertex):
        ok = hit.kind == TRIANGLE
        return ok if max_depth < 0 else ok & (vertex < max_depth)

    def step(st: PathState) -> PathState:
        base = 2 + DIMS_PER_VERTEX * (st.vertex - 1)
        # 1. next-event estimation (the direct light of the mis estimator at this vertex)
        tl = _light_term(scene, st.x, s.u2(base), s.u1(base + 2))
        wl = jnp.where(tl.is_delta, 1, mis_weight(est.heuristic, 1, tl.pdf_light, 1,
                                                  tl.pdf_bsdf))
        radiance = st.radiance + jnp.where(st.active, st.beta * wl * tl.value, 0)
        # 2. the BSDF sample that continues the path, and the emitter it finds
        tb = _bsdf_term(scene, st.x, s.u2(base + 4))
        beta = st.beta * tb.weight
        active = st.active
        if max_depth < 0 or max_depth > rr_depth:
            beta, active = _roulette(beta, active, st.vertex >= rr_depth, s.u1(base + 3))
        active = active & (jnp.max(beta) > 0)
        wb = jnp.where(tb.is_delta, 1, mis_weight(est.heuristic, 1, tb.pdf_bsdf, 1,
                                                  tb.pdf_light))
        radiance = radiance + jnp.where(active, beta * wb * tb.le, 0)
        vertex = st.vertex + 1
        return PathState(shading_point(scene, tb.hit, -tb.wi), beta, radiance, vertex,
                         active & can_scatter(tb.hit, vertex))

    one = jnp.ones(3, dtype)
    start = PathState(x, one, jnp.zeros(3, dtype), jnp.int32(1), can_scatter(x.hit, 1))
    return lax.while_loop(lambda st: st.active, step, start).radiance


def _roulette(beta: Array, active: Array, applies: Array, u: Array) -> tuple[Array, Array]:
    """Russian roulette: survive with ``q = min(max β, 0.95)`` and divide β by q."""
    q = lax.stop_gradient(jnp.minimum(jnp.max(beta), MAX_SURVIVAL))
    survives = u < q
    beta = jnp.where(applies, beta / jnp.where(q > 0, q, 1), beta)
    return beta, active & (~applies | survives)
