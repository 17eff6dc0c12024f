"""Differentiable and batched images: ``estimate_image`` under ``jit``, ``grad`` and ``vmap``.

:func:`estimate_image` is the per-pixel Monte Carlo mean that :func:`jaxrt.render` computes,

    I_p(θ) = 1/N Σ_{k<N} L(θ; seed, p, k),

as a pure function of the scene's arrays: the same per-sample program
(:func:`jaxrt.integrators.techniques.camera_sample`), laid out and summed by the same compiled pass
(:func:`jaxrt.rendering.passes.render_tiles`), so the same seed and sampler give the same image as
``render`` up to the order of float32 sums. It works under ``jax.jit``, ``jax.grad`` /
``jax.vjp`` / ``jax.jvp`` and ``jax.vmap``; the scene's static structure (kinds, counts,
image size) stays static.

Which to use: ``render`` for images (passes, progress, time budget, error target, devices,
processes, files, a float64 sum over passes); ``estimate_image`` inside a JAX program
(losses, optimisers, batches of parameter sets); :func:`image_vjp` / :func:`gradient` for
derivatives at many samples per pixel, whose memory does not grow with spp.

What is differentiable (:func:`scene_params` names it): material parameters (``kd``, ``ks``,
Phong ``exponent``, GGX ``alpha``), emitted radiance of triangle and sphere lights, point and
spot intensities, directional irradiance, constant-environment radiance and environment-map
texels. The derivative of each estimator is taken with its *sampling detached*
(``lax.stop_gradient`` on every sampled direction and point, every pdf and light-selection
pmf, every MIS weight; see :mod:`jaxrt.integrators.direct`): for ``X ~ p_θ``,

    E[∂_θ f(X; θ) / p_θ(X)] = ∫ ∂_θ f(x; θ) dx = ∂_θ ∫ f(x; θ) dx,

so every derivative is an unbiased estimate of the derivative of the expected image, also
where the sampler depends on θ (BSDF sampling on the Phong exponent and GGX α). We chose
this over differentiating the sample (reparameterisation) because a sampled direction that
moves with θ crosses the edges of emitters and occluders, and autodiff misses those boundary
terms (a biased derivative; ``tests/rendering/test_differentiable.py`` shows it).

The identity needs p > 0 wherever ∂_θ f ≠ 0. Light sampling would break it for a light of
zero power and an environment texel of zero luminance, which a sampler proportional to power
never draws; so power-based light selection keeps a floor of 1 % of the mean power per light
(``jaxrt.scene.lights.table.SELECTION_FLOOR``) and environment maps 1 % of the mean luminance per
texel (``jaxrt.scene.lights.environment.TEXEL_FLOOR``): every light and texel is drawn, and the
derivative w.r.t. a black one is unbiased (``test_derivative_wrt_a_black_light``; without
the floor it is exactly 0).

What is not: geometry (vertices, camera, light positions and shapes, environment rotation).
Visibility makes the image discontinuous in it, so derivatives w.r.t. it raise a
``ValueError`` (:func:`jaxrt.scene.container.guard_geometry`); never silently wrong or zero.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.xla import jit_with_options
from jaxrt.integrators.config import Estimator, make_estimator, prepare_scene
from jaxrt.integrators.point import Estimate, samples_at
from jaxrt.integrators.techniques import camera_sample
from jaxrt.rendering.driver import SAMPLES_PER_PASS, default_spp_per_pass
from jaxrt.rendering.passes import LANES, render_tiles, step_layout, zero_sums
from jaxrt.sampling.sampler import SAMPLERS
from jaxrt.scene.container import Scene, guard_geometry

#: Differentiable arrays by name: (table path, field). Materials rows are (M, ·); lights (L, ·).
PARAMS = {
    "materials.kd": ("materials", "kd"),
    "materials.ks": ("materials", "ks"),
    "materials.exponent": ("materials", "exponent"),
    "materials.alpha": ("materials", "alpha"),
    "point.intensity": ("point", "intensity"),
    "spot.intensity": ("spot", "intensity"),
    "directional.irradiance": ("directional", "irradiance"),
    "triangle.radiance": ("triangle", "radiance"),
    "sphere.radiance": ("sphere", "radiance"),
    "environment.radiance": ("environment", "radiance"),
    "environment.image": ("environment", "image"),
}

#: Samples (pixels × spp) per derivative pass of :func:`image_vjp` by default: render's.
#: A pass's memory does not grow with its samples (``_vjp_pass`` folds them), and larger
#: passes run 5–12 % faster (image_vjp at 64² and 256², 1 to 64 spp per pass).
VJP_SAMPLES_PER_PASS = SAMPLES_PER_PASS

#: Lanes (pixels × sample indices) per ``jax.grad`` of a derivative pass: a step of fewer
#: lanes (a small image) takes several sample indices at once, up to this many lanes.
GRAD_LANES = 2**14

#: :func:`gradient`'s derivative passes use the seed XOR this (decorrelated from the image).
DERIVATIVE_SEED_XOR = 0x9E3779B9


def _table(scene: Scene, where: str):
    return scene.materials if where == "materials" else scene.lights.table(where)


def scene_params(scene: Scene) -> dict[str, Array]:
    """The scene's differentiable arrays, by name (only those the scene has).

    ``materials.kd`` / ``materials.ks`` (M, 3), ``materials.exponent`` / ``materials.alpha``
    (M,) — one row per material (per mesh, in :func:`jaxrt.scene.container.build_scene` order);
    ``triangle.radiance`` (L, 3) one row per emissive triangle; ``point.intensity``,
    ``spot.intensity`` (L, 3) in W/sr; ``directional.irradiance`` (L, 3); ``sphere.radiance``
    (L, 3); ``environment.radiance`` (3,) or ``environment.image`` (H, W, 3); ``textures.<k>``
    (H_k, W_k, C_k) the linear texels of image texture k (:mod:`jaxrt.scene.textures`, in
    ``scene.textures.bindings`` order of first use); ``emission.<k>`` (H_k, W_k, 3) the
    texels of emission texture k of the triangle lights
    (:class:`jaxrt.scene.lights.area.EmissionTextures`, in the order of the emissive meshes).
    """
    out = {}
    for name, (where, field) in PARAMS.items():
        t = _table(scene, where)
        if t is not None and field in t._fields:
            out[name] = getattr(t, field)
    if scene.textures is not None:
        out.update({f"textures.{k}": a for k, a in enumerate(scene.textures.texels)})
    glow = _emission(scene)
    if glow is not None:
        out.update({f"emission.{k}": a for k, a in enumerate(glow.texels)})
    return out


def _emission(scene: Scene):
    """The emission textures of the scene's triangle lights, or None."""
    t = scene.lights.triangle
    return None if t is None else t.emission


def with_params(scene: Scene, params: dict[str, Array]) -> Scene:
    """``scene`` with some of its :func:`scene_params` replaced (any subset, same shapes).

    Nothing is validated against the physical ranges (a traced value cannot be): an
    optimiser should keep albedos in [0, 1] and radiances ≥ 0 itself. Raises KeyError for a
    name the scene does not have.
    """
    have = scene_params(scene)
    unknown = set(params) - set(have)
    if unknown:
        raise KeyError(f"not differentiable parameters of this scene: {sorted(unknown)}; it has "
                       f"{sorted(have)}")
    by_table: dict[str, dict] = {}
    texels = None if scene.textures is None else list(scene.textures.texels)
    glow = _emission(scene)
    glow_texels = None if glow is None else list(glow.texels)
    for name, value in params.items():
        if name.startswith("textures."):
            texels[int(name.split(".")[1])] = value
            continue
        if name.startswith("emission."):
            glow_texels[int(name.split(".")[1])] = value
            continue
        where, field = PARAMS[name]
        by_table.setdefault(where, {})[field] = value
    lights = scene.lights
    light_tables = {}
    for where, fields in by_table.items():
        if where != "materials":
            light_tables[where] = lights.table(where)._replace(**fields)
    if any(name.startswith("emission.") for name in params):
        t = light_tables.get("triangle", lights.triangle)
        light_tables["triangle"] = t._replace(
            emission=dataclasses.replace(glow, texels=tuple(glow_texels)))
    materials = scene.materials._replace(**by_table.get("materials", {}))
    # radiometry only: what can block a shadow ray (occluders, convex bodies) stays as it is.
    # Found again, it would be lost wherever the scene is traced (a jitted derivative pass):
    # every triangle tested, every body by its triangles.
    textures = (scene.textures if texels is None
                else dataclasses.replace(scene.textures, texels=tuple(texels)))
    return scene.replace(materials=materials, lights=dataclasses.replace(lights, **light_tables),
                         occluders=scene.occluders, convex=scene.convex, textures=textures)


def _check(spp, sampler: str, name: str = "spp") -> int:
    if not isinstance(spp, int | np.integer) or isinstance(spp, bool) or spp <= 0:
        raise ValueError(f"{name} must be a positive integer, got {spp!r}")
    if sampler not in SAMPLERS:
        raise ValueError(f"unknown sampler {sampler!r}; choose one of {SAMPLERS}")
    return int(spp)


def _image_sums(scene: Scene, seed, start, *, est: Estimator, sampler: str, spp_total: int,
                count: int, tile_size: int, batch_size: int) -> Array:
    """Σ L over samples ``[start, start + count)`` of every pixel, (H, W, 3): one render pass.

    ``scene`` must already be prepared for ``est``; its geometry is guarded here.
    """
    h, w = scene.height, scene.width
    tile_size = LANES * math.ceil(int(tile_size) / LANES)
    num_tiles = math.ceil(h * w / tile_size)
    per_step, steps = step_layout(num_tiles, int(batch_size))
    # the pass advances a carry of running sums (render threads it through its passes);
    # zeros made here, not numpy's: under jit (vjp passes) a numpy carry would be a constant
    # of the program (MBs at 256²), jnp.zeros is a broadcast
    zero = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype),
                        zero_sums((steps * per_step * tile_size,), scene.triangles.dtype))
    sums = render_tiles(guard_geometry(scene), jnp.asarray(seed, jnp.uint32),
                        jnp.asarray(start, jnp.int32), jnp.int32(0), zero, est=est,
                        sampler=sampler, spp_total=spp_total, count=count,
                        tile_size=tile_size, batch_size=int(batch_size), num_tiles=num_tiles)
    # Σ L is the pair hi + lo (TwoSum): lo carries hi's rounding errors and no derivative
    return (sums.s1 + sums.s1_lo)[: h * w].reshape(h, w, 3)


def estimate_image(scene: Scene, estimator: str | Estimator = "mis", spp: int = 16, seed=0,
                   sampler: str = "independent", *, tile_size: int = 256, batch_size: int = 64,
                   **estimator_params) -> Array:
    """The per-pixel Monte Carlo mean ``I_p = 1/N Σ_{k<N} L(seed, p, k)``, (H, W, 3), pure.

    Args:
        scene: a :class:`jaxrt.Scene`; its arrays may be traced (``jit``, ``vmap``, ``grad``
            w.r.t. :func:`scene_params`; derivatives w.r.t. geometry raise).
        estimator, estimator_params: as :func:`jaxrt.render` (static).
        spp: samples per pixel N (static). seed: int or traced uint32 (vmap over seeds works).
        sampler: "independent" | "stratified" | "sobol" (static).
        tile_size, batch_size: the lane layout of :func:`jaxrt.render` (static; they change
            nothing but memory and speed).

    Returns radiance in the measure of the image (mean over the pixel's box filter), float32
    (float64 under x64). Samples that are not finite count as 0, as in ``render``. Under
    reverse mode the whole sample loop is taped: memory ∝ pixels × spp; for many samples
    use :func:`image_vjp`, whose memory does not grow with spp.
    """
    est = make_estimator(estimator, **estimator_params)
    spp = _check(spp, sampler)
    scene = prepare_scene(scene, est)
    s1 = _image_sums(scene, seed, 0, est=est, sampler=sampler, spp_total=spp, count=spp,
                     tile_size=tile_size, batch_size=batch_size)
    return s1 / jnp.asarray(spp, s1.dtype)


@jit_with_options(static_argnames=("est", "sampler", "spp_total", "count", "tile_size",
                                   "batch_size", "grad_lanes"))
def _vjp_pass(scene, params, cotangent, seed, start, *, est, sampler, spp_total, count,
              tile_size, batch_size, grad_lanes=GRAD_LANES):
    """``⟨c, ∂(Σ_{pass} L / N)/∂θ⟩`` for one pass, folded per sample index.

    ``Σ_p ⟨c_p, ∂/∂θ Σ_k L(p, k)⟩ = Σ_k ∂/∂θ Σ_p ⟨c_p, L(p, k)⟩``: for each step of lanes
    and each sample index k, ``jax.grad`` of the scalar ``Σ_lanes ⟨c_p, L(p, k; θ)⟩`` (the
    same :func:`camera_sample` over the same lanes, seed, pixels and indices as
    :func:`_image_sums`, non-finite samples counted as 0 as there) is added to a θ-shaped
    carry. Each grad's tape lives within its loop iteration, so nothing is stacked across
    samples. ``jax.vjp`` of the whole pass would stack every residual of every sample (about
    twice the primal's kernels) and cost 3.0–3.8× the primal pass; this one costs 1.3–1.6×
    (benchmarks/README.md#gradient-fold). Equal up to float32 rounding.
    """
    h, w = scene.height, scene.width
    num_pixels = h * w
    tile_size = LANES * math.ceil(int(tile_size) / LANES)
    per_step, steps = step_layout(math.ceil(num_pixels / tile_size), int(batch_size))
    # the lanes of a step as render_tiles lays them out: one flat axis
    pixels = jnp.arange(steps * per_step * tile_size, dtype=jnp.int32).reshape(steps, -1)
    dtype = scene.triangles.dtype
    # lanes past the image's end take a zero cotangent (row num_pixels)
    c = jnp.concatenate([jnp.asarray(cotangent, dtype).reshape(num_pixels, 3),
                         jnp.zeros((1, 3), dtype)])
    seed = jnp.asarray(seed, jnp.uint32)

    # m sample indices per grad: a step of few lanes (small images) gets up to grad_lanes
    m = max(d for d in range(1, count + 1)
            if count % d == 0 and d * per_step * tile_size <= max(grad_lanes, per_step * tile_size))

    def weighted(p, pix, first):  # Σ_lanes Σ_{j<m} ⟨c_p, L(p, first + j; θ)⟩ / N
        sc = guard_geometry(with_params(scene, p))
        sample = jax.vmap(lambda pixel, i: camera_sample(sc, est, pixel, i, seed, sampler,
                                                         spp_total), (0, None))
        if m > 1:  # (a vmap over one index gives every value an axis of 1: slower)
            sample = jax.vmap(sample, (None, 0))
        inside = pix < num_pixels
        value = sample(jnp.where(inside, pix, 0),
                       first + jnp.arange(m, dtype=jnp.int32) if m > 1 else first)
        ok = (jnp.isfinite(value[..., 0]) & jnp.isfinite(value[..., 1])
              & jnp.isfinite(value[..., 2]))
        cot = c[jnp.where(inside, pix, num_pixels)]
        return jnp.sum(jnp.where(ok[..., None], value, 0) * cot) / spp_total

    grad = jax.grad(weighted)

    def some_samples(k, carry):
        i, g = carry
        return i, jax.tree.map(jnp.add, g, grad(params, pixels[i], start + k * m))

    def one_step(i, g):
        return lax.fori_loop(0, count // m, some_samples, (i, g))[1]

    return lax.fori_loop(0, steps, one_step, jax.tree.map(jnp.zeros_like, params))


def default_vjp_spp_per_pass(num_pixels: int, spp: int) -> int:
    """The largest divisor of ``spp`` not above ``VJP_SAMPLES_PER_PASS / num_pixels`` (≥ 1):
    :func:`jaxrt.rendering.driver.default_spp_per_pass`'s rule and pass size."""
    return default_spp_per_pass(num_pixels, spp, VJP_SAMPLES_PER_PASS)


def _reverse_mode(est: Estimator) -> Estimator:
    """``est`` if reverse mode can run through it. An unbounded path's vertex loop is a
    ``lax.while_loop``, which JAX does not reverse-differentiate: refused before any work
    (bounded paths walk a ``fori_loop``: :func:`jaxrt.integrators.path.trace_path`)."""
    if est.name == "path" and est.max_depth < 0:
        raise ValueError("reverse-mode derivatives (gradient, image_vjp) of the path tracer "
                         "need a bounded max_depth: an unbounded path's vertex loop is a "
                         "lax.while_loop, which JAX does not reverse-differentiate; use "
                         "forward mode (jax.jvp, derivative_at) or set max_depth")
    return est


def image_vjp(scene: Scene, cotangent, estimator: str | Estimator = "mis", *, spp: int,
              spp_per_pass: int | None = None, seed=0, sampler: str = "independent",
              params: tuple[str, ...] | None = None, tile_size: int = 256,
              batch_size: int = 64, **estimator_params) -> dict[str, Array]:
    """``Σ_p ⟨c_p, ∂I_p/∂θ⟩`` for the image of :func:`estimate_image` (same seed, same samples),
    accumulated pass by pass: memory independent of ``spp``.

    ``cotangent`` c: (H, W, 3), fixed (e.g. ``∂loss/∂I`` at an image of *other* samples:
    :func:`gradient`). Pass ``i`` takes samples ``[i·k, (i+1)·k)`` of every pixel
    (``k = spp_per_pass``, default :func:`default_vjp_spp_per_pass`) in one compiled
    program, reused by every pass, and its result is added in float64 on the host. Within a
    pass, a ``jax.grad`` per step of lanes and sample index (or a few indices, up to
    ``GRAD_LANES`` lanes) is added to a running gradient, so only one such grad's tape is
    alive at a time: peak memory grows with neither k nor spp. The sum equals ``jax.vjp`` of
    ``estimate_image`` up to float rounding. ``params``: names from :func:`scene_params` to
    differentiate (default all).

    Returns a dict name → gradient, each of its parameter's shape and dtype.
    """
    est = _reverse_mode(make_estimator(estimator, **estimator_params))
    spp = _check(spp, sampler)
    k = (default_vjp_spp_per_pass(scene.width * scene.height, spp) if spp_per_pass is None
         else min(_check(spp_per_pass, sampler, "spp_per_pass"), spp))
    scene = prepare_scene(scene, est)
    every = scene_params(scene)
    names = tuple(every) if params is None else tuple(params)
    theta = {n: every[n] for n in names}
    c = jnp.asarray(cotangent)
    if c.shape != (scene.height, scene.width, 3):
        raise ValueError(f"cotangent must have shape {(scene.height, scene.width, 3)}, "
                         f"got {c.shape}")
    total = None
    for start in range(0, spp, k):
        count = min(k, spp - start)
        g = _vjp_pass(scene, theta, c, jnp.asarray(seed, jnp.uint32), jnp.int32(start), est=est,
                      sampler=sampler, spp_total=spp, count=count, tile_size=tile_size,
                      batch_size=batch_size, grad_lanes=GRAD_LANES)
        g = {n: np.asarray(v, np.float64) for n, v in g.items()}
        total = g if total is None else {n: total[n] + g[n] for n in g}
    return {n: jnp.asarray(total[n], theta[n].dtype) for n in names}


class Gradient(NamedTuple):
    """What :func:`gradient` returns: the loss at the image, its gradient, the image."""

    loss: Array  # () loss(image)
    grads: dict  # name -> ∂loss/∂θ (image_vjp with decorrelated samples)
    image: Array  # (H, W, 3) the primal image (seed ``seed``)


def gradient(loss: Callable[[Array], Array], scene: Scene, estimator: str | Estimator = "mis",
             *, spp: int, primal_spp: int | None = None, spp_per_pass: int | None = None,
             seed: int = 0, sampler: str = "independent", params: tuple[str, ...] | None = None,
             **estimator_params) -> Gradient:
    """``∂ loss(I)/∂θ`` by the chain rule with *decorrelated* samples, memory independent of spp.

    The image ``I`` is :func:`estimate_image` at ``seed`` (``primal_spp`` samples, default
    ``spp``); the cotangent ``c = ∂loss/∂I`` at it; the derivative ``⟨c, ∂I'/∂θ⟩`` is
    :func:`image_vjp` at seed ``seed ^ DERIVATIVE_SEED_XOR`` (``spp`` samples). The two
    estimates are independent, so ``E[grad] = E[c] · ∂E[I]/∂θ``: unbiased whenever ``c`` is
    affine in the image (an L2 loss); reusing the image's samples for ``∂I/∂θ`` would
    correlate them and bias the product even then.
    """
    est = _reverse_mode(make_estimator(estimator, **estimator_params))
    image = estimate_image(scene, est, spp=primal_spp or spp, seed=seed, sampler=sampler)
    value, c = jax.value_and_grad(loss)(image)
    grads = image_vjp(scene, c, est, spp=spp, spp_per_pass=spp_per_pass,
                      seed=(int(seed) ^ DERIVATIVE_SEED_XOR) & 0xFFFFFFFF, sampler=sampler,
                      params=params)
    return Gradient(value, grads, image)


def derivative_at(scene: Scene, tangents: dict[str, Array], estimator: str | Estimator, p, n,
                  wo, material: int = 0, *, num_samples: int = 1 << 14, seed: int = 0,
                  sampler: str = "independent", **estimator_params) -> Estimate:
    """Directional derivative of :func:`jaxrt.integrators.point.estimate_at` along ``tangents``, ±
    error.

    ``tangents``: name → array of :func:`scene_params` (a subset). The derivative
    ``d/dt E[L(θ + t v)]`` at ``t = 0`` is estimated by the mean of the ``num_samples``
    one-sample derivative estimates (``jax.jvp`` of :func:`jaxrt.integrators.point.samples_at`,
    forward mode: sampling detached, see the module notes), with their standard error
    ``σ/√N`` — the derivative estimator's own error, for tests against closed forms.
    """
    theta = {k: scene_params(scene)[k] for k in tangents}

    def values(t):
        return samples_at(with_params(scene, t), estimator, p, n, wo, material,
                          num_samples=num_samples, seed=seed, sampler=sampler,
                          **estimator_params)

    tan = {k: jnp.asarray(v, theta[k].dtype) for k, v in tangents.items()}
    _, d = jax.jvp(values, (theta,), (tan,))
    return Estimate.of(d)
