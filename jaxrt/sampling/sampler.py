"""Stateless, counter-based sample streams: ``u = F(seed, pixel, index, dim)`` in ``[0, 1)``.

Every value is a pure function of four integers, computed with a handful of uint32 operations,
so a sample is the same whatever the batching, chunking or device count. Kernels are written for
one value; batch them with ``jax.vmap`` (or just pass broadcastable integer arrays: every
operation here is elementwise).

Three streams (:data:`SamplerName`):

- ``"independent"``: a hash of the four integers (the ``lowbias32`` integer finaliser of
  C. Wellons, chained so that for fixed (seed, pixel, dim) the map ``index ↦ hash`` is a
  bijection of uint32).
- ``"stratified"``: jittered stratification of ``spp`` samples per pixel. In 1D the unit
  interval has ``spp`` strata; in 2D (:func:`sample_2d`) an ``nx × ny`` grid with
  ``nx = ceil(√spp)``, ``ny = ceil(spp / nx)`` (exactly ``√spp × √spp`` when ``spp`` is a
  square). Sample ``index`` takes the stratum ``π(index mod spp)`` of a hashed permutation
  ``π`` (Kensler 2013, "Correlated Multi-Jittered Sampling") keyed by (seed, pixel, dim,
  index div spp), plus a hashed jitter. If the grid has more cells than ``spp`` a random subset
  is used — each sample is still uniform, so estimates stay unbiased.
- ``"sobol"``: *padded* Owen-scrambled Sobol (as pbrt-v4's ``PaddedSobolSampler``): dimension
  ``d`` is component ``d mod 2`` of the 2D Sobol (0,2)-sequence (van der Corput and the Pascal
  generator matrix), with the index shuffled per (seed, pixel, pair ``d div 2``) and each
  component nested-uniform scrambled per (seed, pixel, d). Scrambling and shuffling use the
  hash-based Owen scrambling of Burley 2020 ("Practical Hash-based Owen Scrambling", JCGT 9(4))
  with Vegdahl's improved Laine–Karras permutation. The first ``2^m`` indices of a pixel
  form a scrambled (0, m, 2)-net in every dimension pair ``(2k, 2k+1)``.

Floats: the top 24 bits of a uint32 ``h`` give ``u = (h >> 8) · 2^-24 ≤ 1 − 2^-24 < 1``, exact
in float32. The output dtype is JAX's default float (float32, or float64 under
``jax_enable_x64``); the *values* are the same multiples of ``2^-24`` in both modes.

Keys: every hash of a pixel's stream starts from ``pixel_key(seed, pixel) = H(pixel ^
H(seed))``. A loop over a pixel's samples forms it once and draws with :func:`keyed_1d` /
:func:`keyed_2d` (the same values as :func:`sample_1d` / :func:`sample_2d`); the render
passes do.
"""

from __future__ import annotations

import math
from typing import Literal

import jax
import jax.numpy as jnp
from jax import Array

SamplerName = Literal["independent", "stratified", "sobol"]
SAMPLERS: tuple[str, ...] = ("independent", "stratified", "sobol")

_U32 = jnp.uint32


def _u32(x) -> Array:
    """Cast integers (Python, int32, int64, uint32) to uint32 by wrapping modulo 2^32."""
    x = jnp.asarray(x)
    if x.dtype == _U32:
        return x
    # int64 → uint32 would be fine too, but int32 → uint32 must keep the bit pattern.
    return x.astype(jnp.int32 if x.dtype.itemsize <= 4 else x.dtype).astype(_U32)


def _c(v: int) -> Array:
    return jnp.asarray(v, _U32)


# ---------------------------------------------------------------------------- integer hashes


def lowbias32(x: Array) -> Array:
    """The ``lowbias32`` integer finaliser (C. Wellons, "Hash Prospector"): a uint32 bijection.

    ``x ^= x>>16; x *= 0x7feb352d; x ^= x>>15; x *= 0x846ca68b; x ^= x>>16``.
    """
    x = _u32(x)
    x = x ^ (x >> 16)
    x = x * _c(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * _c(0x846CA68B)
    return x ^ (x >> 16)


def pixel_key(seed, pixel) -> Array:
    """``H(pixel ^ H(seed))``: the part of every hash of a pixel's stream that depends on
    ``(seed, pixel)`` alone (uint32, the shape of ``pixel``).

    A loop over a pixel's samples computes it once, before the loop, and draws its variates
    with :func:`keyed_1d` / :func:`keyed_2d`: the same values as :func:`sample_1d` /
    :func:`sample_2d`, two hash rounds fewer per variate in the loop's program (the render
    passes do; what it saves: benchmarks/README.md#trace-once).
    """
    return lowbias32(_u32(pixel) ^ lowbias32(seed))


def keyed_hash(key, index, dim) -> Array:
    """``H(dim ^ H(index ^ key))`` for a :func:`pixel_key` ``key``: :func:`hash4`'s last two
    rounds."""
    return lowbias32(_u32(dim) ^ lowbias32(_u32(index) ^ _u32(key)))


def hash4(seed, pixel, index, dim) -> Array:
    """Hash of four integers to uint32: ``H(dim ^ H(index ^ H(pixel ^ H(seed))))``.

    Each step is a bijection of its innermost argument, so for fixed ``(seed, pixel, dim)``
    distinct indices give distinct hashes. Scalars (seed, dim) are hoisted by XLA.
    """
    return keyed_hash(pixel_key(seed, pixel), index, dim)


def uint_to_unit_float(h: Array) -> Array:
    """``(h >> 8) · 2^-24``: uint32 → ``[0, 1 − 2^-24]``, exact in float32 (never 1.0).

    The dtype is JAX's default float (float32; float64 under ``jax_enable_x64``).
    """
    dtype = jnp.result_type(float)
    return (_u32(h) >> 8).astype(jnp.int32).astype(dtype) * jnp.asarray(2.0**-24, dtype)


# ---------------------------------------------------------------------------- independent


def independent_1d(seed, pixel, index, dim) -> Array:
    """Independent uniform variate ``u ∈ [0, 1)`` for ``(seed, pixel, index, dim)``."""
    return _independent(pixel_key(seed, pixel), index, dim)


def _independent(key, index, dim) -> Array:
    return uint_to_unit_float(keyed_hash(key, index, dim))


# ---------------------------------------------------------------------------- stratified


def permute(i: Array, n: int, key: Array) -> Array:
    """A hashed permutation ``π_key`` of ``[0, n)`` evaluated at ``i`` (Kensler 2013, listing 3).

    A bijection on the enclosing power of two, iterated (cycle walking) until it lands in
    ``[0, n)`` — fewer than 2 rounds on average. ``n`` is static; ``i``, ``key`` uint32.
    """
    if n <= 1:
        return jnp.zeros_like(_u32(i))
    w = (1 << (n - 1).bit_length()) - 1  # mask of the enclosing power of two
    p = _u32(key)
    wc = _c(w)

    def round_(i):
        i = i ^ p
        i = i * _c(0xE170893D)
        i = i ^ (p >> 16)
        i = i ^ ((i & wc) >> 4)
        i = i ^ (p >> 8)
        i = i * _c(0x0929EB3F)
        i = i ^ (p >> 23)
        i = i ^ ((i & wc) >> 1)
        i = i * (_c(1) | (p >> 27))
        i = i * _c(0x6935FA69)
        i = i ^ ((i & wc) >> 11)
        i = i * _c(0x74DCB303)
        i = i ^ ((i & wc) >> 2)
        i = i * _c(0x9E501CC3)
        i = i ^ ((i & wc) >> 2)
        i = i * _c(0xC860A3DF)
        i = i & wc
        return i ^ (i >> 5)

    i = round_(_u32(i))
    i = jax.lax.while_loop(lambda i: jnp.any(i >= n), lambda i: jnp.where(i >= n, round_(i), i), i)
    return (i + p) % _c(n)


def _jittered(stratum: Array, jitter_hash: Array, n: int) -> Array:
    """``(stratum + ξ) / n`` clamped below 1 (the division may round up to 1.0)."""
    u = (stratum.astype(jnp.int32).astype(jnp.result_type(float)) + uint_to_unit_float(
        jitter_hash)) / n
    return jnp.minimum(u, jnp.nextafter(jnp.ones_like(u), jnp.zeros_like(u)))


def _stratum_key(pkey, index, dim, spp: int) -> tuple[Array, Array]:
    """Index within the current pass of ``spp`` samples, and the permutation key of that pass
    (``pkey``: the pixel's :func:`pixel_key`)."""
    index = _u32(index)
    pass_ = index // _c(spp)
    # A fresh permutation per pass of spp samples, so index ≥ spp keeps being stratified.
    key = keyed_hash(pkey, pass_ ^ _c(0xA511E9B3), dim)
    return index % _c(spp), key


def stratified_1d(seed, pixel, index, dim, spp: int) -> Array:
    """Jittered 1D stratum sample: ``(π(index mod spp) + ξ) / spp`` with hashed ``π`` and ``ξ``."""
    return _stratified_1d(pixel_key(seed, pixel), index, dim, spp)


def _stratified_1d(pkey, index, dim, spp: int) -> Array:
    k, key = _stratum_key(pkey, index, dim, spp)
    return _jittered(permute(k, spp, key), keyed_hash(pkey, index, dim), spp)


def _grid(spp: int) -> tuple[int, int]:
    nx = math.isqrt(spp)
    nx = nx if nx * nx == spp else nx + 1
    return nx, -(-spp // nx)


def stratified_2d(seed, pixel, index, dim, spp: int) -> Array:
    """Jittered 2D sample (2,) for dimensions ``(dim, dim + 1)`` on an ``nx × ny`` grid."""
    return _stratified_2d(pixel_key(seed, pixel), index, dim, spp)


def _stratified_2d(pkey, index, dim, spp: int) -> Array:
    nx, ny = _grid(spp)
    k, key = _stratum_key(pkey, index, dim, spp)
    cell = permute(k, nx * ny, key)
    return jnp.stack([_jittered(cell % _c(nx), keyed_hash(pkey, index, dim), nx),
                      _jittered(cell // _c(nx), keyed_hash(pkey, index, _u32(dim) + 1), ny)],
                     axis=-1)


# ---------------------------------------------------------------------------- Owen-scrambled Sobol


def reverse_bits(x: Array) -> Array:
    """Reverse the 32 bits of a uint32 (five swap stages)."""
    x = _u32(x)
    x = ((x >> 1) & _c(0x55555555)) | ((x & _c(0x55555555)) << 1)
    x = ((x >> 2) & _c(0x33333333)) | ((x & _c(0x33333333)) << 2)
    x = ((x >> 4) & _c(0x0F0F0F0F)) | ((x & _c(0x0F0F0F0F)) << 4)
    x = ((x >> 8) & _c(0x00FF00FF)) | ((x & _c(0x00FF00FF)) << 8)
    return (x >> 16) | (x << 16)


def _laine_karras(x: Array, seed: Array) -> Array:
    """A hashed permutation where output bit k depends only on input bits ≤ k (Vegdahl's
    improvement of Burley 2020, listing 5; as pbrt-v4's ``FastOwenScrambler``)."""
    x = x ^ (x * _c(0x3D20ADEA))
    x = x + seed
    x = x * ((seed >> 16) | _c(1))
    x = x ^ (x * _c(0x05526C56))
    return x ^ (x * _c(0x53A22864))


def owen_scramble(x: Array, seed: Array) -> Array:
    """Nested uniform (Owen) scramble of a 32-bit fixed-point fraction: reverse, LK, reverse."""
    return reverse_bits(_laine_karras(reverse_bits(x), _u32(seed)))


def _superset_xor(y: Array) -> Array:
    """Bit ``r`` of the result is the XOR of input bits ``j ⊇ r`` (GF(2) Möbius transform)."""
    for k, m in enumerate((0xAAAAAAAA, 0xCCCCCCCC, 0xF0F0F0F0, 0xFF00FF00, 0xFFFF0000)):
        y = y ^ ((y & _c(m)) >> (1 << k))
    return y


def sobol_2d_bits(index: Array) -> tuple[Array, Array]:
    """Bit-reversed 32-bit Sobol points of dims 0 and 1: ``(rev(x0), rev(x1))``.

    Dim 0 is the van der Corput sequence, ``x0 = rev(index)``. Dim 1 uses the Pascal matrix mod 2:
    digit ``r`` (weight ``2^-(r+1)``) is ``⊕_{j ⊇ r} index_j`` by Lucas' theorem. Returned
    bit-reversed because the Owen scramble works in that order.
    """
    index = _u32(index)
    return index, _superset_xor(index)


def sobol_1d(seed, pixel, index, dim) -> Array:
    """Padded Owen-scrambled Sobol value of dimension ``dim`` (component ``dim mod 2`` of pair
    ``dim div 2``), for ``(seed, pixel, index)``."""
    return _sobol_1d(pixel_key(seed, pixel), index, dim)


def _sobol_1d(pkey, index, dim) -> Array:
    dim = _u32(dim)
    pair, comp = dim >> 1, dim & _c(1)
    # Shuffle the index per (pixel, pair): decorrelates pixels and pairs, keeps nets intact.
    shuffled = owen_scramble(index, keyed_hash(pkey, 0x5BD1E995, pair))
    b0, b1 = sobol_2d_bits(shuffled)
    rev = jnp.where(comp == 0, b0, b1)
    # rev is already bit-reversed: scramble = rev(LK(rev(x))) = rev(LK(rev_bits_value)).
    x = reverse_bits(_laine_karras(rev, keyed_hash(pkey, 0x68E31DA4, dim)))
    return uint_to_unit_float(x)


# ---------------------------------------------------------------------------- renderer API


def _check(sampler: str, spp: int) -> None:
    if sampler not in SAMPLERS:
        raise ValueError(f"unknown sampler {sampler!r}; expected one of {SAMPLERS}")
    if not isinstance(spp, int) or spp <= 0:
        raise ValueError(f"spp must be a positive Python int, got {spp!r}")


def sample_1d(sampler: SamplerName, seed, pixel, index, dim, spp: int = 1) -> Array:
    """One variate ``u ∈ [0, 1)`` of stream ``sampler`` for ``(seed, pixel, index, dim)``.

    ``sampler`` and ``spp`` are static Python values (``spp`` only matters to ``"stratified"``);
    the integer arguments may be traced and broadcast elementwise. Returns the default float
    dtype (float32; float64 under x64).
    """
    return keyed_1d(sampler, pixel_key(seed, pixel), index, dim, spp)


def sample_2d(sampler: SamplerName, seed, pixel, index, dim, spp: int = 1) -> Array:
    """Two variates (…, 2) for dimensions ``(dim, dim + 1)``; draw pairs at even ``dim``.

    ``"stratified"`` stratifies the pair jointly on an ``nx × ny`` grid; ``"sobol"`` returns the
    pair's (0,2)-sequence when ``dim`` is even; ``"independent"`` two independent values.
    """
    return keyed_2d(sampler, pixel_key(seed, pixel), index, dim, spp)


def keyed_1d(sampler: SamplerName, key, index, dim, spp: int = 1) -> Array:
    """:func:`sample_1d` from the pixel's :func:`pixel_key` ``key = pixel_key(seed, pixel)``:
    the same variate, bit for bit; for loops over a pixel's samples, which compute the key
    once."""
    _check(sampler, spp)
    if sampler == "independent":
        return _independent(key, index, dim)
    if sampler == "stratified":
        return _stratified_1d(key, index, dim, spp)
    return _sobol_1d(key, index, dim)


def keyed_2d(sampler: SamplerName, key, index, dim, spp: int = 1) -> Array:
    """:func:`sample_2d` from the pixel's :func:`pixel_key` (as :func:`keyed_1d`)."""
    _check(sampler, spp)
    if sampler == "stratified":
        return _stratified_2d(key, index, dim, spp)
    d = _u32(dim)
    return jnp.stack([keyed_1d(sampler, key, index, d, spp),
                      keyed_1d(sampler, key, index, d + _c(1), spp)], axis=-1)
