"""Direct-illumination estimators: every form of the reflection equation in the lecture.

At a surface point x seen along ``wo``, direct illumination is the reflection equation with
the incident radiance replaced by emission,

    L_r(x, wo) = ∫_{H²} f(x, wi, wo) L_e(r(x, wi), −wi) |cos θi| dwi     (hemispherical)
               = ∫_{A_e} f(x, y, z) L_e(y, x) G(x, y) dA(y),             (surface area)
    G(x, y) = V(x, y) |cos θi| |cos θo| / ‖x − y‖².

Each estimator below is one Monte Carlo estimator ``f(X)/p(X)`` of one of these integrals,
for ONE camera sample (batch with ``jax.vmap``):

=========================  ==============================================  ===============
name                       samples                                         reaches delta
                                                                           lights?
=========================  ==============================================  ===============
``uniform_hemisphere``     wi uniform on H², ``p = 1/2π``                   no
``cosine_hemisphere``      wi ∝ cos θi (Malley), ``p = cos θi / π``          no
``bsdf``                   wi from the BSDF's own sampler                  no
``light_area``             y uniform on the light's area (surface-area     yes
                           form); ``p_A`` → solid angle by ``d²/|cos θo|``
``light_solid_angle``      wi uniform in the light's solid angle           yes
                           (spherical triangle / cone)
``mis``                    ``light_samples`` light + ``bsdf_samples``       yes
                           BSDF samples, balance or power heuristic
``mis_one_sample``         one technique chosen at random (probability     yes
                           ``light_prob`` for light sampling)
=========================  ==============================================  ===============

Hemisphere and BSDF sampling find emitters only by hitting them, so point, spot and
directional lights (a delta in direction) are invisible to them: their images lack that
light altogether (see ``tests/test_estimators.py::test_delta_lights_invisible``). Light
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
not covered (:func:`jaxrt.scene.guard_geometry`).

Random dimensions: (0, 1) pixel jitter; light sample k uses the pair (2 + 4k, 3 + 4k) for the
point on the light and dimension 4 + 4k to choose the light; BSDF sample k the pair
(2 + 4·n_light + 2k, …). One-sample MIS uses 2 for the choice, 4–6 light, 8–9 BSDF.
"""

from __future__ import annotations

import concurrent.futures
import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt import warp
from jaxrt.derivatives import nondifferentiable
from jaxrt.path import path, path_dims
from jaxrt.scene import (
    TRIANGLE,
    Scene,
    SurfaceHit,
    emitted,
    guard_geometry,
    intersect,
    with_triangle_sampling,
)
from jaxrt.spawn import default_point_error
from jaxrt.terms import (  # re-exported: the terms the estimators are built of
    ShadingPoint,
    Stream,
    _bsdf_term,
    _direction_sample,
    _light_term,
    camera_ray,
    mis_weight,
    shading_point,
)

#: XLA:CPU options wanted for every program of the per-sample code (render passes,
#: ``estimate_at``, gradient passes): set per compilation, never process-wide, so a user's own
#: programs are untouched; :func:`compiler_options` keeps those the installed XLA knows.
#: Measured on the 256² Cornell box (benchmarks/README.md, "render hot path"):
#:
#: - ``xla_cpu_prefer_vector_width=512``: MIS 1.5× per CPU-second (AVX-512 on an AMD EPYC of
#:   family 26). On a CPU without AVX-512 XLA uses what exists: on a family-23 EPYC (AVX2)
#:   the pass compiled as fast and ran 0.995-1.02x as fast without the option or at 256,
#:   images identical (10 rounds, one process; benchmarks/README.md, "sixteenth session").
#: - ``xla_cpu_experimental_ynn_fusion_type=""`` (no YNNPACK fusions): XLA:CPU hands every
#:   reduction to YNNPACK, whose reduction over the minor axis of an (N, 3) array (each
#:   ``vecmath.dot`` under ``vmap``) took 298 µs for N = 16 384 where XLA's own loop takes 32;
#:   without them MIS ran 1.28× and the path tracer 1.32× faster per CPU-second, and the MIS
#:   pass compiled in 2.1 instead of 3.0 s (paired, one process, load 1.2).
#: - ``xla_cpu_enable_fast_min_max=True``: ``min``/``max`` as a compare and a select, as C's
#:   ``a < b ? b : a`` (pbrt's and Mitsuba's ``std::max``), not IEEE's NaN-propagating
#:   ``llvm.maximum`` (several x86 instructions around ``vmaxps``): the watertight test takes
#:   eight maxima per triangle. MIS 1.09–1.10× and, with ``computed_once`` a sum instead of a
#:   max-reduction, 1.12×, path 1.06× per CPU-second, images bit-identical (paired, one
#:   process, 16 and 10 rounds, load 1.0–1.5). The price: a NaN met by a min or max inside a
#:   sample may come out as the other operand (and ``max(−0, +0)`` as −0), so a NaN that
#:   would have reached the pixel's sums (and been counted, ``RenderResult.nonfinite``) can
#:   be clamped instead; none of jaxrt's validated scenes produces one.
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": "",
                    "xla_cpu_enable_fast_min_max": True}


@functools.cache
def compiler_options() -> dict:
    """The :data:`COMPILER_OPTIONS` that this jaxlib's XLA:CPU accepts, found once per process.

    An option unknown to the installed version (they are experimental and come and go) would
    fail every compilation, so they are tried on a trivial program first: all at once (one
    probe compile, ~20 ms, in every process that compiles or reads a program), and only if
    that fails one by one, leaving out each one refused. Called when the first program is
    compiled, not at import: compiling starts JAX's backend, after which a user can no longer
    choose its devices.
    """
    probe = jax.jit(lambda x: x + 1).lower(np.float32(0))

    def accepts(options: dict) -> bool:
        try:
            probe.compile(options)
        except Exception:  # noqa: BLE001 — XLA raises INVALID_ARGUMENT for an unknown option
            return False
        return True

    if accepts(COMPILER_OPTIONS):
        return dict(COMPILER_OPTIONS)
    accepted = {}
    for key, value in COMPILER_OPTIONS.items():
        if accepts({**accepted, key: value}):
            accepted[key] = value
    return accepted


def compiler_options_soon() -> concurrent.futures.Future:
    """:func:`compiler_options` as a future, its probe compiled on a thread of its own.

    The probe's trivial program (0.085 s in a fresh process on the 2-core VM of 2026-12-04,
    most of it the process's first-compile set-up) then compiles while the caller traces its
    program, which needs the options only when it compiles
    (:meth:`jaxrt.passes.RenderPass.compile`): ~0.05 s off a first frame, since the probe's
    lowering shares the GIL with the trace (benchmarks/README.md, "seventeenth session").
    Already resolved once :func:`compiler_options` has run in this process.
    """
    if compiler_options.cache_info().currsize:
        done: concurrent.futures.Future = concurrent.futures.Future()
        done.set_result(compiler_options())
        return done
    if not _PROBING or _PROBING[0].done():
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxrt-option-probe")
        _PROBING[:] = [pool.submit(compiler_options)]
        pool.shutdown(wait=False)  # its one thread ends with its one task
    return _PROBING[0]


_PROBING: list[concurrent.futures.Future] = []  # the probe under way, if any


def jit_with_options(**jit_kwargs):
    """``jax.jit(fn, **jit_kwargs)`` with :func:`compiler_options`, resolved at the first call.

    Used as a decorator for jaxrt's own programs; ``fn.program()`` is the jitted function
    itself (for ``.lower``).
    """
    def wrap(fn):
        @functools.cache
        def program():
            return jax.jit(fn, compiler_options=compiler_options(), **jit_kwargs)

        @functools.wraps(fn)
        def call(*args, **kwargs):
            return program()(*args, **kwargs)

        call.program = program
        return call

    return wrap

#: The estimators of the reflection equation (direct illumination): on one scene they all
#: estimate the same image.
DIRECT_ESTIMATORS = ("uniform_hemisphere", "cosine_hemisphere", "bsdf", "light_area",
                     "light_solid_angle", "mis", "mis_one_sample")
#: Every estimator: the direct ones and the path tracer (global illumination, jaxrt.path).
ESTIMATORS = DIRECT_ESTIMATORS + ("path",)
HEURISTICS = ("balance", "power")


class Estimator(NamedTuple):
    """Static configuration of an estimator (hashable: it selects the compiled program).

    name: one of :data:`ESTIMATORS`; light_samples, bsdf_samples: sample counts of the
    multi-sample MIS estimator; heuristic: "balance" | "power" (MIS and the path tracer);
    light_prob: probability of choosing light sampling in one-sample MIS; max_depth,
    rr_depth: the path tracer's longest path in segments (−1: unbounded) and the depth from
    which Russian roulette ends paths (:mod:`jaxrt.path`, Mitsuba 3's convention).
    """

    name: str = "mis"
    light_samples: int = 1
    bsdf_samples: int = 1
    heuristic: str = "power"
    light_prob: float = 0.5
    max_depth: int = -1
    rr_depth: int = 5

    @property
    def triangle_sampling(self) -> str | None:
        """How this estimator forces triangle lights to be sampled, or None: the scene decides.

        ``light_area`` and ``light_solid_angle`` *are* the two measures of light sampling, so
        they set it; every other estimator samples triangle lights as the scene's light table
        says (``build_scene(triangle_sampling=...)``).
        """
        return {"light_area": "area", "light_solid_angle": "solid_angle"}.get(self.name)

    @property
    def num_dims(self) -> int:
        """How many random dimensions one camera sample uses (None: unbounded)."""
        if self.name == "mis":
            return 2 + 4 * self.light_samples + 2 * self.bsdf_samples
        if self.name == "mis_one_sample":
            return 10
        if self.name == "path":
            return path_dims(self.max_depth)
        return 2 + 4


def prepare_scene(scene: Scene, est: Estimator) -> Scene:
    """The scene as ``est`` samples it: triangle lights switched to the measure the estimator
    forces (only the static structure changes, no array is copied); unchanged otherwise."""
    if est.triangle_sampling is None:
        return scene
    # the same lights (only how triangles are sampled changes): the same shadow-ray triangles
    return scene.replace(lights=with_triangle_sampling(scene.lights, est.triangle_sampling),
                         occluders=scene.occluders)


def make_estimator(estimator: str | Estimator = "mis", **params) -> Estimator:
    """Validate and build an :class:`Estimator` from a name and parameters.

    Raises ValueError for unknown names or heuristics, negative sample counts, MIS without
    any sample, ``light_prob`` outside (0, 1), a path depth that is neither −1 nor ≥ 1, an
    ``rr_depth`` < 1, path-tracer options given to a direct estimator, or sample counts
    other than 1 given to the path tracer (one light and one BSDF sample per vertex).
    """
    est = estimator if isinstance(estimator, Estimator) else Estimator(name=estimator)
    est = est._replace(**params)
    if est.name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {est.name!r}; choose one of {', '.join(ESTIMATORS)}")
    if est.heuristic not in HEURISTICS:
        raise ValueError(f"unknown MIS heuristic {est.heuristic!r}; choose 'balance' or 'power'")
    for field in ("light_samples", "bsdf_samples"):
        v = getattr(est, field)
        if not isinstance(v, int) or v < 0:
            raise ValueError(f"{field} must be an integer >= 0, got {v!r}")
    if est.light_samples + est.bsdf_samples == 0:
        raise ValueError("MIS needs at least one light or BSDF sample")
    if not 0.0 < est.light_prob < 1.0:
        raise ValueError(f"light_prob must lie strictly between 0 and 1, got {est.light_prob}")
    for field, v in (("max_depth", est.max_depth), ("rr_depth", est.rr_depth)):
        if not isinstance(v, int | np.integer) or isinstance(v, bool):
            raise ValueError(f"{field} must be an integer, got {v!r}")
    if est.name == "path":
        if not (est.max_depth == -1 or est.max_depth >= 1):
            raise ValueError(f"max_depth must be -1 (unbounded) or >= 1, got {est.max_depth}")
        if est.rr_depth < 1:
            raise ValueError(f"rr_depth must be >= 1, got {est.rr_depth}")
        if (est.light_samples, est.bsdf_samples) != (1, 1):
            raise ValueError("the path tracer takes one light and one BSDF sample per vertex; "
                             "light_samples and bsdf_samples apply to 'mis' only")
        return est._replace(max_depth=int(est.max_depth), rr_depth=int(est.rr_depth))
    for field in ("max_depth", "rr_depth"):
        if field in params and params[field] != Estimator._field_defaults[field]:
            raise ValueError(f"{field} applies to estimator='path' only, not {est.name!r}")
    return est


# ---------------------------------------------------------------------------------------------
# The estimators: one function each, for one shading point
# ---------------------------------------------------------------------------------------------


def uniform_hemisphere(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi`` uniform: ``f L_e cos θi · 2π``."""
    wi = warp.square_to_uniform_hemisphere(s.u2(2))
    return _direction_sample(scene, x, wi, warp.square_to_uniform_hemisphere_pdf(wi))


def cosine_hemisphere(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi ∝ cos θi``: ``f L_e π`` (the cosine cancels)."""
    wi = warp.square_to_cosine_hemisphere(s.u2(2))
    return _direction_sample(scene, x, wi, warp.square_to_cosine_hemisphere_pdf(wi))


def bsdf_sampling(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Hemispherical form, ``wi`` from the BSDF: ``L_e · f cos θi / p_bsdf`` (the sample weight)."""
    return _bsdf_term(scene, x, s.u2(2)).value


def light_sampling(scene: Scene, est: Estimator, x: ShadingPoint, s: Stream) -> Array:
    """Surface-area form (``light_area``) or light solid angle (``light_solid_angle``).

    Area form: ``f L_e G / p_A`` with ``G = V |cos θi| |cos θo| / d²``; the light module returns
    the same density in solid angle, ``p_ω = p_A d² / |cos θo|`` (``area_to_solid_angle_pdf``),
    so the estimate reads ``f L_e V |cos θi| / p_ω`` — the two are equal term by term.
    """
    return _light_term(scene, x, s.u2(2), s.u1(4)).value


def _sum_over(term: Callable[[int], Array], count: int) -> Array:
    """``Σ_k term(k)`` over ``k < count``: a direct call for one sample, else vmapped.

    A vmap over ``arange(1)`` gave every value of the term a trailing axis of 1 and the sum
    over it a reduction kernel: the default 1 light + 1 BSDF sample MIS render ran 1.2× slower
    (paired, benchmarks/RESULTS.md).
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
            t = _light_term(scene, x, s.u2(2 + 4 * k), s.u1(4 + 4 * k))
            w = mis_weight(est.heuristic, n_l, t.pdf_light, n_b, t.pdf_bsdf)
            return jnp.where(t.is_delta, 1, w) * t.value

        total += _sum_over(one_light, n_l) / n_l
    if n_b:
        def one_bsdf(k):
            t = _bsdf_term(scene, x, s.u2(2 + 4 * n_l + 2 * k))
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
    tl = _light_term(scene, x, s.u2(4), s.u1(6))
    tb = _bsdf_term(scene, x, s.u2(8))
    wl = jnp.where(tl.is_delta, 1, mis_weight(est.heuristic, c, tl.pdf_light, 1 - c, tl.pdf_bsdf))
    wb = jnp.where(tb.is_delta, 1, mis_weight(est.heuristic, 1 - c, tb.pdf_bsdf, c, tb.pdf_light))
    return jnp.where(choose_light, wl * tl.value / c, wb * tb.value / (1 - c))


_TECHNIQUES: dict[str, Callable] = {
    "uniform_hemisphere": uniform_hemisphere,
    "cosine_hemisphere": cosine_hemisphere,
    "bsdf": bsdf_sampling,
    "light_area": light_sampling,
    "light_solid_angle": light_sampling,
    "mis": mis,
    "mis_one_sample": mis_one_sample,
}


# ---------------------------------------------------------------------------------------------
# One camera sample
# ---------------------------------------------------------------------------------------------


def shade(scene: Scene, est: Estimator, hit: SurfaceHit, wo: Array, s: Stream) -> Array:
    """Radiance reflected at ``hit`` towards ``wo`` (0 off triangle surfaces): direct
    illumination, or for ``path`` all the light of paths up to ``max_depth`` segments."""
    x = shading_point(scene, hit, wo)
    technique = path if est.name == "path" else _TECHNIQUES[est.name]
    value = technique(scene, est, x, s)
    return jnp.where(hit.kind == TRIANGLE, value, 0)


def camera_sample(scene: Scene, est: Estimator, pixel: Array, index: Array, seed: Array,
                  sampler: str = "independent", spp: int = 1) -> Array:
    """Radiance (3,) of camera sample ``index`` of flat pixel ``pixel`` (row-major, row 0 top).

    ``L = L_e(first hit, −d) + L_direct(first hit, −d)``: emitters seen by the camera add
    their own radiance; surfaces add the estimator's direct illumination.
    """
    s = Stream.of(sampler, seed, pixel, index, spp)
    hit, wo = camera_hit(scene, pixel, s)
    return camera_radiance(scene, est, hit, wo, s)


def camera_hit(scene: Scene, pixel: Array, s: Stream) -> tuple[SurfaceHit, Array]:
    """The first half of :func:`camera_sample`: the camera ray's first hit and ``wo = −d``."""
    o, d = camera_ray(scene, pixel, s)
    # every camera ray starts at the eye: triangles are tested by their planes through it
    return intersect(scene, o, d, jnp.asarray(jnp.inf, o.dtype), shared_origin=True), -d


def camera_radiance(scene: Scene, est: Estimator, hit: SurfaceHit, wo: Array,
                    s: Stream) -> Array:
    """The second half of :func:`camera_sample`: ``L_e(hit, wo)`` plus the estimator's
    direct illumination at the hit (3,)."""
    return emitted(scene, hit, wo) + shade(scene, est, hit, wo, s)


class PointEstimate(NamedTuple):
    """Mean and standard error of an estimator at one shading point (see :func:`estimate_at`)."""

    mean: Array  # (3,)
    stderr: Array  # (3,)
    num_samples: int


def estimate_at(scene: Scene, estimator: str | Estimator, p, n, wo, material: int = 0, *,
                num_samples: int = 1 << 14, seed: int = 0, sampler: str = "independent",
                **params) -> PointEstimate:
    """Run one estimator many times at a chosen surface point: reflected radiance ± error.

    The point ``p`` (3,) with unit normal ``n`` is shaded with material row ``material`` of the
    scene, seen along ``wo`` (unit, towards the viewer); the scene supplies lights and
    occluders (:func:`jaxrt.scene.shading_scene` builds one from a material and lights alone).
    Returns the Monte Carlo mean of ``num_samples`` independent estimates
    (:func:`samples_at`) and its standard error ``σ/√N``. Useful to test an estimator against
    :mod:`jaxrt.analytic`.

    Differentiable w.r.t. the scene's material and emission arrays (derivatives with the
    sampling detached, see the module notes); derivatives w.r.t. ``p``, ``n``, ``wo`` or the
    scene's geometry raise (:func:`jaxrt.scene.guard_geometry`).

    Raises ValueError when ``wo`` is not above the surface (``n · wo ≤ 0``): BSDFs are
    one-sided about ``n``, and the renderer would shade the other side (flip ``n`` yourself
    to mean that).
    """
    values = samples_at(scene, estimator, p, n, wo, material, num_samples=num_samples,
                        seed=seed, sampler=sampler, **params)
    mean = jnp.mean(values, axis=0)
    var = jnp.var(values, axis=0, ddof=1)
    return PointEstimate(mean, jnp.sqrt(var / num_samples), int(num_samples))


def samples_at(scene: Scene, estimator: str | Estimator, p, n, wo, material: int = 0, *,
               num_samples: int = 1 << 14, seed: int = 0, sampler: str = "independent",
               **params) -> Array:
    """The ``num_samples`` independent one-sample estimates (N, 3) that :func:`estimate_at`
    averages: sample ``k`` uses the stream (seed, pixel 0, index k). Same arguments, errors
    and derivatives as :func:`estimate_at`; per-sample values give derivative estimators
    their own standard error (``jax.jvp`` of this, see
    :func:`jaxrt.differentiable.derivative_at`)."""
    est = make_estimator(estimator, **params)
    if not isinstance(wo, jax.core.Tracer) and not isinstance(n, jax.core.Tracer):
        cos_o = float(np.dot(np.asarray(n, np.float64), np.asarray(wo, np.float64)))
        if not cos_o > 0:
            raise ValueError(f"wo is not above the surface: n · wo = {cos_o:.3g} ≤ 0 (flip n to "
                             "shade the other side)")
    scene = guard_geometry(prepare_scene(scene, est))
    dtype = scene.triangles.dtype
    # the shading point is geometry too: its derivatives are refused like the scene's
    p, n, wo = (nondifferentiable(jnp.asarray(a, dtype), f"the shading point's {name}")
                for a, name in ((p, "p"), (n, "n"), (wo, "wo")))
    hit = SurfaceHit(t=jnp.asarray(1, dtype), p=p, p_error=default_point_error(p), ng=n,
                     kind=jnp.int32(TRIANGLE), prim=jnp.int32(-1),
                     material=jnp.int32(material), light=jnp.int32(-1))
    return _estimate_at(scene, est, hit, wo, jnp.uint32(seed), sampler, int(num_samples))


@jit_with_options(static_argnames=("est", "sampler", "num_samples"))
def _estimate_at(scene, est, hit, wo, seed, sampler, num_samples):
    def one(k):
        s = Stream.of(sampler, seed, jnp.uint32(0), k, num_samples)
        return shade(scene, est, hit, wo, s)

    return jax.vmap(one)(jnp.arange(num_samples, dtype=jnp.uint32))
