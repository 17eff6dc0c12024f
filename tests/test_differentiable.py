"""estimate_image under jit / grad / vmap, and its derivatives validated statistically.

Derivative estimators are tested like the estimators themselves: against closed forms
(jaxrt.analytic, differentiated by jax), against finite differences with common random
numbers, and across seeds against a converged reference (a deterministic quadrature), each
within a bound from the derivative estimator's own standard error.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrt
from jaxrt import analytic, scenes
from jaxrt import lights as lt
from jaxrt import materials as mt
from jaxrt.differentiable import (
    DERIVATIVE_SEED_XOR,
    derivative_at,
    estimate_image,
    gradient,
    image_vjp,
    scene_params,
    with_params,
)
from jaxrt.estimators import ESTIMATORS
from jaxrt.scene import mesh, shading_scene

CORNELL = scenes.cornell_box(8, 8)


def test_estimate_image_is_render_image():
    """Same seed, same sampler: the image of render, up to float32 rounding."""
    for est, sampler in (("mis", "independent"), ("light_area", "sobol")):
        img = np.asarray(estimate_image(CORNELL, est, spp=4, seed=3, sampler=sampler))
        ref = jaxrt.render(CORNELL, est, spp=4, seed=3, sampler=sampler).image
        assert img.shape == (8, 8, 3) and img.dtype == np.float32
        np.testing.assert_allclose(img, ref, rtol=2e-6, atol=1e-7)
        other = np.asarray(estimate_image(CORNELL, est, spp=4, seed=4, sampler=sampler))
        assert np.max(np.abs(other - ref)) > 1e-3  # the seed matters: not a tautology


def test_exported_and_validated():
    assert jaxrt.estimate_image is estimate_image and jaxrt.image_vjp is image_vjp
    with pytest.raises(ValueError, match="spp"):
        estimate_image(CORNELL, spp=0)
    with pytest.raises(ValueError, match="sampler"):
        estimate_image(CORNELL, spp=1, sampler="halton")
    with pytest.raises(KeyError, match="point.intensity"):
        with_params(CORNELL, {"point.intensity": jnp.ones((1, 3))})


def _kd_batch(scale):
    kd = scene_params(CORNELL)["materials.kd"]
    return kd * scale[:, None, None]


def test_vmap_over_albedos_is_a_loop_of_images():
    """One compiled program renders a batch of parameter sets; each equals its own image."""
    scales = jnp.asarray([0.5, 1.0, 1.2])
    batch = jax.jit(jax.vmap(lambda kd: estimate_image(
        with_params(CORNELL, {"materials.kd": kd}), spp=2, seed=1)))(_kd_batch(scales))
    assert batch.shape == (3, 8, 8, 3)
    for i, kd in enumerate(_kd_batch(scales)):
        one = estimate_image(with_params(CORNELL, {"materials.kd": kd}), spp=2, seed=1)
        np.testing.assert_allclose(batch[i], one, rtol=1e-5, atol=1e-7)
    assert np.max(np.abs(np.asarray(batch[0] - batch[2]))) > 1e-3


def test_geometry_derivatives_raise_for_jvp_vjp_and_grad():
    """Vertices, camera pose and light geometry: a clear error, never a silent zero."""
    def image_of(field, value):
        if field == "triangles":
            return estimate_image(CORNELL.replace(triangles=value), spp=1)
        if field == "eye":
            cam = CORNELL.camera
            return estimate_image(CORNELL.replace(camera=dataclasses.replace(cam, eye=value)),
                                  spp=1)
        tri = CORNELL.lights.triangle._replace(vertices=value)
        return estimate_image(CORNELL.replace(
            lights=dataclasses.replace(CORNELL.lights, triangle=tri)), spp=1)

    for field, x, what in (("triangles", CORNELL.triangles, "triangle vertices"),
                           ("eye", CORNELL.camera.eye, "camera's eye"),
                           ("light", CORNELL.lights.triangle.vertices, "triangle light vertices")):
        f = lambda v, field=field: image_of(field, v)  # noqa: E731
        with pytest.raises(ValueError, match=what):
            jax.jvp(f, (x,), (jnp.ones_like(x),))
        with pytest.raises(ValueError, match=what):
            jax.vjp(f, x)
        with pytest.raises(ValueError, match=what):
            jax.grad(lambda v, f=f: jnp.sum(f(v)))(x)
    # a parameter next to the geometry differentiates (the geometry is a closed-over constant)
    g = jax.grad(lambda kd: jnp.sum(estimate_image(with_params(CORNELL, {"materials.kd": kd}),
                                                   spp=1)))(scene_params(CORNELL)["materials.kd"])
    assert np.all(np.isfinite(g)) and np.max(np.abs(g)) > 0


def test_image_vjp_in_passes_is_the_vjp_of_the_image():
    """Pass-by-pass accumulation (1 spp per pass) equals one jax.vjp over all 4 spp."""
    theta = {k: v for k, v in scene_params(CORNELL).items()
             if k in ("materials.kd", "triangle.radiance")}
    c = jax.random.normal(jax.random.key(0), (8, 8, 3))
    _, vjp = jax.vjp(lambda t: estimate_image(with_params(CORNELL, t), spp=4, seed=2), theta)
    ref = vjp(c)[0]
    got = image_vjp(CORNELL, c, spp=4, spp_per_pass=1, seed=2, params=tuple(theta))
    for k in theta:
        assert got[k].shape == theta[k].shape
        np.testing.assert_allclose(got[k], ref[k], rtol=1e-4, atol=1e-6 * np.abs(ref[k]).max())
    assert np.abs(ref["triangle.radiance"]).max() > 0


def test_gradient_uses_decorrelated_samples():
    target = jnp.zeros((8, 8, 3))
    out = gradient(lambda im: jnp.mean((im - target) ** 2), CORNELL, spp=2, seed=5,
                   params=("materials.kd",))
    np.testing.assert_allclose(out.image, estimate_image(CORNELL, spp=2, seed=5), rtol=1e-6)
    same = image_vjp(CORNELL, 2 * out.image / out.image.size, spp=2, seed=5,
                     params=("materials.kd",))["materials.kd"]
    g = out.grads["materials.kd"]
    assert np.all(np.isfinite(g)) and not np.allclose(g, same, rtol=1e-3)  # other samples
    # the derivative passes are image_vjp at the decorrelated seed, against c = ∂loss/∂I
    other = image_vjp(CORNELL, 2 * out.image / out.image.size, spp=2,
                      seed=5 ^ DERIVATIVE_SEED_XOR, params=("materials.kd",))["materials.kd"]
    np.testing.assert_allclose(g, other, rtol=1e-5, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# (a) finite differences with common random numbers on the Cornell box
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow  # ~30 s each: 2 × 9 perturbed images and 9 gradients, each over 8 seeds
@pytest.mark.parametrize("estimator, spp", [("mis", 4), ("bsdf", 16)])
def test_cornell_gradient_matches_central_differences(estimator, spp):
    """d/ds of the image mean and of an L2 loss, s scaling one wall's albedo (each of the 8
    materials) or the light's radiance, vs central differences at the same seeds: the
    difference of the means over 8 seeds within 4 combined standard errors (from the spread
    over seeds). Measured: relative differences ≤ 2e-3, |diff| / SE ≤ 0.03. Forgetting the
    1/p of the BSDF sample's derivative (``materials.detached_weight``) fails with ``bsdf``:
    |diff| / SE up to 6.0 (mean) and 4.9 (L2); under MIS the power heuristic gives the BSDF
    samples that hit this light almost no weight, so the same bug moves it by 1e-4 only."""
    scene = scenes.cornell_box(16, 16)
    base = scene_params(scene)
    kd, rad = base["materials.kd"], base["triangle.radiance"]
    m = kd.shape[0]
    target = estimate_image(with_params(scene, {"materials.kd": kd * 0.8}), spp=64, seed=99)
    seeds = jnp.arange(8, dtype=jnp.uint32)

    def image(s, seed):  # s: (M + 1,) scale factors of the albedo rows and the radiance
        return estimate_image(with_params(scene, {"materials.kd": kd * s[:m, None],
                                                  "triangle.radiance": rad * s[m]}),
                              estimator, spp=spp, seed=seed)

    losses = {"mean": lambda im: jnp.mean(im), "l2": lambda im: jnp.mean((im - target) ** 2)}
    one = jnp.ones(m + 1)
    h = 0.05
    for name, loss in losses.items():
        f = lambda s, seed, loss=loss: loss(image(s, seed))  # noqa: E731
        ad = jax.jit(jax.vmap(jax.grad(f), (None, 0)))(one, seeds)  # (seeds, M + 1)
        steps = jnp.concatenate([jnp.eye(m + 1) * h, -jnp.eye(m + 1) * h])
        vals = jax.jit(jax.vmap(jax.vmap(f, (None, 0)), (0, None)))(one + steps, seeds)
        fd = (vals[: m + 1] - vals[m + 1:]).T / (2 * h)  # (seeds, M + 1)
        se = np.sqrt(np.var(ad, 0, ddof=1) / len(seeds) + np.var(fd, 0, ddof=1) / len(seeds))
        diff = np.abs(np.mean(ad, 0) - np.mean(fd, 0))
        visible = np.abs(np.mean(fd, 0)) > 0
        assert visible.sum() >= 6, name
        assert np.all(diff[visible] <= 4 * se[visible] + 1e-6 * np.abs(np.mean(fd, 0))[visible]), (
            name, diff, se)
        assert np.all(ad[:, ~visible] == 0), name


# ---------------------------------------------------------------------------------------------
# (b) closed forms, differentiated by jax
# ---------------------------------------------------------------------------------------------

P, N = np.zeros(3), np.array([0.0, 0.0, 1.0])
WO = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
RHO = np.array([0.6, 0.5, 0.4])
QUAD = np.array([[-0.3, -0.4, 1.0], [-0.3, 0.4, 1.0], [0.5, 0.4, 1.0], [0.5, -0.4, 1.0]])


def _oracle_env_point(rho, le, inten, with_point):
    e = analytic.constant_environment_irradiance(le)
    if with_point:
        e = e + analytic.point_light_irradiance(jnp.asarray([0.3, 0.2, 1.5]), inten, P, N)
    return analytic.lambertian_radiance(rho, e)


@pytest.mark.slow  # ~60 s: 7 estimators × 2 scenes, one forward-mode program each
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_derivatives_match_closed_forms(estimator):
    """d/dρ, d/dL_e (environment, area light) and d/dI (point light) of the one-point
    estimate vs jax.jvp of analytic's oracle, within 5 standard errors of the derivative
    estimator (channels carry different derivatives: R ρ, G radiance, B intensity)."""
    sees_delta = estimator not in ("uniform_hemisphere", "cosine_hemisphere", "bsdf")
    le, inten = np.array([0.3, 0.7, 0.2]), np.array([2.0, 1.0, 3.0])
    tan_rho, tan_le, tan_i = np.eye(3)
    env_point = shading_scene(mt.diffuse(RHO), [lt.constant_environment(le),
                                                lt.point_light([0.3, 0.2, 1.5], inten)])
    d = derivative_at(env_point, {"materials.kd": tan_rho[None],
                                  "environment.radiance": tan_le, "point.intensity": tan_i[None]},
                      estimator, P, N, WO, num_samples=1 << 15, seed=1)
    _, ref = jax.jvp(lambda r, e, i: _oracle_env_point(r, e, i, sees_delta),
                     (jnp.asarray(RHO), jnp.asarray(le), jnp.asarray(inten)),
                     (jnp.asarray(tan_rho), jnp.asarray(tan_le), jnp.asarray(tan_i)))
    z = (np.asarray(d.mean) - np.asarray(ref)) / np.maximum(np.asarray(d.stderr), 1e-12)
    assert np.all(np.abs(z) < 5), (d.mean, ref, d.stderr)
    assert np.all(np.asarray(d.mean)[:2] > 0.05)

    light = mesh(QUAD, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=le, name="quad")
    area = shading_scene(mt.diffuse(RHO), [], occluders=[light])
    d = derivative_at(area, {"materials.kd": np.stack([tan_rho, 0 * tan_rho]),
                             "triangle.radiance": np.stack([tan_le, tan_le])},
                      estimator, P, N, WO, num_samples=1 << 15, seed=2)
    _, ref = jax.jvp(lambda r, e: analytic.lambertian_radiance(
        r, analytic.polygon_irradiance(jnp.asarray(QUAD), e, P, N)),
        (jnp.asarray(RHO), jnp.asarray(le)), (jnp.asarray(tan_rho), jnp.asarray(tan_le)))
    z = (np.asarray(d.mean) - np.asarray(ref)) / np.maximum(np.asarray(d.stderr), 1e-12)
    assert np.all(np.abs(z) < 5), (d.mean, ref, d.stderr)
    assert np.all(np.asarray(d.mean)[:2] > 0.01)


# ---------------------------------------------------------------------------------------------
# (c) unbiased where the sampler depends on the parameter: GGX α, Phong exponent
# ---------------------------------------------------------------------------------------------

LE = np.array([1.0, 1.0, 1.0])


def _wo(angle):
    """Viewer at ``angle`` from the normal towards −x: the mirror ray meets the light's plane
    z = 1 at x = tan(angle), near the light's edge x = 0.5 (0.58 for π/6, 0.31 for 0.3)."""
    return np.array([-np.sin(angle), 0.0, np.cos(angle)])


def _quadrature(material_fn, theta, wo, n=512):
    """``∫_quad f(wo, wi; θ) L_e cos θi cos θl / d² dA`` by the midpoint rule (float64): the
    reflected radiance (R channel), smooth in θ; its jax.grad is the reference derivative."""
    x0, x1, y0, y1 = -0.3, 0.5, -0.4, 0.4
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
    ys = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    y = jnp.concatenate([jnp.asarray(pts), jnp.ones((len(pts), 1))], axis=1)
    d2 = jnp.sum(y * y, axis=1)
    wi = y / jnp.sqrt(d2)[:, None]
    m = material_fn(theta)
    wo = jnp.asarray(wo)
    evaluate = mt.conductor_eval if int(m.kind) == mt.CONDUCTOR else mt.phong_eval
    f = jax.vmap(lambda w: evaluate(m, wo, w))(wi)[:, 0]
    cos = wi[:, 2]  # cos θi = cos θl (the quad is parallel to the receiver)
    da = (x1 - x0) * (y1 - y0) / n**2
    return jnp.sum(f * LE[0] * cos * cos / d2) * da


def _ggx(alpha):
    return mt.Material(*(jnp.asarray(a) for a in mt.conductor(0.3, 0.9)))._replace(alpha=alpha)


def _phong(exponent):
    return mt.Material(*(jnp.asarray(a) for a in mt.phong(0.2, 0.6, 20.0)))._replace(
        exponent=exponent)


@pytest.mark.slow  # ~40 s: 2 materials × 3 estimators at 2^16 samples, a float64 quadrature
@pytest.mark.parametrize("name, material, param, value, angle", [
    ("ggx", _ggx, "materials.alpha", 0.3, np.pi / 6),
    ("phong", _phong, "materials.exponent", 20.0, 0.3)])
def test_derivative_unbiased_where_the_sampler_depends_on_it(name, material, param, value,
                                                             angle):
    """Mean of 2^16 independent one-sample derivative estimates vs the derivative of a
    converged quadrature: |z| < 4 for BSDF sampling and both MIS variants, whose sampled
    directions move with the parameter. Differentiating through the sampled direction
    instead (dropping its stop_gradient) misses the light's edges and fails (z ≈ ...)."""
    with jax.enable_x64(True):
        ref_value = float(_quadrature(material, jnp.float64(value), _wo(angle)))
        ref = float(jax.grad(lambda t: _quadrature(material, t, _wo(angle)))(jnp.float64(value)))
    base = mt.conductor(0.3, 0.9) if name == "ggx" else mt.phong(0.2, 0.6, 20.0)
    light = mesh(QUAD, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=LE, name="quad")
    scene = shading_scene(base, [], occluders=[light])
    tangent = np.array([1.0, 0.0])
    for estimator in ("bsdf", "mis", "mis_one_sample"):
        est = jaxrt.estimators.estimate_at(scene, estimator, P, N, _wo(angle),
                                           num_samples=1 << 16, seed=7)
        zv = (float(est.mean[0]) - ref_value) / float(est.stderr[0])
        assert abs(zv) < 4, (estimator, "value", est.mean, ref_value)  # the reference holds
        d = derivative_at(scene, {param: tangent}, estimator, P, N, _wo(angle),
                          num_samples=1 << 16, seed=11)
        z = (float(d.mean[0]) - ref) / float(d.stderr[0])
        assert abs(z) < 4, (estimator, float(d.mean[0]), ref, float(d.stderr[0]))
        assert abs(ref) > 10 * float(d.stderr[0])  # the test can tell a wrong derivative
