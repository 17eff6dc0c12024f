"""Light selection by a light BVH (``light_selection="bvh"``): its pmf is exact (the sampled
frequencies match it, it sums to one, the sampler returns it), it is positive wherever a light
can contribute, and estimators that use it stay unbiased on many polygon lights; a wrong pmf
is caught."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrt.integrators.point import estimate_at
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import lamp_grid
from jaxrt.scene.container import mesh, shading_scene
from jaxrt.scene.lights import bvh, bvh_build
from jaxrt.validation import analytic
from jaxrt.validation.chi2 import pearson_chi2, pool_cells, sidak_significance

Z = np.array([0.0, 0.0, 1.0])


def _mixed_lights(selection="bvh"):
    """Every kind: points, a spot, one- and two-sided triangles, spheres, a directional light
    and an environment."""
    rng = np.random.default_rng(4)
    tris = rng.uniform(-2, 2, (24, 3, 3)) + np.array([0, 0, 2.0])
    records = [lt.point_light([0.5, 0.2, 1.5], [3.0, 3, 3]),
               lt.point_light([-1.5, 1.0, 0.4], [0.0, 0, 0]),  # black: the floor keeps it
               lt.spot_light([0, 0, 3], [0, 0, -1], [20.0, 20, 20], 0.35, 0.5),
               lt.triangle_lights(tris, rng.uniform(0.5, 5, (24, 3)), np.arange(24),
                                  two_sided=np.arange(24) % 3 == 0),
               lt.sphere_light([[1, 1, 2.5], [-1, 0.5, 1.0]], [0.2, 0.4], [[4.0, 4, 4], [1, 2, 3]]),
               lt.directional_light([0.2, 0.1, -1], [1.0, 1, 1]),
               lt.constant_environment([0.2, 0.2, 0.3])]
    return lt.light_table(records, selection=selection, scene_radius=3.0)


POINTS = np.array([[0.0, 0.0, 0.0], [1.2, -0.7, 2.1], [-1.9, 1.9, 4.5], [0.5, 0.2, 1.5]])
NORMALS = np.array([[0.0, 0, 1], [0.6, 0, 0.8], [0, -1.0, 0], [1.0, 0, 0]])


def _pmf_table(lights, p, n):
    count = lights.structure.num_lights
    f = jax.jit(jax.vmap(lambda i: lt.selection_pmf(lights, p, i, n)))
    return np.asarray(f(jnp.arange(count)), np.float64)


@pytest.fixture(scope="module")
def mixed():
    return _mixed_lights()


def test_pmf_sums_to_one_and_is_positive_where_light_can_arrive(mixed):
    for p, n in zip(POINTS, NORMALS, strict=True):
        pmf = _pmf_table(mixed, jnp.asarray(p), jnp.asarray(n))
        assert abs(pmf.sum() - 1) < 1e-5, pmf.sum()
        # every light of the mixed table can send light to these points (the spot's cone and
        # the one-sided triangles aside, which are checked against their geometry below)
        tri = mixed.table("triangle")
        off = mixed.structure.offset("triangle")
        v = np.asarray(tri.vertices, np.float64)
        nrm = np.asarray(tri.normal, np.float64)
        front = np.einsum("ij,ij->i", p - v.mean(1), nrm) > 0
        # a one-sided triangle with p on its front side (the centroid's side test suffices
        # for these triangles, far from p's plane) must be reachable
        reachable = front | np.asarray(tri.two_sided)
        assert np.all(pmf[off:off + len(v)][reachable] > 0)


def test_sampled_frequencies_match_the_pmf(mixed):
    """χ² of 400 000 selections at each fixed point against ``pmf · n``, Šidák-corrected."""
    count = mixed.structure.num_lights
    level = sidak_significance(1e-3, len(POINTS))
    for k, (p, n) in enumerate(zip(POINTS, NORMALS, strict=True)):
        pj, nj = jnp.asarray(p, jnp.float32), jnp.asarray(n, jnp.float32)
        u = jax.random.uniform(jax.random.key(k), (400_000,))
        idx, pmf_s = jax.jit(jax.vmap(lt.select_light, (None, None, None, 0)))(mixed, pj, nj, u)
        idx = np.asarray(idx)
        pmf = _pmf_table(mixed, pj, nj)
        # the sampler reports the pmf of what it chose, as pdf_li evaluates it
        np.testing.assert_allclose(np.asarray(pmf_s), pmf[idx], rtol=1e-5)
        observed = np.bincount(idx, minlength=count)
        obs, exp, _ = pool_cells(observed, pmf * len(u))
        stat, dof, p_value = pearson_chi2(obs, exp)
        assert p_value > level, (k, stat, dof, p_value)


def test_a_wrong_pmf_fails_the_frequency_test(mixed, monkeypatch):
    """The descent's first choice evaluated with the children's importances squared: the pmf
    no longer describes the sampler, and the χ² test rejects it."""
    p, n = jnp.asarray(POINTS[1], jnp.float32), jnp.asarray(NORMALS[1], jnp.float32)
    u = jax.random.uniform(jax.random.key(9), (400_000,))
    idx, _ = jax.jit(jax.vmap(lambda u: lt.select_light(mixed, p, n, u)))(u)
    importance = bvh.importance
    monkeypatch.setattr(bvh, "importance", lambda *a: importance(*a) ** 2)
    pmf = _pmf_table(mixed, p, n)
    obs, exp, _ = pool_cells(np.bincount(np.asarray(idx), minlength=len(pmf)), pmf * len(u))
    assert pearson_chi2(obs, exp)[2] < 1e-6


def test_a_point_no_light_faces_gets_pmf_zero_everywhere():
    """Only one-sided lamps facing up, the shading point far below them: nothing reaches it,
    and the pmf says so (0 for every light) rather than choosing a light that cannot
    contribute. (Close below them, inside a node's bounding sphere, the bound is not tight.)"""
    quad = np.array([[[-1, -1, 0], [1, -1, 0], [1, 1, 0]], [[-1, -1, 0], [1, 1, 0], [-1, 1, 0]]],
                    np.float64)
    lights = lt.light_table([lt.triangle_lights(quad, [1.0, 1, 1], [0, 1]),
                             lt.triangle_lights(quad + [3.0, 0, 0], [2.0, 2, 2], [2, 3])],
                            selection="bvh")
    below = _pmf_table(lights, jnp.array([0.5, 0.0, -10.0]), jnp.array([0.0, 0, 1]))
    above = _pmf_table(lights, jnp.array([0.5, 0.0, 1.0]), jnp.array([0.0, 0, -1]))
    assert np.all(below == 0)
    assert abs(above.sum() - 1) < 1e-6 and np.all(above > 0)


def _cone_directions(w, theta, rng, k=64):
    """``k`` unit directions within ``theta`` of ``w``, the cone's rim included."""
    t = np.concatenate([[theta], rng.uniform(0, theta, k - 1)])
    phi = rng.uniform(0, 2 * np.pi, k)
    a = np.cross(w, [1.0, 0, 0] if abs(w[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(w, a)
    return (np.cos(t)[:, None] * w + np.sin(t)[:, None] * (np.cos(phi)[:, None] * a
                                                           + np.sin(phi)[:, None] * b))


unit = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(unit, st.floats(0, np.pi)), min_size=1, max_size=6),
       st.integers(0, 2**31))
def test_a_nodes_cone_contains_its_lights_cones(cones, seed):
    """Every direction of a member light's normal cone lies in its node's cone (the law the
    tree's bounds rest on): the node row's axis and cos θ_o, as the build forms them."""
    axes = np.array([np.array(w) / np.linalg.norm(w) for w, _ in cones])
    theta = np.array([t for _, t in cones])
    k = len(cones)
    s = bvh_build.LightSet(np.zeros((k, 3)), np.ones((k, 3)), np.ones(k), axes, theta,
                           np.zeros(k))
    (row,) = bvh_build._segment_rows(s, np.zeros(k, np.int64))
    w, cos_o = row[3:6], row[8]
    assert abs(np.linalg.norm(w) - 1) < 1e-9 and -1 <= cos_o <= 1
    rng = np.random.default_rng(seed)
    for axis, t in zip(axes, theta, strict=True):
        d = _cone_directions(axis, t, rng)
        assert np.all(d @ w >= cos_o - 1e-7)


@settings(max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(-3, 3)] * 3), unit)
def test_pmf_sums_to_one_anywhere(p, n):
    """At any shading point and normal the pmf over the lamp grid sums to one (every lamp of
    it faces down: points above the ceiling see none and get 0 everywhere)."""
    lights = _LAMPS.lights
    pmf = _pmf_table(lights, jnp.asarray(p, jnp.float32), jnp.asarray(n, jnp.float32))
    total = pmf.sum()
    assert np.all(pmf >= 0)
    if p[1] < 2.4:  # below the lamps (at y = 2.499)
        assert abs(total - 1) < 1e-5, total
    else:
        assert total == 0 or abs(total - 1) < 1e-5


_LAMPS = lamp_grid(4, 3, rows=6, light_selection="bvh")


def test_the_tree_is_only_compiled_when_asked_for():
    """Power selection keeps its Discrete table and depth 0; ``bvh`` sets the static depth."""
    s_power = lamp_grid(4, 3, rows=6)
    assert s_power.lights.structure.selection == "power"
    assert s_power.lights.structure.bvh_depth == 0
    assert _LAMPS.lights.structure.bvh_depth == int(np.ceil(np.log(72) / np.log(bvh.BRANCHING)))
    with pytest.raises(ValueError, match="selection must be one of"):
        lamp_grid(4, 3, rows=2, light_selection="tree")


# ---------------------------------------------------------------------------------------------
# Estimators with BVH selection on many polygon lights: the sum of Lambert's formulas.

ALBEDO = 0.6
WO = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])


@pytest.fixture(scope="module")
def polygons():
    quads, radiance = analytic.polygon_lamp_grid(k=6, spread=2.0)
    meshes = [mesh(q, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=r)
              for q, r in zip(quads, radiance, strict=True)]
    return meshes, analytic.polygons_lambertian_radiance(quads, radiance, ALBEDO, np.zeros(3), Z)


@pytest.mark.parametrize("estimator", ["light_area", "light_solid_angle", "mis", "ris"])
def test_bvh_selection_matches_the_sum_of_lambert_formulas(polygons, estimator):
    meshes, exact = polygons
    scene = shading_scene(mt.diffuse(ALBEDO), [], occluders=meshes, light_selection="bvh")
    r = estimate_at(scene, estimator, np.zeros(3), Z, WO, num_samples=1 << 14, seed=5)
    mean, err = np.asarray(r.mean, np.float64), np.asarray(r.stderr, np.float64)
    assert np.all(np.abs(mean - exact) < 5 * err), (mean, err, exact)
    assert np.all(err < 0.03 * exact)  # the bound resolves a 3 % bias


def test_bvh_selection_lowers_the_error_of_light_sampling(polygons):
    """The bright lamps are far off to one side: the tree sends fewer shadow rays there."""
    meshes, _ = polygons
    errs = {}
    for sel in ("power", "bvh"):
        scene = shading_scene(mt.diffuse(ALBEDO), [], occluders=meshes, light_selection=sel)
        r = estimate_at(scene, "light_solid_angle", np.zeros(3), Z, WO, num_samples=1 << 14,
                        seed=5)
        errs[sel] = float(np.max(np.asarray(r.stderr)))
    assert errs["bvh"] < 0.7 * errs["power"], errs


def test_a_wrong_pmf_biases_the_estimate(monkeypatch):
    """A selection that reports the square root of its pmf (too large for every light):
    light sampling divides by the wrong density and misses the closed form. (One lamp fewer
    than above: a scene of a new structure, so the patched kernel is the one compiled.)"""
    quads, radiance = analytic.polygon_lamp_grid(k=6, spread=2.0)
    meshes = [mesh(q, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=r)
              for q, r in zip(quads[:-1], radiance[:-1], strict=True)]
    exact = analytic.polygons_lambertian_radiance(quads[:-1], radiance[:-1], ALBEDO,
                                                  np.zeros(3), Z)
    scene = shading_scene(mt.diffuse(ALBEDO), [], occluders=meshes, light_selection="bvh")
    select = bvh.bvh_select
    monkeypatch.setattr(bvh, "bvh_select",
                        lambda *a: (lambda i, q: (i, jnp.sqrt(q)))(*select(*a)))
    r = estimate_at(scene, "light_solid_angle", np.zeros(3), Z, WO, num_samples=1 << 14, seed=5)
    mean, err = np.asarray(r.mean, np.float64), np.asarray(r.stderr, np.float64)
    assert np.any(np.abs(mean - exact) > 5 * err)


def test_derivatives_through_bvh_selection(polygons):
    """d/dρ (R) and d/dL_e of every lamp (G) of light sampling and MIS with the tree's pmf,
    against the closed forms ``L_r/ρ`` and ``ρ/π Σ Ω⊥_i``: the selection carries no
    derivative and takes none away."""
    from jaxrt.rendering.differentiable import derivative_at

    meshes, exact = polygons
    scene = shading_scene(mt.diffuse(ALBEDO), [], occluders=meshes, light_selection="bvh")
    quads, _ = analytic.polygon_lamp_grid(k=6, spread=2.0)
    d_radiance = analytic.polygons_lambertian_radiance(quads, np.ones(len(quads)), ALBEDO,
                                                       np.zeros(3), Z)
    kd = np.zeros((1 + len(meshes), 3))
    kd[0, 0] = 1.0
    radiance = np.zeros((2 * len(meshes), 3))
    radiance[:, 1] = 1.0
    for estimator in ("light_solid_angle", "mis"):
        d = derivative_at(scene, {"materials.kd": kd, "triangle.radiance": radiance}, estimator,
                          np.zeros(3), Z, WO, num_samples=1 << 14, seed=8)
        mean, err = np.asarray(d.mean, np.float64)[:2], np.asarray(d.stderr, np.float64)[:2]
        ref = np.array([exact / ALBEDO, d_radiance])
        assert np.all(np.abs(mean - ref) < 5 * err) and np.all(ref > 10 * err), \
            (estimator, mean, ref, err)
