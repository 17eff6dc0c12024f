"""Tests of the counter-based sample streams: uniformity, independence, determinism, convergence."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxrt.sampling import sampler as smp
from jaxrt.sampling.sampler import SAMPLERS, sample_1d, sample_2d

SEED = 1234
SPP = 64  # a square, so "stratified" uses an 8 × 8 grid
# Bonferroni: 1% over all chi-square tests of this file (3 kinds × (1D + 2D) × 4 cases).
ALPHA = 0.01 / (3 * 2 * 4)


@functools.partial(jax.jit, static_argnames=("sampler", "spp"))
def grid_2d(sampler, seed, pixels, indices, dim, spp):
    """u (P, S, 2) for every (pixel, index) pair of dimensions (dim, dim + 1)."""
    return sample_2d(sampler, seed, pixels[:, None], indices[None, :], dim, spp)


@functools.partial(jax.jit, static_argnames=("sampler", "spp"))
def grid_1d(sampler, seed, pixels, indices, dim, spp):
    return sample_1d(sampler, seed, pixels[:, None], indices[None, :], dim, spp)


def chi2_uniform_pvalue(u, bins):
    """Pearson chi-square p-value of the points u (n, d) against the uniform law on [0,1)^d."""
    counts, _ = np.histogramdd(np.asarray(u, float).reshape(len(u), -1), bins=bins,
                               range=[(0, 1)] * np.shape(u)[1])
    return stats.chisquare(counts.ravel()).pvalue


PIXEL_SETS = {"first": np.arange(64), "far": np.arange(10**6, 10**6 + 64)}


@pytest.mark.parametrize("sampler", SAMPLERS)
@pytest.mark.parametrize("pixels", PIXEL_SETS, ids=list(PIXEL_SETS))
@pytest.mark.parametrize("dim", [0, 4])
def test_uniformity_chi2(sampler, pixels, dim):
    # 64 pixels × 1024 indices: 65536 points, ~64 per cell of a 32 × 32 grid (and 1D, 256 bins).
    p = jnp.asarray(PIXEL_SETS[pixels], jnp.int32)
    idx = jnp.arange(1024, dtype=jnp.int32)
    u2 = np.asarray(grid_2d(sampler, SEED, p, idx, dim, SPP)).reshape(-1, 2)
    u1 = np.asarray(grid_1d(sampler, SEED, p, idx, dim + 1, SPP)).reshape(-1, 1)
    assert chi2_uniform_pvalue(u2, 32) > ALPHA  # Bonferroni-corrected 1% level
    assert chi2_uniform_pvalue(u1, 256) > ALPHA
    assert u2.min() >= 0 and u2.max() < 1 and u1.min() >= 0 and u1.max() < 1


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_cross_pair_uniformity_chi2(sampler):
    # Dimensions from two different pairs, (1, 2), must be jointly uniform too (padding works).
    p, idx = jnp.arange(64, dtype=jnp.int32), jnp.arange(1024, dtype=jnp.int32)
    a = grid_1d(sampler, SEED, p, idx, 1, SPP).ravel()
    b = grid_1d(sampler, SEED, p, idx, 2, SPP).ravel()
    assert chi2_uniform_pvalue(np.stack([a, b], -1), 32) > ALPHA


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_no_correlation_across_dimensions_and_pixels(sampler):
    p, idx = jnp.arange(256, dtype=jnp.int32), jnp.arange(256, dtype=jnp.int32)
    # (6, P, S)
    u = np.stack([np.asarray(grid_1d(sampler, SEED, p, idx, d, SPP)) for d in range(6)])
    n = u[0].size
    bound = 5 / np.sqrt(n)  # |r| of independent uniforms has standard deviation 1/√N
    for d in range(5):
        assert abs(np.corrcoef(u[d].ravel(), u[d + 1].ravel())[0, 1]) < bound, d
    # Per pixel, over its S indices, for every pair of dims (a per-pixel random sign would cancel
    # in the pooled r): under independence S·r² averages 1 (iid; less for stratified streams),
    # with spread √(2/P) ≈ 0.09 over P = 256 pixels; bound 2.
    s = u.shape[2]
    c = u - u.mean(axis=2, keepdims=True)
    c /= np.sqrt((c**2).sum(axis=2, keepdims=True))
    for a in range(6):
        for b in range(a + 1, 6):
            r = (c[a] * c[b]).sum(axis=1)  # (P,) per-pixel correlation
            assert s * np.mean(r**2) < 2.0, (a, b, s * np.mean(r**2))
    for d in (0, 3):
        # Pixel p against pixel p + 1 at the same index and dimension.
        r = np.corrcoef(u[d][:-1].ravel(), u[d][1:].ravel())[0, 1]
        assert abs(r) < 5 / np.sqrt(u[d][:-1].size), d
    if sampler == "independent":
        # Consecutive indices of one pixel are independent too. (Not so for stratified and
        # Sobol: strata drawn without replacement are negatively correlated by design.)
        r = np.corrcoef(u[0][:, :-1].ravel(), u[0][:, 1:].ravel())[0, 1]
        assert abs(r) < 5 / np.sqrt(u[0][:, :-1].size)


def test_never_one():
    top = jnp.asarray(0xFFFFFFFF, jnp.uint32)
    u = smp.uint_to_unit_float(top)
    assert u.dtype == jnp.float32 and float(u) == 1 - 2.0**-24 and float(u) < 1.0
    # The jittered stratum formula (stratum + ξ)/n rounds up to 1.0 without the clamp.
    for n in (1, 3, 7, 64, 1000, 4096, 12345):
        v = smp._jittered(jnp.asarray(n - 1, jnp.uint32), top, n)
        assert float(v) < 1.0, n
    for sampler in SAMPLERS:
        u = grid_1d(sampler, SEED, jnp.arange(64, dtype=jnp.int32),
                    jnp.arange(1024, dtype=jnp.int32), 0, SPP)
        assert float(u.max()) < 1.0


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_identical_whatever_the_batching(sampler):
    pixels = jnp.arange(8, dtype=jnp.int32) * 997
    idx = jnp.arange(500, dtype=jnp.int32)
    full = np.asarray(grid_2d(sampler, SEED, pixels, idx, 2, SPP))  # (8, 500, 2) broadcast
    # vmap over pixels, then indices (one sample per kernel call).
    one = lambda p, i: sample_2d(sampler, SEED, p, i, 2, SPP)
    nested = jax.jit(jax.vmap(jax.vmap(one, (None, 0)), (0, None)))(pixels, idx)
    np.testing.assert_array_equal(nested, full)
    # A flattened batch in chunks of 37 through lax.map (the renderer's tiling), reshaped.
    pp, ii = jnp.meshgrid(pixels, idx, indexing="ij")
    chunked = jax.jit(lambda a: jax.lax.map(lambda r: one(r[0], r[1]), a, batch_size=37))(
        jnp.stack([pp.ravel(), ii.ravel()], -1)).reshape(8, 500, 2)
    np.testing.assert_array_equal(chunked, full)


# Each stream's variates (in units of 2^-24) at seed 7, pixels (0, 1, 255, 65535, 123457) ×
# indices (0, 1, 31, 1000): dimension 3 (the first ten, and the sum of all twenty), and the sum
# of the forty of the pair at dimension 4, pinned: a seeded render is the same from version to
# version, however the hash is factored (pixel_key included).
STREAM_VALUES = {
    "independent": ([9864101, 9528448, 2886468, 10672499, 4013824, 9986541, 16638591, 9882960,
                     870402, 2131229], 187062705, 362388390),
    "stratified": ([14247994, 16324168, 3326132, 667031, 12833776, 10061343, 16768552, 617685,
                    6345856, 12716114], 154297754, 270952171),
    "sobol": ([1279431, 9224986, 9471253, 10574163, 14546606, 5785148, 5318527, 8294211,
               12832684, 932798], 154044572, 339407301),
}


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_streams_keep_their_values(sampler):
    pixels = jnp.array([0, 1, 255, 65535, 123457], jnp.int32)[:, None]
    idx = jnp.array([0, 1, 31, 1000], jnp.int32)[None, :]
    as_int = lambda u: np.round(np.asarray(u, np.float64) * 2**24).astype(np.int64)
    first, total, pair_total = STREAM_VALUES[sampler]
    one = as_int(sample_1d(sampler, 7, pixels, idx, 3, 16))
    assert one.ravel()[:10].tolist() == first
    assert int(one.sum()) == total
    assert int(as_int(sample_2d(sampler, 7, pixels, idx, 4, 16)).sum()) == pair_total
    # the same from the pixel's key, as a render pass draws them
    key = smp.pixel_key(7, pixels)
    np.testing.assert_array_equal(as_int(smp.keyed_1d(sampler, key, idx, 3, 16)), one)
    np.testing.assert_array_equal(smp.keyed_2d(sampler, key, idx, 4, 16),
                                  sample_2d(sampler, 7, pixels, idx, 4, 16))


def test_x64_output_dtype_and_same_values(enable_x64):
    # Same shapes as the uniformity test, so the float32 kernels come from the jit cache.
    p, idx = jnp.arange(64, dtype=jnp.int32), jnp.arange(1024, dtype=jnp.int32)
    for sampler in SAMPLERS:
        u64 = grid_2d(sampler, SEED, p, idx, 0, SPP)
        assert u64.dtype == jnp.float64
        with jax.enable_x64(False):
            u32 = grid_2d(sampler, SEED, p, idx, 0, SPP)
        assert u32.dtype == jnp.float32
        # The values are multiples of 2^-24 (or (k + ξ)/n): identical or within float32 rounding.
        np.testing.assert_allclose(u64, u32, rtol=0, atol=2e-7)


def test_float32_by_default():
    for sampler in SAMPLERS:
        assert sample_1d(sampler, 0, 0, 0, 0, 4).dtype == jnp.float32


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown sampler"):
        sample_1d("halton", 0, 0, 0, 0)
    with pytest.raises(ValueError, match="spp must be a positive"):
        sample_2d("stratified", 0, 0, 0, 0, 0)


# ------------------------------------------------------------------------- structure


@pytest.mark.parametrize("n", [1, 5, 64, 1000])
def test_permute_is_a_permutation(n):
    perm = jax.jit(smp.permute, static_argnums=1)
    for key in (0, 12345, 0xDEADBEEF):
        out = np.asarray(perm(jnp.arange(n, dtype=jnp.uint32), n, jnp.asarray(key, jnp.uint32)))
        np.testing.assert_array_equal(np.sort(out), np.arange(n))


@pytest.mark.parametrize("spp", [16, 64, 12])
def test_stratified_hits_every_stratum_once_per_pass(spp):
    idx = jnp.arange(2 * spp, dtype=jnp.int32)
    nx, ny = smp._grid(spp)
    for pixel in (0, 77):
        u1 = np.asarray(grid_1d("stratified", SEED, jnp.asarray([pixel]), idx, 0, spp))[0]
        u2 = np.asarray(grid_2d("stratified", SEED, jnp.asarray([pixel]), idx, 2, spp))[0]
        for sl in (slice(0, spp), slice(spp, 2 * spp)):  # two passes, each stratified
            np.testing.assert_array_equal(np.sort(np.floor(u1[sl] * spp)), np.arange(spp))
            cells = np.floor(u2[sl, 0] * nx) + nx * np.floor(u2[sl, 1] * ny)
            assert len(np.unique(cells)) == spp  # distinct cells of the nx × ny grid


def _sobol_reference(index, dim):
    """Unscrambled Sobol dims 0/1 from direction numbers (v_k = v_{k-1} ^ v_{k-1} >> 1)."""
    v = [1 << 31]
    for _ in range(31):
        v.append(v[-1] ^ (v[-1] >> 1) if dim else v[-1] >> 1)
    x = 0
    for k in range(32):
        if (index >> k) & 1:
            x ^= v[k]
    return x


def test_sobol_generator_matches_direction_numbers():
    idx = np.concatenate([np.arange(300), [2**20 + 5, 2**31 - 1, 2**32 - 1]]).astype(np.uint32)
    b0, b1 = smp.sobol_2d_bits(jnp.asarray(idx))
    got0 = np.asarray(smp.reverse_bits(b0))
    got1 = np.asarray(smp.reverse_bits(b1))
    np.testing.assert_array_equal(got0, [_sobol_reference(int(i), 0) for i in idx])
    np.testing.assert_array_equal(got1, [_sobol_reference(int(i), 1) for i in idx])


@pytest.mark.parametrize("dim", [0, 2, 6])
def test_sobol_pairs_are_scrambled_nets(dim):
    # The first 2^m samples of each pixel form a (0, m, 2)-net: one point per elementary interval.
    m = 8
    for pixel in (0, 4242):
        u = np.asarray(sample_2d("sobol", SEED, pixel, jnp.arange(2**m), dim))
        for a in range(m + 1):
            cx = np.floor(u[:, 0] * 2**a).astype(int)
            cy = np.floor(u[:, 1] * 2 ** (m - a)).astype(int)
            np.testing.assert_array_equal(np.bincount(cx * 2 ** (m - a) + cy, minlength=2**m), 1)


def test_owen_scramble_depends_only_on_leading_bits():
    # Nested scrambling: points sharing their first k bits still share them after scrambling.
    x = jnp.asarray(np.random.default_rng(0).integers(0, 2**32, 4096, dtype=np.uint32))
    y = x ^ jnp.uint32(0x0000FFFF)  # same leading 16 bits
    sx, sy = smp.owen_scramble(x, 99), smp.owen_scramble(y, 99)
    np.testing.assert_array_equal(np.asarray(sx) >> 16, np.asarray(sy) >> 16)
    assert np.mean(np.asarray(sx) != np.asarray(x)) > 0.99  # and it does scramble


# ------------------------------------------------------------------------- convergence

EXACT = (np.e - 1) ** 2  # ∫∫ exp(x + y) dx dy over [0,1]^2


@functools.partial(jax.jit, static_argnames=("sampler", "n"))
def _integrand(sampler, n, pixels):
    """f(u) = exp(u_0 + u_1) for indices 0..n−1 of every pixel (replicate): (P, n)."""
    u = sample_2d(sampler, SEED, pixels[:, None], jnp.arange(n, dtype=jnp.int32)[None, :], 0, n)
    return jnp.exp(u[..., 0] + u[..., 1])


def _mse_slope(sampler, exponents, replicates=512):
    """Log-log slope of the MSE of the N-sample estimate over ``replicates`` pixels."""
    pixels = jnp.arange(replicates, dtype=jnp.int32)
    ns = [2**e for e in exponents]
    if sampler == "stratified":
        # The strata depend on spp = N: one pattern per N.
        est = [np.asarray(_integrand(sampler, n, pixels), float).mean(1) for n in ns]
    else:
        # Independent and Sobol are sequences: the first N samples are the N-sample estimate
        # (for Sobol, the first 2^m form a net), so one compiled batch serves every N.
        f = np.asarray(_integrand(sampler, ns[-1], pixels), float)
        est = [f[:, :n].mean(1) for n in ns]
    mse = [np.mean((e - EXACT) ** 2) for e in est]
    return np.polyfit(np.log(ns), np.log(mse), 1)[0]


@pytest.fixture(scope="module")
def slopes():
    s = {"independent": _mse_slope("independent", range(4, 13)),
         "stratified": _mse_slope("stratified", range(4, 13, 2)),  # square sample counts
         "sobol": _mse_slope("sobol", range(4, 13))}
    print("MSE-vs-N slopes:", {k: round(float(v), 3) for k, v in s.items()})
    return s


def test_mse_slope_independent(slopes):
    # Plain Monte Carlo: MSE = σ²/N exactly in expectation; ±0.15 covers the 512-replicate noise.
    assert abs(slopes["independent"] + 1) < 0.15


def test_mse_slope_stratified(slopes):
    # Jittered 2D sampling of a smooth integrand: variance O(N^-2) (theory), at least −1.5.
    assert slopes["stratified"] < -1.5


def test_mse_slope_sobol(slopes):
    # Owen-scrambled (0,2)-sequence, smooth integrand: O(N^-3 log N) (Owen 1997); at least −2.
    assert slopes["sobol"] < -2.0
