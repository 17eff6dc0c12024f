"""Direct-illumination estimators: every form of the reflection equation in the lecture.

At a surface point x seen along ``wo``, direct illumination is the reflection equation with
the incident radiance replaced by emission::

    L_r(x, wo) = ∫_{H²} f(x, wi, wo) L_e(r(x, wi), −wi) |cos θi| dwi     (hemispherical)
               = ∫_{A_e} f(x, y, z) L_e(y, x) G(x, y) dA(y),             (surface area)
    G(x, y) = V(x, y) |cos θi| |cos θo| / ‖x − y‖².

Each estimator below is one Monte Carlo estimator ``f(X)/p(X)`` of one of these integrals,
for ONE camera sample (batch with ``jax.vmap``):

=========================  ======================================================  =========
name                       samples                                                 reaches
                                                                                   delta?
=========================  ======================================================  =========
``uniform_hemisphere``     wi uniform on H², ``p = 1/2π``                          no
``cosine_hemisphere``      wi ∝ cos θi (Malley), ``p = cos θi / π``                no
``bsdf``                   wi from the BSDF's own sampler                          no
``light_area``             y uniform on the light's area (surface-area form);      yes
                           ``p_A`` → solid angle by ``d²/|cos θo|``
``light_solid_angle``      wi uniform in the light's solid angle                   yes
                           (spherical triangle / cone)
``mis``                    ``light_samples`` light + ``bsdf_samples`` BSDF         yes
                           samples, balance or power heuristic
``mis_one_sample``         one technique chosen at random (probability             yes
                           ``light_prob`` for light sampling)
``ris``                    ``ris_candidates`` light samples resampled by their     yes
                           unshadowed luminance, one shadow ray
=========================  ======================================================  =========

Hemisphere and BSDF sampling find emitters only by hitting them, so point, spot and
directional lights (a delta in direction) are invisible to them: their images lack that
light altogether (see ``tests/integrators/test_estimators.py::test_delta_lights_invisible``). Light
sampling in area and solid-angle measure differ only for triangle lights (spheres always use
the cone they subtend; environments the map's own distribution).

Emitters seen directly by the camera contribute their radiance ``L_e`` to the pixel.

Derivatives (``jax.jvp`` / ``jax.vjp`` / ``jax.grad`` w.r.t. material and emission
parameters θ) are those of each estimator with its *sampling detached*: every sampled
direction and point, every pdf (light-selection pmf included) and every MIS weight is under
``lax.stop_gradient``, so only the integrand ``f(θ) · L_e(θ)`` carries a derivative. With the
sample held fixed, ``E_{X~p}[∂_θ f(X; θ) / p(X)] = ∂_θ ∫ f`` for any density p that covers
f's support, and the MIS weights sum to one at every X whatever θ, so each derivative is an
unbiased estimate of the derivative of the expected image — also where the sampler itself
depends on θ (Phong lobe choice and exponent, GGX α): differentiating *through* the sampled
direction instead would miss the boundary terms where the emitter seen along it changes.
``stop_gradient`` is the identity in the primal: the render program is unchanged. Geometry is
not covered (:func:`jaxrt.scene.container.guard_geometry`).

Random dimensions: (0, 1) pixel jitter; light sample k uses the pair (2 + 4k, 3 + 4k) for the
point on the light and dimension 4 + 4k to choose the light; BSDF sample k the pair
(2 + 4·n_light + 2k, …). One-sample MIS uses 2 for the choice, 4–6 light, 8–9 BSDF.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import Array

from jaxrt.integrators.config import Estimator
from jaxrt.integrators.ris import ris
from jaxrt.integrators.terms import (
    ShadingPoint,
    Stream,
    bsdf_term,
    direction_sample,
    light_term,
    mis_weight,
)
from jaxrt.sampling import warp
from jaxrt.scene.container import Scene


def uniform_hemisphere(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi`` uniform: ``f L_e cos θi · 2π``."""
    wi = warp.square_to_uniform_hemisphere(s.u2(2))
    return direction_sample(scene, x, wi, warp.square_to_uniform_hemisphere_pdf(wi))


def cosine_hemisphere(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi ∝ cos θi``: ``f L_e π`` (the cosine cancels)."""
    wi = warp.square_to_cosine_hemisphere(s.u2(2))
    return direction_sample(scene, x, wi, warp.square_to_cosine_hemisphere_pdf(wi))


def bsdf_sampling(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi`` from the BSDF: ``L_e · f cos θi / p_bsdf`` (the sample weight)."""
    return bsdf_term(scene, x, s.u2(2)).value


def light_sampling(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Surface-area form (``light_area``) or light solid angle (``light_solid_angle``).

    Area form: ``f L_e G / p_A`` with ``G = V |cos θi| |cos θo| / d²``; the light module returns
    the same density in solid angle, ``p_ω = p_A d² / |cos θo|`` (``area_to_solid_angle_pdf``),
    so the estimate reads ``f L_e V |cos θi| / p_ω`` — the two are equal term by term.
    """
    return light_term(scene, x, s.u2(2), s.u1(4)).value


def _sum_over(term: Callable[[int], Array], count: int) -> Array:
    """``Σ_k term(k)`` over ``k < count``: a direct call for one sample, else vmapped.

    A vmap over ``arange(1)`` gives every value of the term a trailing axis of 1 and the sum
    over it a reduction kernel: the default 1 light + 1 BSDF sample MIS render runs 1.2× slower
    (benchmarks/README.md#xla-cpu).
    """
    if count == 1:
        return term(0)
    return jnp.sum(jax.vmap(term)(jnp.arange(count)), axis=0)


def mis(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Multi-sample MIS (Veach 1997, eq. 9.12) of ``n_l`` light and ``n_b`` BSDF samples.

    ``F = 1/n_l Σ_j w_l(X_j) f(X_j)/p_l(X_j) + 1/n_b Σ_k w_b(Y_k) f(Y_k)/p_b(Y_k)`` with the
    heuristic weights taking the counts ``n_l``, ``n_b``. Delta lights and delta BSDF lobes
    cannot be sampled by the other technique: their weight is 1, but they are still divided by
    their own sample count (otherwise a point light brightens as n_l grows).
    """
    n_l, n_b = est.light_samples, est.bsdf_samples
    dtype = x.hit.p.dtype
    total = jnp.zeros(3, dtype)
    if n_l:
        def one_light(k):
            t = light_term(scene, x, s.u2(2 + 4 * k), s.u1(4 + 4 * k))
            w = mis_weight(est.heuristic, n_l, t.pdf_light, n_b, t.pdf_bsdf)
            return jnp.where(t.is_delta, 1, w) * t.value

        total += _sum_over(one_light, n_l) / n_l
    if n_b:
        def one_bsdf(k):
            t = bsdf_term(scene, x, s.u2(2 + 4 * n_l + 2 * k))
            w = mis_weight(est.heuristic, n_b, t.pdf_bsdf, n_l, t.pdf_light)
            return jnp.where(t.is_delta, 1, w) * t.value

        total += _sum_over(one_bsdf, n_b) / n_b
    return total


def mis_one_sample(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """One-sample MIS (Veach 1997, §9.2.4): pick light sampling with probability c, else BSDF.

    The chosen technique i contributes ``w_i f / (c_i p_i)`` with ``c_l = c``, ``c_b = 1 − c``
    and the heuristic weight over ``(c_l p_l, c_b p_b)``; for the balance heuristic this is
    ``f / (c p_l + (1 − c) p_b)``. Delta samples have weight 1 and divide by their own c_i.
    """
    c = jnp.asarray(est.light_prob, x.hit.p.dtype)
    choose_light = s.u1(2) < c
    tl = light_term(scene, x, s.u2(4), s.u1(6))
    tb = bsdf_term(scene, x, s.u2(8))
    wl = jnp.where(tl.is_delta, 1, mis_weight(est.heuristic, c, tl.pdf_light, 1 - c, tl.pdf_bsdf))
    wb = jnp.where(tb.is_delta, 1, mis_weight(est.heuristic, 1 - c, tb.pdf_bsdf, c, tb.pdf_light))
    return jnp.where(choose_light, wl * tl.value / c, wb * tb.value / (1 - c))


#: name → the direct-illumination technique at one shading point
DIRECT_TECHNIQUES: dict[str, Callable] = {
    "uniform_hemisphere": uniform_hemisphere,
    "cosine_hemisphere": cosine_hemisphere,
    "bsdf": bsdf_sampling,
    "light_area": light_sampling,
    "light_solid_angle": light_sampling,
    "mis": mis,
    "mis_one_sample": mis_one_sample,
    "ris": ris,
}
