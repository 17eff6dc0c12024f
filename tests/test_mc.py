"""Tests of the Monte Carlo estimator: exact bookkeeping, unbiasedness, variance, 1/√N."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt import mc, warp
from jaxrt.mc import Estimate, estimate_zero, pairwise_sum
from jaxrt.sampler import sample_2d

SEED = 2024
# Compiled once; eager op-by-op dispatch is slow on a shared machine.
estimate_from_values = jax.jit(mc.estimate_from_values)
combine = jax.jit(mc.combine)
combine_many = jax.jit(mc.combine_many)


def mc_estimate(f, sample, pdf, u):
    """Jitted :func:`jaxrt.mc.mc_estimate` (shape errors are raised while tracing)."""
    return jax.jit(lambda u: mc.mc_estimate(f, sample, pdf, u))(u)
# float32 floor for a mean of O(1) terms: pairwise sums keep round-off near a few ε ≈ 1e-6.
F32_FLOOR = 1e-5


def variates(n, pixel=0, seed=SEED):
    """(n, 2) independent variates from the counter-based stream."""
    return sample_2d("independent", seed, pixel, jnp.arange(n, dtype=jnp.int32), 0)


def check_unbiased(est: Estimate, exact: float):
    """|mean − exact| < 5 σ̂ + floor: a 5σ deviation has probability 6e-7 for a normal mean."""
    err = abs(float(est.mean) - exact)
    assert err < 5 * float(est.stderr) + F32_FLOOR * abs(exact), (err, float(est.stderr))


# --------------------------------------------------------------------------- bookkeeping


def test_estimate_from_values_matches_numpy():
    x = np.random.default_rng(0).normal(size=(1001, 3)) * [1.0, 10.0, 0.1] + [0.0, 5.0, -2.0]
    est = estimate_from_values(jnp.asarray(x, jnp.float32))
    assert est.mean.shape == est.stderr.shape == (3,) and int(est.n) == 1001
    # float32 storage of the data (relative 6e-8) bounds the agreement.
    np.testing.assert_allclose(est.mean, x.mean(0), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(est.variance, x.var(0, ddof=1), rtol=1e-5)
    np.testing.assert_allclose(est.stderr, x.std(0, ddof=1) / np.sqrt(1001), rtol=1e-5)


def test_single_sample_has_unknown_error_and_bad_n_raises():
    est = estimate_from_values(jnp.asarray([2.0]))
    assert float(est.mean) == 2.0 and np.isinf(float(est.stderr))
    with pytest.raises(ValueError, match="at least one sample"):
        estimate_from_values(jnp.zeros((0,)))
    with pytest.raises(ValueError, match="scalar"):
        estimate_from_values(jnp.asarray(1.0))
    with pytest.raises(ValueError, match="at least one sample"):
        mc_estimate(lambda x: x[0], lambda u: u, lambda x: 1.0, jnp.zeros((0, 2)))


def test_integer_values_are_promoted():
    est = estimate_from_values(jnp.arange(10))
    assert est.mean.dtype == jnp.float32 and float(est.mean) == 4.5


def test_combine_equals_one_batch():
    x = jnp.asarray(np.random.default_rng(1).exponential(size=(3000, 2)), jnp.float32)
    full = estimate_from_values(x)
    parts = combine(estimate_from_values(x[:1500]), estimate_from_values(x[1500:]))
    assert int(parts.n) == 3000
    np.testing.assert_allclose(parts.mean, full.mean, rtol=1e-6)  # float32 round-off
    np.testing.assert_allclose(parts.m2, full.m2, rtol=1e-5)
    # The empty estimate is the identity, on either side.
    for e in (combine(estimate_zero((2,)), full), combine(full, estimate_zero((2,)))):
        np.testing.assert_array_equal(e.mean, full.mean)
        np.testing.assert_array_equal(e.m2, full.m2)
    # Stacked chunk estimates (10 chunks, odd levels padded) and a scan accumulate the same.
    chunks = jax.jit(jax.vmap(mc.estimate_from_values))(x.reshape(10, 300, 2))
    many = combine_many(chunks)
    np.testing.assert_allclose(many.mean, full.mean, rtol=1e-6)
    np.testing.assert_allclose(many.m2, full.m2, rtol=1e-5)
    step = lambda acc, c: (mc.combine(acc, mc.estimate_from_values(c)), None)
    run, _ = jax.jit(lambda x: jax.lax.scan(step, estimate_zero((2,)), x))(x.reshape(10, 300, 2))
    assert int(run.n) == 3000
    np.testing.assert_allclose(run.mean, full.mean, rtol=1e-6)
    np.testing.assert_allclose(run.stderr, full.stderr, rtol=1e-5)


def test_float32_stability_for_large_n():
    # 2^22 values 1000 + U[0,1): a naive running float32 sum loses ~8 bits; E[x²] − E[x]² loses
    # everything (1e6 vs a variance of 1/12). Pairwise two-pass keeps both accurate.
    rng = np.random.default_rng(2)
    x64 = 1000.0 + rng.random(1 << 22)
    est = estimate_from_values(jnp.asarray(x64, jnp.float32))
    x32 = x64.astype(np.float32).astype(np.float64)  # what the estimator actually sees
    assert abs(float(est.mean) - x32.mean()) < 2e-4  # 3 ulps of 1000 in float32 (6.1e-5 each)
    # Variance to 1%: the mean's own ~1e-4 error and float32 rounding of x − mean (ulp 6e-5).
    assert abs(float(est.variance) / x32.var(ddof=1) - 1) < 1e-2
    assert jax.jit(pairwise_sum)(jnp.ones(12345, jnp.float32)) == 12345
    # Stacked estimates report per-chunk errors.
    chunks = jax.jit(jax.vmap(mc.estimate_from_values))(
        jnp.asarray(x64[:4000], jnp.float32).reshape(4, -1))
    assert chunks.stderr.shape == (4,) and np.all(np.isfinite(chunks.stderr))


# --------------------------------------------------------------------------- unbiasedness

N = 1 << 17


def test_polynomial_1d():
    # ∫_0^1 (3x² + 2x + 1) dx = 3, with x = u (pdf 1).
    est = mc_estimate(lambda x: 3 * x * x + 2 * x + 1, lambda u: u[0],
                      lambda x: jnp.ones_like(x), variates(N))
    check_unbiased(est, 3.0)


@pytest.mark.parametrize("k", [1, 2, 5])
def test_cos_power_over_hemisphere(k):
    # ∫_{H²} cos^k θ dω = 2π / (k + 1), with uniform hemisphere sampling.
    est = mc_estimate(lambda w: w[2] ** k, warp.square_to_uniform_hemisphere,
                      warp.square_to_uniform_hemisphere_pdf, variates(N, pixel=k))
    check_unbiased(est, 2 * np.pi / (k + 1))


def test_disk_area_and_second_moment():
    u = variates(N, pixel=7)
    # Area: f = 1, f/p = π for every sample (zero variance).
    area = mc_estimate(lambda p: jnp.ones_like(p[0]), warp.square_to_uniform_disk,
                       warp.square_to_uniform_disk_pdf, u)
    check_unbiased(area, np.pi)
    # ∫_{disk} x² dA = ∫∫ r² cos²φ r dr dφ = π/4.
    est = mc_estimate(lambda p: p[0] ** 2, warp.square_to_uniform_disk,
                      warp.square_to_uniform_disk_pdf, u)
    check_unbiased(est, np.pi / 4)


def test_triangle_integral():
    p = jnp.asarray([[0.5, -1.0], [3.0, 0.5], [-0.5, 2.0]], jnp.float32)
    area = 0.5 * abs(float(jnp.cross(p[1] - p[0], p[2] - p[0])))

    def sample(u):
        b = warp.square_to_uniform_triangle(u)
        return (1 - b[0] - b[1]) * p[0] + b[0] * p[1] + b[1] * p[2]

    # Barycentric density 2 over a parameter triangle of area 1/2 → 1/area on the triangle.
    pdf = lambda x: jnp.asarray(1 / area, x.dtype)
    est = mc_estimate(lambda x: x[0] ** 2, sample, pdf, variates(N, pixel=9))
    x0, x1, x2 = np.asarray(p[:, 0], float)
    # ∫_T x² dA = area/6 · (x0² + x1² + x2² + x0 x1 + x0 x2 + x1 x2) (exact for quadratics).
    exact = area / 6 * (x0**2 + x1**2 + x2**2 + x0 * x1 + x0 * x2 + x1 * x2)
    check_unbiased(est, exact)


def test_vector_valued_integrand():
    # An RGB integrand: ∫_0^1 (1, x, x²) dx = (1, 1/2, 1/3).
    est = mc_estimate(lambda x: jnp.stack([jnp.ones_like(x), x, x * x]), lambda u: u[0],
                      lambda x: jnp.ones_like(x), variates(N, pixel=11))
    assert est.mean.shape == (3,)
    for c, exact in enumerate((1.0, 0.5, 1 / 3)):
        check_unbiased(Estimate(est.mean[c], est.m2[c], est.n), exact)


def test_zero_pdf_terms_are_zero_not_nan():
    # A sampler that sometimes lands where its pdf is zero: those terms count as 0, never NaN.
    est = mc_estimate(lambda x: x, lambda u: u[0], lambda x: jnp.where(x < 0.5, 0.0, 1.0),
                      variates(1000))
    assert np.isfinite(float(est.mean)) and np.isfinite(float(est.stderr))


# --------------------------------------------------------------------------- importance sampling


def test_cosine_sampling_of_cosine_has_zero_variance():
    # f/p = cos θ / (cos θ / π) = π for every sample.
    est = mc_estimate(lambda w: w[2], warp.square_to_cosine_hemisphere,
                      warp.square_to_cosine_hemisphere_pdf, variates(N, pixel=3))
    assert abs(float(est.mean) / np.pi - 1) < 1e-6  # float32 round-off only
    assert float(est.stderr) <= 1e-6 * np.pi  # relative 1e-6: the spread is round-off


def test_uniform_sampling_of_cosine_has_the_predicted_stderr():
    # Under uniform hemisphere sampling cos θ ~ U[0, 1], so f/p = 2π cos θ has σ = 2π/√12.
    est = mc_estimate(lambda w: w[2], warp.square_to_uniform_hemisphere,
                      warp.square_to_uniform_hemisphere_pdf, variates(N, pixel=4))
    predicted = 2 * np.pi / np.sqrt(12 * N)
    # The sample σ̂ has relative spread √((κ − 1)/4N) ≈ 1e-3 here; 10% cannot be missed by luck.
    assert abs(float(est.stderr) / predicted - 1) < 0.1
    check_unbiased(est, np.pi)


# --------------------------------------------------------------------------- convergence


def test_error_falls_as_one_over_sqrt_n():
    # RMS error over 400 independent replicates (pixels) of ∫_0^1 (3x² + 2x + 1) dx = 3.
    pixels = jnp.arange(400, dtype=jnp.int32)
    f, sample, pdf = lambda x: 3 * x * x + 2 * x + 1, lambda u: u[0], lambda x: jnp.ones_like(x)
    ns = [2**e for e in range(6, 15, 2)]
    rms = []
    for n in ns:
        one = lambda px, n=n: mc.mc_estimate(f, sample, pdf, variates(n, px)).mean
        run = jax.jit(jax.vmap(one))
        rms.append(np.sqrt(np.mean((np.asarray(run(pixels), float) - 3.0) ** 2)))
    slope = np.polyfit(np.log(ns), np.log(rms), 1)[0]
    print(f"RMS-error slope: {slope:.3f}")
    # Theory −1/2; each RMS from 400 replicates is within ~3.5% so the fit is within ±0.03.
    assert abs(slope + 0.5) < 0.1


# --------------------------------------------------------------------------- dtypes


def test_dtypes(x64):
    dtype = jnp.float64 if x64 else jnp.float32
    est = mc_estimate(lambda w: w[2], warp.square_to_uniform_hemisphere,
                      warp.square_to_uniform_hemisphere_pdf, variates(4096))
    assert est.mean.dtype == est.m2.dtype == est.stderr.dtype == dtype
    assert est.n.dtype == jnp.int32
    check_unbiased(est, np.pi)
