"""Resampled importance sampling of direct light (Talbot et al. 2005): many candidates, one ray.

Light sampling draws one point ``y`` on the lights with density ``p`` and traces a shadow ray
to it, whatever the BSDF makes of it. RIS draws ``M`` candidates ``y_1 … y_M`` from the same
source, weighs each by a target ``p̂`` that costs no ray, keeps one of them, ``y``, with
probability ``w_j / Σ w_k``, and traces one shadow ray to ``y`` alone:

    w_k = p̂(y_k) / p(y_k),      F = f(y) / p̂(y) · (1/M) Σ_k w_k,

where ``f(y) = f_r(x, wi, wo) L_e cos θi V(x, y)`` is the light-sampling integrand (in the
measure of ``p``: solid angle, or the selection pmf for delta lights) and the target
``p̂(y) = Y(f_r L_e cos θi)`` its luminance without the visibility. ``F`` is unbiased
(Talbot, eq. 3.3) whenever ``p̂ > 0`` wherever ``f ≠ 0``: the unshadowed contribution is
positive wherever the shadowed one is, and luminance is positive for any non-negative colour
but black. With ``M = 1``, ``F = f(y)/p(y)``: light sampling itself. As ``M`` grows, ``y``
is distributed ever closer to ``p̂ / ∫p̂``, so the shadow ray goes where the BSDF and the
lights' radiance (not only the light's pdf) send light; the cost is ``M`` light samples and
BSDF evaluations per shading point, and still one ray.

Derivatives (module notes of :mod:`jaxrt.integrators.direct`): the candidates, their weights
and the target are detached, so only ``f`` carries a derivative: ``∂F = ∂f(y) / p̂(y) ·
(1/M) Σ w_k``, unbiased for ``∂E[F]`` with the resampling held fixed.

Random dimensions: candidate ``k`` takes ``(2 + 3k, 3 + 3k)`` for the point on the light and
``4 + 3k`` to choose the light (candidate 0 uses light sampling's dimensions); the choice
among the candidates takes ``2 + 3M``.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import Array, lax

from jaxrt.integrators.config import Estimator
from jaxrt.integrators.terms import (
    ShadingPoint,
    Stream,
    light_candidate,
    light_visible,
    mis_weight,
)
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.container import Scene


def ris_dims(candidates: int) -> int:
    """Random dimensions one camera sample of RIS with ``candidates`` candidates uses."""
    return 2 + 3 * candidates + 1


def resampling_weight(target: Array, pdf: Array) -> Array:
    """``w = p̂ / p`` of one candidate (0 where either is 0)."""
    return jnp.where((pdf > 0) & (target > 0), target / jnp.where(pdf > 0, pdf, 1), 0)


def resampled_light(scene: Scene, x: ShadingPoint, s: Stream, m: int,
                    dims: Callable[[int], tuple[int, int]], choice_dim: int,
                    heuristic: str | None = None) -> Array:
    """``F = f(y)/p̂(y) · (1/M) Σ w_k`` (3,) at ``x`` from ``m`` candidates: candidate ``k``
    samples its light point from ``s.u2(dims(k)[0])`` and chooses its light with
    ``s.u1(dims(k)[1])``; ``s.u1(choice_dim)`` picks among them.

    ``heuristic`` (static): ``None`` for direct light alone; ``"balance"`` or ``"power"`` when
    BSDF-sampled hits of the lights are counted too (the path tracer's next-event estimation):
    the integrand is then ``f · w_l`` with ``w_l`` the MIS weight of the chosen light sample
    against BSDF sampling, from the light-sampling density ``p`` (1 for delta lights). The
    BSDF hits take ``w_b = 1 − w_l`` from the same two densities, so the two sum to the
    integrand wherever either can sample it: unbiased, whatever RIS's own density of ``y``.
    """

    def candidate(k):
        point_dim, select_dim = dims(k)
        c = light_candidate(scene, x, s.u2(point_dim), s.u1(select_dim))
        target = lax.stop_gradient(lt.luminance(c.unshadowed))
        return c, target, resampling_weight(target, c.sample.pdf)

    cands, target, weight = jax.vmap(candidate)(jnp.arange(m))
    total = jnp.sum(weight)
    # the candidate j with Σ_{k<j} w_k ≤ u Σ w < Σ_{k≤j} w_k (the last one with weight > 0
    # at the top end, where rounding could leave u Σ w above the running sum)
    cumulative = jnp.cumsum(weight)
    j = jnp.sum(cumulative <= s.u1(choice_dim) * total).astype(jnp.int32)
    last = m - 1 - jnp.argmax((weight > 0)[::-1]).astype(jnp.int32)
    j = jnp.minimum(j, last)
    chosen = jax.tree.map(lambda a: a[j], cands)
    visible = light_visible(scene, x, chosen.sample)
    t = target[j]
    value = chosen.unshadowed / jnp.where(t > 0, t, 1) * (total / m)
    if heuristic is not None:
        pdf_bsdf = lax.stop_gradient(mt.bsdf_pdf(x.material, x.wo_local, chosen.wi_local,
                                                 scene.material_kinds))
        w = mis_weight(heuristic, 1, chosen.sample.pdf, 1, pdf_bsdf)
        value = value * jnp.where(chosen.sample.is_delta, 1, w)
    return jnp.where(visible & (total > 0) & (t > 0), value, 0)


def ris(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """``F = f(y)/p̂(y) · (1/M) Σ w_k`` (3,) at shading point ``x``, ``M = est.ris_candidates``
    light samples resampled by their unshadowed luminance, one shadow ray."""
    m = est.ris_candidates
    return resampled_light(scene, x, s, m, lambda k: (2 + 3 * k, 4 + 3 * k), 2 + 3 * m)
