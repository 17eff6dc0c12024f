"""Chi-square goodness-of-fit test of a sampler against its own pdf (public).

:func:`chi2_test` draws ``N`` seeded uniform points ``u``, warps them with ``sample_fn``,
histograms the results over a grid of cells of a domain (see :mod:`jaxrt.validation.domains`),
integrates ``pdf_fn`` over every cell by adaptive Gauss–Legendre cubature, pools the cells
with small expected counts, and compares observed with expected counts (Pearson's χ²) on the
2D table and on each 1D marginal, with a Šidák correction for the number of tables and tests.
It also checks that the pdf integrates to one, is finite and non-negative, that no sample
falls outside the domain, and that no sample falls where the pdf is zero.

Example — a uniform-disk sampler (polar map) and its pdf, each written for ONE point::

    >>> import jax.numpy as jnp
    >>> from jaxrt.validation.chi2 import chi2_test
    >>> def sample_disk(u):
    ...     r, phi = jnp.sqrt(u[0]), 2 * jnp.pi * u[1]
    ...     return jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi)])
    >>> def pdf_disk(p):
    ...     return jnp.where(p @ p <= 1, 1 / jnp.pi, 0.0).astype(p.dtype)
    >>> result = chi2_test(sample_disk, pdf_disk, "disk", num_samples=100_000,
    ...                    resolution=(40, 20))
    >>> result.passed
    True

A direction sampler that needs conditioning (a BSDF with a fixed ``wo``) is tested through
closures; directions live on the sphere in the BSDF's local frame::

    >>> wo = jnp.array([0.0, 0.6, 0.8])                       # doctest: +SKIP
    >>> chi2_test(lambda u: bsdf_sample(wo, u).wi,            # doctest: +SKIP
    ...           lambda wi: bsdf_pdf(wo, wi), "sphere", sample_dim=2)

References: Mitsuba 3 ``mitsuba.chi2`` and Nori's ``warptest`` (same idea: histogram vs the
integrated pdf with small-cell pooling); Šidák, "Rectangular confidence regions for the
means of multivariate normal distributions", JASA 1967.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from jaxrt.validation.domains import Domain, resolve_domain

# Cells with expected count below this are pooled (the usual validity rule of Pearson's χ²).
MIN_EXPECTED = 5.0
# A cell whose pdf integral is at most this (as a probability) is a zero-pdf cell.
ZERO_PROBABILITY = 1e-12
# Samples allowed in zero-pdf cells, as a fraction of N (float32 round-off at a boundary).
LEAK_FRACTION = 1e-5
# The pdf must integrate to one within this (plus the quadrature's own error estimate).
NORMALISATION_TOL = 1e-3
# Quadrature target per cell: this fraction of the cell's Poisson standard deviation.
QUAD_FRACTION_OF_SD = 0.01


class Chi2Table(NamedTuple):
    """One contingency table of the test (the 2D grid or a 1D marginal).

    ``observed`` and ``expected`` are the unpooled tables (counts); ``statistic``, ``dof`` and
    ``p_value`` are computed after dropping zero-pdf cells and pooling small cells.
    """

    name: str
    statistic: float
    dof: int
    p_value: float
    passed: bool
    observed: np.ndarray
    expected: np.ndarray
    num_pooled: int


class Chi2Result(NamedTuple):
    """Outcome of :func:`chi2_test`.

    Attributes:
        passed: overall verdict (every check and every table passed).
        statistic, dof, p_value: Pearson's χ² of the full table (2D, or 1D for intervals).
        observed, expected: full (n1, n2) tables of counts, expected = N ∫_cell pdf dμ.
        significance: per-table level after Šidák, ``1 − (1 − alpha)^(1/(tables·num_tests))``.
        messages: why it failed (empty when it passed), plus warnings.
        tables: every table tested: the full one, then the marginals over s1 and s2.
        integral: ∫ pdf dμ over the domain; quadrature_error: its estimated error.
        num_outside: samples outside the domain (NaN/inf included);
        num_leaked: samples in zero-pdf cells.
        num_samples, domain, axis_names: N, the domain's name and its cell axes.
    """

    passed: bool
    statistic: float
    dof: int
    p_value: float
    observed: np.ndarray
    expected: np.ndarray
    significance: float
    messages: list[str]
    tables: tuple[Chi2Table, ...]
    integral: float
    quadrature_error: float
    num_outside: int
    num_leaked: int
    num_samples: int
    domain: str
    axis_names: tuple[str, str] = ("s1", "s2")

    def summary(self) -> str:
        """A few lines: verdict, each table's χ², dof and p-value, and the messages."""
        lines = [
            f"chi2_test on {self.domain}: {'PASSED' if self.passed else 'FAILED'} "
            f"(N={self.num_samples}, grid {self.observed.shape}, per-table significance "
            f"{self.significance:.3g}, integral of pdf {self.integral:.6f} "
            f"± {self.quadrature_error:.1e})"
        ]
        for t in self.tables:
            lines.append(
                f"  {t.name:>18}: chi2={t.statistic:.1f} dof={t.dof} p={t.p_value:.3g} "
                f"pooled={t.num_pooled} {'ok' if t.passed else 'REJECTED'}"
            )
        lines += [f"  - {m}" for m in self.messages]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()


def sidak_significance(alpha: float, num_tests: int) -> float:
    """Per-test level so that ``num_tests`` independent tests have family-wise level alpha.

    ``α' = 1 − (1 − α)^(1/m)`` (Šidák 1967); slightly larger than Bonferroni's ``α / m``.
    """
    return 1.0 - (1.0 - alpha) ** (1.0 / num_tests)


def pool_cells(
    observed: np.ndarray, expected: np.ndarray, min_expected: float = MIN_EXPECTED
) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge every cell with expected count < ``min_expected`` into one pooled cell.

    Cells are sorted by expected count; all small ones are summed into a pool; if the pool
    itself is still below ``min_expected`` it absorbs the smallest remaining cell. Returns
    ``(observed, expected, num_pooled)`` as flat float64 arrays (pool last) and the number of
    original cells that went into the pool (0 when nothing was pooled).
    """
    obs = np.asarray(observed, np.float64).ravel()
    exp = np.asarray(expected, np.float64).ravel()
    order = np.argsort(exp, kind="stable")
    obs, exp = obs[order], exp[order]
    num_small = int(np.sum(exp < min_expected))
    if num_small == 0:
        return obs, exp, 0
    pool_o, pool_e = obs[:num_small].sum(), exp[:num_small].sum()
    rest_o, rest_e = obs[num_small:], exp[num_small:]
    num_pooled = num_small
    if pool_e < min_expected and rest_e.size > 0:
        # One big-enough cell is enough to lift the pool over the threshold.
        pool_o, pool_e = pool_o + rest_o[0], pool_e + rest_e[0]
        rest_o, rest_e = rest_o[1:], rest_e[1:]
        num_pooled += 1
    return np.append(rest_o, pool_o), np.append(rest_e, pool_e), num_pooled


def pearson_chi2(observed: np.ndarray, expected: np.ndarray) -> tuple[float, int, float]:
    """Pearson's ``χ² = Σ (O − E)² / E`` with ``dof = cells − 1`` and its p-value.

    Cells must already be pooled (every E > 0). The p-value is ``scipy.stats.chi2.sf``.
    """
    stat = float(np.sum((observed - expected) ** 2 / expected))
    dof = int(observed.size - 1)
    p_value = float(stats.chi2.sf(stat, dof)) if dof > 0 else 1.0
    return stat, dof, p_value


# ---------------------------------------------------------------------------------------------
# Histogram of samples
# ---------------------------------------------------------------------------------------------
# Samples are drawn in chunks of this many: one compilation of the generator per process.
SAMPLE_CHUNK = 1 << 17


@jax.jit(static_argnums=(1, 2, 3))
def _uniform_chunk(key, chunk: int, sample_dim: int, dtype):
    """``chunk`` uniform points of [0, 1)^sample_dim (threefry; compiled once per shape)."""
    return jax.random.uniform(key, (chunk, sample_dim), dtype)


def _cached(builder, *args):
    """``builder(*args)`` through its LRU cache, or uncached for unhashable callables."""
    try:
        return builder(*args)
    except TypeError:
        return builder.__wrapped__(*args)


@functools.lru_cache(maxsize=64)
def _cell_indexer(sample_fn, domain: Domain, n1: int, n2: int):
    """Jitted ``u (chunk, dim) -> cell index`` (n1·n2 marks outside); cached so that repeated
    tests of the same sampler (other seeds, sizes) compile nothing new."""
    num_cells = n1 * n2

    def cell_index(u):
        x = jnp.asarray(sample_fn(u))
        finite = jnp.all(jnp.isfinite(x))
        ok = finite & domain.in_domain(x)
        s = domain.to_cell_coords(jnp.where(finite, x, jnp.zeros_like(x)))
        # Points on the far edge (s == 1 up to round-off) belong to the last cell.
        i = jnp.clip(jnp.floor(s[0] * n1).astype(jnp.int32), 0, n1 - 1)
        j = jnp.clip(jnp.floor(s[1] * n2).astype(jnp.int32), 0, n2 - 1)
        return jnp.where(ok, i * n2 + j, num_cells)

    return jax.jit(jax.vmap(cell_index))


def _histogram(sample_fn, domain: Domain, shape, num_samples, sample_dim, seed, dtype):
    """Counts per cell (n1, n2) and the number of samples outside the domain."""
    n1, n2 = shape
    num_cells = n1 * n2
    chunk = SAMPLE_CHUNK
    num_chunks = -(-num_samples // chunk)
    cell_indices = _cached(_cell_indexer, sample_fn, domain, n1, n2)
    key = jax.random.key(seed)
    counts = np.zeros(num_cells + 1, np.int64)
    for c in range(num_chunks):  # a few chunks of 2^17 samples, not a loop over samples
        num_valid = min(chunk, num_samples - c * chunk)
        u = _uniform_chunk(jax.random.fold_in(key, c), chunk, sample_dim, dtype)
        idx = np.asarray(cell_indices(u))[:num_valid]
        counts += np.bincount(idx, minlength=num_cells + 1)
    return counts[:num_cells].reshape(n1, n2), int(counts[num_cells])


# ---------------------------------------------------------------------------------------------
# Adaptive cubature of the pdf over the cells
# ---------------------------------------------------------------------------------------------
def _rect_rule(order: int):
    """Gauss–Legendre nodes/weights on [0,1]^2: one k×k rule and the same on 2×2 quarters."""
    t, w = np.polynomial.legendre.leggauss(order)
    t, w = (t + 1) / 2, w / 2
    coarse_x = np.stack(np.meshgrid(t, t, indexing="ij"), -1).reshape(-1, 2)
    coarse_w = np.outer(w, w).ravel()
    fine_x = np.concatenate(
        [(coarse_x + np.array([a, b])) / 2 for a in (0, 1) for b in (0, 1)]
    )
    fine_w = np.tile(coarse_w, 4) / 4
    return coarse_x, coarse_w, fine_x, fine_w


@functools.lru_cache(maxsize=64)
def _make_rect_integrator(pdf_fn, domain: Domain, dtype, order: int, chunk: int):
    """Jitted ``rects (chunk, 4) -> (coarse, fine, min pdf, any non-finite)`` integrals."""
    coarse_x, coarse_w, fine_x, fine_w = (jnp.asarray(a, dtype) for a in _rect_rule(order))
    nodes = jnp.concatenate([coarse_x, fine_x])

    def integrand(rect, r):
        a, b, c, d = rect[0], rect[1], rect[2], rect[3]
        s1 = a + (b - a) * r[0]
        # Inside a support boundary s2 ≤ s2_max(s1), integrate s2 over [c, min(d, s2_max)].
        top = d if domain.s2_max is None else jnp.clip(domain.s2_max(s1), c, d)
        s2 = c + (top - c) * r[1]
        p = pdf_fn(domain.from_cell_coords(jnp.stack([s1, s2])))
        p = jnp.reshape(jnp.asarray(p), ())
        return p * (b - a) * (top - c), p

    def one_rect(rect):
        vals, p = jax.vmap(integrand, in_axes=(None, 0))(rect, nodes)
        k = coarse_x.shape[0]
        jac = jnp.asarray(domain.jacobian, dtype)
        coarse = jac * jnp.sum(vals[:k] * coarse_w)
        fine = jac * jnp.sum(vals[k:] * fine_w)
        return coarse, fine, jnp.min(p), jnp.any(~jnp.isfinite(p))

    return jax.jit(jax.vmap(one_rect)), chunk


def _integrate_cells(pdf_fn, domain: Domain, shape, num_samples, dtype, order=4,
                     max_depth=12, max_rects=1 << 21, chunk=1 << 13):
    """Probability of every cell, ``∫_cell pdf dμ``, by adaptive Gauss–Legendre cubature.

    Each rectangle is integrated with a k×k Gauss–Legendre rule and with the same rule on its
    four quarters; the difference estimates the coarse rule's error. Rectangles whose
    difference exceeds their share of the cell tolerance are split in four and redone.
    Tolerance: ``QUAD_FRACTION_OF_SD`` of the cell's Poisson standard deviation
    ``√max(N p, 1) / N`` (so quadrature error moves χ² negligibly), shared as ``2^-level``
    per rectangle (a kink or jump line crosses ~2^level rectangles of a cell at that level).
    Returns (probabilities (n1, n2) float64, total error estimate, min pdf, non-finite flag).
    """
    n1, n2 = shape
    integrate, chunk = _cached(_make_rect_integrator, pdf_fn, domain, dtype, order, chunk)
    e1, e2 = np.linspace(0, 1, n1 + 1), np.linspace(0, 1, n2 + 1)
    i, j = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    rects = np.stack([e1[i], e1[i + 1], e2[j], e2[j + 1]], -1).reshape(-1, 4)
    owner = np.arange(n1 * n2)
    prob, err = np.zeros(n1 * n2), np.zeros(n1 * n2)
    pmin, nonfinite, cell_tol = np.inf, False, None
    for level in range(max_depth + 1):
        coarse, fine = np.empty(len(rects)), np.empty(len(rects))
        for start in range(0, len(rects), chunk):  # fixed-size batches: one compilation
            part = rects[start:start + chunk]
            padded = np.zeros((chunk, 4))
            padded[: len(part)] = part
            c, f, m, bad = integrate(jnp.asarray(padded, dtype))
            coarse[start:start + len(part)] = np.asarray(c, np.float64)[: len(part)]
            fine[start:start + len(part)] = np.asarray(f, np.float64)[: len(part)]
            pmin = min(pmin, float(np.min(np.asarray(m)[: len(part)])))
            nonfinite |= bool(np.any(np.asarray(bad)[: len(part)]))
        if cell_tol is None:
            # Tolerance from the first estimate of each cell's probability.
            cell_tol = QUAD_FRACTION_OF_SD * np.sqrt(np.maximum(num_samples * fine, 1.0))
            cell_tol /= num_samples
        diff = np.abs(fine - coarse)
        done = diff <= cell_tol[owner] * 0.5**level
        last = level == max_depth or 4 * np.count_nonzero(~done) > max_rects
        if last:
            done[:] = True
        np.add.at(prob, owner[done], fine[done])
        np.add.at(err, owner[done], diff[done])
        if last or done.all():
            break
        # Split the unconverged rectangles into quarters.
        a, b, c, d = rects[~done].T
        mx, my = (a + b) / 2, (c + d) / 2
        rects = np.concatenate([np.stack(q, -1) for q in (
            (a, mx, c, my), (a, mx, my, d), (mx, b, c, my), (mx, b, my, d))])
        owner = np.tile(owner[~done], 4)
    return prob.reshape(n1, n2), float(err.sum()), pmin, nonfinite


# ---------------------------------------------------------------------------------------------
# The test
# ---------------------------------------------------------------------------------------------
def chi2_test(sample_fn, pdf_fn, domain, *, num_samples: int = 1_000_000,
              resolution=(101, 51), seed: int = 0, alpha: float = 0.01, num_tests: int = 1,
              sample_dim: int = 2) -> Chi2Result:
    """Pearson χ² test that ``sample_fn`` draws points distributed as ``pdf_fn``.

    Expected count of cell C: ``E_C = N ∫_C pdf dμ`` (μ the domain's measure: area on the
    square/disk/triangle, solid angle on the sphere/hemisphere, length on an interval),
    computed by adaptive Gauss–Legendre cubature in the domain's constant-Jacobian cell
    coordinates (see :mod:`jaxrt.validation.domains`). Cells with ``E < 5`` are pooled into one
    cell; zero-pdf cells are left out of χ² and checked separately. Tables tested: the full
    grid and, for 2D domains, the marginal over each axis (marginals catch small smooth biases
    that the full table dilutes over many cells). Each table is rejected when its p-value is
    below the Šidák level ``1 − (1 − alpha)^(1/(tables · num_tests))``.

    It also fails (with a message) when: any sample is outside the domain or non-finite; more
    than ``LEAK_FRACTION · N`` samples land in cells where the pdf integrates to zero;
    ``|∫ pdf dμ − 1| > NORMALISATION_TOL + quadrature error``; the pdf is negative or
    non-finite somewhere.

    Args:
        sample_fn: ``u`` (sample_dim,) in [0, 1) -> one point of the domain (see the table in
            :mod:`jaxrt.validation.domains`); vmapped and jitted here. ``u`` is float32 (float64
            under ``jax_enable_x64``), drawn with ``jax.random.uniform`` from ``seed``.
        pdf_fn: one point -> its density in the domain's measure (scalar).
        domain: "square", "disk", "sphere", "hemisphere", "triangle", "interval",
            ``("interval", lo, hi)`` or a :class:`jaxrt.validation.domains.Domain`.
        num_samples: N.
        resolution: cells along (s1, s2); an int means (n, n); 1D domains use the first.
        seed: seed of the uniform variates.
        alpha: family-wise significance level of this call (before ``num_tests``).
        num_tests: how many chi2_test calls the caller's family holds (Šidák over them too).
        sample_dim: dimension of ``u``.

    Returns:
        A :class:`Chi2Result`; ``str(result)`` is a readable summary.
    """
    dom = resolve_domain(domain)
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    shape = (int(res[0]), 1) if dom.dim == 1 else (int(res[0]), int(res[-1]))
    if min(shape) < 1 or num_samples < 1 or not 0 < alpha < 1 or num_tests < 1:
        raise ValueError(f"chi2_test needs resolution ≥ 1 (got {resolution}), num_samples ≥ 1 "
                         f"(got {num_samples}), 0 < alpha < 1 (got {alpha}) and num_tests ≥ 1 "
                         f"(got {num_tests})")
    dtype = jnp.zeros(()).dtype  # float32, or float64 under jax_enable_x64
    n = int(num_samples)
    messages: list[str] = []

    observed, num_outside = _histogram(sample_fn, dom, shape, n, sample_dim, seed, dtype)
    prob, quad_err, pmin, nonfinite = _integrate_cells(pdf_fn, dom, shape, n, dtype)
    expected = n * prob
    integral = float(prob.sum())

    if num_outside > 0:
        messages.append(f"{num_outside} of {n} samples are outside the {dom.name} domain "
                        "or not finite")
    if nonfinite:
        messages.append("pdf_fn returned NaN or inf inside the domain")
    if pmin < 0:
        messages.append(f"pdf_fn is negative somewhere (min {pmin:.3g})")
    if abs(integral - 1) > NORMALISATION_TOL + quad_err:
        messages.append(f"pdf integrates to {integral:.6f}, not 1 (tolerance "
                        f"{NORMALISATION_TOL:g} + quadrature error {quad_err:.1e})")
    zero = prob <= ZERO_PROBABILITY
    num_leaked = int(observed[zero].sum())
    if num_leaked > LEAK_FRACTION * n:
        messages.append(f"{num_leaked} samples fell in {int(zero.sum())} zero-pdf cells "
                        f"(allowance {LEAK_FRACTION:g}·N = {LEAK_FRACTION * n:g})")

    # The full table, then the marginal over each axis of a 2D domain.
    candidates = [("full " + "x".join(map(str, shape)), observed, expected, zero)]
    if dom.dim == 2:
        for axis, name in ((1, dom.axis_names[0]), (0, dom.axis_names[1])):
            e = expected.sum(axis)
            candidates.append((f"marginal {name}", observed.sum(axis), e,
                               e <= ZERO_PROBABILITY * n))
    significance = sidak_significance(alpha, len(candidates) * num_tests)
    tables = []
    for name, o, e, z in candidates:
        po, pe, num_pooled = pool_cells(o[~z], e[~z])
        stat, dof, p_value = pearson_chi2(po, pe)
        ok = dof > 0 and p_value >= significance
        if dof <= 0:
            messages.append(f"{name}: fewer than two cells after pooling; raise num_samples")
        elif not ok:
            messages.append(f"{name}: chi2={stat:.1f} with {dof} dof, p={p_value:.3g} < "
                            f"{significance:.3g}: samples do not follow the pdf")
        tables.append(Chi2Table(name, stat, dof, p_value, ok, o, e, num_pooled))

    passed = not messages
    if quad_err > 0.1 * math.sqrt(n) / n:
        messages.append(f"warning: pdf quadrature error estimate {quad_err:.1e} is large "
                        "(discontinuous pdf?)")
    main = tables[0]
    return Chi2Result(passed, main.statistic, main.dof, main.p_value, observed, expected,
                      significance, messages, tuple(tables), integral, quad_err,
                      num_outside, num_leaked, n, dom.name, dom.axis_names)


def plot_chi2(result: Chi2Result, path) -> None:
    """Write observed, expected and (O − E)/√E heat maps of ``result`` as a PNG at ``path``.

    Needs matplotlib (``pip install jaxrt[plot]``); imported here so jaxrt does not need it.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("plot_chi2 needs matplotlib: pip install 'jaxrt[plot]'") from exc
    obs, exp = result.observed.astype(np.float64), result.expected
    safe = np.where(exp > 0, exp, 1.0)
    resid = np.where(exp > 0, (obs - exp) / np.sqrt(safe), 0.0)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), constrained_layout=True)
    vmax = max(obs.max(), exp.max())
    lim = max(np.abs(resid).max(), 1e-9)
    panels = (("observed", obs, "viridis", 0, vmax), ("expected", exp, "viridis", 0, vmax),
              ("(O - E) / sqrt(E)", resid, "coolwarm", -lim, lim))
    for ax, (title, data, cmap, lo, hi) in zip(axes, panels, strict=True):
        im = ax.imshow(data.T, origin="lower", aspect="auto", cmap=cmap, vmin=lo, vmax=hi,
                       extent=(0, 1, 0, 1))
        ax.set_title(title)
        ax.set_xlabel(result.axis_names[0])
        ax.set_ylabel(result.axis_names[1])
        fig.colorbar(im, ax=ax)
    fig.suptitle(result.summary().splitlines()[0], fontsize=9)
    fig.savefig(path, dpi=100)
    plt.close(fig)
