"""The Monte Carlo estimator ``F_N = 1/N Σ f(X_i) / p(X_i)`` with its standard error.

An :class:`Estimate` carries the sample mean, the sum of squared deviations ``M2`` and the
count ``n``; the standard error ``√(s² / n)`` with ``s² = M2 / (n − 1)`` is derived from them.
Estimates of the same quantity from independent batches merge exactly with :func:`combine`
(Chan, Golub & LeVeque 1979), so a render can accumulate chunk by chunk (``lax.scan`` from
:func:`estimate_zero`) and get the same answer as one big batch up to round-off.

Numerics: sums are pairwise (a tree of halvings, error ``O(ε log N)`` instead of ``O(ε N)``)
and the variance uses the two-pass formula ``Σ (x − mean)²``, both stable in float32.

Reference: Veach 1997, ch. 2; PBR book (4th ed.) §2.1–2.2.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array


class Estimate(NamedTuple):
    """A Monte Carlo estimate of a scalar or vector quantity (shape ``(...)``, e.g. ``(3,)``).

    Fields: ``mean`` (...) the sample mean; ``m2`` (...) ``Σ (x_i − mean)²``; ``n`` () int32
    sample count. Properties: ``variance`` (sample variance of one term, ``M2/(n−1)``) and
    ``stderr`` (standard error of the mean, ``√(variance / n)``); both ``inf`` when ``n < 2``.
    """

    mean: Array
    m2: Array
    n: Array

    def _count(self) -> Array:
        """``n`` as a float broadcastable against ``mean`` (also for stacked estimates)."""
        extra = self.mean.ndim - self.n.ndim
        return self.n.astype(self.mean.dtype).reshape(self.n.shape + (1,) * extra)

    @property
    def variance(self) -> Array:
        nf = self._count()
        ok = nf >= 2
        inf = jnp.asarray(jnp.inf, self.mean.dtype)
        return jnp.where(ok, self.m2 / jnp.where(ok, nf - 1, 1), inf)

    @property
    def stderr(self) -> Array:
        return jnp.sqrt(self.variance / jnp.maximum(self._count(), 1))


_BLOCK = 64  # leaf size of the summation tree


def pairwise_sum(x: Array) -> Array:
    """``Σ_i x_i`` over the leading axis by a tree of additions (error ``O(ε (B + log N))``).

    Leaves are blocks of ``B = 64`` values summed directly; the block sums are then added
    pairwise. The loop runs over the ``⌈log2 (N/B)⌉`` tree levels (static shapes), not samples.
    """
    n = x.shape[0]
    if n > _BLOCK:
        pad = -n % _BLOCK
        if pad:
            x = jnp.concatenate([x, jnp.zeros((pad,) + x.shape[1:], x.dtype)])
        x = jnp.sum(x.reshape((-1, _BLOCK) + x.shape[1:]), axis=1)
    while x.shape[0] > 1:
        if x.shape[0] % 2:
            x = jnp.concatenate([x, jnp.zeros_like(x[:1])])
        x = x[0::2] + x[1::2]
    return x[0]


def estimate_from_values(values: Array) -> Estimate:
    """Estimate from per-sample values ``values`` (N,) or (N, k): mean, ``M2`` and ``N``.

    ``mean = Σ x_i / N`` and ``M2 = Σ (x_i − mean)²`` (two-pass, pairwise sums). Raises
    ``ValueError`` when ``N ≤ 0``. Integer inputs are promoted to the default float dtype.
    """
    values = jnp.asarray(values)
    if values.ndim == 0:
        raise ValueError("values: expected shape (N,) or (N, k), got a scalar")
    n = values.shape[0]
    if n <= 0:
        raise ValueError(f"need at least one sample, got N = {n}")
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = values.astype(jnp.result_type(float))
    mean = pairwise_sum(values) / n
    m2 = pairwise_sum(jnp.square(values - mean))
    return Estimate(mean, m2, jnp.asarray(n, jnp.int32))


def mc_estimate(f: Callable, sample: Callable, pdf: Callable, u: Array) -> Estimate:
    """Importance-sampled estimate of ``∫ f(x) dμ(x)`` from variates ``u`` (N, d).

    ``X_i = sample(u_i)`` has density ``pdf(X_i)`` w.r.t. ``μ``; the terms are
    ``f(X_i) / pdf(X_i)``, taken as 0 where ``pdf == 0`` (such points are never drawn by a
    correct sampler, and this keeps NaN out). ``f``, ``sample`` and ``pdf`` are written for one
    sample and batched here with ``jax.vmap``; ``f`` may return a scalar or a (k,) vector.
    Raises ``ValueError`` when ``N ≤ 0``.
    """
    u = jnp.asarray(u)
    if u.ndim == 0 or u.shape[0] <= 0:
        raise ValueError(f"need at least one sample, got u of shape {u.shape}")

    def term(ui):
        x = sample(ui)
        p = pdf(x)
        fx = f(x)
        ok = p > 0
        # NaN-safe division: f/p only where the density is positive.
        return jnp.where(ok, fx / jnp.where(ok, p, jnp.ones_like(p)), jnp.zeros_like(fx))

    return estimate_from_values(jax.vmap(term)(u))


def estimate_zero(shape: tuple[int, ...] = (), dtype=None) -> Estimate:
    """The empty estimate (``n = 0``): the identity of :func:`combine`, to start a ``scan``."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    z = jnp.zeros(shape, dtype)
    return Estimate(z, z, jnp.asarray(0, jnp.int32))


def combine(a: Estimate, b: Estimate) -> Estimate:
    """Merge two estimates of the same quantity from independent samples (Chan et al. 1979).

    ``n = n_a + n_b``, ``δ = mean_b − mean_a``, ``mean = mean_a + δ n_b / n``,
    ``M2 = M2_a + M2_b + δ² n_a n_b / n``. Exact (up to round-off) versus one batch of all
    samples; either side may be empty (``n = 0``).
    """
    n = a.n + b.n
    dtype = jnp.result_type(a.mean, b.mean)
    # Counts of stacked estimates (B,) broadcast against means (B, k).
    expand = lambda c: c.astype(dtype).reshape(c.shape + (1,) * (a.mean.ndim - c.ndim))
    na, nb = expand(a.n), expand(b.n)
    nf = expand(n)
    nf = jnp.where(nf > 0, nf, jnp.ones((), dtype))
    delta = b.mean - a.mean
    mean = a.mean + delta * (nb / nf)
    m2 = a.m2 + b.m2 + jnp.square(delta) * (na * (nb / nf))
    return Estimate(mean, m2, n)


def combine_many(estimates: Estimate) -> Estimate:
    """Merge a stacked batch of estimates (leading axis ``B``) into one, pairwise."""
    while estimates.n.shape[0] > 1:
        if estimates.n.shape[0] % 2:
            pad = estimate_zero(estimates.mean.shape[1:], estimates.mean.dtype)
            estimates = jax.tree.map(lambda s, z: jnp.concatenate([s, z[None]]), estimates, pad)
        estimates = combine(jax.tree.map(lambda s: s[0::2], estimates),
                            jax.tree.map(lambda s: s[1::2], estimates))
    return jax.tree.map(lambda s: s[0], estimates)
