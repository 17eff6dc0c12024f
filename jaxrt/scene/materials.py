"""BSDFs for one shading point: evaluate, sample and pdf, in the local shading frame.

All directions are unit vectors in the local frame (+z is the shading normal) and *leave*
the surface: ``wo`` towards the viewer, ``wi`` towards the light (pbrt's convention, see
:mod:`jaxrt.core.vecmath`). The BSDFs are one-sided reflectors: ``f = 0`` unless ``wo_z > 0``
and ``wi_z > 0``.

Four kinds, each a triad of plain functions of ONE :class:`Material` row:

- ``DIFFUSE``: Lambertian, ``f = kd / π``; cosine-weighted sampling.
- ``PHONG``: energy-normalised modified Phong (Lafortune & Willems 1994),
  ``f = kd/π + ks (n+2)/(2π) cos^n α``; mixture of cosine and Phong-lobe sampling.
- ``CONDUCTOR``: rough GGX conductor (Walter et al. 2007) with the height-correlated Smith
  shadowing-masking term (Heitz 2014) and Schlick's Fresnel with ``F0 = ks``; sampling of
  the visible normals (Heitz 2018).
- ``MIRROR``: perfect specular reflection (a delta BSDF) with constant reflectance ``ks``.

The public entry points :func:`bsdf_eval`, :func:`bsdf_pdf` and :func:`bsdf_sample` take a
static tuple ``kinds`` (as returned by :func:`material_table`) and compile only the kinds it
lists: a ``lax.switch`` over those, or a direct call when there is only one.

Densities are per unit solid angle of ``wi`` over the WHOLE sphere: the Phong lobe and the
visible-normal reflection can send ``wi`` below the horizon; such samples carry their true
density and a zero weight, so that every sampler's density integrates to one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.autodiff import with_tangent_of
from jaxrt.core.vecmath import device_array, dot, normalize, reflect, to_local, to_world
from jaxrt.sampling import warp

DIFFUSE, PHONG, CONDUCTOR, MIRROR = 0, 1, 2, 3
KIND_NAMES = {DIFFUSE: "diffuse", PHONG: "phong", CONDUCTOR: "conductor", MIRROR: "mirror"}

#: Smallest GGX roughness: smoother values are raised to this (use :func:`mirror` for a delta).
ALPHA_MIN = 1e-3


class Material(NamedTuple):
    """Parameters of ONE material; a table of M materials has a leading (M,) axis on every field.

    Fields a kind does not use are zero.
    """

    kind: Array  # () int32 kind id (DIFFUSE, PHONG, CONDUCTOR, MIRROR)
    kd: Array  # (3,) diffuse albedo (diffuse, phong)
    ks: Array  # (3,) phong: specular albedo; conductor: Schlick F0; mirror: reflectance
    exponent: Array  # () phong exponent n
    alpha: Array  # () GGX roughness α (conductor)
    fresnel_schlick: Array  # () conductor: 1 Schlick F(wo·h) with F0 = ks; 0 F = ks constant
    masking_separable: Array  # () conductor: 1 separable G1(wo)·G1(wi); 0 height-correlated G2


class BSDFSample(NamedTuple):
    """A direction drawn by :func:`bsdf_sample`, with its density and Monte Carlo weight."""

    wi: Array  # (3,) unit, local frame
    pdf: Array  # () solid-angle density of wi (1 for a delta lobe by convention)
    weight: Array  # (3,) f·|cos θi| / pdf, 0 where pdf == 0; delta: the reflectance
    is_delta: Array  # () bool, True when wi comes from a delta lobe (never MIS-weighted)


# ---------------------------------------------------------------------------------------------
# Host-side constructors with validation
# ---------------------------------------------------------------------------------------------


def _float_dtype():
    # float32 by default, float64 under jax_enable_x64
    return jax.dtypes.canonicalize_dtype(jnp.float64)


def _rgb(name: str, value, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v.tolist()}")
    if np.any(v < lo) or np.any(v > hi):
        raise ValueError(f"{name} must lie in [{lo}, {hi}] per channel, got {v.tolist()}")
    return v


def _make(kind: int, kd=0.0, ks=0.0, exponent=0.0, alpha=0.0, fresnel_schlick=1.0,
          masking_separable=0.0) -> Material:
    dt = _float_dtype()
    return Material(
        kind=device_array(kind, jnp.int32),
        kd=device_array(np.broadcast_to(kd, (3,)), dt),
        ks=device_array(np.broadcast_to(ks, (3,)), dt),
        exponent=device_array(exponent, dt),
        alpha=device_array(alpha, dt),
        fresnel_schlick=device_array(fresnel_schlick, dt),
        masking_separable=device_array(masking_separable, dt),
    )


def diffuse(albedo) -> Material:
    """Lambertian ``f = albedo / π``; ``albedo``: scalar or RGB in [0, 1], else rejected."""
    return _make(DIFFUSE, kd=_rgb("albedo", albedo))


def phong(kd, ks, exponent) -> Material:
    """Normalised modified Phong material; rejects ``kd + ks > 1`` in any channel (energy gain).

    ``kd``, ``ks``: RGB or scalar albedos in [0, 1]; ``exponent``: finite ``n ≥ 0``.
    """
    kd, ks = _rgb("kd", kd), _rgb("ks", ks)
    if np.any(kd + ks > 1.0):
        raise ValueError(f"phong: kd + ks must be <= 1 per channel (energy conservation), "
                         f"got {(kd + ks).tolist()}")
    n = float(exponent)
    if not np.isfinite(n) or n < 0:
        raise ValueError(f"phong: exponent must be finite and >= 0, got {exponent}")
    return _make(PHONG, kd=kd, ks=ks, exponent=n)


FRESNEL_MODES = ("schlick", "none")
MASKING_MODES = ("correlated", "separable")


def conductor(alpha, ks, fresnel: str = "schlick", masking: str = "correlated") -> Material:
    """Rough GGX conductor ``f = F D G / (4 cos θo cos θi)`` with reflectance ``ks`` in [0, 1].

    ``alpha``: GGX roughness; rejected if non-finite, negative or > 1; values in
    ``[0, ALPHA_MIN)`` are CLAMPED up to ``ALPHA_MIN = 1e-3`` (use :func:`mirror` for a delta).
    ``fresnel``: ``"schlick"`` (``F = F0 + (1 − F0)(1 − wo·h)⁵`` with ``F0 = ks``) or
    ``"none"`` (``F = ks``, Mitsuba 3's ``roughconductor`` with a ``specular_reflectance`` and
    no complex IOR, i.e. ``material="none"``). ``masking``: ``"correlated"`` (height-correlated
    Smith ``G2 = 1 / (1 + Λ(wo) + Λ(wi))``, Heitz 2014) or ``"separable"`` (``G1(wo) G1(wi)``,
    Mitsuba 3's default). Both choices are traced numbers, not structure: switching them
    compiles nothing new.
    """
    a = float(alpha)
    if not np.isfinite(a) or a < 0 or a > 1:
        raise ValueError(f"conductor: alpha must be finite and in [0, 1], got {alpha}")
    if fresnel not in FRESNEL_MODES:
        raise ValueError(f"conductor: fresnel must be one of {FRESNEL_MODES}, got {fresnel!r}")
    if masking not in MASKING_MODES:
        raise ValueError(f"conductor: masking must be one of {MASKING_MODES}, got {masking!r}")
    return _make(CONDUCTOR, ks=_rgb("ks", ks), alpha=max(a, ALPHA_MIN),
                 fresnel_schlick=float(fresnel == "schlick"),
                 masking_separable=float(masking == "separable"))


def mirror(ks=1.0) -> Material:
    """Perfect mirror (delta BSDF) of constant reflectance ``ks`` in [0, 1] (no Fresnel)."""
    return _make(MIRROR, ks=_rgb("ks", ks))


def material_table(materials: Sequence[Material]) -> tuple[Material, tuple[int, ...]]:
    """Stack materials into a table (leading (M,) axis) and list the kinds present.

    Returns ``(table, kinds)`` with ``kinds`` the sorted tuple of distinct kind ids, a static
    value to pass to :func:`bsdf_eval` & co. so the compiled code contains only those kinds.
    """
    if len(materials) == 0:
        raise ValueError("material_table needs at least one material")
    # stacked on the host: jnp.stack would compile a program per field
    table = jax.tree.map(lambda *xs: device_array(np.stack([np.asarray(x) for x in xs])),
                         *materials)
    kinds = tuple(sorted({int(k) for k in np.asarray(table.kind)}))
    unknown = set(kinds) - set(KIND_NAMES)
    if unknown:
        raise ValueError(f"unknown material kind ids {sorted(unknown)}; known: {KIND_NAMES}")
    return table, kinds


# ---------------------------------------------------------------------------------------------
# Shared pieces
# ---------------------------------------------------------------------------------------------


def _safe_div(num: Array, den: Array) -> Array:
    """``num / den`` where ``den > 0``, else 0 (NaN-safe in value and gradient)."""
    ok = den > 0
    safe = jnp.where(ok, den, jnp.ones_like(den))
    return jnp.where(ok, num / safe, jnp.zeros_like(num))


def _both_above(wo: Array, wi: Array) -> Array:
    """One-sided reflection: both directions strictly in the upper hemisphere."""
    return (wo[2] > 0) & (wi[2] > 0)


def _zero3(wo: Array) -> Array:
    return jnp.zeros_like(wo)


def half_vector_to_reflected_pdf(pdf_h: Array, wo_dot_h: Array) -> Array:
    """Change of measure from the half vector to the reflected direction.

    ``p(wi) = p(h) / (4 |wo·h|)`` for ``wi = reflect(wo, h)`` (Walter et al. 2007, eq. 14);
    0 where ``wo·h == 0``.
    """
    return _safe_div(pdf_h, 4 * jnp.abs(wo_dot_h))


def schlick_fresnel(f0: Array, cos_theta: Array) -> Array:
    """Schlick's approximation ``F = F0 + (1 − F0)(1 − cos θ)^5`` (Schlick 1994)."""
    c = jnp.clip(cos_theta, 0, 1)
    return f0 + (1 - f0) * (1 - c) ** 5


def luminance(rgb: Array) -> Array:
    """Rec. 709 luminance ``0.2126 R + 0.7152 G + 0.0722 B``."""
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]


def _mirror_dir(wo: Array) -> Array:
    # reflection of wo about the shading normal +z
    return reflect(wo, jnp.array([0, 0, 1], wo.dtype))


def _sample_record(f: Array, wi: Array, pdf: Array) -> BSDFSample:
    """Assemble a sample with ``weight = f |cos θi| / pdf`` (0 where pdf == 0)."""
    return BSDFSample(wi, pdf, _safe_div(f * jnp.abs(wi[2]), pdf[None]),
                      jnp.asarray(False))


# ---------------------------------------------------------------------------------------------
# Lambertian
# ---------------------------------------------------------------------------------------------


def diffuse_eval(m: Material, wo: Array, wi: Array) -> Array:
    """``f = kd / π`` for ``wo_z, wi_z > 0``, else 0 (pbrt v3 §8.3)."""
    return jnp.where(_both_above(wo, wi), m.kd / jnp.pi, _zero3(wo)).astype(wo.dtype)


def diffuse_pdf(m: Material, wo: Array, wi: Array) -> Array:
    """Cosine-weighted density ``cos θi / π`` on the upper hemisphere (0 if ``wo_z ≤ 0``)."""
    return jnp.where(wo[2] > 0, warp.square_to_cosine_hemisphere_pdf(wi), 0 * wi[2])


def diffuse_sample(m: Material, wo: Array, u: Array) -> BSDFSample:
    """Cosine-weighted ``wi``; the weight is ``kd`` (0 if ``wo_z ≤ 0``)."""
    wi = warp.square_to_cosine_hemisphere(u).astype(wo.dtype)
    return _sample_record(diffuse_eval(m, wo, wi), wi, diffuse_pdf(m, wo, wi))


# ---------------------------------------------------------------------------------------------
# Normalised modified Phong
# ---------------------------------------------------------------------------------------------


def _phong_spec_prob(m: Material, dtype) -> Array:
    """Probability of sampling the glossy lobe: ``lum(ks) / (lum(kd) + lum(ks))``."""
    ld, ls = luminance(m.kd), luminance(m.ks)
    return _safe_div(ls, ld + ls).astype(dtype)


def phong_eval(m: Material, wo: Array, wi: Array) -> Array:
    """``f = kd/π + ks (n+2)/(2π) max(0, wi·wr)^n`` with ``wr`` the mirror direction of ``wo``.

    The ``(n+2)/(2π)`` normalisation makes the albedo at normal incidence exactly ``kd + ks``
    and at most that elsewhere (Lafortune & Willems 1994), so ``kd + ks ≤ 1`` conserves energy.
    """
    cos_alpha = jnp.maximum(dot(wi, _mirror_dir(wo)), 0)
    n = m.exponent.astype(wo.dtype)
    lobe = (n + 2) / (2 * jnp.pi) * cos_alpha**n
    f = m.kd / jnp.pi + m.ks * lobe
    return jnp.where(_both_above(wo, wi), f, _zero3(wo)).astype(wo.dtype)


def phong_pdf(m: Material, wo: Array, wi: Array) -> Array:
    """Mixture density ``(1 − P) cos θi/π + P (n+1)/(2π) max(0, wi·wr)^n`` over the sphere.

    ``P`` = :func:`_phong_spec_prob`; the lobe part is nonzero below the horizon.
    """
    p_spec = _phong_spec_prob(m, wo.dtype)
    lobe = warp.square_to_phong_lobe_pdf(to_local(wi, _mirror_dir(wo)), m.exponent.astype(wo.dtype))
    pdf = (1 - p_spec) * warp.square_to_cosine_hemisphere_pdf(wi) + p_spec * lobe
    return jnp.where(wo[2] > 0, pdf, 0 * pdf)


def phong_sample(m: Material, wo: Array, u: Array) -> BSDFSample:
    """Pick the lobe with ``u_0`` (probability ``P`` for the glossy one), reuse it, then warp.

    Glossy: ``square_to_phong_lobe`` about the mirror direction; a ``wi`` below the horizon
    keeps its density and gets weight 0.
    """
    p_spec = _phong_spec_prob(m, wo.dtype)
    choose_spec = u[0] < p_spec
    # rescale u_0 into [0, 1) inside the chosen branch so both warps see a uniform variate
    u0 = jnp.where(choose_spec, _safe_div(u[0], p_spec), _safe_div(u[0] - p_spec, 1 - p_spec))
    u_re = jnp.stack([jnp.minimum(u0, jnp.asarray(1 - jnp.finfo(u.dtype).epsneg, u.dtype)), u[1]])
    wi_diffuse = warp.square_to_cosine_hemisphere(u_re).astype(wo.dtype)
    wi_lobe = to_world(warp.square_to_phong_lobe(u_re, m.exponent.astype(wo.dtype)),
                       _mirror_dir(wo))
    wi = normalize(jnp.where(choose_spec, wi_lobe, wi_diffuse))
    return _sample_record(phong_eval(m, wo, wi), wi, phong_pdf(m, wo, wi))


# ---------------------------------------------------------------------------------------------
# Rough conductor (GGX; height-correlated or separable Smith; Schlick or constant Fresnel)
# ---------------------------------------------------------------------------------------------


def _smith_g2(wo: Array, wi: Array, alpha: Array) -> Array:
    """Height-correlated masking-shadowing ``G2 = 1 / (1 + Λ(wo) + Λ(wi))`` (Heitz 2014, eq. 99)."""
    return 1 / (1 + warp.ggx_lambda(wo, alpha) + warp.ggx_lambda(wi, alpha))


def _masking(m: Material, wo: Array, wi: Array, alpha: Array) -> Array:
    """The material's ``G(wo, wi)``: height-correlated ``G2`` or separable ``G1(wo) G1(wi)``."""
    separable = warp.ggx_g1(wo, alpha) * warp.ggx_g1(wi, alpha)
    return jnp.where(m.masking_separable > 0, separable, _smith_g2(wo, wi, alpha))


def _fresnel(m: Material, cos_h: Array) -> Array:
    """The material's ``F``: Schlick's with ``F0 = ks``, or the constant ``ks``."""
    ks = m.ks.astype(cos_h.dtype)
    return jnp.where(m.fresnel_schlick > 0, schlick_fresnel(ks, cos_h), ks)


def conductor_eval(m: Material, wo: Array, wi: Array) -> Array:
    """``f = F(wo·h) D(h) G(wo, wi) / (4 cos θo cos θi)``, ``h = normalize(wo + wi)``.

    Walter et al. 2007, eq. 20; 0 unless ``wo_z, wi_z > 0``.
    """
    alpha = m.alpha.astype(wo.dtype)
    h = normalize(wo + wi)
    above = _both_above(wo, wi)
    d = warp.ggx_d(h, alpha)
    g = _masking(m, wo, wi, alpha)
    f = _fresnel(m, dot(wo, h)) * _safe_div(d * g, 4 * wo[2] * wi[2])
    return jnp.where(above, f, _zero3(wo))


def conductor_pdf(m: Material, wo: Array, wi: Array) -> Array:
    """Density of reflecting ``wo`` about a visible normal: ``D_wo(h) / (4 wo·h)``.

    ``D_wo(h) = G1(wo) max(0, wo·h) D(h) / cos θo`` (Heitz 2018); over the whole sphere
    (reflection about a visible normal may go below the horizon); 0 if ``wo_z ≤ 0``.
    """
    alpha = m.alpha.astype(wo.dtype)
    h = normalize(wo + wi)
    pdf_h = warp.square_to_ggx_visible_pdf(h, wo, alpha)
    pdf = half_vector_to_reflected_pdf(pdf_h, dot(wo, h))
    return jnp.where(wo[2] > 0, pdf, 0 * pdf)


def conductor_sample(m: Material, wo: Array, u: Array) -> BSDFSample:
    """Sample a visible normal ``h`` (Heitz 2018) and reflect ``wo`` about it.

    The weight is evaluated in closed form, ``f cos θi / p = F(wo·h) G / G1(wo)``, which
    stays finite when ``D`` overflows at tiny α; 0 when ``wi`` falls below the horizon.
    """
    alpha = m.alpha.astype(wo.dtype)
    wo_up = wo.at[2].set(jnp.maximum(wo[2], jnp.finfo(wo.dtype).tiny))  # sampler needs wo_z > 0
    h = warp.square_to_ggx_visible(u, wo_up, alpha).astype(wo.dtype)
    wi = normalize(reflect(wo, h))
    # the density from wi itself, so that bsdf_pdf(wi) (e.g. in MIS) agrees with it exactly
    pdf = conductor_pdf(m, wo, wi)
    g1 = warp.ggx_g1(wo, alpha)
    w = _fresnel(m, dot(wo, h)) * _safe_div(_masking(m, wo, wi, alpha), g1)
    ok = _both_above(wo, wi) & (pdf > 0)
    return BSDFSample(wi, pdf, jnp.where(ok, w, _zero3(wo)), jnp.asarray(False))


# ---------------------------------------------------------------------------------------------
# Perfect mirror (delta)
# ---------------------------------------------------------------------------------------------


def mirror_eval(m: Material, wo: Array, wi: Array) -> Array:
    """A delta BSDF has no finite value: 0 for every pair of directions."""
    return _zero3(wo)


def mirror_pdf(m: Material, wo: Array, wi: Array) -> Array:
    """A delta lobe has no finite density: 0 (sampled directions carry ``pdf = 1``, is_delta)."""
    return jnp.zeros_like(wo[2])


def mirror_sample(m: Material, wo: Array, u: Array) -> BSDFSample:
    """``wi = (−wo_x, −wo_y, wo_z)`` exactly, ``pdf = 1``, ``weight = ks`` (0 if ``wo_z ≤ 0``)."""
    wi = _mirror_dir(wo)
    w = jnp.where(wo[2] > 0, m.ks.astype(wo.dtype), _zero3(wo))
    return BSDFSample(wi, jnp.ones_like(wo[2]), w, jnp.asarray(True))


# ---------------------------------------------------------------------------------------------
# Registry and dispatch
# ---------------------------------------------------------------------------------------------


class BSDFKind(NamedTuple):
    """The three functions of one BSDF kind, and whether it is a delta distribution."""

    name: str
    eval: Callable[[Material, Array, Array], Array]
    pdf: Callable[[Material, Array, Array], Array]
    sample: Callable[[Material, Array, Array], BSDFSample]
    is_delta: bool


REGISTRY: dict[int, BSDFKind] = {
    DIFFUSE: BSDFKind("diffuse", diffuse_eval, diffuse_pdf, diffuse_sample, False),
    PHONG: BSDFKind("phong", phong_eval, phong_pdf, phong_sample, False),
    CONDUCTOR: BSDFKind("conductor", conductor_eval, conductor_pdf, conductor_sample, False),
    MIRROR: BSDFKind("mirror", mirror_eval, mirror_pdf, mirror_sample, True),
}


def _dispatch(which: str, kinds: tuple[int, ...], m: Material, *args):
    """Call ``REGISTRY[kind].<which>`` for the kinds present: direct if one, else ``lax.switch``."""
    kinds = tuple(kinds)
    if len(kinds) == 0:
        raise ValueError("kinds must list at least one material kind")
    branches = [getattr(REGISTRY[k], which) for k in kinds]
    if len(branches) == 1:
        return branches[0](m, *args)
    # map kind id -> branch position (ids absent from `kinds` fall to branch 0)
    lut = np.zeros(max(kinds) + 1, np.int32)
    lut[list(kinds)] = np.arange(len(kinds), dtype=np.int32)
    index = jnp.asarray(lut)[jnp.clip(m.kind, 0, len(lut) - 1)]
    return lax.switch(index, branches, m, *args)


def bsdf_eval(m: Material, wo: Array, wi: Array, kinds: tuple[int, ...]) -> Array:
    """BSDF value ``f(wo, wi)`` WITHOUT the cosine; one-sided, 0 for delta kinds.

    ``m``: one material row; ``wo``, ``wi``: unit (3,) local directions leaving the surface;
    ``kinds``: static tuple of kinds that may occur (from :func:`material_table`).
    """
    return _dispatch("eval", kinds, m, wo, wi)


def bsdf_pdf(m: Material, wo: Array, wi: Array, kinds: tuple[int, ...]) -> Array:
    """Solid-angle density with which :func:`bsdf_sample` produces ``wi``; 0 for delta kinds."""
    return _dispatch("pdf", kinds, m, wo, wi)


def bsdf_sample(m: Material, wo: Array, u: Array, kinds: tuple[int, ...]) -> BSDFSample:
    """Draw ``wi`` from ``u ∈ [0,1)^2``; see :class:`BSDFSample` for the weight convention."""
    return _dispatch("sample", kinds, m, wo, u)


def detached_weight(m: Material, wo: Array, s: BSDFSample, kinds: tuple[int, ...]) -> Array:
    """``s.weight`` as a number; as a derivative, that of ``f(wo, wi; θ) |cos θi| / p(wi)``
    with the sampled ``wi`` and its density ``p`` held fixed (sampling detached).

    For ``wi ~ p_θ``, ``E[∂_θ f(wi; θ) |cos θi| / p_θ(wi)] = ∂_θ ∫ f |cos θi| dwi``: the
    derivative of the BSDF sampling estimator is unbiased whatever the sampler does with θ
    (the Phong lobe choice moves with kd, ks; the lobe with the exponent; the visible normal
    with α). The weight's own autodiff derivative is not that: it differentiates through the
    sampled direction (missing the boundary terms where the emitter seen along ``wi``
    changes) and, for GGX, through the closed form ``F G / G1`` of ``f cos / p``. Delta lobes
    (mirror) keep the weight's own derivative (their ``wi`` does not depend on θ). An
    identity in the primal (:func:`jaxrt.core.autodiff.with_tangent_of`). Shape (3,).
    """
    wi, pdf = lax.stop_gradient(s.wi), lax.stop_gradient(s.pdf)
    f_cos_over_p = _safe_div(bsdf_eval(m, wo, wi, kinds) * jnp.abs(wi[2]), pdf)
    return with_tangent_of(s.weight, jnp.where(s.is_delta, s.weight, f_cos_over_p))


def bsdf_albedo(m: Material, wo: Array, u: Array,
                kinds: tuple[int, ...]) -> tuple[Array, Array]:
    """Monte Carlo directional albedo ``ρ(wo) = ∫ f(wo, wi) cos θi dωi`` and its standard error.

    ``u``: (N, 2) uniform samples; the estimate is the mean sample weight (white furnace).
    """
    w = jax.vmap(lambda uu: bsdf_sample(m, wo, uu, kinds).weight)(u)
    n = w.shape[0]
    return jnp.mean(w, axis=0), jnp.std(w, axis=0) / jnp.sqrt(jnp.asarray(n, w.dtype))

