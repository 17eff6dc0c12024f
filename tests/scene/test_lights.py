"""Light models: delta lights exactly, sample/pdf consistency, normalisation, irradiance,
selection, sphere intersection, validation, dtypes and extremes.

The chi-square fits of every light's direction sampling live in ``test_lights_chi2.py``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from jaxrt.geometry.triangle import intersect_triangle
from jaxrt.sampling.distributions import discrete_pmf
from jaxrt.scene.lights import (
    constant_environment,
    directional_light,
    environment_map,
    intersect_spheres,
    le_environment,
    le_sphere,
    le_triangle,
    light_table,
    pdf_li,
    point_light,
    sample_li,
    sphere_light,
    spot_light,
    triangle_lights,
)
from jaxrt.scene.lights import table as lt_table
from jaxrt.validation import analytic

sample_batch = jax.jit(jax.vmap(sample_li, (None, None, None, 0)))
pdf_batch = jax.jit(jax.vmap(pdf_li, (None, None, 0, 0, 0)))
N_UP = jnp.array([0.0, 0.0, 1.0])

# A triangle in the plane z = 1 whose emitting side (normal of (v1−v0)×(v2−v0)) faces −z.
TRI = np.array([[-0.5, -0.4, 1.0], [0.1, 0.6, 1.0], [0.6, -0.3, 1.0]])
assert np.cross(TRI[1] - TRI[0], TRI[2] - TRI[0])[2] < 0


def uniforms(n, seed=0, dim=3, dtype=jnp.float32):
    return jax.random.uniform(jax.random.PRNGKey(seed), (n, dim), dtype=dtype)


def hit_point(lights, p, wi):
    """Where ``wi`` from ``p`` hits the (single) triangle / sphere light, by an independent
    intersection routine: the triangle by jaxrt.geometry.triangle, the sphere by
    intersect_spheres."""
    if lights.triangle is not None:
        v = lights.triangle.vertices[0].astype(p.dtype)
        t, _, _ = jax.vmap(intersect_triangle, (None, 0, None, None, None, None))(
            p, wi, v[0], v[1], v[2], jnp.inf)
    elif lights.sphere is not None:
        t, _ = jax.vmap(intersect_spheres, (None, None, 0, None))(lights, p, wi, jnp.inf)
    else:
        t = jnp.full(wi.shape[0], jnp.inf, p.dtype)
    return p + jnp.where(jnp.isfinite(t), t, 0)[:, None] * wi, t


def env_image(seed=3, h=8, w=16):
    rng = np.random.default_rng(seed)
    return rng.gamma(0.7, 1.0, size=(h, w, 3))


# Non-delta configurations: (name, light records, table kwargs, shading point).
CONFIGS = {
    "tri_area": ([lambda: triangle_lights(TRI, [1, 2, 3], [7])], {"triangle_sampling": "area"},
                 [0.1, 0.0, 0.0]),
    "tri_sa": ([lambda: triangle_lights(TRI, [1, 2, 3], [7])],
               {"triangle_sampling": "solid_angle"}, [0.1, 0.0, 0.0]),
    # 1e-4 below the plane, inside the triangle's shadow: Ω close to 2π.
    "tri_area_close": ([lambda: triangle_lights(TRI, [1, 2, 3], [7])],
                       {"triangle_sampling": "area"}, [0.05, 0.0, 1.0 - 1e-4]),
    "tri_sa_close": ([lambda: triangle_lights(TRI, [1, 2, 3], [7])],
                     {"triangle_sampling": "solid_angle"}, [0.05, 0.0, 1.0 - 1e-4]),
    "sphere_near": ([lambda: sphere_light([0.3, 0.2, 2.0], 1.0, [2, 2, 2])], {}, [0.0, 0.0, 0.0]),
    # r/d = 5.6e-4: the sphere subtends ~1e-6 sr.
    "sphere_far": ([lambda: sphere_light([1.0, 2.0, 2.0], 3 * 5.64e-4, [2, 2, 2])], {},
                   [0.0, 0.0, 0.0]),
    "sphere_inside": ([lambda: sphere_light([0.3, 0.2, 0.1], 1.0, [2, 2, 2])], {}, [0.0, 0.0, 0.0]),
    "env_const": ([lambda: constant_environment([0.5, 0.4, 0.3])], {}, [0.0, 0.0, 0.0]),
    "env_map": ([lambda: environment_map(env_image())], {}, [0.0, 0.0, 0.0]),
}


def build(name):
    recs, kw, p = CONFIGS[name]
    return light_table([r() for r in recs], **kw), jnp.asarray(p, jnp.result_type(float))


# ---------------------------------------------------------------------------------------------
# Delta lights.


def test_point_light_exact():
    lights = light_table([point_light([1.0, 2.0, 3.0], [4.0, 8.0, 12.0])])
    p = jnp.array([1.0, 2.0, 1.0])
    s = sample_batch(lights, p, N_UP, uniforms(16))
    # wi and li are deterministic: exact up to float32 rounding (rel 1e-6).
    np.testing.assert_allclose(s.wi, np.tile([0, 0, 1.0], (16, 1)), atol=1e-6)
    np.testing.assert_allclose(s.dist, 2.0, rtol=1e-6)
    np.testing.assert_allclose(s.li, np.tile([1.0, 2.0, 3.0], (16, 1)), rtol=1e-6)
    assert np.all(s.is_delta) and np.all(s.pdf == 1.0) and np.all(s.light == 0)
    # A BSDF sample can never hit a delta light: pdf_li is exactly 0.
    assert float(pdf_li(lights, p, s.wi[0], jnp.int32(0), p)) == 0.0


def test_spot_light_falloff():
    inner, outer = 0.2, 0.5
    lights = light_table([spot_light([0.0, 0.0, 2.0], [0.0, 0.0, -3.0], [5.0, 5.0, 5.0],
                                     inner, outer)])
    u = jnp.zeros(3)

    def li_at(theta):
        # A receiver at distance 2 from the spot, at angle theta off its axis.
        p = jnp.array([2 * np.sin(theta), 0.0, 2 - 2 * np.cos(theta)], jnp.float32)
        return sample_li(lights, p, N_UP, u)

    # Inside the inner cone: full intensity I/d² = 5/4; beyond the outer cone: 0 (rel 1e-5).
    np.testing.assert_allclose(li_at(0.0).li, 1.25, rtol=1e-5)
    np.testing.assert_allclose(li_at(inner * 0.999).li, 1.25, rtol=1e-5)
    np.testing.assert_allclose(li_at(outer * 1.001).li, 0.0, atol=1e-7)
    # Midway in cos θ the smoothstep is exactly 1/2 (t = 1/2 → t²(3 − 2t) = 1/2).
    mid = np.arccos(0.5 * (np.cos(inner) + np.cos(outer)))
    np.testing.assert_allclose(li_at(mid).li, 0.625, rtol=1e-4)
    # At t = 1/4 of the way from the outer cone: 1/16·(3 − 1/2) = 5/32.
    quarter = np.arccos(np.cos(outer) + 0.25 * (np.cos(inner) - np.cos(outer)))
    np.testing.assert_allclose(li_at(quarter).li, 1.25 * 5 / 32, rtol=1e-4)
    s = li_at(0.3)
    assert bool(s.is_delta) and float(s.pdf) == 1.0


def test_directional_light_exact():
    lights = light_table([directional_light([0.0, 3.0, 4.0], [1.0, 0.5, 0.25])])
    s = sample_li(lights, jnp.array([5.0, -7.0, 1.0]), N_UP, jnp.array([0.3, 0.6, 0.9]))
    np.testing.assert_allclose(s.wi, [0.0, 0.6, 0.8], rtol=1e-6)
    np.testing.assert_allclose(s.li, [1.0, 0.5, 0.25], rtol=1e-6)
    assert np.isinf(float(s.dist)) and bool(s.is_delta) and float(s.pdf) == 1.0


# ---------------------------------------------------------------------------------------------
# Consistency: pdf_li at the sampled direction (and the independently found hit point)
# equals the pdf the sampler reported.


# Every configuration in float32; in float64 the default run keeps two, the slow run all.
PDF_CASES = [pytest.param(n, False, id=f"f32-{n}") for n in sorted(CONFIGS)] + [
    pytest.param(n, True, id=f"x64-{n}",
                 marks=() if n in ("tri_sa", "sphere_far") else pytest.mark.slow)
    for n in sorted(CONFIGS)]


@pytest.mark.parametrize("name, x64", PDF_CASES)
def test_pdf_matches_sample(name, x64):
    with jax.enable_x64(x64):
        _check_pdf_matches_sample(name, x64)


def _check_pdf_matches_sample(name, x64):
    lights, p = build(name)
    dtype = jnp.result_type(float)
    s = sample_batch(lights, p, N_UP, uniforms(4096, dtype=dtype))
    p_light, t = hit_point(lights, p, s.wi)
    hit = np.ones(t.shape, bool)
    if (lights.triangle is not None or lights.sphere is not None) and name != "sphere_inside":
        # Sampled directions hit the light, at the reported distance (rel 1e-3: recomputed
        # by an independent intersection routine). A direction can round onto an edge and
        # miss the watertight test: allow 2 in 4096 (measured: at most 1, 4e-8 off the edge).
        hit = np.isfinite(t)
        assert (~hit).sum() <= 2
        np.testing.assert_allclose(t[hit], s.dist[hit], rtol=1e-3)
    pdf = pdf_batch(lights, p, s.wi, s.light, p_light)
    # rel 1e-4 in float32 (a few ulp of the dist²/cos conversion); 1e-9 in float64.
    np.testing.assert_allclose(pdf[hit], s.pdf[hit], rtol=1e-9 if x64 else 1e-4)
    assert np.all(s.pdf > 0) and not np.any(s.is_delta)
    assert s.wi.dtype == dtype and s.pdf.dtype == dtype and s.li.dtype == dtype
    assert s.light.dtype == jnp.int32


# ---------------------------------------------------------------------------------------------
# A far triangle (Ω ~ 1e-7 sr): too peaked for a sphere histogram, so check consistency and
# that 1/pdf is an unbiased estimator of Ω (E[1/p] = ∫ (1/p) p dω = Ω).


def solid_angle64(v, p):
    """Van Oosterom–Strackee solid angle of a triangle, float64 on the host."""
    a, b, c = (np.asarray(x, np.float64) - np.asarray(p, np.float64) for x in v)
    la, lb, lc = np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(c)
    num = abs(np.dot(a, np.cross(b, c)))
    den = la * lb * lc + np.dot(a, b) * lc + np.dot(a, c) * lb + np.dot(b, c) * la
    return 2 * np.arctan2(num, den)


@pytest.mark.parametrize("sampling", ["area", "solid_angle"])
def test_far_triangle_inverse_pdf_mean(sampling):
    tri = np.array([[0.0, 0.0, 2.0], [1e-3, 0.0, 2.0], [0.0, 1e-3, 2.0]])[::-1]
    lights = light_table([triangle_lights(tri, [1, 1, 1], [0])], triangle_sampling=sampling)
    p = jnp.zeros(3)
    omega = solid_angle64(tri, np.zeros(3))
    assert 1e-7 < omega < 2e-7
    s = sample_batch(lights, p, N_UP, uniforms(8192, seed=5))
    p_light, t = hit_point(lights, p, s.wi)
    hit = np.isfinite(t)
    assert hit.mean() > 0.999  # edge round-off only (see test_pdf_matches_sample)
    pdf = pdf_batch(lights, p, s.wi, s.light, p_light)
    np.testing.assert_allclose(pdf[hit], s.pdf[hit], rtol=1e-4)  # float32 consistency
    inv = 1 / np.asarray(s.pdf, np.float64)
    # 1/p varies by ~1e-3 relative over so small a triangle: its mean has stderr ~1e-5·Ω;
    # the bound 1e-3 allows float32 round-off in dist²/cos and Ω (≈1e-4 at this size).
    np.testing.assert_allclose(inv.mean(), omega, rtol=1e-3)


# ---------------------------------------------------------------------------------------------
# Irradiance: area and solid-angle sampling estimate the same E = ∫ L cos θ dω, which matches
# Lambert's polygon formula.


def irradiance_estimate(lights, p, n, num, seed):
    s = sample_batch(lights, p, n, uniforms(num, seed=seed))
    cos = jnp.maximum(s.wi @ n, 0)
    safe = jnp.where(s.pdf > 0, s.pdf, 1)
    f = np.asarray(jnp.where(s.pdf[:, None] > 0, s.li * cos[:, None] / safe[:, None], 0),
                   np.float64)
    return f.mean(0), f.std(0, ddof=1) / np.sqrt(num)


@pytest.mark.parametrize("p, n", [
    ([0.1, 0.0, 0.0], [0.0, 0.0, 1.0]),
    ([0.3, -0.2, 0.5], [0.6, 0.0, 0.8]),     # tilted receiver, light partly near the horizon
    ([0.05, 0.0, 1.0 - 1e-3], [0.0, 0.0, 1.0]),  # just below the light: Ω close to 2π
])
def test_irradiance_area_vs_solid_angle(p, n):
    p, n = jnp.asarray(p, jnp.float32), jnp.asarray(n, jnp.float32)
    rad = np.array([1.0, 2.0, 3.0])
    est = {}
    for sampling in ("area", "solid_angle"):
        lights = light_table([triangle_lights(TRI, rad, [0])], triangle_sampling=sampling)
        est[sampling] = irradiance_estimate(lights, p, n, 1 << 15, seed=11)
    (m_a, se_a), (m_s, se_s) = est["area"], est["solid_angle"]
    # Independent estimates of the same mean: within 5 joint standard errors.
    assert np.all(np.abs(m_a - m_s) <= 5 * np.hypot(se_a, se_s)), (m_a, m_s, se_a, se_s)
    with jax.enable_x64(True):
        exact = np.asarray(analytic.polygon_irradiance(jnp.asarray(TRI), jnp.asarray(rad),
                                                       jnp.asarray(p, jnp.float64),
                                                       jnp.asarray(n, jnp.float64)))
    # Each against the exact value: 5 of its own standard errors plus a float32 floor 1e-5·E.
    for m, se in est.values():
        assert np.all(np.abs(m - exact) <= 5 * se + 1e-5 * exact), (m, se, exact)


def test_irradiance_sphere_matches_analytic():
    lights = light_table([sphere_light([0.3, 0.2, 2.0], 0.8, [1.0, 1.0, 1.0])])
    p, n = jnp.zeros(3), jnp.asarray([0.0, 0.6, 0.8])
    m, se = irradiance_estimate(lights, p, n, 1 << 15, seed=12)
    exact = np.asarray(analytic.sphere_light_irradiance(
        jnp.asarray([0.3, 0.2, 2.0]), jnp.float32(0.8), jnp.ones(3), p, n))
    # 5 standard errors plus a float32 floor of 1e-5·E.
    assert np.all(np.abs(m - exact) <= 5 * se + 1e-5 * exact), (m, se, exact)


# ---------------------------------------------------------------------------------------------
# Selection.


def mixed_records():
    return [point_light([0, 0, 3], [1.0, 2.0, 3.0]),
            spot_light([0, 0, 3], [0, 0, -1], [4.0, 4.0, 4.0], 0.2, 0.4),
            directional_light([0, 1, 1], [0.5, 0.5, 0.5]),
            triangle_lights(np.stack([TRI, TRI + [0, 0, 1]]), [[1, 1, 1], [2, 0, 0]], [3, 4],
                            two_sided=[False, True]),
            sphere_light([3, 0, 0], 0.5, [2, 2, 2]),
            constant_environment([0.1, 0.2, 0.3])]


def hand_powers(scene_radius):
    lum = lambda c: 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    area = 0.5 * np.linalg.norm(np.cross(TRI[1] - TRI[0], TRI[2] - TRI[0]))
    return np.array([
        4 * np.pi * lum([1, 2, 3]),
        2 * np.pi * 4 * (1 - 0.5 * (np.cos(0.2) + np.cos(0.4))),
        np.pi * scene_radius**2 * 0.5,
        np.pi * area * 1.0,
        2 * np.pi * area * lum([2, 0, 0]),
        np.pi * 4 * np.pi * 0.25 * 2,
        4 * np.pi**2 * scene_radius**2 * lum([0.1, 0.2, 0.3]),
    ])


@pytest.mark.parametrize("selection", ["uniform", "power"])
def test_selection_pmf(selection):
    lights = light_table(mixed_records(), selection=selection, scene_radius=2.0)
    assert lights.structure.counts == (1, 1, 1, 2, 1, 1)
    idx = jnp.arange(7, dtype=jnp.int32)
    pmf = np.asarray(jax.vmap(discrete_pmf, (None, 0))(lights.selection, idx), np.float64)
    power = hand_powers(2.0)
    floored = power + lt_table.SELECTION_FLOOR * power.mean()
    want = np.full(7, 1 / 7) if selection == "uniform" else floored / floored.sum()
    np.testing.assert_allclose(pmf, want, rtol=1e-6)  # float32 storage of a float64 pmf
    # Empirical selection frequencies over 2^16 samples: Pearson χ² at 1%.
    num = 1 << 16
    s = sample_batch(lights, jnp.asarray([0.2, 0.1, 0.0]), N_UP, uniforms(num, seed=7))
    counts = np.bincount(np.asarray(s.light), minlength=7)
    assert scipy.stats.chisquare(counts, num * want).pvalue > 0.01
    # Every kind's sample reports pdf = pmf · kind density, and the delta flag by kind.
    is_delta = np.asarray(s.is_delta)
    assert np.array_equal(is_delta, np.asarray(s.light) < 3)
    np.testing.assert_allclose(np.asarray(s.pdf)[is_delta], want[np.asarray(s.light)[is_delta]],
                               rtol=1e-6)


def test_pdf_li_includes_pmf_and_index_mapping():
    lights = light_table(mixed_records(), selection="power", triangle_sampling="area")
    s = sample_batch(lights, jnp.asarray([0.2, 0.1, 0.0]), N_UP, uniforms(4096, seed=8))
    area_lights = (np.asarray(s.light) >= 3)
    p = jnp.asarray([0.2, 0.1, 0.0])
    p_light = p + jnp.where(jnp.isfinite(s.dist), s.dist, 0)[:, None] * s.wi
    pdf = pdf_batch(lights, p, s.wi, s.light, p_light)
    # Same pmf·density for every non-delta kind (rel 1e-4), exactly 0 for delta lights.
    np.testing.assert_allclose(np.asarray(pdf)[area_lights], np.asarray(s.pdf)[area_lights],
                               rtol=1e-4)
    assert np.all(np.asarray(pdf)[~area_lights] == 0)


# ---------------------------------------------------------------------------------------------
# Emission.


def test_le_triangle_sides():
    lights = light_table([triangle_lights(np.stack([TRI, TRI]), [[1, 2, 3], [4, 5, 6]], [0, 1],
                                          two_sided=[False, True])])
    down, up = jnp.array([0.0, 0.0, -1.0]), jnp.array([0.0, 0.0, 1.0])
    # TRI's geometric normal points to −z: the one-sided light emits downwards only.
    np.testing.assert_array_equal(le_triangle(lights, 0, down), [1, 2, 3])
    np.testing.assert_array_equal(le_triangle(lights, 0, up), [0, 0, 0])
    np.testing.assert_array_equal(le_triangle(lights, 1, up), [4, 5, 6])
    np.testing.assert_array_equal(le_triangle(lights, 1, down), [4, 5, 6])
    # A one-sided light seen from behind: sampled with its true pdf but li = 0.
    s = sample_li(lights, jnp.array([0.1, 0.0, 2.0]), N_UP, jnp.array([0.1, 0.3, 0.6]))
    assert int(s.light) == 0 and float(s.pdf) > 0 and np.all(np.asarray(s.li) == 0)


def test_le_sphere_and_environment():
    lights = light_table([point_light([0, 0, 0], [1, 1, 1]),
                          sphere_light([0, 0, 5], 1.0, [2, 3, 4]),
                          constant_environment([0.1, 0.2, 0.3])])
    t, light = intersect_spheres(lights, jnp.zeros(3), jnp.array([0.0, 0.0, 1.0]), jnp.inf)
    assert int(light) == 1 and abs(float(t) - 4.0) < 1e-6  # global index: after the point
    hit = jnp.array([0.0, 0.0, 4.0])
    np.testing.assert_array_equal(le_sphere(lights, light, jnp.array([0.0, 0, -1]), hit), [2, 3, 4])
    np.testing.assert_array_equal(le_sphere(lights, light, jnp.array([0.0, 0, 1]), hit), [0, 0, 0])
    np.testing.assert_array_equal(le_sphere(lights, 0, jnp.array([0.0, 0, -1]), hit), [0, 0, 0])
    np.testing.assert_allclose(le_environment(lights, jnp.array([0.0, 1.0, 0.0])), [0.1, 0.2, 0.3])
    no_env = light_table([point_light([0, 0, 0], [1, 1, 1])])
    np.testing.assert_array_equal(le_environment(no_env, jnp.array([0.0, 1.0, 0.0])), [0, 0, 0])
    assert int(intersect_spheres(no_env, jnp.zeros(3), jnp.ones(3), jnp.inf)[1]) == -1


def test_environment_map_orientation():
    # One bright texel: row 1 of 4 (θ ∈ [π/4, π/2)), column 5 of 8 (φ ∈ [5π/4, 3π/2)).
    img = np.zeros((4, 8, 3))
    img[1, 5] = [3.0, 2.0, 1.0]
    lights = light_table([environment_map(img)])
    theta, phi = 3 * np.pi / 8, 11 * np.pi / 8
    d = jnp.asarray([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)],
                    jnp.float32)
    np.testing.assert_array_equal(le_environment(lights, d), [3, 2, 1])
    np.testing.assert_array_equal(le_environment(lights, -d), [0, 0, 0])
    s = sample_batch(lights, jnp.zeros(3), N_UP, uniforms(1024, seed=9))
    # Samples land in the bright texel, carrying its radiance, but for the ~1 % share that
    # environment.TEXEL_FLOOR spreads over the map (black texels: li 0, pdf > 0)
    li = np.asarray(s.li)
    bright = np.all(li == [3.0, 2.0, 1.0], axis=1)
    assert 0.97 < bright.mean() < 1.0
    assert np.all(li[~bright] == 0) and np.all(np.asarray(s.pdf) > 0)
    # A rotation moves the texel with it: R d sees what d saw before.
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = light_table([environment_map(img, rotation=rot)])
    np.testing.assert_array_equal(le_environment(turned, jnp.asarray(rot, jnp.float32) @ d),
                                  [3, 2, 1])


# ---------------------------------------------------------------------------------------------
# Sphere intersection against a float64 reference.


def ray_sphere64(o, d, c, r):
    o, d, c = (np.asarray(x, np.float64) for x in (o, d, c))
    f = o - c
    a, b, cc = d @ d, f @ d, f @ f - r * r
    disc = b * b - a * cc
    if disc < 0:
        return np.inf
    sq = np.sqrt(disc)
    for t in sorted([(-b - sq) / a, (-b + sq) / a]):
        if t > 0:
            return t
    return np.inf


@pytest.mark.parametrize("scale", [1.0, 1e4])
def test_intersect_spheres_vs_float64(scale):
    rng = np.random.default_rng(4)
    centers = rng.normal(size=(5, 3)) * 4 * scale
    radii = rng.uniform(0.05, 1.0, size=5) * scale
    radii[0] = 1e-3 * scale  # a small far sphere
    lights = light_table([sphere_light(centers, radii, [1, 1, 1])])
    o = rng.normal(size=(400, 3)) * scale
    # Half the rays aimed at sphere centres (hits), half random (mostly misses).
    target = centers[rng.integers(0, 5, 400)] + rng.normal(size=(400, 3)) * radii.min() * 0.3
    d = np.where(np.arange(400)[:, None] % 2 == 0, target - o, rng.normal(size=(400, 3)))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, light = jax.vmap(intersect_spheres, (None, 0, 0, None))(
        lights, jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32), jnp.inf)
    ref = np.array([[ray_sphere64(o[k], d[k], centers[j], radii[j]) for j in range(5)]
                    for k in range(400)])
    t_ref, j_ref = ref.min(1), np.where(np.isfinite(ref.min(1)), ref.argmin(1), -1)
    # Rays grazing a sphere within float32 resolution may go either way: skip them.
    f = o[:, None, :] - centers[None]
    miss_dist = np.linalg.norm(f - (f * d[:, None, :]).sum(-1, keepdims=True) * d[:, None, :],
                               axis=-1)
    clear = np.all(np.abs(miss_dist - radii) > 1e-4 * (np.linalg.norm(f, axis=-1) + radii), axis=1)
    assert clear.sum() > 380 and (np.isfinite(t_ref) & clear).sum() > 150
    np.testing.assert_array_equal(np.asarray(light)[clear], j_ref[clear])
    hit = clear & np.isfinite(t_ref)
    # float32 relative error of the stable quadratic: 1e-5 (a few ulp of the larger terms).
    np.testing.assert_allclose(np.asarray(t)[hit], t_ref[hit], rtol=1e-5)
    # t_max clips.
    t_c, l_c = jax.vmap(intersect_spheres, (None, 0, 0, 0))(
        lights, jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32),
        jnp.float32(0.5) * jnp.asarray(np.where(np.isfinite(t_ref), t_ref, 1.0), jnp.float32))
    assert np.all(np.asarray(l_c)[hit] == -1) and np.all(np.isinf(np.asarray(t_c)[hit]))


# ---------------------------------------------------------------------------------------------
# Validation.


@pytest.mark.parametrize("make, match", [
    (lambda: point_light([0, 0, 0], [1, -1, 1]), "negative"),
    (lambda: point_light([0, np.nan, 0], [1, 1, 1]), "not finite"),
    (lambda: point_light([0, 0, 0], [1, np.inf, 1]), "not finite"),
    (lambda: triangle_lights([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [1, 1, 1], [0]), "zero area"),
    (lambda: triangle_lights(TRI, [1, 1, -1e-3], [0]), "negative"),
    (lambda: sphere_light([0, 0, 0], 0.0, [1, 1, 1]), "radius"),
    (lambda: sphere_light([0, 0, 0], -1.0, [1, 1, 1]), "radius"),
    (lambda: spot_light([0, 0, 0], [0, 0, 1], [1, 1, 1], 0.5, 0.2), "cone angles"),
    (lambda: spot_light([0, 0, 0], [0, 0, 0], [1, 1, 1], 0.1, 0.2), "zero vector"),
    (lambda: directional_light([0, 0, 1], [np.nan, 1, 1]), "not finite"),
    (lambda: constant_environment([1, -1, 1]), "negative"),
    (lambda: environment_map(-np.ones((2, 4, 3))), "negative"),
    (lambda: environment_map(np.ones((2, 4))), r"\(H, W, 3\)"),
    (lambda: environment_map(np.ones((2, 4, 3)), rotation=2 * np.eye(3)), "orthonormal"),
    (lambda: light_table([]), "at least one"),
    (lambda: light_table([constant_environment([1, 1, 1])] * 2), "one environment"),
    (lambda: light_table([point_light([0, 0, 0], [1, 1, 1])], selection="best"), "selection"),
    (lambda: light_table([point_light([0, 0, 0], [1, 1, 1])], triangle_sampling="x"),
     "triangle_sampling"),
])
def test_validation_errors(make, match):
    with pytest.raises(ValueError, match=match):
        make()


# ---------------------------------------------------------------------------------------------
# Dtypes, x64, extremes, recompilation.


def test_float32_preserved_and_x64_agrees():
    recs = mixed_records
    p = [0.2, 0.1, 0.0]
    u = np.asarray(uniforms(512, seed=10), np.float64)
    s32 = sample_batch(light_table(recs()), jnp.asarray(p, jnp.float32), N_UP,
                       jnp.asarray(u, jnp.float32))
    for leaf in (s32.wi, s32.dist, s32.li, s32.pdf):
        assert leaf.dtype == jnp.float32
    assert s32.light.dtype == jnp.int32 and s32.is_delta.dtype == jnp.bool_
    with jax.enable_x64(True):
        lights64 = light_table(recs())
        s64 = sample_batch(lights64, jnp.asarray(p, jnp.float64), jnp.asarray(N_UP, jnp.float64),
                           jnp.asarray(u, jnp.float64))
        assert s64.wi.dtype == jnp.float64 and s64.pdf.dtype == jnp.float64
        assert lights64.triangle.vertices.dtype == jnp.float64
    # Same choices; directions and pdfs agree to float32 precision (rel 1e-4 on the pdf).
    same = np.asarray(s32.light) == np.asarray(s64.light)
    assert same.mean() > 0.99  # a u[0] within float32 round-off of a cdf step may differ
    # atol 1e-4: Arvo's spherical-triangle trigonometry in float32 (measured 1.2e-5 worst).
    np.testing.assert_allclose(np.asarray(s32.wi)[same], np.asarray(s64.wi)[same], atol=1e-4)
    np.testing.assert_allclose(np.asarray(s32.pdf)[same], np.asarray(s64.pdf)[same], rtol=1e-4)


@pytest.mark.parametrize("size", [1e-4, 1e4])
def test_no_nan_at_extreme_sizes(size):
    tri = TRI * size + np.array([0.0, 0.0, 1.0 if size < 1 else 0.5 * size])
    recs = [triangle_lights(tri, [1, 1, 1], [0]),
            sphere_light([3.0 * size, 0, 1.0], size, [1, 1, 1])]
    one_minus_ulp = float(np.nextafter(np.float32(1), np.float32(0)))
    grid = np.array(np.meshgrid([0.0, 0.5, one_minus_ulp], [0.0, 0.5, one_minus_ulp],
                                [0.0, 0.3, one_minus_ulp])).reshape(3, -1).T
    u = jnp.asarray(np.concatenate([grid, np.asarray(uniforms(256, seed=13))]), jnp.float32)
    for sampling in ("area", "solid_angle"):
        lights = light_table(recs, triangle_sampling=sampling, selection="uniform")
        p = jnp.zeros(3)
        s = sample_batch(lights, p, N_UP, u)
        for leaf in (s.wi, s.dist, s.li, s.pdf):
            assert np.all(np.isfinite(np.asarray(leaf))), (sampling, leaf)
        assert np.all(np.asarray(s.pdf) > 0)
        np.testing.assert_allclose(np.linalg.norm(np.asarray(s.wi), axis=1), 1, atol=1e-6)
        pdf = pdf_batch(lights, p, s.wi, s.light, p + s.dist[:, None] * s.wi)
        assert np.all(np.isfinite(np.asarray(pdf)))


def test_same_structure_compiles_nothing():
    f = jax.jit(jax.vmap(sample_li, (None, None, None, 0)))
    u = uniforms(64)
    a = light_table(mixed_records())
    f(a, jnp.zeros(3), N_UP, u)
    size = f._cache_size()
    recs = mixed_records()
    recs[0] = point_light([1, 2, 3], [5.0, 5.0, 5.0])
    recs[4] = sphere_light([0, 4, 0], 0.25, [1, 1, 1])
    b = light_table(recs)
    f(b, jnp.ones(3), N_UP, u)
    assert f._cache_size() == size  # new numbers, same structure: no new compilation
    f(light_table(mixed_records()[:3]), jnp.zeros(3), N_UP, u)
    assert f._cache_size() == size + 1  # a different structure compiles once more


# ---------------------------------------------------------------------------------------------
# Normalisation ∫ pdf_li dω = 1 by smooth quadratures (the chi-square harness's cubature is
# blind to part of the jump at a light's silhouette, see test_lights_chi2.py).


@pytest.mark.parametrize("sampling", ["area", "solid_angle"])
def test_pdf_normalised_triangle(sampling, enable_x64):
    lights = light_table([triangle_lights(TRI, [1, 1, 1], [0])], triangle_sampling=sampling)
    p = jnp.asarray([0.1, 0.0, 0.0])
    # ∫ p_ω dω = ∫_T p_ω(y) |cos θ_y| / ‖y − p‖² dA: midpoint rule on 2·150² sub-triangles.
    m = 150
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    up = np.stack([(i + 1 / 3) / m, (j + 1 / 3) / m], -1)[i + j < m]
    down = np.stack([(i + 2 / 3) / m, (j + 2 / 3) / m], -1)[i + j < m - 1]
    b = np.concatenate([up, down])
    y = TRI[0] + b[:, :1] * (TRI[1] - TRI[0]) + b[:, 1:] * (TRI[2] - TRI[0])
    y = jnp.asarray(y)
    wi = (y - p) / jnp.linalg.norm(y - p, axis=1, keepdims=True)
    pdf = pdf_batch(lights, p, wi, jnp.zeros(len(b), jnp.int32), y)
    cos = jnp.abs(wi[:, 2])
    area = 0.5 * np.linalg.norm(np.cross(TRI[1] - TRI[0], TRI[2] - TRI[0]))
    integral = float(jnp.mean(pdf * cos / jnp.sum((y - p) ** 2, axis=1))) * area
    # Midpoint rule on a smooth integrand, h = 1/150: error O(h²) ≈ 1e-5 relative.
    assert abs(integral - 1) < 1e-4, integral


def test_pdf_normalised_closed_forms():
    # Solid-angle triangle sampling: pdf = 1/Ω, so normalisation is Ω_warp = Ω (float64 ref).
    for p in ([0.1, 0.0, 0.0], [0.05, 0.0, 1.0 - 1e-4]):
        lights = light_table([triangle_lights(TRI, [1, 1, 1], [0])],
                             triangle_sampling="solid_angle")
        s = sample_li(lights, jnp.asarray(p, jnp.float32), N_UP, jnp.array([0.5, 0.3, 0.3]))
        # rel 1e-5: float32 Van Oosterom–Strackee (near 2π too).
        np.testing.assert_allclose(float(s.pdf) * solid_angle64(TRI, p), 1, rtol=1e-5)
    # Spheres: pdf = 1 / (2π(1 − cos θ_max)) against float64.
    for c, r in (([0.3, 0.2, 2.0], 1.0), ([1.0, 2.0, 2.0], 3 * 5.64e-4)):
        lights = light_table([sphere_light(c, r, [1, 1, 1])])
        s = sample_li(lights, jnp.zeros(3), N_UP, jnp.array([0.5, 0.3, 0.3]))
        sin2 = r * r / np.dot(c, c)
        omega = 2 * np.pi * sin2 / (1 + np.sqrt(1 - sin2))
        np.testing.assert_allclose(float(s.pdf) * omega, 1, rtol=1e-5)  # float32 ulps
    # Environment map: ∫∫ p_ω 2π² sin θ dx dy on 4×4 points per texel (p_ω sin θ is constant
    # per texel, so the midpoint rule is exact up to round-off).
    img = env_image()
    lights = light_table([environment_map(img)])
    h, w = img.shape[:2]
    x = (np.arange(4 * w) + 0.5) / (4 * w)
    yy = (np.arange(4 * h) + 0.5) / (4 * h)
    xg, yg = np.meshgrid(x, yy)
    th, ph = np.pi * yg.ravel(), 2 * np.pi * xg.ravel()
    d = jnp.asarray(np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], 1),
                    jnp.float32)
    pdf = np.asarray(pdf_batch(lights, jnp.zeros(3), d, jnp.zeros(len(th), jnp.int32),
                               jnp.zeros((len(th), 3))), np.float64)
    integral = np.mean(pdf * 2 * np.pi**2 * np.sin(th))
    assert abs(integral - 1) < 1e-5, integral  # float32 round-off only
