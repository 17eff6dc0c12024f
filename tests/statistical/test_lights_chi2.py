"""Chi-square fits of every non-delta light's direction sampling against its own ``pdf_li``.

Each light is alone in its table (selection pmf 1) and sampled from a fixed shading point; the
harness (:func:`jaxrt.validation.chi2.chi2_test`) histograms ``wi`` over the sphere in (φ, cos θ)
and integrates ``pdf_li`` over every cell. ``pdf_li`` is only defined for directions that hit the
light, so the pdf adapters multiply by a hit indicator from an independent intersection routine
(``jaxrt.geometry.triangle`` for triangles, :func:`intersect_spheres` for spheres).

A sphere subtending 1e-6 sr would fall into a single cell of any sphere grid, so it is tested
in its cone's own coordinates instead: ``s = ((1 − cos θ)/(1 − cos θ_max), φ/2π)`` on the unit
square, where a uniform cone is uniform, with ``pdf_square = pdf_li · 2π(1 − cos θ_max)``.
The far (1e-7 sr) triangle is checked in ``test_lights.py`` by pdf consistency and
``E[1/pdf] = Ω`` instead.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.core.vecmath import coordinate_system, dot, spherical_direction
from jaxrt.geometry.triangle import intersect_triangle
from jaxrt.scene.lights import (
    constant_environment,
    environment_map,
    intersect_spheres,
    light_table,
    pdf_li,
    sample_li,
    sphere_light,
    triangle_lights,
)
from jaxrt.validation.chi2 import chi2_test

N_UP = jnp.array([0.0, 0.0, 1.0])
TRI = np.array([[-0.5, -0.4, 1.0], [0.1, 0.6, 1.0], [0.6, -0.3, 1.0]])


def rotation_xyz(a, b, c):
    """A generic rotation matrix (so the env map's frame differs from the world's)."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


def env_image(seed=3, h=8, w=16):
    rng = np.random.default_rng(seed)
    return rng.gamma(0.7, 1.0, size=(h, w, 3))


# (light records, table kwargs, shading point)
SPHERE_DOMAIN = {
    "tri_area": (lambda: [triangle_lights(TRI, [1, 2, 3], [0])], {"triangle_sampling": "area"},
                 [0.1, 0.0, 0.0]),
    "tri_sa": (lambda: [triangle_lights(TRI, [1, 2, 3], [0])],
               {"triangle_sampling": "solid_angle"}, [0.1, 0.0, 0.0]),
    # 1e-4 below the light (Ω ≈ 2π − 1.7e-3). Area sampling from there puts nearly every
    # direction within 1e-3 rad of the horizon, which no (φ, cos θ) grid resolves: that case is
    # covered by the consistency and irradiance tests in test_lights.py instead.
    "tri_sa_close": (lambda: [triangle_lights(TRI, [1, 2, 3], [0])],
                     {"triangle_sampling": "solid_angle"}, [0.05, 0.0, 1.0 - 1e-4]),
    "tri_area_twosided_behind": (lambda: [triangle_lights(TRI, [1, 2, 3], [0], two_sided=True)],
                                 {"triangle_sampling": "area"}, [0.0, 0.1, 1.7]),
    "sphere_near": (lambda: [sphere_light([0.3, 0.2, 2.0], 1.0, [2, 2, 2])], {}, [0, 0, 0]),
    "sphere_inside": (lambda: [sphere_light([0.3, 0.2, 0.1], 1.0, [2, 2, 2])], {}, [0, 0, 0]),
    "env_const": (lambda: [constant_environment([0.5, 0.4, 0.3])], {}, [0, 0, 0]),
    "env_map": (lambda: [environment_map(env_image(), rotation_xyz(0.3, -0.7, 1.1))], {},
                [0, 0, 0]),
}


def _adapters(lights, p):
    """(sample_fn, pdf_fn) over directions for a single-light table."""
    half = jnp.asarray(0.5, p.dtype)

    def sample_fn(u):
        return sample_li(lights, p, N_UP, jnp.stack([half, u[0], u[1]])).wi

    def pdf_fn(wi):
        if lights.triangle is not None:
            v = lights.triangle.vertices[0].astype(wi.dtype)
            t, _, _ = intersect_triangle(p, wi, v[0], v[1], v[2], jnp.inf)
        elif lights.sphere is not None:
            t, _ = intersect_spheres(lights, p, wi, jnp.inf)
        else:
            t = jnp.zeros_like(wi[0])
        hit = jnp.isfinite(t)
        p_light = p + jnp.where(hit, t, 0) * wi
        pdf = pdf_li(lights, p, wi, jnp.int32(0), p_light)
        return jnp.where(hit, pdf, jnp.zeros_like(pdf))

    return sample_fn, pdf_fn


def _accept(result, num_samples):
    """The harness verdict, except for one known cubature blind spot (reported to its owner).

    The harness integrates the pdf over each cell with a Gauss–Legendre rule that refines only
    where its coarse and fine estimates differ; a cell that a triangle's corner clips by a
    sliver thinner than the node spacing integrates to exactly 0, so its few samples count as
    "leaked" (measured: 5–22 of 2e5 samples, in one or two cells, at every resolution tried).
    We accept that case only when every leaking cell touches a cell with positive expected
    count (a support boundary, not a stray sample) and the leak is below 1e-4·N; that sampled
    directions do hit the light is checked separately in test_lights.py. Any other failure
    (χ² p-value, normalisation, out-of-domain samples) still fails.
    """
    if result.passed:
        return True
    # Second blind spot, same cause: the cubature's error estimate misses the jump error, so the
    # integral of a pdf with a jump at its support edge moves with the grid (measured for the
    # triangle: 1.0011 at 48×24, 0.9991 at 50×26). Tolerated up to 2e-3 here because
    # test_lights.py::test_pdf_normalised checks the normalisation to 1e-5 by a smooth quadrature.
    norm_ok = abs(result.integral - 1) <= 2e-3
    other = [m for m in result.messages
             if "zero-pdf" not in m and not ("integrates to" in m and norm_ok)]
    chi2_ok = all(t.passed for t in result.tables)
    leak_cells = np.argwhere((result.observed > 0) & (result.expected <= 0))
    padded = np.pad(result.expected, 1, mode="wrap")
    boundary = all(padded[i:i + 3, j:j + 3].max() > 0 for i, j in leak_cells)
    return not other and chi2_ok and boundary and result.num_leaked <= 1e-4 * num_samples


def _run(name, num_samples, resolution, pdf_override=None, seed=1, dtype=jnp.float32):
    recs, kw, p = SPHERE_DOMAIN[name]
    lights = light_table(recs(), **kw)
    p = jnp.asarray(p, dtype)
    sample_fn, pdf_fn = _adapters(lights, p)
    if pdf_override is not None:
        pdf_fn = pdf_override(lights, p, pdf_fn)
    return chi2_test(sample_fn, pdf_fn, "sphere", num_samples=num_samples,
                     resolution=resolution, seed=seed, num_tests=len(SPHERE_DOMAIN))


# The default run fits one light of each sampling technique; the slow run fits all of them.
# tri_sa_close (Ω within 2e-3 of 2π) is the hard case of solid-angle triangle sampling: float32
# failed it (χ² ≈ 1e4) until warp_sphtri split the triangle at its closest point.
DEFAULT = ("tri_area", "tri_sa_close", "sphere_near", "env_map", "env_const")


@pytest.mark.parametrize("name", DEFAULT)
def test_chi2_sphere_domain(name):
    # alpha = 1% family-wise over all configurations (Šidák inside the harness).
    result = _run(name, 200_000, (48, 24))
    assert _accept(result, 200_000), str(result)


@pytest.mark.slow
def test_chi2_triangle_near_2pi_x64(enable_x64):
    result = _run("tri_sa_close", 200_000, (48, 24), dtype=jnp.float64)
    assert _accept(result, 200_000), str(result)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SPHERE_DOMAIN))
def test_chi2_sphere_domain_all(name):
    result = _run(name, 200_000, (48, 24))
    assert _accept(result, 200_000), str(result)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sphere_near", "env_map"])
def test_chi2_sphere_domain_large(name):
    result = _run(name, 1_000_000, (101, 51), seed=2)
    assert _accept(result, 1_000_000), str(result)


# ---------------------------------------------------------------------------------------------
# A tiny sphere (~1e-6 sr) in its own cone coordinates.


def _cone_frame(center, radius, p):
    """Axis frame and 1 − cos θ_max (float64, host) of the cone a sphere subtends at p."""
    v = np.asarray(center, np.float64) - np.asarray(p, np.float64)
    d = np.linalg.norm(v)
    sin2 = (radius / d) ** 2
    return v / d, sin2 / (1 + np.sqrt(1 - sin2))


@pytest.mark.parametrize("radius", [5.64e-4 * 3, 0.3])
def test_chi2_sphere_cone_coordinates(radius):
    center, p = np.array([1.0, 2.0, 2.0]), np.zeros(3)  # d = 3: Ω ≈ π (r/d)² ≈ 1e-6 sr first
    lights = light_table([sphere_light(center, radius, [1, 1, 1])])
    axis64, omc64 = _cone_frame(center, radius, p)
    axis = jnp.asarray(axis64, jnp.float32)
    s_t, t_t = coordinate_system(axis)
    omc = jnp.float32(omc64)
    pj = jnp.asarray(p, jnp.float32)

    def sample_fn(u):
        wi = sample_li(lights, pj, N_UP, jnp.stack([jnp.float32(0.5), u[0], u[1]])).wi
        x, y = dot(wi, s_t), dot(wi, t_t)
        z = dot(wi, axis)
        # 1 − cos θ from the (accurate) transverse components: sin²θ / (1 + cos θ).
        one_minus_cos = (x * x + y * y) / (1 + z)
        phi = jnp.arctan2(y, x)
        phi = jnp.where(phi < 0, phi + 2 * jnp.pi, phi)
        # Clamp the test's own float32 round-off of s1 at the cap edge (measured: 2 in 2e5
        # samples at 1 + 1e-7); the sampler's directions are inside the cap.
        top = jnp.nextafter(jnp.float32(1), jnp.float32(0))
        return jnp.stack([jnp.minimum(one_minus_cos / omc, top), phi / (2 * jnp.pi)])

    def pdf_fn(s):
        omcos = s[0] * omc
        cos_t = 1 - omcos
        sin_t = jnp.sqrt(omcos * (2 - omcos))
        local = spherical_direction(sin_t, cos_t, 2 * jnp.pi * s[1])
        wi = local[0] * s_t + local[1] * t_t + local[2] * axis
        # dω = (1 − cos θ_max) 2π ds1 ds2 on this square.
        return pdf_li(lights, pj, wi, jnp.int32(0), pj) * omc * 2 * jnp.pi

    result = chi2_test(sample_fn, pdf_fn, "square", num_samples=200_000, resolution=(40, 20),
                       seed=3, num_tests=2)
    assert result.passed, str(result)


# ---------------------------------------------------------------------------------------------
# Teeth: the same harness rejects a plausible but wrong pdf.


def _solid_angle_pdf_for_area_sampler(lights, p, pdf_fn):
    """Wrong: reports 1/Ω (solid-angle sampling) for the area sampler."""
    v = lights.triangle.vertices[0]
    from jaxrt.sampling.warp import spherical_triangle_solid_angle

    omega = spherical_triangle_solid_angle(v[0] - p, v[1] - p, v[2] - p)
    return lambda wi: jnp.where(pdf_fn(wi) > 0, 1 / omega, 0.0).astype(wi.dtype)


def _env_pdf_blurred(lights, p, pdf_fn):
    """Wrong but normalised: 15% of the density moved to a uniform sphere."""
    del lights, p
    return lambda wi: (0.85 * pdf_fn(wi) + 0.15 / (4 * jnp.pi)).astype(wi.dtype)


@pytest.mark.parametrize("name, wrong", [
    pytest.param("tri_area", _solid_angle_pdf_for_area_sampler, marks=pytest.mark.slow),
    ("env_map", _env_pdf_blurred),
])
def test_chi2_rejects_wrong_pdf(name, wrong):
    result = _run(name, 200_000, (48, 24), pdf_override=wrong)
    assert not _accept(result, 200_000), str(result)
