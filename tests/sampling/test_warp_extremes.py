"""Warps at the numerical extremes, and the spherical triangle's corner cases.

Sharp lobes (Phong n = 1e4, GGX/Beckmann α = 1e-3, a cone of θmax = 1e-4) are too peaked
for a chi-square grid on the hemisphere. They are checked radially instead: float32 samples
of ``m = 1 − cos θ`` against the CDF obtained by integrating the warp's own pdf in float64 on
a log-spaced grid (Kolmogorov–Smirnov), plus normalisation of that integral.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxrt.sampling import warp as W
from jaxrt.validation import analytic

N_KS = 20_000


def _radial_cdf(pdf_fn):
    """CDF of m = 1 − cos θ for an isotropic pdf about +z, in float64 (dω = dm dφ)."""
    with jax.enable_x64(True):
        m = jnp.logspace(-22, np.log10(2.0), 40_001, dtype=jnp.float64)
        sin_t = jnp.sqrt(m * (2 - m))
        v = jnp.stack([sin_t, jnp.zeros_like(m), 1 - m], -1)
        f = 2 * np.pi * np.asarray(jax.vmap(pdf_fn)(v))
        m = np.asarray(m)
    # trapezoid in m; the mass below m = 1e-22 is negligible for every case here
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(m))])
    return m, cdf


def _ks(sample_fn, pdf_fn):
    u = jax.random.uniform(jax.random.PRNGKey(11), (N_KS, 2), jnp.float32)
    v = np.asarray(jax.jit(jax.vmap(sample_fn))(u), np.float64)
    # 1 − cos θ from x² + y²: exact where z has rounded to 1
    m_s = (v[:, 0] ** 2 + v[:, 1] ** 2) / (1 + v[:, 2])
    m, cdf = _radial_cdf(pdf_fn)
    total = cdf[-1]
    log_m = np.log(m)
    cdf_fn = lambda x: np.interp(np.log(np.maximum(x, 1e-300)), log_m, cdf / total)
    return total, stats.kstest(m_s, cdf_fn).pvalue


EXTREMES = [
    pytest.param(W.square_to_phong_lobe, W.square_to_phong_lobe_pdf, 1e4, id="phong-1e4"),
    pytest.param(W.square_to_ggx, W.square_to_ggx_pdf, 1e-3, id="ggx-1e-3"),
    pytest.param(W.square_to_beckmann, W.square_to_beckmann_pdf, 1e-3, id="beckmann-1e-3"),
    pytest.param(W.square_to_uniform_cone_sin2, W.square_to_uniform_cone_sin2_pdf,
                 float(np.sin(1e-4) ** 2), id="cone-theta-1e-4"),
]


@pytest.mark.parametrize("sample, pdf, param", EXTREMES)
def test_sharp_lobes_radial_ks(sample, pdf, param):
    p32 = jnp.float32(param)
    total, p_value = _ks(lambda u: sample(u, p32), lambda v: pdf(v, jnp.float64(param)))
    # the pdf integrates to one (trapezoid on 40k log-spaced nodes: error < 1e-4)
    assert abs(total - 1) < 1e-3, total
    # 4 cases at 1% each: a correct sampler fails with probability < 4%; fixed seed
    assert p_value > 0.01, p_value
    # float32 samples have a finite positive float32 density
    u = jax.random.uniform(jax.random.PRNGKey(2), (4096, 2), jnp.float32)
    v = jax.vmap(lambda uu: sample(uu, p32))(u)
    d = jax.vmap(lambda vv: pdf(vv, p32))(v)
    assert d.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(d) & (d > 0)))


def test_radial_ks_has_teeth():
    # GGX samples at α = 1e-3 against the pdf of α = 1.2e-3, Phong 1e4 against 1.2e4
    a, a_bad = jnp.float32(1e-3), jnp.float32(1.2e-3)
    _, p = _ks(lambda u: W.square_to_ggx(u, a), lambda v: W.square_to_ggx_pdf(v, a_bad))
    assert p < 1e-6, p
    n, n_bad = jnp.float32(1e4), jnp.float32(1.2e4)
    _, p = _ks(lambda u: W.square_to_phong_lobe(u, n),
               lambda v: W.square_to_phong_lobe_pdf(v, n_bad))
    assert p < 1e-6, p


def test_tiny_cone_float32():
    theta = 1e-4
    sin2 = jnp.float32(np.sin(theta) ** 2)
    u = jax.random.uniform(jax.random.PRNGKey(0), (4096, 2), jnp.float32)
    v = jax.vmap(lambda uu: W.square_to_uniform_cone_sin2(uu, sin2))(u)
    pdf = jax.vmap(lambda vv: W.square_to_uniform_cone_sin2_pdf(vv, sin2))(v)
    assert v.dtype == jnp.float32 and pdf.dtype == jnp.float32
    # inside the cap: sin²θ of every sample ≤ sin²θmax (to float32 rounding)
    s2 = v[:, 0] ** 2 + v[:, 1] ** 2
    assert float(jnp.max(s2)) <= float(sin2) * (1 + 1e-5)
    exact = 1 / (2 * np.pi * 2 * np.sin(theta / 2) ** 2)  # 1/(2π(1 − cos θmax)), float64
    # relative error of a few float32 ulps, not the total loss of 1 − cos in float32
    assert np.max(np.abs(np.asarray(pdf, np.float64) / exact - 1)) < 1e-5
    # documented: from cos θmax in float32 the cap is gone; the result is 0, never NaN/inf
    cos_max = jnp.float32(np.cos(theta))
    assert float(cos_max) == 1.0
    v1 = W.square_to_uniform_cone(u[0], cos_max)
    p1 = W.square_to_uniform_cone_pdf(v1, cos_max)
    assert bool(jnp.all(jnp.isfinite(v1))) and float(p1) == 0.0


# ---------------------------------------------------------------- spherical triangle


def _tri(vs, dtype):
    return tuple(jnp.asarray(v, dtype) for v in vs)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["f32", "x64"])
def test_solid_angle_closed_forms(dtype):
    with jax.enable_x64(dtype == jnp.float64):
        # octant: π/2; lune wedge of 135° between meridians, capped by the equator: 3π/4
        om = W.spherical_triangle_solid_angle(*_tri(W._TRI_OCTANT, dtype))
        assert om.dtype == dtype
        tol = 10 * float(jnp.finfo(dtype).eps)  # a few ulps of an atan2
        assert abs(float(om) - np.pi / 2) < tol
        om = W.spherical_triangle_solid_angle(*_tri(W._TRI_WEDGE, dtype))
        assert abs(float(om) - 3 * np.pi / 4) < tol
        # far tiny triangle: Ω ≈ area cos / d² = 0.125 · (1000/|c|)... against float64 below
        om = W.spherical_triangle_solid_angle(*_tri(W._TRI_TINY, dtype))
        assert float(om) < 1e-6


def _area_quadrature(a, b, c, n=1500):
    """Ω = ∫ cos θ_l / dist² dA, midpoint rule on an n² barycentric grid (float64 numpy)."""
    a, b, c = (np.asarray(x, np.float64) for x in (a, b, c))
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    keep = i + j < n
    # midpoints of the sub-triangles (upward ones only; the area weights are exact halves)
    b1 = (i[keep] + 1 / 3) / n
    b2 = (j[keep] + 1 / 3) / n
    up = np.stack([b1, b2], 1)
    keep2 = i + j < n - 1
    down = np.stack([(i[keep2] + 2 / 3) / n, (j[keep2] + 2 / 3) / n], 1)
    bb = np.concatenate([up, down])
    p = a + bb[:, :1] * (b - a) + bb[:, 1:] * (c - a)
    nrm = np.cross(b - a, c - a)
    area = np.linalg.norm(nrm) / 2
    d = np.linalg.norm(p, axis=1)
    cos_l = np.abs(p @ nrm) / (np.linalg.norm(nrm) * d)
    return np.mean(cos_l / d**2) * area


@pytest.mark.parametrize("name", ["_TRI_GENERIC", "_TRI_LARGE", "_TRI_TINY"])
def test_solid_angle_against_quadrature(name, enable_x64):
    vs = getattr(W, name)
    om = float(W.spherical_triangle_solid_angle(*_tri(vs, jnp.float64)))
    ref = _area_quadrature(*vs)
    # midpoint rule, 2.25e6 cells: relative error < 1e-4 even for the near-2π one
    assert abs(om / ref - 1) < 1e-4, (om, ref)


DEGENERATE = {
    "collinear": ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (2.0, 0.0, 1.0)),
    "repeated_vertex": ((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), (1.0, 1.0, 1.0)),
    "all_at_origin": ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    "vertex_at_origin": ((0.0, 0.0, 0.0), (1.0, 0.0, 1.0), (0.0, 1.0, 1.0)),
    "on_plane_inside": ((-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (0.0, 1.0, 0.0)),
    "on_plane_outside": ((1.0, 1.0, 0.0), (2.0, 1.0, 0.0), (1.0, 2.0, 0.0)),
    "near_2pi": ((-1.0, -1.0, 1e-6), (1.0, -1.0, 1e-6), (0.0, 1.0, 1e-6)),
    "tiny": W._TRI_TINY,
    "far_huge_scale": ((1e15, 0.0, 1e18), (0.0, 1e15, 1e18), (0.0, 0.0, 1e18)),
    "very_close": ((1e-20, 0.0, 1e-20), (0.0, 1e-20, 1e-20), (0.0, 0.0, 1e-20)),
}


@pytest.mark.parametrize("name", list(DEGENERATE))
def test_spherical_triangle_never_nan(name, x64):
    dtype = jnp.float64 if x64 else jnp.float32
    a, b, c = _tri(DEGENERATE[name], dtype)
    vals = jnp.asarray([0.0, 1e-7, 0.5, np.nextafter(np.asarray(1, dtype), 0)], dtype)
    grid = jnp.stack(jnp.meshgrid(vals, vals, indexing="ij"), -1).reshape(-1, 2)
    u = jnp.concatenate([grid, jax.random.uniform(jax.random.PRNGKey(0), (256, 2), dtype)])
    v = jax.vmap(lambda uu: W.square_to_spherical_triangle(uu, a, b, c))(u)
    pdf = jax.vmap(lambda vv: W.square_to_spherical_triangle_pdf(vv, a, b, c))(v)
    inv = jax.vmap(lambda vv: W.spherical_triangle_to_square(vv, a, b, c))(v)
    om = W.spherical_triangle_solid_angle(a, b, c)
    assert v.dtype == dtype and pdf.dtype == dtype
    assert bool(jnp.all(jnp.isfinite(v))) and bool(jnp.all(jnp.isfinite(inv)))
    assert bool(jnp.all(jnp.isfinite(pdf) & (pdf >= 0)))
    assert np.isfinite(float(om)) and 0 <= float(om) <= 2 * np.pi + 1e-6
    norms = np.linalg.norm(np.asarray(v, np.float64), axis=1)
    # unit directions, or the zero vector when every vertex sits at the shading point
    assert np.all((np.abs(norms - 1) < 1e-5) | (norms == 0))
    if name in ("collinear", "repeated_vertex", "all_at_origin", "on_plane_inside",
                "on_plane_outside"):
        # no solid angle: Ω = 0 and the density is 0 (a great-circle arc has measure zero)
        assert float(om) == 0.0 and float(jnp.max(pdf)) == 0.0
    if name == "near_2pi":
        # just above a big triangle's interior: nearly a hemisphere; random samples inside
        # (u on the square's edges maps onto arcs 1e-6 above the horizon, where float32
        # rounding may put a direction on either side of the edge: pdf 0, never NaN)
        assert float(om) > 2 * np.pi - 1e-3
        assert float(jnp.mean(pdf[grid.shape[0]:] > 0)) > 0.99


@pytest.mark.parametrize("name", ["_TRI_TINY", "_TRI_GENERIC", "_TRI_LARGE"])
def test_spherical_triangle_estimates_its_solid_angle(name):
    # E[1/pdf(V)] = ∫_support dω = Ω: the sampler and pdf agree whichever branch ran (the
    # tiny one is the area-sampling fallback, whose 1/pdf varies across the triangle)
    a, b, c = _tri(getattr(W, name), jnp.float32)
    u = jax.random.uniform(jax.random.PRNGKey(4), (65_536, 2), jnp.float32)
    v = jax.vmap(lambda uu: W.square_to_spherical_triangle(uu, a, b, c))(u)
    pdf = np.asarray(jax.vmap(lambda vv: W.square_to_spherical_triangle_pdf(vv, a, b, c))(v),
                     np.float64)
    assert np.all(pdf > 0)
    est = 1 / pdf
    ref = _area_quadrature(*getattr(W, name), n=600)
    err = abs(est.mean() / ref - 1)
    # 5 standard errors of the mean, plus float32 resolution of Ω (1e-4 relative)
    assert err < 5 * est.std() / est.mean() / np.sqrt(len(est)) + 1e-4 + 1e-3 * (
        name == "_TRI_LARGE"), err


@pytest.mark.parametrize("name", ["_TRI_GENERIC", "_TRI_LARGE"])
def test_spherical_triangle_two_sample_against_rejection(name):
    # reference: uniform sphere directions kept where the pdf is positive are exactly uniform
    # on the spherical triangle; compare both point sets on a (φ, cos θ) grid (χ² homogeneity)
    vs = _tri(getattr(W, name), jnp.float32)
    n = 200_000
    u = jax.random.uniform(jax.random.PRNGKey(8), (n, 2), jnp.float32)
    x = jax.jit(jax.vmap(lambda uu: W.square_to_spherical_triangle(uu, *vs)))(u)
    pdf = jax.jit(jax.vmap(lambda vv: W.square_to_spherical_triangle_pdf(vv, *vs)))
    g = jax.random.uniform(jax.random.PRNGKey(9), (4 * n, 2), jnp.float32)
    ref = jax.vmap(W.square_to_uniform_sphere)(g)
    ref = np.asarray(ref)[np.asarray(pdf(ref) > 0)]

    def hist(p):
        phi = np.arctan2(p[:, 1], p[:, 0]) % (2 * np.pi)
        return np.histogram2d(phi, p[:, 2], bins=(32, 32), range=((0, 2 * np.pi), (-1, 1)))[0]

    h1, h2 = hist(np.asarray(x)).ravel(), hist(ref).ravel()
    keep = (h1 + h2) >= 20  # χ² needs expected counts of ≥ 5 per cell and sample
    _, p_value, _, _ = stats.chi2_contingency(np.stack([h1[keep], h2[keep]]))
    assert p_value > 0.01, p_value


# Shading points next to a triangle's plane: Ω within 1e-3 of 2π (just under its interior)
# or ≈ π (just outside an edge). Float32 Arvo on the whole triangle puts E[cos θ] at 0.354
# instead of 0.500 at 1e-4 and 0.022 at 1e-5 (every inner angle ≈ π, arcs nearly antipodal),
# hence the sampler's split of the triangle at its point closest to the shading point.
NEAR_PLANE = {
    "interior-1e-4": ((-1.0, -1.0, 1e-4), (2.0, -1.0, 1e-4), (-1.0, 2.0, 1e-4)),
    "interior-1e-5": ((-1.0, -1.0, 1e-5), (2.0, -1.0, 1e-5), (-1.0, 2.0, 1e-5)),
    # 1e-4 from the plane and 1e-6 outside the edge y = 1e-6
    "outside-edge-1e-4": ((-1.0, 1e-6, 1e-4), (2.0, 1e-6, 1e-4), (-1.0, 3.0, 1e-4)),
}


def _rotation(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


@pytest.mark.parametrize("rotated", [False, True], ids=["axis", "rotated"])
@pytest.mark.parametrize("name", list(NEAR_PLANE))
def test_spherical_triangle_near_plane_float32(name, rotated):
    rot = _rotation(0.3, -0.7, 1.1) if rotated else np.eye(3)
    vs32 = (np.asarray(NEAR_PLANE[name]) @ rot.T).astype(np.float32)
    normal = rot @ np.array([0.0, 0.0, 1.0])
    # reference for exactly these float32 vertices: E[cos θ] = Φ/Ω (Lambert's Φ), in x64
    with jax.enable_x64(True):
        tri64 = jnp.asarray(vs32, jnp.float64)
        phi = float(analytic.polygon_projected_solid_angle(tri64, jnp.zeros(3), normal))
        om = float(W.spherical_triangle_solid_angle(*tri64))
    if name.startswith("interior"):
        assert 2 * np.pi - om < 1e-3, om
    else:
        assert abs(om - np.pi) < 0.05, om
    a, b, c = (jnp.asarray(v) for v in vs32)
    n = 1 << 17
    u = jax.random.uniform(jax.random.PRNGKey(12), (n, 2), jnp.float32)
    v = jax.jit(jax.vmap(lambda uu: W.square_to_spherical_triangle(uu, a, b, c)))(u)
    pdf = jax.jit(jax.vmap(lambda vv: W.square_to_spherical_triangle_pdf(vv, a, b, c)))(v)
    assert v.dtype == jnp.float32
    v64, pdf = np.asarray(v, np.float64), np.asarray(pdf, np.float64)
    assert np.all(np.isfinite(v64)) and np.all(np.abs(np.linalg.norm(v64, axis=1) - 1) < 1e-6)
    # every sample inside the triangle, with the density 1/Ω (to float32's Van Oosterom Ω,
    # 1.1e-4 relative off when two vertices are nearly antipodal as in outside-edge)
    assert np.all(pdf > 0), int(np.sum(pdf <= 0))
    np.testing.assert_allclose(pdf, 1 / om, rtol=5e-4)
    # uniform: E[cos θ] within 5 standard errors (one statistic per case; false alarm 6e-7)
    cos = v64 @ normal
    se = cos.std() / np.sqrt(n)
    assert abs(cos.mean() - phi / om) < 5 * se, (cos.mean(), phi / om, se)
    # and the inverse brings u back (u kept 1e-3 off the square's border)
    inv = jax.jit(jax.vmap(lambda vv: W.spherical_triangle_to_square(vv, a, b, c)))(v[:4096])
    keep = np.all((np.asarray(u[:4096]) > 1e-3) & (np.asarray(u[:4096]) < 1 - 1e-3), axis=1)
    assert np.max(np.abs(np.asarray(inv) - np.asarray(u[:4096]))[keep]) < 1e-4
