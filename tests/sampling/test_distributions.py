"""Tests of the tabulated distributions: each sampler against its own pmf/pdf, inverses, edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxrt.sampling.distributions import (
    discrete_from_weights,
    discrete_pmf,
    discrete_sample,
    pc1d_from_values,
    pc1d_pdf,
    pc1d_sample,
    pc1d_to_square,
    pc2d_from_values,
    pc2d_pdf,
    pc2d_sample,
    pc2d_to_square,
)

# Bonferroni-corrected significance: 1% over the chi-square tests of this file.
NUM_CHI2_TESTS = 4
ALPHA = 0.01 / NUM_CHI2_TESTS
N = 200_000

WEIGHTS = np.array([0.0, 1.0, 0.0, 0.0, 3.0, 0.5, 2.0, 0.0, 0.25, 0.0])
VALUES_1D = np.array([2.0, 0.0, 0.0, 1.0, 5.0, 0.5, 0.0])
TABLE_2D = np.array([[1.0, 2.0, 0.0, 4.0, 0.5],
                     [0.0, 0.0, 0.0, 0.0, 0.0],
                     [3.0, 0.0, 1.0, 1.0, 2.0],
                     [0.2, 0.3, 6.0, 0.0, 1.0]])


# Jitted, vmapped kernels compiled once per table shape and reused by every test.
def _batched(fn):
    return jax.jit(jax.vmap(fn, in_axes=(None, 0)))


DISCRETE_SAMPLE = _batched(discrete_sample)
PC1D_SAMPLE, PC1D_PDF, PC1D_TO_SQUARE = map(_batched, (pc1d_sample, pc1d_pdf, pc1d_to_square))
PC2D_SAMPLE, PC2D_PDF, PC2D_TO_SQUARE = map(_batched, (pc2d_sample, pc2d_pdf, pc2d_to_square))


def uniforms(shape, seed=0):
    return jax.random.uniform(jax.random.key(seed), shape, jnp.float32)


def edge_variates(cdf):
    """u at every CDF value, one ulp either side, 0 and 1 − ulp (all clipped into [0, 1))."""
    c = np.asarray(cdf, np.float32)
    one = np.float32(1)
    u = np.concatenate([c, np.nextafter(c, np.float32(0)), np.nextafter(c, one),
                        [0, np.nextafter(one, np.float32(0))]]).astype(np.float32)
    return jnp.asarray(u[(u >= 0) & (u < 1)])


def chi2_pvalue(observed, expected):
    """Pearson chi-square p-value; cells with zero expected count must be empty."""
    observed, expected = np.asarray(observed, float), np.asarray(expected, float)
    zero = expected == 0
    assert observed[zero].sum() == 0, "samples landed where the pdf is zero"
    expected = expected[~zero] * observed.sum() / expected.sum()
    assert expected.min() >= 5, "cells too small for the chi-square approximation"
    return stats.chisquare(observed[~zero], expected).pvalue


def exact_cell_probabilities_1d(pdf_fn, lo, hi, n_bins, edges):
    """∫ pdf over each histogram cell, exactly: the pdf is constant between the union of edges."""
    pts = np.union1d(edges, np.linspace(lo, hi, n_bins + 1))
    mids = 0.5 * (pts[1:] + pts[:-1])
    mass = np.asarray(pdf_fn(jnp.asarray(mids, jnp.float32)), float) * np.diff(pts)
    cell = np.clip(np.searchsorted(edges, mids, side="right") - 1, 0, len(edges) - 2)
    return np.bincount(cell, weights=mass, minlength=len(edges) - 1)


# ---------------------------------------------------------------------------------- Discrete


def test_discrete_chi2_against_pmf():
    d = discrete_from_weights(WEIGHTS)
    idx, pmf, _ = DISCRETE_SAMPLE(d, uniforms((N,)))
    counts = np.bincount(np.asarray(idx), minlength=len(WEIGHTS))
    pmf_all = np.asarray(jax.jit(jax.vmap(discrete_pmf, (None, 0)))(d, jnp.arange(len(WEIGHTS))))
    # The returned pmf is the pmf of the returned index.
    np.testing.assert_array_equal(np.asarray(pmf), pmf_all[np.asarray(idx)])
    assert chi2_pvalue(counts, pmf_all) > ALPHA  # Bonferroni-corrected 1% level


def test_discrete_exact_frequencies_on_grid():
    # On a uniform grid of M variates, bin i receives pmf_i · M values up to ±1 (deterministic).
    d = discrete_from_weights(WEIGHTS)
    m = 1 << 16
    u = (jnp.arange(m, dtype=jnp.float32) + 0.5) / m
    counts = np.bincount(np.asarray(DISCRETE_SAMPLE(d, u)[0]),
                         minlength=len(WEIGHTS))
    assert np.all(np.abs(counts - WEIGHTS / WEIGHTS.sum() * m) <= 1)


def test_discrete_zero_bins_never_sampled_at_edges():
    d = discrete_from_weights(WEIGHTS)
    u = edge_variates(d.cdf)
    idx, pmf, ur = DISCRETE_SAMPLE(d, u)
    assert np.all(WEIGHTS[np.asarray(idx)] > 0)
    assert np.all(np.asarray(pmf) > 0)
    # Sample reuse stays in [0, 1), also at u = 1 − ulp.
    assert np.all((np.asarray(ur) >= 0) & (np.asarray(ur) < 1))


def test_discrete_sample_reuse_is_uniform():
    # Given the chosen bin, the remapped variate is uniform on [0, 1): KS test per bin.
    d = discrete_from_weights(WEIGHTS)
    idx, _, ur = DISCRETE_SAMPLE(d, uniforms((N,), 1))
    idx, ur = np.asarray(idx), np.asarray(ur)
    bins = np.flatnonzero(WEIGHTS)
    for i in bins:
        # Bonferroni over the non-zero bins, 1% overall.
        assert stats.kstest(ur[idx == i], "uniform").pvalue > 0.01 / len(bins)


def test_discrete_pmf_outside_is_zero():
    d = discrete_from_weights(WEIGHTS)
    assert float(discrete_pmf(d, -1)) == 0.0
    assert float(discrete_pmf(d, len(WEIGHTS))) == 0.0


@pytest.mark.parametrize(
    "w, message",
    [([0.0, 0.0, 0.0], "all 3 values are zero"),
     ([1.0, -2.0, 3.0], r"negative value -2.0 at index \(1,\)"),
     ([1.0, 2.0, np.nan], r"non-finite value nan at index \(2,\)"),
     ([np.inf, 2.0], r"non-finite value inf at index \(0,\)"),
     ([], "empty"),
     ([[1.0, 2.0]], "1D array")])
def test_discrete_bad_weights(w, message):
    with pytest.raises(ValueError, match=message):
        discrete_from_weights(np.asarray(w))


def test_discrete_builds_from_jax_and_integers():
    a = discrete_from_weights(np.asarray([1, 2, 3]))
    b = discrete_from_weights(jnp.asarray([1.0, 2.0, 3.0]))
    assert a.pmf.dtype == jnp.float32 and b.cdf.dtype == jnp.float32
    np.testing.assert_array_equal(a.cdf, b.cdf)
    np.testing.assert_allclose(a.pmf, [1 / 6, 2 / 6, 3 / 6], rtol=1e-7)  # float32 round-off


def test_discrete_traced_build_matches_host():
    host = discrete_from_weights(WEIGHTS.astype(np.float32))
    traced = jax.jit(discrete_from_weights)(jnp.asarray(WEIGHTS, jnp.float32))
    # Host tables are normalised in float64; float32 tracing differs by a few ulps at most.
    np.testing.assert_allclose(traced.cdf, host.cdf, rtol=0, atol=3e-7)
    np.testing.assert_allclose(traced.pmf, host.pmf, rtol=0, atol=3e-7)


# ----------------------------------------------------------------------- PiecewiseConstant1D


def test_pc1d_chi2_against_pdf_and_normalisation():
    lo, hi = -1.0, 3.0
    d = pc1d_from_values(VALUES_1D, lo, hi)
    x, pdf, _ = PC1D_SAMPLE(d, uniforms((N,), 2))
    x = np.asarray(x)
    assert np.all((x >= lo) & (x < hi))
    edges = np.linspace(lo, hi, 41)  # cells not aligned with the 7 bins
    expected = exact_cell_probabilities_1d(lambda x: PC1D_PDF(d, x), lo, hi, len(VALUES_1D), edges)
    # Exact integral of the pdf over [lo, hi] is 1 (float32 round-off only).
    assert abs(expected.sum() - 1) < 1e-6
    counts, _ = np.histogram(x, edges)
    assert chi2_pvalue(counts, expected) > ALPHA  # Bonferroni-corrected 1% level
    # The pdf returned with the sample equals the pdf function at the sample.
    np.testing.assert_array_equal(pdf, PC1D_PDF(d, jnp.asarray(x)))


def test_pc1d_pdf_values_and_support():
    d = pc1d_from_values(VALUES_1D, -1.0, 3.0)
    integral = VALUES_1D.sum() * 4.0 / len(VALUES_1D)
    np.testing.assert_allclose(float(d.integral), integral, rtol=1e-6)
    centres = -1.0 + (np.arange(len(VALUES_1D)) + 0.5) * 4.0 / len(VALUES_1D)
    got = PC1D_PDF(d, jnp.asarray(centres, jnp.float32))
    np.testing.assert_allclose(got, VALUES_1D / integral, rtol=1e-6)  # float32 round-off
    assert float(pc1d_pdf(d, -1.5)) == 0.0 and float(pc1d_pdf(d, 3.5)) == 0.0


def test_pc1d_zero_bins_never_sampled_at_edges():
    d = pc1d_from_values(VALUES_1D)
    x, pdf, idx = PC1D_SAMPLE(d, edge_variates(d.cdf))
    assert np.all(VALUES_1D[np.asarray(idx)] > 0)
    assert np.all(np.asarray(pdf) > 0)
    # The sample lies in the bin whose pdf it reports (round-off never crosses an edge).
    np.testing.assert_array_equal(PC1D_PDF(d, x), pdf)


def test_pc1d_inverse_round_trip():
    d = pc1d_from_values(VALUES_1D, -1.0, 3.0)
    u = uniforms((10_000,), 3)
    x, _, _ = PC1D_SAMPLE(d, u)
    back = PC1D_TO_SQUARE(d, x)
    # float32: x carries ~1 ulp of [−1, 3] (≈ 2.4e-7 absolute), amplified by the pdf ≤ 0.7.
    np.testing.assert_allclose(back, u, rtol=0, atol=2e-6)


@pytest.mark.parametrize("f, lo, hi, message", [
    ([0.0, 0.0], 0.0, 1.0, "all 2 values are zero"),
    ([1.0, -1.0], 0.0, 1.0, "negative"),
    ([1.0, np.nan], 0.0, 1.0, "non-finite"),
    ([1.0, 1.0], 1.0, 1.0, "lo < hi")])
def test_pc1d_bad_values(f, lo, hi, message):
    with pytest.raises(ValueError, match=message):
        pc1d_from_values(np.asarray(f), lo, hi)


# ----------------------------------------------------------------------- PiecewiseConstant2D


def exact_cell_probabilities_2d(d, shape, edges_x, edges_y):
    """∫ pdf over each histogram cell of an (ny_h, nx_h) grid, exact for a piecewise constant."""
    ny, nx = shape
    px = np.union1d(edges_x, np.linspace(0, 1, nx + 1))
    py = np.union1d(edges_y, np.linspace(0, 1, ny + 1))
    mx, my = 0.5 * (px[1:] + px[:-1]), 0.5 * (py[1:] + py[:-1])
    gx, gy = np.meshgrid(mx, my)
    pts = jnp.asarray(np.stack([gx.ravel(), gy.ravel()], -1), jnp.float32)
    pdf = np.asarray(PC2D_PDF(d, pts), float).reshape(gy.shape)
    mass = pdf * np.outer(np.diff(py), np.diff(px))
    cx = np.clip(np.searchsorted(edges_x, mx, side="right") - 1, 0, len(edges_x) - 2)
    cy = np.clip(np.searchsorted(edges_y, my, side="right") - 1, 0, len(edges_y) - 2)
    out = np.zeros((len(edges_y) - 1, len(edges_x) - 1))
    np.add.at(out, (cy[:, None], cx[None, :]), mass)
    return out


def test_pc2d_chi2_against_pdf_and_normalisation():
    d = pc2d_from_values(TABLE_2D)
    xy, pdf = PC2D_SAMPLE(d, uniforms((N, 2), 4))
    xy = np.asarray(xy)
    assert np.all((xy >= 0) & (xy < 1))
    ex, ey = np.linspace(0, 1, 13), np.linspace(0, 1, 11)  # not aligned with the 5 × 4 cells
    expected = exact_cell_probabilities_2d(d, TABLE_2D.shape, ex, ey)
    assert abs(expected.sum() - 1) < 1e-6  # pdf integrates to one (float32 round-off)
    counts, _, _ = np.histogram2d(xy[:, 1], xy[:, 0], [ey, ex])
    assert chi2_pvalue(counts.ravel(), expected.ravel()) > ALPHA  # Bonferroni-corrected 1%
    np.testing.assert_array_equal(pdf, PC2D_PDF(d, jnp.asarray(xy)))


def test_pc2d_orientation_and_pdf_values():
    # f[j, i] lives on x ∈ [i/nx, (i+1)/nx), y ∈ [j/ny, (j+1)/ny); pdf = f / mean(f).
    d = pc2d_from_values(TABLE_2D)
    ny, nx = TABLE_2D.shape
    gx, gy = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(ny) + 0.5) / ny)
    pts = jnp.asarray(np.stack([gx.ravel(), gy.ravel()], -1), jnp.float32)
    got = np.asarray(PC2D_PDF(d, pts)).reshape(ny, nx)
    np.testing.assert_allclose(got, TABLE_2D / TABLE_2D.mean(), rtol=1e-6)  # float32 round-off
    assert float(pc2d_pdf(d, jnp.asarray([1.5, 0.5]))) == 0.0
    assert float(pc2d_pdf(d, jnp.asarray([0.5, -0.1]))) == 0.0


def test_pc2d_zero_cells_never_sampled_at_edges():
    d = pc2d_from_values(TABLE_2D)
    ux = edge_variates(np.unique(np.asarray(d.conditional.cdf)))
    uy = edge_variates(d.marginal.cdf)
    u = jnp.stack(jnp.meshgrid(ux, uy), -1).reshape(-1, 2)
    xy, pdf = PC2D_SAMPLE(d, u)
    assert np.all(np.asarray(pdf) > 0)
    # The sample lies in the cell whose pdf it reports (round-off never crosses an edge).
    np.testing.assert_array_equal(PC2D_PDF(d, xy), pdf)


def test_pc2d_inverse_round_trip():
    d = pc2d_from_values(TABLE_2D)
    u = uniforms((10_000, 2), 5)
    xy, _ = PC2D_SAMPLE(d, u)
    back = PC2D_TO_SQUARE(d, xy)
    # float32 round-off of x ∈ [0, 1) (≤ 6e-8) times a conditional pdf ≤ 5, with margin.
    np.testing.assert_allclose(back, u, rtol=0, atol=2e-6)


def test_pc2d_bad_values():
    with pytest.raises(ValueError, match="all 4 values are zero"):
        pc2d_from_values(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"negative value -1.0 at index \(1, 0\)"):
        pc2d_from_values(np.array([[1.0, 1.0], [-1.0, 1.0]]))
    with pytest.raises(ValueError, match="2D array"):
        pc2d_from_values(np.ones(3))


def test_pc2d_traced_build_matches_host():
    host = pc2d_from_values(TABLE_2D.astype(np.float32))
    traced = jax.jit(pc2d_from_values)(jnp.asarray(TABLE_2D, jnp.float32))
    u = uniforms((10_000, 2), 6)
    a = PC2D_SAMPLE(host, u)
    b = PC2D_SAMPLE(traced, u)
    # float32 normalisation differs by ulps: a few samples move by ~1e-6 near bin edges.
    np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-5)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-5)


# ---------------------------------------------------------------------------- jit, vmap, dtypes


def test_vmap_equals_loop_and_jit_equals_eager():
    d1, d2 = pc1d_from_values(VALUES_1D), pc2d_from_values(TABLE_2D)
    u = uniforms((10_000, 2), 7)  # the round-trip test's shape: compiled once
    batched = PC2D_SAMPLE(d2, u)
    # Eager op-by-op execution is slow to dispatch: one sample is enough.
    eager = pc2d_sample(d2, u[0])
    # Compiled code may turn f / I into f · (1/I): allow 2 ulps (float32 ε = 1.19e-7).
    np.testing.assert_allclose(batched[0][0], eager[0], rtol=2.4e-7)
    np.testing.assert_allclose(batched[1][0], eager[1], rtol=2.4e-7)
    single = jax.jit(pc2d_sample)
    for k in range(4):
        np.testing.assert_allclose(single(d2, u[k])[0], batched[0][k], rtol=2.4e-7)
        np.testing.assert_allclose(single(d2, u[k])[1], batched[1][k], rtol=2.4e-7)
        np.testing.assert_allclose(jax.jit(pc1d_sample)(d1, u[k, 0])[0],
                                   PC1D_SAMPLE(d1, u[:, 0])[0][k], rtol=2.4e-7)


def test_float32_preserved():
    d1, d2, dd = pc1d_from_values(VALUES_1D), pc2d_from_values(TABLE_2D), discrete_from_weights(
        WEIGHTS)
    u = jnp.asarray([0.3, 0.7], jnp.float32)
    x, pdf, i = pc1d_sample(d1, u[0])
    assert x.dtype == pdf.dtype == pc1d_to_square(d1, x).dtype == jnp.float32
    assert i.dtype == jnp.int32
    xy, pdf2 = pc2d_sample(d2, u)
    assert xy.dtype == pdf2.dtype == pc2d_pdf(d2, xy).dtype == jnp.float32
    idx, pmf, ur = discrete_sample(dd, u[0])
    assert idx.dtype == jnp.int32 and pmf.dtype == ur.dtype == jnp.float32


def test_x64(x64):
    dtype = jnp.float64 if x64 else jnp.float32
    d2 = pc2d_from_values(TABLE_2D)  # float64 numpy in → float64 tables under x64
    assert d2.integral.dtype == dtype
    u = jax.random.uniform(jax.random.key(8), (N, 2), dtype)  # chi2 test's shape: cached
    xy, pdf = PC2D_SAMPLE(d2, u)
    assert xy.dtype == pdf.dtype == dtype
    back = PC2D_TO_SQUARE(d2, xy)
    # Round trip at the precision of the dtype (with margin for the pdf ≤ 5 amplification).
    np.testing.assert_allclose(back, u, rtol=0, atol=2e-6 if not x64 else 1e-13)
    # Monte Carlo mean of 1/pdf is the area of the support: E[1/p] = ∫_{p>0} dA = 12/20 cells.
    # Its variance is E[1/p²] − area² = ∫_{p>0} 1/p dA − area²; bound 5 standard errors.
    pos = TABLE_2D[TABLE_2D > 0]
    area = pos.size / TABLE_2D.size
    sigma = np.sqrt(np.sum(TABLE_2D.mean() / pos) / TABLE_2D.size - area**2)
    assert abs(float(jnp.mean(1 / pdf)) - area) < 5 * sigma / np.sqrt(len(u))


@pytest.mark.parametrize("n", [2, 5, 16, 17, 40])
def test_discrete_bin_search_both_forms_match_numpy(n):
    """Light selection counts with unrolled compares up to UNROLLED_BINS bins and an unrolled
    binary search beyond: both return numpy's ``searchsorted(cdf, u, 'right') − 1`` (clamped),
    zero-width bins skipped, also for u exactly on a CDF value and at 1 − ulp."""
    from jaxrt.sampling.distributions import UNROLLED_BINS

    assert (n <= UNROLLED_BINS) == (n in (2, 5, 16))  # both forms are exercised
    rng = np.random.default_rng(n)
    w = rng.uniform(0.1, 1.0, n)
    w[rng.choice(n, size=n // 3, replace=False)] = 0.0  # zero-width bins
    w[0] = max(w[0], 0.5)
    d = discrete_from_weights(w)
    cdf = np.asarray(d.cdf)
    # u in [0, 1): every CDF value below 1 (trailing zero bins put some at exactly 1)
    u = np.concatenate([rng.uniform(size=4096).astype(np.float32), cdf[cdf < 1],
                        [np.nextafter(np.float32(1), np.float32(0))]]).astype(np.float32)
    idx = np.asarray(DISCRETE_SAMPLE(d, u)[0])
    expect = np.clip(np.searchsorted(cdf, u, side="right") - 1, 0, n - 1)
    np.testing.assert_array_equal(idx, expect)
    assert np.all(w[idx] > 0)
