"""Numerical stability at the extremes: warps, sharp BSDFs, tiny and huge lights.

Each test pushes one component to an extreme where float32 loses digits and checks that it
still returns finite numbers that respect a stated physical bound, or that it still agrees with
an analytic oracle evaluated in float64:

- every registry warp at ``u ∈ {0, tiny, 1 − 2⁻²⁴}²``: finite, in its support, finite density
  that is positive wherever the exact (float64) density is representable in float32;
- Phong n = 1e4 and GGX α = 1e-3 at normal, oblique and grazing (z = 1e-6) incidence;
- triangle and sphere lights of size 1e-4 and 1e4 (light sampling, and ``estimate_at`` against
  Lambert's formula / the sphere's closed form), a receiver 1e-5 below an area light;
- zero-radiance lights, and float32 against float64 estimates.

Whole-scene scaling and translation are in ``tests/statistical/test_stability_scenes.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.integrators.point import estimate_at
from jaxrt.sampling import warp as W
from jaxrt.scene import container as sc
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.validation import analytic

F32 = jnp.float32
TINY = float(np.finfo(np.float32).tiny)  # smallest normal float32, 1.2e-38
U_EXTREME = (0.0, TINY, 1.0 - 2.0**-24)
U9 = np.array([(a, b) for a in U_EXTREME for b in U_EXTREME], np.float32)
#: densities below this are not required to be positive in float32: they approach the smallest
#: normal float32 (1.2e-38), and XLA on CPU flushes denormals to zero
REPRESENTABLE = 1e-30


# ---------------------------------------------------------------------------------------------
# Warps at u next to 0 and 1
# ---------------------------------------------------------------------------------------------


def _arrays(params, dtype):
    return tuple(jnp.asarray(p, dtype) for p in params)


def _in_support(spec, x, params):
    """Boolean per sample: x lies in the warp's support (with float32 rounding slack)."""
    d = spec.domain
    if d == "disk":
        return np.sum(x**2, -1) <= 1 + 1e-6
    if d == "triangle":
        return np.all(x >= 0, -1) & (x.sum(-1) <= 1 + 1e-6)
    if isinstance(d, tuple):
        lo, hi = d[1], d[2]
        return np.all((x >= lo) & (x <= hi), -1)
    # directions: unit length to float32 rounding (a few ulp of 1)
    ok = np.abs(np.linalg.norm(x, axis=-1) - 1) <= 1e-5
    if d == "hemisphere":
        ok &= x[..., 2] >= 0
    if spec.name == "uniform_cone":
        ok &= x[..., 2] >= params[0] - 1e-6
    return ok


WARP_CASES = [pytest.param(spec, params, id=f"{spec.name}-{i}")
              for spec in W.REGISTRY for i, params in enumerate(spec.params)]


@pytest.mark.parametrize("spec, params", WARP_CASES)
def test_warp_extreme_u(spec, params):
    p32 = _arrays(params, F32)
    x = jax.vmap(lambda u: spec.sample(u, *p32))(jnp.asarray(U9))
    pdf = jax.vmap(lambda v: spec.pdf(v, *p32))(x)
    x_np, pdf_np = np.asarray(x, np.float64).reshape(len(U9), -1), np.asarray(pdf)
    # float32 in, float32 out (no float64 constant leaking in)
    assert x.dtype == F32 and pdf.dtype == F32
    # no NaN/Inf for any u on the boundary of the square
    assert np.all(np.isfinite(x_np)) and np.all(np.isfinite(pdf_np)), (x_np, pdf_np)
    assert np.all(_in_support(spec, x_np.reshape(x.shape), params)), x_np
    # a density is never negative
    assert np.all(pdf_np >= 0), pdf_np
    # positive wherever the exact density at the same float32 point is representable: the
    # only zeros allowed are where the density itself vanishes (the tent's ends, the horizon of
    # cosine-weighted warps) or is below float32's range
    with jax.enable_x64(True):
        exact = np.asarray(jax.vmap(lambda v: spec.pdf(v, *_arrays(params, jnp.float64)))(
            jnp.asarray(np.asarray(x), jnp.float64)))
    need = exact > REPRESENTABLE
    assert np.all(pdf_np[need] > 0), (x_np[need], pdf_np[need], exact[need])


# ---------------------------------------------------------------------------------------------
# Sharp BSDFs: Phong n = 1e4, GGX α = 1e-3, at normal, oblique and grazing incidence
# ---------------------------------------------------------------------------------------------

KD, KS, N_PHONG = 0.3, 0.6, 1e4
P_SPEC = KS / (KD + KS)  # lobe-selection probability for grey albedos (luminance ratio)
# f cos/p of a two-lobe mixture is at most the sum of the per-lobe ratios:
# kd/(1 − P) for the diffuse lobe and ks (n+2)/(n+1) cos θi / P for the normalised Phong lobe
PHONG_BOUND = KD / (1 - P_SPEC) + KS * (N_PHONG + 2) / (N_PHONG + 1) / P_SPEC
MATERIALS = {"phong-1e4": (mt.PHONG, lambda: mt.phong(KD, KS, N_PHONG), PHONG_BOUND),
             # GGX weight F·G2/G1(wo) ≤ F ≤ 1: height-correlated G2 = 1/(1+Λo+Λi) ≤ G1(wo)
             "ggx-1e-3": (mt.CONDUCTOR, lambda: mt.conductor(1e-3, 0.9), 1.0)}
GRAZING = 1e-6
WOS = {"normal": (0.0, 0.0, 1.0), "60deg": (np.sqrt(0.75), 0.0, 0.5),
       "grazing": (np.sqrt(1 - GRAZING**2), 0.0, GRAZING)}
N_BSDF = 1 << 14


@pytest.mark.parametrize("wo_name", list(WOS))
@pytest.mark.parametrize("mat_name", list(MATERIALS))
def test_sharp_bsdf_sampling(mat_name, wo_name):
    kind, make, bound = MATERIALS[mat_name]
    m, kinds = make(), (kind,)
    wo = jnp.asarray(WOS[wo_name], F32)
    u = np.concatenate([U9, np.asarray(jax.random.uniform(jax.random.PRNGKey(5), (N_BSDF, 2)))])
    s = jax.jit(jax.vmap(lambda uu: mt.bsdf_sample(m, wo, uu, kinds)))(jnp.asarray(u))
    wi, pdf, w = (np.asarray(a, np.float64) for a in (s.wi, s.pdf, s.weight))
    assert s.weight.dtype == F32
    # finite everything, unit directions, non-negative densities
    assert np.all(np.isfinite(wi)) and np.all(np.isfinite(pdf)) and np.all(np.isfinite(w))
    assert np.all(np.abs(np.linalg.norm(wi, axis=-1) - 1) < 1e-5)
    assert np.all(pdf >= 0)
    # the per-sample weight f|cos θi|/p obeys the physical bound of the lobe (+ float32 slack)
    assert np.all(w >= 0) and np.all(w <= bound * (1 + 1e-5)), (w.max(), bound)
    # energy conservation: the albedo (mean weight) ≤ kd + ks ≤ 1 (Phong), ≤ max F = 1 (GGX),
    # up to 5 standard errors of the mean
    mean, se = w.mean(0), w.std(0) / np.sqrt(len(w))
    assert np.all(mean <= 1 + 5 * se), (mean, se)
    # the density the sampler reports is the one bsdf_pdf gives for the same wi (MIS needs it)
    pdf_again = np.asarray(jax.jit(jax.vmap(lambda d: mt.bsdf_pdf(m, wo, d, kinds)))(s.wi))
    ok = pdf > REPRESENTABLE
    assert np.allclose(pdf_again[ok], pdf[ok], rtol=1e-3), np.max(
        np.abs(pdf_again[ok] / pdf[ok] - 1))
    # where the closed-form GGX weight is used, it equals f cos / p from eval and pdf: at
    # α = 1e-3 the pdf has 1e6 dynamic range, so allow 1% (float32 h from wo + wi)
    if kind == mt.CONDUCTOR and wo_name != "grazing":
        f = np.asarray(jax.jit(jax.vmap(lambda d: mt.bsdf_eval(m, wo, d, kinds)))(s.wi))
        sel = (w[:, 0] > 1e-3) & ok
        ratio = f[sel, 0] * wi[sel, 2] / pdf[sel] / w[sel, 0]
        assert np.all(np.abs(ratio - 1) < 1e-2), np.max(np.abs(ratio - 1))


@pytest.mark.parametrize("mat_name", list(MATERIALS))
def test_sharp_bsdf_grazing_eval(mat_name):
    """eval/pdf with grazing wi (z = 1e-6), incl. the specular grazing pair: finite, reciprocal."""
    kind, make, _ = MATERIALS[mat_name]
    m, kinds = make(), (kind,)
    g = WOS["grazing"]
    pairs = np.array([[(0, 0, 1), g],  # normal wo, grazing wi
                      [WOS["60deg"], g],
                      [g, (-g[0], 0, g[2])],  # mirror pair, both grazing: the lobe's peak
                      [g, (0, g[0], g[2])]], np.float32)
    ev = jax.jit(jax.vmap(lambda a, b: (mt.bsdf_eval(m, a, b, kinds), mt.bsdf_pdf(m, a, b, kinds))))
    f, pdf = (np.asarray(a, np.float64) for a in ev(pairs[:, 0], pairs[:, 1]))
    f_rev, _ = (np.asarray(a, np.float64) for a in ev(pairs[:, 1], pairs[:, 0]))
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(pdf)), (f, pdf)
    assert np.all(f >= 0) and np.all(pdf >= 0)
    # Helmholtz reciprocity f(wo, wi) = f(wi, wo) holds for both models; 1e-3 relative is
    # float32 rounding of the half vector / mirror direction amplified by the sharp lobe
    assert np.allclose(f, f_rev, rtol=1e-3, atol=1e-30), (f, f_rev)
    # the grazing mirror pair hits the lobe's peak: the value is large but finite and positive
    assert np.all(f[2] > 0), f[2]


# ---------------------------------------------------------------------------------------------
# Tiny and huge lights
# ---------------------------------------------------------------------------------------------

ALBEDO = 0.5
N_EST = 1 << 13
Z = np.array([0.0, 0.0, 1.0])
WO = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])


def _triangle(size, height):
    """A triangle of the given size at z = height, wound to face down (towards the origin)."""
    return np.array([[-size, -size, height], [-size, 2 * size, height], [2 * size, -size, height]])


def _sphere(radius):
    """Centre such that the sphere's surface is 1 above the receiver (off-axis by 0.3)."""
    return np.array([0.3, 0.0, radius + 1.0])


def _triangle_scene(tri, radiance):
    # material row 0 for the shading point, nothing else but the lamp
    lamp = sc.mesh(tri, [[0, 1, 2]], mt.diffuse(0.0), emission=radiance, name="lamp")
    return sc.shading_scene(mt.diffuse(ALBEDO), [], occluders=[lamp])


def _sphere_scene(radius, radiance):
    return sc.shading_scene(mt.diffuse(ALBEDO), [lt.sphere_light(_sphere(radius), radius,
                                                                 [radiance] * 3)])


def _triangle_exact(tri, radiance):
    """Lambertian reflected radiance ρ L Φ / π, Φ by Lambert's formula in float64."""
    with jax.enable_x64(True):
        phi = float(analytic.polygon_projected_solid_angle(jnp.asarray(tri, jnp.float64),
                                                           jnp.zeros(3), jnp.asarray(Z)))
    return ALBEDO * radiance * phi / np.pi


def _sphere_exact(radius, radiance):
    with jax.enable_x64(True):
        e = float(analytic.sphere_light_irradiance(
            jnp.asarray(_sphere(radius)), jnp.float64(radius), jnp.float64(radiance),
            jnp.zeros(3), jnp.asarray(Z)))
    return ALBEDO * e / np.pi


# radiance chosen so that the reflected radiance is O(1) for every size
LIGHTS = {
    "triangle-1e-4": ("triangle", 1e-4, 1e8),
    "triangle-1e4": ("triangle", 1e4, 1.0),
    "sphere-1e-4": ("sphere", 1e-4, 1e8),
    "sphere-1e4": ("sphere", 1e4, 1.0),
}


def _light_table(kind, size, radiance, sampling):
    if kind == "triangle":
        rec = lt.triangle_lights(_triangle(size, 1.0), [radiance] * 3, [0])
    else:
        rec = lt.sphere_light(_sphere(size), size, [radiance] * 3)
    return lt.light_table([rec], triangle_sampling=sampling)


@pytest.mark.parametrize("sampling", ["area", "solid_angle"])
@pytest.mark.parametrize("name", list(LIGHTS))
def test_light_sampling_extreme_sizes(name, sampling):
    kind, size, radiance = LIGHTS[name]
    if kind == "sphere" and sampling == "area":
        pytest.skip("spheres are always sampled by their cone")
    lights = _light_table(kind, size, radiance, sampling)
    p = jnp.zeros(3, F32)
    u = jax.random.uniform(jax.random.PRNGKey(1), (4096, 3), F32)
    u = jnp.concatenate([u, jnp.asarray(np.c_[np.full(9, 0.5), U9], F32)])
    s = jax.jit(jax.vmap(lambda uu: lt.sample_li(lights, p, jnp.asarray(Z, F32), uu)))(u)
    wi, dist, li, pdf = (np.asarray(a, np.float64) for a in (s.wi, s.dist, s.li, s.pdf))
    assert np.all(np.isfinite(wi)) and np.all(np.isfinite(dist)) and np.all(np.isfinite(li))
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0), (pdf.min(), pdf.max())
    assert np.all(np.abs(np.linalg.norm(wi, axis=-1) - 1) < 1e-5)
    # the sampled point lies on the light's visible part: between the nearest point (height 1
    # for the triangle, |c| − r for the sphere) and the farthest (a vertex; the tangent
    # distance √(|c|² − r²)), to float32 rounding
    if kind == "triangle":
        lo, hi = 1.0, np.linalg.norm(_triangle(size, 1.0), axis=-1).max()
    else:
        c = np.linalg.norm(_sphere(size))
        lo, hi = c - size, np.sqrt(c * c - size * size)
    assert np.all(dist >= lo * (1 - 1e-5)) and np.all(dist <= hi * (1 + 1e-5)), (
        dist.min(), dist.max(), lo, hi)
    # facing the receiver, every sample sees the full radiance (the lights are uniform)
    assert np.allclose(li, radiance, rtol=1e-6)
    # pdf_li at the same direction and light point reproduces the sampler's density (MIS uses
    # it); 1e-3 relative: float32 geometry of a 1e-4 light seen from 1 away
    q = s.wi * s.dist[:, None]
    again = np.asarray(jax.jit(jax.vmap(lambda w, lg, ql: lt.pdf_li(lights, p, w, lg, ql)))(
        s.wi, s.light, q))
    assert np.allclose(again, pdf, rtol=1e-3), np.max(np.abs(again / pdf - 1))


# floor on |mean − exact| / exact beyond 5σ: float32 in the solid angle / cone of a light that
# subtends 1e-8 sr, and the x64 oracle itself (exact); measured errors are below 1e-4
FLOOR = 2e-3
_scenes = {}


def _scene_for(name):
    if name not in _scenes:
        kind, size, radiance = LIGHTS[name]
        if kind == "triangle":
            _scenes[name] = (_triangle_scene(_triangle(size, 1.0), radiance),
                             _triangle_exact(_triangle(size, 1.0), radiance))
        else:
            _scenes[name] = _sphere_scene(size, radiance), _sphere_exact(size, radiance)
    return _scenes[name]


def _check_estimate(r, exact, what, floor=FLOOR):
    mean, se = np.asarray(r.mean, np.float64), np.asarray(r.stderr, np.float64)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(se)), what
    # 5σ of a mean over 8192 samples (3 channels: false alarm < 2e-6) plus the float32 floor
    assert np.all(np.abs(mean - exact) <= 5 * se + floor * exact), (what, mean, se, exact)


# Triangles covering nearly a hemisphere (size 1e4 at height 1, or a unit triangle 1e-5 away):
# float32 Arvo sampling of the whole triangle is biased here (E[cos θ] 0.26 instead of 0.50),
# hence warp_sphtri's split at the triangle's point closest to the shading point; and with a
# light point error bound of γ₇|q| rather than the light's extent seen from p
# (scene.light_point_error) 11-17% of the shadow rays would re-hit the light itself.
ESTIMATE_CASES = [("triangle-1e-4", "light_solid_angle"), ("sphere-1e4", "mis")]
# light_area on the 1e4 triangle is left out: unbiased, but its variance ∝ A/h² (~1e8 here) is
# so heavy-tailed that 8192 samples almost never reach the near part (σ̂ is meaningless)
SLOW_ESTIMATE_CASES = [("triangle-1e-4", "light_area"), ("triangle-1e-4", "mis"),
                       ("sphere-1e-4", "light_solid_angle"), ("sphere-1e-4", "mis"),
                       ("sphere-1e4", "light_solid_angle")]


@pytest.mark.parametrize("name, est", ESTIMATE_CASES + [
    pytest.param(*c, marks=pytest.mark.slow) for c in SLOW_ESTIMATE_CASES] + [
    pytest.param("triangle-1e4", est, marks=pytest.mark.slow)
    for est in ("light_solid_angle", "mis")])
def test_estimate_extreme_lights_against_oracle(name, est):
    scene, exact = _scene_for(name)
    r = estimate_at(scene, est, np.zeros(3), Z, WO, num_samples=N_EST, seed=3)
    _check_estimate(r, exact, f"{name} {est}")


@pytest.mark.slow
@pytest.mark.parametrize("size", [10.0, 1e4])
def test_large_spherical_triangle_sample_distribution(size):
    """Uniform directions in the spherical triangle have E[cos θ] = Φ/Ω (Φ: Lambert, x64)."""
    lights = _light_table("triangle", size, 1.0, "solid_angle")
    u = jax.random.uniform(jax.random.PRNGKey(8), (1 << 15, 3), F32)
    s = jax.jit(jax.vmap(lambda uu: lt.sample_li(lights, jnp.zeros(3, F32), jnp.asarray(Z, F32),
                                                 uu)))(u)
    cos = np.asarray(s.wi[:, 2], np.float64)
    with jax.enable_x64(True):
        tri = jnp.asarray(_triangle(size, 1.0))
        phi = float(analytic.polygon_projected_solid_angle(tri, jnp.zeros(3), jnp.asarray(Z)))
        omega = 1 / float(lt.sample_li(_light_table("triangle", size, 1.0, "solid_angle"),
                                       jnp.zeros(3), jnp.asarray(Z), jnp.full(3, 0.5)).pdf)
    # 5σ of the sample mean of cos θ (one statistic: false alarm 6e-7) + 1e-4 for Ω in x64
    se = cos.std() / np.sqrt(len(cos))
    assert abs(cos.mean() - phi / omega) <= 5 * se + 1e-4, (cos.mean(), phi / omega, se)


H_NEAR = 1e-5


@pytest.mark.parametrize("size, est", [
    (1e-4, "light_solid_angle"), (1e-4, "mis"),
    pytest.param(1e-4, "light_area", marks=pytest.mark.slow),
    # a unit triangle 1e-5 away covers a near-hemisphere (the float32 Arvo case above)
    pytest.param(1.0, "mis", marks=pytest.mark.slow)])
def test_receiver_next_to_area_light(size, est):
    """A receiver 1e-5 below a triangle light: 1/d² near-singular, yet finite and unbiased."""
    tri = _triangle(size, H_NEAR)
    scene, exact = _triangle_scene(tri, 1.0), _triangle_exact(tri, 1.0)
    # the light covers most of the hemisphere (size/height = 10): ρLΦ/π is O(ρL) = O(0.5)
    assert 0.3 < exact < 0.5, exact
    r = estimate_at(scene, est, np.zeros(3), Z, WO, num_samples=N_EST, seed=4)
    # light_area's variance grows like A/h² (its σ is large but finite); the others are precise
    _check_estimate(r, exact, est)


def test_zero_radiance_light_estimates_exactly_zero():
    """Only a light of radiance 0: estimates are exactly 0, never 0/0 = NaN."""
    scene = _sphere_scene(1e-4, 0.0)
    assert scene.lights.structure.counts[4] == 1  # the dark sphere is a light of the scene
    for est in ("light_solid_angle", "mis"):
        r = estimate_at(scene, est, np.zeros(3), Z, WO, num_samples=N_EST, seed=5)
        assert np.all(np.asarray(r.mean) == 0) and np.all(np.asarray(r.stderr) == 0), est
    # a dark triangle light, through its light table: the
    # samples carry li = 0 exactly with a finite positive density
    for sampling in ("area", "solid_angle"):
        lights = _light_table("triangle", 1.0, 0.0, sampling)
        u = jax.random.uniform(jax.random.PRNGKey(9), (256, 3), F32)
        s = jax.vmap(lambda uu, lg=lights: lt.sample_li(lg, jnp.zeros(3, F32), jnp.asarray(Z, F32),
                                             uu))(u)
        assert np.all(np.asarray(s.li) == 0), sampling
        assert np.all(np.isfinite(s.pdf)) and np.all(np.asarray(s.pdf) > 0), sampling


# ---------------------------------------------------------------------------------------------
# float32 against float64
# ---------------------------------------------------------------------------------------------

# float32 floor on the relative difference beyond the joint 5σ: Φ and pdfs in float32 carry
# ~1e-6 relative error; 1e-4 leaves room for the sum over 8192 samples
F32_FLOOR = 1e-4


@pytest.mark.parametrize("name, est", [
    ("triangle-1e-4", "light_solid_angle"),
    pytest.param("sphere-1e4", "mis", marks=pytest.mark.slow)])
def test_float32_matches_float64(name, est):
    kind, size, radiance = LIGHTS[name]
    scene32, exact = _scene_for(name)
    r32 = estimate_at(scene32, est, np.zeros(3), Z, WO, num_samples=N_EST, seed=6)
    with jax.enable_x64(True):
        # rebuilt inside the context so every array of the scene is float64
        scene64 = (_triangle_scene(_triangle(size, 1.0), radiance) if kind == "triangle"
                   else _sphere_scene(size, radiance))
        assert scene64.triangles.dtype == jnp.float64
        r64 = estimate_at(scene64, est, np.zeros(3), Z, WO, num_samples=N_EST, seed=6)
        m64, s64 = np.asarray(r64.mean), np.asarray(r64.stderr)
    assert r32.mean.dtype == F32
    m32, s32 = np.asarray(r32.mean, np.float64), np.asarray(r32.stderr, np.float64)
    # independent-or-not, two estimates of one value differ by < 5 joint σ + the float32 floor
    assert np.all(np.abs(m32 - m64) <= 5 * np.hypot(s32, s64) + F32_FLOOR * np.abs(m64)), (
        m32, m64, s32, s64)
    # and the float64 run agrees with the oracle too (the oracle is not float32-specific)
    _check_estimate(r64, exact, f"x64 {name}", floor=1e-6)
