"""estimate_image under jit / grad / vmap, and its derivatives validated statistically.

Derivative estimators are tested like the estimators themselves: against closed forms
(jaxrt.validation.analytic, differentiated by jax), against finite differences with common random
numbers, and across seeds against a converged reference (a deterministic quadrature), each
within a bound from the derivative estimator's own standard error.
"""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrt
from jaxrt.integrators.config import ESTIMATORS
from jaxrt.rendering import differentiable
from jaxrt.rendering.differentiable import (
    DERIVATIVE_SEED_XOR,
    GRAD_LANES,
    derivative_at,
    estimate_image,
    gradient,
    image_vjp,
    scene_params,
    with_params,
)
from jaxrt.scene import builtin as scenes
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.container import mesh, shading_scene
from jaxrt.validation import analytic

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


def test_with_params_keeps_what_blocks_shadow_rays_when_traced():
    """Radiometric parameters change neither the shadow rays' occluders nor the convex
    bodies; re-found from traced arrays (the derivative pass takes the scene as an argument
    of its program) they would be dropped, and every triangle tested."""
    assert CORNELL.occluders is not None and CORNELL.convex is not None
    seen = {}

    @jax.jit
    def traced(scene, params):
        s = with_params(scene, params)
        seen["occluders"], seen["convex"] = s.occluders, s.convex
        return s.materials.kd

    traced(CORNELL, scene_params(CORNELL))
    assert seen["occluders"].shape == CORNELL.occluders.shape
    assert seen["convex"] is not None
    assert seen["convex"].planes.shape == CORNELL.convex.planes.shape


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


@pytest.mark.parametrize("accel, spp, spp_per_pass, layout, grad_lanes", [
    ("auto", 4, 1, dict(tile_size=256, batch_size=64), GRAD_LANES),
    ("bvh", 8, 4, dict(tile_size=16, batch_size=3), 96)])
def test_image_vjp_in_passes_is_the_vjp_of_the_image(accel, spp, spp_per_pass, layout,
                                                      grad_lanes, monkeypatch):
    """Pass-by-pass accumulation equals one jax.vjp over all samples: 1 spp per pass; and
    on a BVH scene whose 4 tiles run in 2 steps of 3 (the last padded), 2 passes of 4 spp,
    each folded as 2 grads of 2 sample indices (96 lanes per grad)."""
    monkeypatch.setattr(differentiable, "GRAD_LANES", grad_lanes)
    scene = CORNELL if accel == "auto" else scenes.cornell_box(8, 8, accel="bvh")
    theta = {k: v for k, v in scene_params(scene).items()
             if k in ("materials.kd", "triangle.radiance")}
    c = jax.random.normal(jax.random.key(0), (8, 8, 3))
    _, vjp = jax.vjp(lambda t: estimate_image(with_params(scene, t), spp=spp, seed=2, **layout),
                     theta)
    ref = vjp(c)[0]
    got = image_vjp(scene, c, spp=spp, spp_per_pass=spp_per_pass, seed=2, params=tuple(theta),
                    **layout)
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


class Check(NamedTuple):
    """A derivative estimate at a point vs its reference, per channel (RGB channels carry
    derivatives w.r.t. different parameters: ``params[c]`` names channel c's, None if unused)."""

    params: tuple
    mean: np.ndarray  # (3,) mean of the one-sample derivative estimates
    stderr: np.ndarray  # (3,) their standard error
    ref: np.ndarray  # (3,) the reference derivative

    @property
    def z(self) -> np.ndarray:
        """(mean − ref) / stderr; a zero-variance estimate (cosine sampling of a diffuse point
        under a constant environment: every sample's d/dkd is L) is held to float32 rounding
        of the mean instead, 1e-5 relative."""
        return (self.mean - self.ref) / np.maximum(self.stderr, 1e-5 * np.abs(self.ref) + 1e-12)


def _check(params, d, ref) -> Check:
    return Check(tuple(params), np.asarray(d.mean, np.float64), np.asarray(d.stderr, np.float64),
                 np.asarray(ref, np.float64))


def assert_checks(checks, bound=5.0, power=10.0):
    """|z| < ``bound`` on every channel in use, and every non-zero reference at least
    ``power`` standard errors from 0 (so a derivative that vanishes would fail)."""
    for c in checks:
        used = np.array([p is not None for p in c.params])
        assert np.all(np.abs(c.z[used]) < bound), (c.params, c.mean, c.ref, c.stderr, c.z)
        live = used & (c.ref != 0)
        assert np.all(np.abs(c.ref[live]) > power * c.stderr[live]), (c.params, c.ref, c.stderr)


def _oracle_env_point(rho, le, inten, with_point):
    e = analytic.constant_environment_irradiance(le)
    if with_point:
        e = e + analytic.point_light_irradiance(jnp.asarray([0.3, 0.2, 1.5]), inten, P, N)
    return analytic.lambertian_radiance(rho, e)


def sees_delta(estimator) -> bool:
    return estimator not in ("uniform_hemisphere", "cosine_hemisphere", "bsdf")


def emission_checks(estimator) -> list[Check]:
    """d/dρ, d/dL_e (constant environment, area light) and d/dI (point light) of the one-point
    estimate vs jax.jvp of analytic's oracle (R ρ, G radiance, B intensity)."""
    le, inten = np.array([0.3, 0.7, 0.2]), np.array([2.0, 1.0, 3.0])
    tan_rho, tan_le, tan_i = np.eye(3)
    env_point = shading_scene(mt.diffuse(RHO), [lt.constant_environment(le),
                                                lt.point_light([0.3, 0.2, 1.5], inten)])
    d = derivative_at(env_point, {"materials.kd": tan_rho[None],
                                  "environment.radiance": tan_le, "point.intensity": tan_i[None]},
                      estimator, P, N, WO, num_samples=1 << 15, seed=1)
    delta = sees_delta(estimator)
    _, ref = jax.jvp(lambda r, e, i: _oracle_env_point(r, e, i, delta),
                     (jnp.asarray(RHO), jnp.asarray(le), jnp.asarray(inten)),
                     (jnp.asarray(tan_rho), jnp.asarray(tan_le), jnp.asarray(tan_i)))
    out = [_check(("kd (environment + point)", "environment.radiance",
                   "point.intensity" if delta else None), d, ref)]

    light = mesh(QUAD, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=le, name="quad")
    area = shading_scene(mt.diffuse(RHO), [], occluders=[light])
    d = derivative_at(area, {"materials.kd": np.stack([tan_rho, 0 * tan_rho]),
                             "triangle.radiance": np.stack([tan_le, tan_le])},
                      estimator, P, N, WO, num_samples=1 << 15, seed=2)
    _, ref = jax.jvp(lambda r, e: analytic.lambertian_radiance(
        r, analytic.polygon_irradiance(jnp.asarray(QUAD), e, P, N)),
        (jnp.asarray(RHO), jnp.asarray(le)), (jnp.asarray(tan_rho), jnp.asarray(tan_le)))
    out.append(_check(("kd (area light)", "triangle.radiance", None), d, ref))
    return out


@pytest.mark.slow  # ~60 s: 7 estimators × 2 scenes, one forward-mode program each
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_derivatives_match_closed_forms(estimator):
    """d/dρ, d/dL_e (environment, area light) and d/dI (point light) of the one-point
    estimate vs jax.jvp of analytic's oracle, within 5 standard errors of the derivative
    estimator (channels carry different derivatives: R ρ, G radiance, B intensity)."""
    assert_checks(emission_checks(estimator))


SPHERE_C, SPHERE_R = np.array([0.5, -0.3, 1.2]), 0.5
SPOT_AT = np.array([-0.6, 0.1, 1.0])
SPOT_AXIS = np.array([0.25, -0.1, -1.0])  # P is 0.29 rad off the axis: falloff 0.48
SPOT_INNER, SPOT_OUTER = 0.1, 0.4
SUN = np.array([0.4, 0.5, 1.0]) / np.linalg.norm([0.4, 0.5, 1.0])


def _spot_irradiance(inten):
    """I · smoothstep(cos θ; cos θ_outer, cos θ_inner) · cos θi / d², written out here."""
    v = SPOT_AT - P
    d2 = v @ v
    wi = v / np.sqrt(d2)
    cos_theta = -wi @ (SPOT_AXIS / np.linalg.norm(SPOT_AXIS))
    t = np.clip((cos_theta - np.cos(SPOT_OUTER)) / (np.cos(SPOT_INNER) - np.cos(SPOT_OUTER)), 0, 1)
    falloff = t * t * (3 - 2 * t)
    assert 0.3 < falloff < 0.7  # the falloff is exercised, not saturated
    return inten * falloff * max(N @ wi, 0.0) / d2


def light_checks(estimator) -> list[Check]:
    """d/dL_e of a sphere light (R), d/dI of a spot light in its falloff (G), d/dE of a
    directional light (B) at a Lambertian point, vs jax.jvp of the closed forms (analytic's
    sphere irradiance, spot and sun irradiance written out): one scene with all three."""
    ls, inten, irr = np.array([0.9, 0.5, 0.7]), np.array([2.0, 3.0, 1.0]), np.array([1.5, 0.8, 1.2])
    scene = shading_scene(mt.diffuse(RHO), [
        lt.sphere_light(SPHERE_C, SPHERE_R, ls),
        lt.spot_light(SPOT_AT, SPOT_AXIS, inten, SPOT_INNER, SPOT_OUTER),
        lt.directional_light(SUN, irr)])
    t_sphere, t_spot, t_sun = np.eye(3)
    d = derivative_at(scene, {"sphere.radiance": t_sphere[None], "spot.intensity": t_spot[None],
                              "directional.irradiance": t_sun[None]},
                      estimator, P, N, WO, num_samples=1 << 17, seed=3)
    delta = sees_delta(estimator)

    def oracle(a, b, c):
        e = analytic.sphere_light_irradiance(jnp.asarray(SPHERE_C), jnp.asarray(SPHERE_R), a, P, N)
        if delta:
            e = e + _spot_irradiance(b) + c * max(N @ SUN, 0.0)
        return analytic.lambertian_radiance(jnp.asarray(RHO), e)

    _, ref = jax.jvp(oracle, (jnp.asarray(ls), jnp.asarray(inten), jnp.asarray(irr)),
                     (jnp.asarray(t_sphere), jnp.asarray(t_spot), jnp.asarray(t_sun)))
    names = ("sphere.radiance",) + (("spot.intensity", "directional.irradiance") if delta
                                    else (None, None))
    return [_check(names, d, ref)]


ENV_H, ENV_W = 8, 16
ENV_N = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])  # a tilted receiver
ENV_ROT = np.array([[1.0, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]])


def _texel_projected_solid_angles(n, rotation, k=64):
    """Φ_t = ∫_texel max(0, n·R ω) dω for every texel of an (ENV_H, ENV_W) lat-long map,
    by the midpoint rule on k × k points per texel in (θ, φ) with dω = sin θ dθ dφ (float64):
    the radiance reflected by a Lambertian point is ρ/π Σ_t L_t Φ_t, linear in the texels."""
    theta = np.pi * (np.arange(ENV_H * k) + 0.5) / (ENV_H * k)
    phi = 2 * np.pi * (np.arange(ENV_W * k) + 0.5) / (ENV_W * k)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    local = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), ct), -1)
    cos = np.maximum(local @ (rotation.T @ n), 0) * st
    da = (np.pi / (ENV_H * k)) * (2 * np.pi / (ENV_W * k))
    return cos.reshape(ENV_H, k, ENV_W, k).sum(axis=(1, 3)) * da


def env_map_checks(estimator) -> list[Check]:
    """Directional derivative of a Lambertian point's reflected radiance under an 8 × 16
    environment map (rotated, receiver tilted) along three texel images, one per channel (R
    random positive, G cos φ, B one texel), vs ρ/π Σ_t T_t Φ_t with Φ_t each texel's
    projected solid angle by quadrature."""
    rng = np.random.default_rng(12)
    image = 0.2 + rng.random((ENV_H, ENV_W, 3))
    tangent = np.zeros((ENV_H, ENV_W, 3))
    tangent[..., 0] = rng.random((ENV_H, ENV_W))  # all texels, weighted
    tangent[..., 1] = np.cos(2 * np.pi * (np.arange(ENV_W) + 0.5) / ENV_W)  # signed, cos φ
    tangent[2, 5, 2] = 1.0  # one texel: ∂L/∂L_t = ρ/π Φ_t
    scene = shading_scene(mt.diffuse(RHO), [lt.environment_map(image, ENV_ROT)])
    phi = _texel_projected_solid_angles(ENV_N, ENV_ROT)
    assert abs(phi.sum() - np.pi) < 1e-4  # the quadrature covers the hemisphere
    d = derivative_at(scene, {"environment.image": tangent}, estimator, P, ENV_N, WO,
                      num_samples=1 << 17, seed=4)
    ref = RHO / np.pi * np.einsum("hwc,hw->c", tangent, phi)
    return [_check(("environment.image (all, >0)", "environment.image (cos φ)",
                    "environment.image (one texel)"), d, ref)]


PHONG_KD, PHONG_KS, PHONG_N = np.array([0.3, 0.25, 0.2]), np.array([0.5, 0.6, 0.4]), 20.0
ENV_LE = np.array([0.8, 1.0, 0.6])
WO_PHONG = np.array([np.sin(0.6), 0.0, np.cos(0.6)])


def _phong_lobe_albedo(wo, exponent, k=1024):
    """A(wo) = ∫_{H²} (n+2)/(2π) max(0, wi·wr)^n cos θi dwi, in polar coordinates about the
    mirror direction wr by the midpoint rule (float64); 1 at normal incidence."""
    wr = np.array([-wo[0], -wo[1], wo[2]])
    t1 = np.cross(wr, [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(wr, t1)
    a = (np.arange(k) + 0.5) * (np.pi / 2) / k
    b = (np.arange(k) + 0.5) * 2 * np.pi / k
    sa, ca = np.sin(a)[:, None], np.cos(a)[:, None]
    cos_i = ca * wr[2] + sa * (np.cos(b) * t1[2] + np.sin(b) * t2[2])
    f = (exponent + 2) / (2 * np.pi) * ca**exponent * np.maximum(cos_i, 0) * sa
    return f.sum() * (np.pi / 2 / k) * (2 * np.pi / k)


def phong_checks(estimator) -> list[Check]:
    """d/dkd (R), d/dks (G) and both (B) of a Phong point (exponent 20, viewed 0.6 rad off
    the normal) under a constant environment L: ``L (dkd + A(wo) dks)`` with A the glossy
    lobe's albedo (its lobe partly below the horizon) by quadrature. The BSDF sampler's lobe
    choice ∝ lum(ks) / (lum(kd) + lum(ks)) moves with both parameters."""
    scene = shading_scene(mt.phong(PHONG_KD, PHONG_KS, PHONG_N),
                          [lt.constant_environment(ENV_LE)])
    t_kd, t_ks = np.array([[1.0, 0.0, 1.0]]), np.array([[0.0, 1.0, 1.0]])
    d = derivative_at(scene, {"materials.kd": t_kd, "materials.ks": t_ks}, estimator, P, N,
                      WO_PHONG, num_samples=1 << 17, seed=5)
    ref = ENV_LE * (t_kd[0] + _phong_lobe_albedo(WO_PHONG, PHONG_N) * t_ks[0])
    return [_check(("kd (Phong)", "ks (Phong)", "kd + ks (Phong)"), d, ref)]


@pytest.mark.slow  # ~45 s: 7 estimators × 3 scenes at 2^17 samples, one program each
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_more_derivatives_match_closed_forms(estimator):
    """Sphere-light radiance, spot intensity, directional irradiance, environment-map texels,
    Phong kd and ks: the one-point derivative estimate within 5 of its own standard errors of
    the closed form or float64 quadrature, every reference ≥ 10 standard errors from 0.

    Teeth, each broken locally (with_tangent_of in the light or BSDF code) and |z| measured:
    env texel lookup's derivative taken from the mirrored row: 8.9–31 on the all-texel
    tangent, 4.3–7.9 on cos φ, the one texel's derivative 0 (1e5; all estimators); from one
    column over (22.5°): 13–27 on cos φ, 7.6–12 on the one texel; stopped: 1e5 (0);
    sphere radiance's derivative ×0.95 in light sampling: 14–23 (light, MIS), in the
    emission BSDF rays find: 5.7–6.7 (hemisphere, BSDF; not MIS, whose weight leaves those
    samples little); spot derivative without the falloff: 36–53; directional ×1.03: 5.1–6.3;
    Phong's sample weight differentiated through the sampling (no detached_weight): 7.3 bsdf,
    23 mis, 8.5 mis_one_sample; its 1/p made to depend on kd, ks: 9.8–18."""
    assert_checks(light_checks(estimator) + env_map_checks(estimator) + phong_checks(estimator))


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


SAMPLER_DEPENDENT = {"ggx": (_ggx, "materials.alpha", 0.3, np.pi / 6),
                     "phong": (_phong, "materials.exponent", 20.0, 0.3)}


def _sampler_dependent_scene(name):
    base = mt.conductor(0.3, 0.9) if name == "ggx" else mt.phong(0.2, 0.6, 20.0)
    light = mesh(QUAD, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=LE, name="quad")
    return shading_scene(base, [], occluders=[light])


def sampler_dependent_checks(name, estimator, ref=None) -> list[Check]:
    """d/dα (GGX) or d/dn (Phong exponent) of the R channel from 2^16 one-sample estimates vs
    jax.grad of the float64 quadrature (``ref``, computed if not given)."""
    material, param, value, angle = SAMPLER_DEPENDENT[name]
    if ref is None:
        with jax.enable_x64(True):
            ref = float(jax.grad(lambda t: _quadrature(material, t, _wo(angle)))(
                jnp.float64(value)))
    d = derivative_at(_sampler_dependent_scene(name), {param: np.array([1.0, 0.0])}, estimator,
                      P, N, _wo(angle), num_samples=1 << 16, seed=11)
    return [Check((param, None, None), np.asarray(d.mean, np.float64),
                  np.asarray(d.stderr, np.float64), np.array([ref, 0.0, 0.0]))]


@pytest.mark.slow  # ~40 s: 2 materials × 3 estimators at 2^16 samples, a float64 quadrature
@pytest.mark.parametrize("name", ["ggx", "phong"])
def test_derivative_unbiased_where_the_sampler_depends_on_it(name):
    """Mean of 2^16 independent one-sample derivative estimates vs the derivative of a
    converged quadrature: |z| < 4 for BSDF sampling and both MIS variants, whose sampled
    directions move with the parameter. Differentiating through the sampled direction
    instead (dropping the stop_gradient on ``wi`` in ``materials.detached_weight``) misses
    the light's edges and fails: |z| 13–90 for α, 42–162 for the exponent (measured)."""
    material, param, value, angle = SAMPLER_DEPENDENT[name]
    with jax.enable_x64(True):
        ref_value = float(_quadrature(material, jnp.float64(value), _wo(angle)))
        ref = float(jax.grad(lambda t: _quadrature(material, t, _wo(angle)))(jnp.float64(value)))
    scene = _sampler_dependent_scene(name)
    for estimator in ("bsdf", "mis", "mis_one_sample"):
        est = jaxrt.integrators.point.estimate_at(scene, estimator, P, N, _wo(angle),
                                           num_samples=1 << 16, seed=7)
        zv = (float(est.mean[0]) - ref_value) / float(est.stderr[0])
        assert abs(zv) < 4, (estimator, "value", est.mean, ref_value)  # the reference holds
        (c,) = sampler_dependent_checks(name, estimator, ref)
        assert abs(c.z[0]) < 4, (estimator, c.mean[0], ref, c.stderr[0])
        assert abs(ref) > 10 * c.stderr[0]  # the test can tell a wrong derivative


@pytest.mark.parametrize("estimator", ["light_area", "mis", "mis_one_sample"])
def test_derivative_wrt_a_black_light(estimator):
    """d/dI of a point light of intensity 0 beside a lit one: ρ/π · cos θ / d² per unit
    intensity, within 5σ. Light selection keeps a floor for every light
    (``lights.table.SELECTION_FLOOR``); with the floor at 0 the black light is never
    sampled and its derivative is exactly 0, with a standard error of 0 (the test fails),
    so an optimiser could never light a light that starts black."""
    dark_at, lit_at = np.array([0.6, -0.2, 1.1]), np.array([-0.3, 0.2, 1.5])
    scene = shading_scene(mt.diffuse(RHO), [lt.point_light(lit_at, [2.0, 2.0, 2.0]),
                                            lt.point_light(dark_at, [0.0, 0.0, 0.0])])
    tangent = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    d = derivative_at(scene, {"point.intensity": tangent}, estimator, P, N, WO,
                      num_samples=1 << 17, seed=5)
    r2 = float(dark_at @ dark_at)
    ref = RHO / np.pi * (dark_at[2] / np.sqrt(r2)) / r2
    z = (np.asarray(d.mean) - ref) / np.asarray(d.stderr)
    assert np.all(np.abs(z) < 5), (d.mean, ref, d.stderr)
    assert np.all(ref > 10 * np.asarray(d.stderr))


@pytest.mark.slow  # ~40 s: 2 × 9 perturbed path-traced images over 8 seeds, 8 VJPs
def test_path_gradient_matches_central_differences():
    """Reverse mode through the path tracer (bounded depth: its vertex loop is a fori_loop).
    d/ds of the image mean, s scaling one material's albedo or the light's radiance, by
    ``image_vjp`` of ``path`` with max_depth 3 (up to two reflections), vs central
    differences of ``estimate_image`` at the same seeds (common random numbers): within 4
    combined standard errors over 8 seeds. The ceiling, which only indirect light reaches,
    has a derivative here (none under direct light), and the test checks it is found.
    Dropping the derivative of the throughput in the NEE term fails it."""
    scene = scenes.cornell_box(12, 12)
    base = scene_params(scene)
    kd, rad = base["materials.kd"], base["triangle.radiance"]
    m = kd.shape[0]
    seeds = jnp.arange(8, dtype=jnp.uint32)
    opts = dict(spp=4, max_depth=3)

    def mean(s, seed):  # s: (M + 1,) scale factors of the albedo rows and the radiance
        box = with_params(scene, {"materials.kd": kd * s[:m, None],
                                  "triangle.radiance": rad * s[m]})
        return jnp.mean(estimate_image(box, "path", seed=seed, **opts))

    c = jnp.full((12, 12, 3), 1.0 / (12 * 12 * 3))
    ad = []
    for seed in np.asarray(seeds):
        g = jaxrt.image_vjp(scene, c, "path", seed=int(seed),
                            params=("materials.kd", "triangle.radiance"), **opts)
        ad.append(np.concatenate([np.sum(np.asarray(g["materials.kd"] * kd), axis=1),
                                  [float(np.sum(g["triangle.radiance"] * rad))]]))
    ad = np.stack(ad)  # (seeds, M + 1)
    h = 0.05
    one = jnp.ones(m + 1)
    steps = jnp.concatenate([jnp.eye(m + 1) * h, -jnp.eye(m + 1) * h])
    vals = jax.jit(jax.vmap(jax.vmap(mean, (None, 0)), (0, None)))(one + steps, seeds)
    fd = np.asarray((vals[: m + 1] - vals[m + 1:]).T / (2 * h))  # (seeds, M + 1)
    se = np.sqrt(np.var(ad, 0, ddof=1) / len(seeds) + np.var(fd, 0, ddof=1) / len(seeds))
    diff = np.abs(ad.mean(0) - fd.mean(0))
    visible = np.abs(fd.mean(0)) > 0
    assert visible.sum() >= 7 and visible[1], fd.mean(0)  # material 1: the ceiling
    assert np.all(diff[visible] <= 4 * se[visible] + 1e-6 * np.abs(fd.mean(0))[visible]), (
        diff, se)
    assert np.all(ad[:, ~visible] == 0)
