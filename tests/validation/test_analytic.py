"""The analytic oracles against independent float64 quadrature.

Quadrature references are computed with numpy in float64: polygons in the surface-area form
(Gauss–Legendre on a fine sub-grid of each triangle, ``∫ L cosθ cosθ_l / d² dA``), spheres in
the hemispherical form on a fine (φ, cos θ) midpoint grid. These are independent of Lambert's
formula and of Snyder's sphere formula, so agreement checks the maths, not the code twice.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.validation import analytic


def _quad_triangle_irradiance(tri, p, n, m=160):
    """∫_T max(0, n·ω) |cos θ_l| / d² dA by a midpoint rule on m² sub-triangles (float64)."""
    v0, v1, v2 = (np.asarray(v, np.float64) for v in tri)
    # barycentric midpoints of a regular m×m subdivision (upward and downward sub-triangles)
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    keep = i + j < m
    up = np.stack([(i + 1 / 3) / m, (j + 1 / 3) / m], -1)[keep]
    keep2 = i + j < m - 1
    down = np.stack([(i + 2 / 3) / m, (j + 2 / 3) / m], -1)[keep2]
    b = np.concatenate([up, down])
    x = v0 + b[:, :1] * (v1 - v0) + b[:, 1:] * (v2 - v0)
    area_vec = 0.5 * np.cross(v1 - v0, v2 - v0)
    area = np.linalg.norm(area_vec)
    nl = area_vec / area
    w = x - p
    d2 = np.sum(w * w, -1)
    wn = w / np.sqrt(d2)[:, None]
    cos_r = np.maximum(wn @ n, 0)
    cos_l = np.abs(wn @ nl)
    return np.sum(cos_r * cos_l / d2) * area / (m * m)


def _quad_polygon(poly, p, n):
    poly = np.asarray(poly, np.float64)
    return sum(_quad_triangle_irradiance([poly[0], poly[k], poly[k + 1]], p, n)
               for k in range(1, len(poly) - 1))


def _quad_sphere(center, radius, p, n, m=1500):
    """∫ over the cone subtended by the sphere of max(0, n·ω) dω, midpoint rule in (φ, cos θ)."""
    c = np.asarray(center, np.float64) - p
    d = np.linalg.norm(c)
    axis = c / d
    cos_max = np.sqrt(max(0.0, 1 - (radius / d) ** 2))
    z = 1 - (np.arange(m) + 0.5) / m * (1 - cos_max)
    phi = (np.arange(2 * m) + 0.5) / (2 * m) * 2 * np.pi
    z, phi = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - z * z)
    # frame about the axis
    a = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    t1 = np.cross(axis, a)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    w = (s * np.cos(phi))[..., None] * t1 + (s * np.sin(phi))[..., None] * t2 + z[..., None] * axis
    cell = (1 - cos_max) * 2 * np.pi / (m * 2 * m)
    return np.sum(np.maximum(w @ n, 0)) * cell


RECT = np.array([[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]])


def _rot_x(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


POLY_CASES = {
    "parallel": (RECT, np.zeros(3), np.array([0, 0, 1.0])),
    "tilted_light": (RECT @ _rot_x(35).T + [0, 0, 0.3], np.zeros(3), np.array([0, 0, 1.0])),
    "tilted_receiver": (RECT, np.zeros(3), _rot_x(50) @ [0, 0, 1.0]),
    # the receiver's horizon cuts the rectangle: part of it lies below
    "horizon_clipped": (RECT, np.zeros(3), _rot_x(80) @ [0, 0, 1.0]),
    "triangle_near": (np.array([[-1, -1, 0.25], [2, -1, 0.25], [-1, 2, 0.25]]), np.zeros(3),
                      np.array([0, 0, 1.0])),
    "fully_below": (RECT * [1, 1, -1], np.zeros(3), np.array([0, 0, 1.0])),
}


@pytest.mark.parametrize("name", list(POLY_CASES))
def test_polygon_matches_quadrature(name, enable_x64):
    poly, p, n = POLY_CASES[name]
    ref = _quad_polygon(poly, p, n)
    got = float(analytic.polygon_projected_solid_angle(jnp.asarray(poly), jnp.asarray(p),
                                                       jnp.asarray(n)))
    # the midpoint rule with 160² cells per triangle is accurate to ~1e-4 relative on these
    # smooth integrands (the horizon kink costs a little more): 1e-3 relative or 1e-6 absolute
    assert got == pytest.approx(ref, rel=1e-3, abs=1e-6)


def test_polygon_winding_and_dtype():
    poly, p, n = POLY_CASES["parallel"]
    o, n32 = jnp.zeros(3, jnp.float32), jnp.asarray(n, jnp.float32)
    a = analytic.polygon_projected_solid_angle(jnp.asarray(poly, jnp.float32), o, n32)
    b = analytic.polygon_projected_solid_angle(jnp.asarray(poly[::-1], jnp.float32), o, n32)
    assert a.dtype == jnp.float32
    assert float(a) == pytest.approx(float(b), rel=1e-6)


@pytest.mark.parametrize("dist", [1e1, 1e2, 1e3, 1e4])
def test_polygon_far_float32_error(dist):
    """Measured float32 error of Lambert's formula grows like ε·d/ℓ, as documented."""
    tri = np.array([[-0.5, -0.5, dist], [0.5, -0.5, dist], [0.0, 0.5, dist]]) + [3e-3, 0, 0]
    n = np.array([0, 0, 1.0])
    with jax.enable_x64(True):
        ref = float(analytic.polygon_projected_solid_angle(jnp.asarray(tri), jnp.zeros(3),
                                                           jnp.asarray(n)))
    got = float(analytic.polygon_projected_solid_angle(jnp.asarray(tri, jnp.float32),
                                                       jnp.zeros(3, jnp.float32),
                                                       jnp.asarray(n, jnp.float32)))
    far = float(analytic.polygon_irradiance_far(jnp.asarray(tri, jnp.float32), jnp.float32(1),
                                                jnp.zeros(3, jnp.float32),
                                                jnp.asarray(n, jnp.float32)))
    # documented bound: relative error ≤ 30 ε d/ℓ (ε = 6e-8) for Lambert's formula in float32
    assert abs(got - ref) / ref < 30 * 6e-8 * dist
    # the far-field form is within O((ℓ/d)²) of the exact value
    assert abs(far - ref) / ref < max(2.0 / dist**2, 1e-5)


SPHERE_CASES = {
    "overhead": (np.array([0, 0, 3.0]), 1.0, np.array([0, 0, 1.0])),
    "tilted": (np.array([1.5, 0, 2.0]), 0.5, np.array([0, 0, 1.0])),
    "straddling": (np.array([2.0, 0, 0.3]), 1.0, np.array([0, 0, 1.0])),
    "mostly_below": (np.array([2.0, 0, -0.6]), 1.0, np.array([0, 0, 1.0])),
    "fully_below": (np.array([0, 0, -3.0]), 1.0, np.array([0, 0, 1.0])),
    "tiny_far": (np.array([0.0, 1e2, 1e2]), 1e-1, np.array([0, 0, 1.0])),
}


@pytest.mark.parametrize("name", list(SPHERE_CASES))
def test_sphere_matches_quadrature(name, enable_x64):
    c, r, n = SPHERE_CASES[name]
    ref = _quad_sphere(c, r, np.zeros(3), n)
    got = float(analytic.sphere_light_irradiance(jnp.asarray(c), jnp.asarray(r), jnp.float64(1),
                                                 jnp.zeros(3), jnp.asarray(n)))
    # 1500×3000 midpoint cells: ~1e-5 relative accuracy; the horizon kink costs more
    assert got == pytest.approx(ref, rel=2e-4, abs=1e-9)


def test_sphere_float32_far_stable():
    c = jnp.array([0.0, 0.0, 1e4], jnp.float32)
    e = analytic.sphere_light_irradiance(c, jnp.float32(1e-1), jnp.float32(1), jnp.zeros(3),
                                         jnp.array([0, 0, 1.0], jnp.float32))
    # π r²/d² exactly: no cancellation anywhere in the fully-above branch
    assert e.dtype == jnp.float32
    assert float(e) == pytest.approx(np.pi * 1e-2 / 1e8, rel=1e-5)


def test_point_and_environment():
    e = analytic.point_light_irradiance(jnp.array([0, 0, 2.0]), jnp.float32(8), jnp.zeros(3),
                                        jnp.array([0, 0, 1.0]))
    assert float(e) == pytest.approx(2.0)
    e = analytic.point_light_irradiance(jnp.array([2.0, 0, 0.0]), jnp.float32(8), jnp.zeros(3),
                                        jnp.array([0, 0, 1.0]))
    assert float(e) == 0.0  # grazing: exactly on the horizon
    assert float(analytic.constant_environment_irradiance(jnp.float32(2))) == pytest.approx(
        2 * np.pi)
    assert float(analytic.lambertian_radiance(0.5, 2 * np.pi)) == pytest.approx(1.0)


def test_clip_polygon_keeps_compact_polygon():
    poly = jnp.asarray(RECT)
    clipped, ok = analytic.clip_polygon_to_plane(poly, jnp.zeros(3), jnp.array([1.0, 0, 0]))
    pts = np.asarray(clipped)[np.asarray(ok)]
    # the half x ≥ 0 of the square: 4 vertices (two originals, two crossings at x = 0)
    assert len(pts) == 4
    assert np.all(pts[:, 0] >= 0)


def test_polygon_very_close_tends_to_pi():
    """A receiver 1e-4 below the middle of a big triangle sees almost the whole hemisphere."""
    tri = jnp.array([[-1, -1, 1e-4], [2, -1, 1e-4], [-1, 2, 1e-4]], jnp.float32)
    phi = float(analytic.polygon_projected_solid_angle(tri, jnp.zeros(3), jnp.array([0, 0, 1.0])))
    # the missing part is the projected solid angle beyond the edges, O(h/dist_to_edge) = O(1e-4)
    assert np.pi - 1e-3 < phi <= np.pi + 1e-6
