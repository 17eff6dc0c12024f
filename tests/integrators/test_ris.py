"""Resampled importance sampling (``estimator="ris"``): unbiased, light sampling at M = 1,
better than light sampling where the lights' pdf ignores what the BSDF does, and a broken
resampling weight or target is caught.

The reference is a sum of Lambert's formula over many polygon lights
(:func:`jaxrt.validation.analytic.polygon_projected_solid_angle` per polygon, at a point no
polygon occludes): ``L_r = ρ/π Σ_i L_i Ω⊥_i``. Bounds are 5 standard errors of the estimate.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrt.integrators.point
from jaxrt.integrators import ris as ris_module
from jaxrt.integrators.config import make_estimator
from jaxrt.integrators.point import estimate_at, samples_at
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.container import mesh, shading_scene, with_triangle_sampling
from jaxrt.validation import analytic

N = 1 << 14
ALBEDO = 0.6
Z = np.array([0.0, 0.0, 1.0])
WO = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])


def _lamp_grid(**grid):
    """The lamps of :func:`jaxrt.validation.analytic.polygon_lamp_grid` as meshes, and the
    exact diffuse reflection at 0."""
    quads, radiance = analytic.polygon_lamp_grid(**grid)
    meshes = [mesh(q, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=r, name=f"lamp {i}")
              for i, (q, r) in enumerate(zip(quads, radiance, strict=True))]
    return meshes, analytic.polygons_lambertian_radiance(quads, radiance, ALBEDO, np.zeros(3), Z)


@pytest.fixture(scope="module")
def grid():
    meshes, exact = _lamp_grid()
    return shading_scene(mt.diffuse(ALBEDO), [], occluders=meshes), exact


def _estimate(scene, estimator="ris", **params):
    r = estimate_at(scene, estimator, np.zeros(3), Z, WO, num_samples=N, seed=3, **params)
    return np.asarray(r.mean, np.float64), np.asarray(r.stderr, np.float64)


@pytest.mark.parametrize("candidates", [1, 8])
def test_ris_matches_the_sum_of_lambert_formulas(grid, candidates):
    scene, exact = grid
    mean, err = _estimate(scene, ris_candidates=candidates)
    assert np.all(np.abs(mean - exact) < 5 * err), (mean, err, exact)
    assert np.all(err < 0.05 * exact)  # the bound resolves a 5 % bias


def test_one_candidate_is_light_sampling(grid):
    """M = 1 keeps the only candidate: ``f/p̂ · p̂/p = f/p``, light sampling's estimate from
    light sampling's random dimensions, sample by sample."""
    scene, _ = grid
    scene = scene.replace(lights=with_triangle_sampling(scene.lights, "solid_angle"))
    a = np.asarray(samples_at(scene, "ris", np.zeros(3), Z, WO, num_samples=4096,
                              ris_candidates=1))
    b = np.asarray(samples_at(scene, "light_solid_angle", np.zeros(3), Z, WO,
                              num_samples=4096))
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-7)
    assert np.count_nonzero(b) > 1000


def test_more_candidates_lower_the_error(grid):
    """Many lights, the bright ones far away: power selection sends shadow rays to lamps the
    cosine makes dim; resampling by the unshadowed contribution does not."""
    scene, _ = grid
    _, err1 = _estimate(scene, ris_candidates=1)
    _, err16 = _estimate(scene, ris_candidates=16)
    assert np.all(err16 < 0.6 * err1), (err16, err1)


def test_ris_through_the_delta_and_sphere_lights():
    """Candidates from point, spot and sphere lights mix delta and solid-angle pdfs."""
    lights = [lt.point_light([0.4, 0.1, 1.2], [2.0, 2.0, 2.0]),
              lt.sphere_light([-0.6, 0.2, 1.5], 0.3, [3.0, 3.0, 3.0])]
    scene = shading_scene(mt.diffuse(ALBEDO), lights)
    with jax.enable_x64(True):
        e = float(analytic.point_light_irradiance(jnp.asarray([0.4, 0.1, 1.2]),
                                                  jnp.float64(2.0), jnp.zeros(3),
                                                  jnp.asarray(Z)))
        e += float(analytic.sphere_light_irradiance(jnp.asarray([-0.6, 0.2, 1.5]),
                                                    jnp.float64(0.3), jnp.float64(3.0),
                                                    jnp.zeros(3), jnp.asarray(Z)))
    exact = ALBEDO * e / np.pi
    mean, err = _estimate(scene, ris_candidates=4)
    assert np.all(np.abs(mean - exact) < 5 * err) and np.all(err < 0.05 * exact), \
        (mean, err, exact)


@pytest.mark.parametrize("broken", ["weight", "target"])
def test_a_broken_resampling_is_caught(grid, monkeypatch, broken):
    """A weight that is not ``p̂/p`` (here ``p̂/p^0.9``), or a target that is zero where the
    integrand is not (the brightest candidates ignored), biases RIS: the analytic test fails."""
    scene, exact = grid
    if broken == "weight":
        monkeypatch.setattr(ris_module, "resampling_weight",
                            lambda t, p: jnp.where(p > 0, t / jnp.where(p > 0, p, 1) ** 0.9, 0))
    else:  # as a target zero on the bright candidates: they are never chosen
        weight = ris_module.resampling_weight
        monkeypatch.setattr(ris_module, "resampling_weight",
                            lambda t, p: jnp.where(t < 2.0, weight(t, p), 0))
    jaxrt.integrators.point._estimate_at.program.cache_clear()
    jax.clear_caches()
    try:
        mean, err = _estimate(scene, ris_candidates=8)
    finally:
        monkeypatch.undo()
        jaxrt.integrators.point._estimate_at.program.cache_clear()
        jax.clear_caches()
    assert np.any(np.abs(mean - exact) >= 5 * err), (mean, err, exact)


@pytest.mark.parametrize("params, match", [
    (dict(ris_candidates=0), "ris_candidates"),
    (dict(ris_candidates=2.5), "ris_candidates"),
])
def test_ris_options_are_checked(params, match):
    with pytest.raises(ValueError, match=match):
        make_estimator("ris", **params)
    with pytest.raises(ValueError, match="applies to estimator='ris' and to 'path' with nee='ris'"):
        make_estimator("mis", ris_candidates=4)
