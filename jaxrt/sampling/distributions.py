"""Tabulated distributions sampled by the inversion method: discrete, 1D and 2D piecewise constant.

Each distribution is a NamedTuple of arrays (a pytree), built once on the host from a table of
non-negative values and then sampled inside ``jit``/``vmap`` by binary search in its CDF.
Kernels are written for one variate ``u``; batch them with ``jax.vmap``.

Tables are normalised in float64 on the host and stored in the dtype of the input (float32 by
default; float64 under ``jax_enable_x64`` when the input is float64). If a builder is called on
traced values (inside ``jit``) it computes the same tables in JAX without the host validation.

Zero-valued bins are never sampled: a zero bin ``i`` has ``cdf[i] == cdf[i + 1]``, and the search
``searchsorted(cdf, u, side="right") - 1`` returns the *last* index whose CDF value is ``<= u``,
which is always a bin with positive width because ``cdf[n] == 1 > u``.

Reference: Pharr, Jakob, Humphreys, *Physically Based Rendering* (4th ed.), §A.1 (the inversion
method) and §A.5 (PiecewiseConstant1D / 2D).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import device_array


class Discrete(NamedTuple):
    """A probability mass function over ``n`` items.

    Fields: ``pmf`` (n,) normalised weights; ``cdf`` (n + 1,) with ``cdf[0] = 0``, ``cdf[n] = 1``.
    """

    pmf: Array
    cdf: Array


class PiecewiseConstant1D(NamedTuple):
    """A piecewise-constant density on ``[lo, hi]`` with ``n`` equal bins.

    Fields: ``func`` (n,) the (unnormalised) bin values; ``cdf`` (n + 1,); ``integral`` () is
    ``Σ func_i (hi − lo) / n``; ``lo``, ``hi`` () the interval. The density is
    ``p(x) = func[i] / integral`` per unit length of ``[lo, hi]``.
    """

    func: Array
    cdf: Array
    integral: Array
    lo: Array
    hi: Array


class PiecewiseConstant2D(NamedTuple):
    """A piecewise-constant density on ``[0, 1]^2`` from a table ``f`` of shape ``(ny, nx)``.

    Orientation: ``f[j, i]`` is the value on the cell ``x ∈ [i/nx, (i+1)/nx)``,
    ``y ∈ [j/ny, (j+1)/ny)`` — rows are ``y`` (e.g. θ of an environment map, image row ``j``)
    and columns are ``x`` (e.g. φ). ``marginal`` is the 1D distribution of ``y`` (over rows);
    ``conditional`` is a batch of ``ny`` 1D distributions of ``x`` given the row (every field
    has a leading ``ny`` axis). ``integral`` is ``mean(f)``, the integral over the unit square.
    """

    marginal: PiecewiseConstant1D
    conditional: PiecewiseConstant1D
    integral: Array


# ---------------------------------------------------------------------------- host validation


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _float_dtype(x) -> jnp.dtype:
    """The float dtype tables are stored in: the input's if floating, else the default float."""
    dtype = jax.dtypes.canonicalize_dtype(x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype)
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


def _validate(values: np.ndarray, name: str, allow_all_zero: bool = False) -> None:
    """Raise ``ValueError`` naming the first non-finite or negative entry, or an all-zero table."""
    if values.size == 0:
        raise ValueError(f"{name}: empty table (need at least one entry)")
    bad = ~np.isfinite(values)
    if bad.any():
        idx = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(f"{name}: non-finite value {values[idx]} at index {idx}")
    neg = values < 0
    if neg.any():
        idx = tuple(int(k) for k in np.argwhere(neg)[0])
        raise ValueError(f"{name}: negative value {values[idx]} at index {idx}")
    if not allow_all_zero and not values.any():
        raise ValueError(f"{name}: all {values.size} values are zero (nothing to sample)")


def _cdf_rows(xp, f):
    """Normalised CDFs (…, n + 1) of the rows of ``f``; an all-zero row gets a uniform CDF."""
    n = f.shape[-1]
    csum = xp.cumsum(f, axis=-1)
    total = csum[..., -1:]
    # A zero row is never selected by its marginal but needs a valid CDF (as in pbrt).
    uniform = xp.arange(1, n + 1, dtype=f.dtype) / n
    cdf = xp.where(total > 0, csum / xp.where(total > 0, total, 1), uniform)
    zeros = xp.zeros(f.shape[:-1] + (1,), f.dtype)
    # Pin the last entry to exactly 1 so that every u < 1 falls inside some bin.
    return xp.concatenate([zeros, cdf[..., :-1], xp.ones_like(zeros)], axis=-1)


# ---------------------------------------------------------------------------------- discrete


def discrete_from_weights(w) -> Discrete:
    """Build a :class:`Discrete` distribution from non-negative weights ``w`` (n,).

    ``pmf_i = w_i / Σ_j w_j`` and ``cdf_k = Σ_{i<k} pmf_i``. Host-side validation raises
    ``ValueError`` naming the offending index for negative or non-finite weights and for an
    all-zero table. Accepts numpy or JAX arrays; tables take ``w``'s float dtype.
    """
    dtype = _float_dtype(w)
    if _is_traced(w):
        w = jnp.asarray(w, dtype)
        return Discrete(w / jnp.sum(w), _cdf_rows(jnp, w))
    w64 = np.asarray(w, np.float64)
    if w64.ndim != 1:
        raise ValueError(f"weights: expected a 1D array, got shape {w64.shape}")
    _validate(w64, "weights")
    return Discrete(device_array(w64 / w64.sum(), dtype), device_array(_cdf_rows(np, w64), dtype))


#: Up to this many bins, :func:`_find_bin` counts with unrolled compares (no loop, no gather).
UNROLLED_BINS = 16


def _find_bin(cdf: Array, u: Array) -> Array:
    """Index ``i`` with ``cdf[i] <= u < cdf[i+1]`` (int32), skipping zero-width bins.

    ``i = #{k ∈ [1, n) : cdf[k] ≤ u}``. Small tables count with ``n − 1`` unrolled compares,
    which fuse with their neighbours; larger ones use a binary search unrolled to ⌈log₂ n⌉
    steps. ``jnp.searchsorted``'s default method is a ``while`` loop inside every sample
    (one kernel boundary per light selection: the whole Cornell render ~1.2× slower).
    """
    n = cdf.shape[-1] - 1
    if cdf.ndim == 1 and n <= UNROLLED_BINS:
        i = jnp.zeros(jnp.shape(u), jnp.int32)
        for k in range(1, n):
            i = i + (cdf[k] <= u).astype(jnp.int32)
    else:
        i = jnp.searchsorted(cdf, u, side="right", method="scan_unrolled").astype(jnp.int32) - 1
    return jnp.clip(i, 0, n - 1)


def _one_minus_ulp(x: Array) -> Array:
    one = jnp.ones((), x.dtype)
    return jnp.nextafter(one, jnp.zeros_like(one))


def discrete_sample(dist: Discrete, u: Array) -> tuple[Array, Array, Array]:
    """Draw an index by inverting the CDF, and reuse ``u`` for further sampling.

    Returns ``(i, pmf_i, u_remapped)``: ``i`` int32 with ``cdf[i] <= u < cdf[i+1]``,
    ``pmf_i = dist.pmf[i]``, and ``u_remapped = (u − cdf[i]) / (cdf[i+1] − cdf[i])`` which is
    again uniform on ``[0, 1)`` given ``i`` (clamped below 1 so it can feed another warp).
    """
    u = jnp.asarray(u, dist.cdf.dtype)
    i = _find_bin(dist.cdf, u)
    lo, hi = dist.cdf[i], dist.cdf[i + 1]
    width = hi - lo
    # The selected bin has positive width (u < cdf[i+1]); the where only guards round-off.
    r = jnp.where(width > 0, (u - lo) / jnp.where(width > 0, width, 1), jnp.zeros_like(u))
    r = jnp.clip(r, jnp.zeros_like(r), _one_minus_ulp(r))
    return i, dist.pmf[i], r


def discrete_pmf(dist: Discrete, i: Array) -> Array:
    """Probability of index ``i``; 0 outside ``[0, n)``."""
    n = dist.pmf.shape[0]
    inside = (i >= 0) & (i < n)
    return jnp.where(inside, dist.pmf[jnp.clip(i, 0, n - 1)], jnp.zeros((), dist.pmf.dtype))


# ------------------------------------------------------------------------- piecewise 1D


def pc1d_from_values(f, lo: float = 0.0, hi: float = 1.0) -> PiecewiseConstant1D:
    """Build a :class:`PiecewiseConstant1D` on ``[lo, hi]`` from bin values ``f`` (n,) ≥ 0.

    ``p(x) = f_i / I`` for ``x`` in bin ``i``, with ``I = Σ f_i (hi − lo) / n``. Raises
    ``ValueError`` for negative, non-finite or all-zero values, or ``hi <= lo``.
    """
    dtype = _float_dtype(f)
    if _is_traced(f):
        f = jnp.asarray(f, dtype)
        n = f.shape[-1]
        integral = jnp.sum(f, axis=-1) * (hi - lo) / n
        lo_a, hi_a = jnp.full(f.shape[:-1], lo, dtype), jnp.full(f.shape[:-1], hi, dtype)
        return PiecewiseConstant1D(f, _cdf_rows(jnp, f), integral, lo_a, hi_a)
    f64 = np.asarray(f, np.float64)
    if f64.ndim != 1:
        raise ValueError(f"values: expected a 1D array, got shape {f64.shape}")
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise ValueError(f"interval: need finite lo < hi, got [{lo}, {hi}]")
    _validate(f64, "values")
    return _pc1d_host(f64, lo, hi, dtype)


def _pc1d_host(f64: np.ndarray, lo: float, hi: float, dtype) -> PiecewiseConstant1D:
    """Tables in float64 for ``f64`` (…, n) (rows may be all zero), cast to ``dtype``."""
    n = f64.shape[-1]
    integral = f64.sum(axis=-1) * (hi - lo) / n
    batch = f64.shape[:-1]
    return PiecewiseConstant1D(
        device_array(f64, dtype), device_array(_cdf_rows(np, f64), dtype),
        device_array(integral, dtype), device_array(np.full(batch, lo), dtype),
        device_array(np.full(batch, hi), dtype))


def pc1d_sample(d: PiecewiseConstant1D, u: Array) -> tuple[Array, Array, Array]:
    """Invert the piecewise-linear CDF: ``x = lo + (i + (u − cdf_i)/(cdf_{i+1} − cdf_i)) Δ``.

    Returns ``(x, pdf, i)``: the point in ``[lo, hi)``, its density ``func[i] / integral`` per
    unit length, and the bin index (int32). Zero-valued bins are never returned.
    """
    u = jnp.asarray(u, d.cdf.dtype)
    n = d.func.shape[-1]
    i, _, du = discrete_sample(Discrete(d.func, d.cdf), u)
    x = d.lo + (i.astype(u.dtype) + du) * ((d.hi - d.lo) / n)
    # Round-off can push x onto a neighbouring (maybe zero) bin: step back by ulps until
    # the bin lookup of pc1d_pdf agrees, so pdf(x) is always the pdf returned here.
    for _ in range(3):
        j, _, _ = _bin_of(d, x)
        x = jnp.where(j > i, jnp.nextafter(x, d.lo), jnp.where(j < i, jnp.nextafter(x, d.hi), x))
    x = jnp.minimum(x, jnp.nextafter(d.hi, d.lo))
    return x, d.func[i] / d.integral, i


def _bin_of(d: PiecewiseConstant1D, x: Array) -> tuple[Array, Array, Array]:
    """Bin index of ``x``, its fractional position in the bin, and whether ``x ∈ [lo, hi]``."""
    n = d.func.shape[-1]
    t = (x - d.lo) / (d.hi - d.lo) * n
    i = jnp.clip(jnp.floor(t).astype(jnp.int32), 0, n - 1)
    inside = (x >= d.lo) & (x <= d.hi)
    return i, t - i.astype(t.dtype), inside


def pc1d_pdf(d: PiecewiseConstant1D, x: Array) -> Array:
    """Density ``func[i] / integral`` at ``x`` (per unit length of ``[lo, hi]``); 0 outside."""
    x = jnp.asarray(x, d.func.dtype)
    i, _, inside = _bin_of(d, x)
    return jnp.where(inside, d.func[i] / d.integral, jnp.zeros_like(x))


def pc1d_to_square(d: PiecewiseConstant1D, x: Array) -> Array:
    """The CDF at ``x``, inverse of :func:`pc1d_sample`: ``u = cdf_i + t (cdf_{i+1} − cdf_i)``."""
    x = jnp.asarray(x, d.func.dtype)
    i, t, _ = _bin_of(d, x)
    t = jnp.clip(t, jnp.zeros_like(t), jnp.ones_like(t))
    return d.cdf[i] + t * (d.cdf[i + 1] - d.cdf[i])


# ------------------------------------------------------------------------- piecewise 2D


def pc2d_from_values(f) -> PiecewiseConstant2D:
    """Build a :class:`PiecewiseConstant2D` on ``[0, 1]^2`` from a table ``f`` (ny, nx) ≥ 0.

    ``p(x, y) = f[j, i] / mean(f)`` per unit area, factored as ``p(y) p(x | y)`` with the
    marginal over rows ``p(y) ∝ Σ_i f[j, i]`` and the conditional along each row. Rows that are
    all zero are allowed (never sampled); raises ``ValueError`` for negative, non-finite or
    all-zero tables. For an environment map in latitude–longitude layout, multiply each row by
    ``sin θ_j`` before building, so that the density is proportional to radiance × solid angle.
    """
    dtype = _float_dtype(f)
    if _is_traced(f):
        f = jnp.asarray(f, dtype)
        cond = pc1d_from_values(f)
        return PiecewiseConstant2D(pc1d_from_values(cond.integral), cond, jnp.mean(f))
    f64 = np.asarray(f, np.float64)
    if f64.ndim != 2:
        raise ValueError(f"values: expected a 2D array (ny, nx), got shape {f64.shape}")
    _validate(f64, "values")
    cond = _pc1d_host(f64, 0.0, 1.0, dtype)
    marginal = _pc1d_host(f64.mean(axis=1), 0.0, 1.0, dtype)
    return PiecewiseConstant2D(marginal, cond, device_array(f64.mean(), dtype))


def _row(d: PiecewiseConstant2D, j: Array) -> PiecewiseConstant1D:
    return jax.tree.map(lambda a: a[j], d.conditional)


def pc2d_sample(d: PiecewiseConstant2D, u: Array) -> tuple[Array, Array]:
    """Sample ``(x, y)`` in ``[0, 1)^2``: ``u[1]`` picks the row ``y`` from the marginal, then
    ``u[0]`` picks ``x`` from that row's conditional (as pbrt's ``PiecewiseConstant2D``).

    Returns ``(xy (2,), pdf)`` with ``pdf = p(y) p(x | y) = f[j, i] / mean(f)`` per unit area.
    """
    u = jnp.asarray(u, d.integral.dtype)
    y, _, j = pc1d_sample(d.marginal, u[1])
    row = _row(d, j)
    x, _, i = pc1d_sample(row, u[0])
    # p(y) p(x | y) = f[j, i] / mean(f); computed directly so it equals pc2d_pdf bit for bit.
    return jnp.stack([x, y]), row.func[i] / d.integral


def pc2d_pdf(d: PiecewiseConstant2D, xy: Array) -> Array:
    """Density ``f[j, i] / mean(f)`` at ``xy = (x, y)`` per unit area of ``[0, 1]^2``; 0 outside."""
    xy = jnp.asarray(xy, d.integral.dtype)
    j, _, inside_y = _bin_of(d.marginal, xy[1])
    row = _row(d, j)
    i, _, inside_x = _bin_of(row, xy[0])
    zero = jnp.zeros((), xy.dtype)
    return jnp.where(inside_x & inside_y, row.func[i] / d.integral, zero)


def pc2d_to_square(d: PiecewiseConstant2D, xy: Array) -> Array:
    """Inverse of :func:`pc2d_sample`: ``(F_{x|y}(x), F_y(y))``."""
    xy = jnp.asarray(xy, d.integral.dtype)
    j, _, _ = _bin_of(d.marginal, xy[1])
    return jnp.stack([pc1d_to_square(_row(d, j), xy[0]), pc1d_to_square(d.marginal, xy[1])])
