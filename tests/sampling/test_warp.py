"""Contract suite for every warp in ``jaxrt.sampling.warp.REGISTRY``, driven by the registry.

Each (warp, parameter) case is checked for: chi-square fit of samples against its own pdf
(a cheap version by default, the full grid under ``slow``), pdf normalisation by quadrature,
samples inside the support with pdf > 0, inverse round trip, vmap == loop, jit == eager,
float32 preserved, agreement of float32 with x64, and finite in-support output at the
extreme variates u ∈ {0, 0.5, 1 − ulp}². The stability extremes and the spherical-triangle
corner cases are in ``tests/sampling/test_warp_extremes.py``.
"""

from __future__ import annotations

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.sampling import warp as W
from jaxrt.validation.chi2 import chi2_test
from jaxrt.validation.domains import Domain
from jaxrt.validation.gallery import registry_domain

CASES = [
    pytest.param(spec, params, id=f"{spec.name}-{i}")
    for spec in W.REGISTRY
    for i, params in enumerate(spec.params)
]
# one parameter value per warp for the default (fast) run; peaked lobes (Phong n=100,
# Beckmann α=0.1) need the slow run's finer grid, so the quick run takes a broader one
QUICK_INDEX = {"phong_lobe": 2, "ggx": 1, "beckmann": 1}
QUICK_CASES = [
    pytest.param(spec, spec.params[QUICK_INDEX.get(spec.name, 0)],
                 id=f"{spec.name}-{QUICK_INDEX.get(spec.name, 0)}")
    for spec in W.REGISTRY
]
# Spherical triangles whose edges cut the (φ, cos θ) grid at an angle leave sliver cells
# that the harness's cubature integrates to exactly 0 while a few samples land in them (it
# then reports a leak); those are checked by a two-sample test in test_warp_extremes.py.
# The tiny triangle (Ω ~ 1e-7 sr) lies inside one cell of any sphere grid.
REST_CASES = [
    pytest.param(spec, params, id=f"{spec.name}-{i}", marks=pytest.mark.slow)
    for spec in W.REGISTRY
    for i, params in enumerate(spec.params)
    if i != QUICK_INDEX.get(spec.name, 0)
]
# the contract runs on one parameter per warp by default and on all of them under slow
CONTRACT_CASES = QUICK_CASES + REST_CASES
CHI2_GRID_UNRESOLVED = {("spherical_triangle", 2), ("spherical_triangle", 3),
                        ("spherical_triangle", 4)}
# resolution (s1 = φ, s2 = cos θ) where the octant and wedge triangles' edges are cell edges
TRI_RESOLUTION = (64, 32)


def args_of(params, dtype):
    """Registry parameters (floats or nested float tuples) as arrays of ``dtype``."""
    return tuple(jnp.asarray(p, dtype) for p in params)


def sampler(spec, args):
    """``u`` (2,) → point; 1-D warps (the tent) read ``u[0]`` only."""
    if spec.dim == 1:
        return lambda u: spec.sample(u[0], *args)
    return lambda u: spec.sample(u, *args)


def pdf_of(spec, args):
    return lambda x: spec.pdf(x, *args)


def domain_of(spec) -> Domain:
    """Harness domain of a registry entry (``("square", lo, hi)`` built by the gallery)."""
    return registry_domain(spec)


def uniform(n, dtype, seed=0):
    """float32 variates cast to ``dtype``, so float32 and x64 runs see the same u."""
    return jax.random.uniform(jax.random.PRNGKey(seed), (n, 2), jnp.float32).astype(dtype)


def edge_grid(dtype):
    """All 9 combinations of u ∈ {0, 0.5, 1 − ulp}."""
    vals = jnp.asarray([0.0, 0.5, np.nextafter(np.asarray(1, dtype), 0)], dtype)
    return jnp.stack(jnp.meshgrid(vals, vals, indexing="ij"), -1).reshape(-1, 2)


def case_id(spec, params):
    return spec.name, spec.params.index(params)


# ----------------------------------------------------------------------- registry guard


def test_every_public_sampler_has_pdf_and_is_registered():
    registered = {spec.sample for spec in W.REGISTRY}
    samplers = [n for n, f in inspect.getmembers(W, inspect.isfunction)
                if n.startswith("square_to_") and not n.endswith("_pdf")]
    assert len(samplers) >= 15  # the API contract lists at least this many warps
    for name in samplers:
        assert hasattr(W, name + "_pdf"), f"{name} has no {name}_pdf"
        assert getattr(W, name) in registered, f"{name} is not in warp.REGISTRY"
    for spec in W.REGISTRY:
        assert spec.pdf is getattr(W, spec.sample.__name__ + "_pdf")
        assert len(spec.params) >= 1
        domain_of(spec)  # every domain name is known to the harness


# ------------------------------------------------------------------------ chi-square


def _chi2(spec, params, num_samples, resolution, seed=0):
    args = args_of(params, jnp.float32)
    if spec.name == "spherical_triangle":
        resolution = TRI_RESOLUTION
    return chi2_test(sampler(spec, args), pdf_of(spec, args), domain_of(spec),
                     num_samples=num_samples, resolution=resolution, seed=seed)


@pytest.mark.parametrize("spec, params", QUICK_CASES)
def test_chi2_quick(spec, params):
    # 2e5 samples on a coarse grid: a cheap fit check; each call holds alpha = 1% itself
    if case_id(spec, params) in CHI2_GRID_UNRESOLVED:
        pytest.skip("grid cannot resolve this case (see CHI2_GRID_UNRESOLVED)")
    result = _chi2(spec, params, 200_000, (40, 20))
    assert result.passed, str(result)


@pytest.mark.slow
@pytest.mark.parametrize("spec, params", CASES)
def test_chi2_full(spec, params):
    if case_id(spec, params) in CHI2_GRID_UNRESOLVED:
        pytest.skip("grid cannot resolve this case (see CHI2_GRID_UNRESOLVED)")
    result = _chi2(spec, params, 1_000_000, (101, 51), seed=1)
    assert result.passed, str(result)


def test_chi2_has_teeth():
    # a cosine sampler against the uniform pdf, and Phong n=10 against n=12: both must fail
    bad = chi2_test(W.square_to_cosine_hemisphere, W.square_to_uniform_hemisphere_pdf,
                    "hemisphere", num_samples=200_000, resolution=(40, 20))
    assert not bad.passed
    n10, n12 = jnp.float32(10), jnp.float32(12)
    bad = chi2_test(lambda u: W.square_to_phong_lobe(u, n10),
                    lambda v: W.square_to_phong_lobe_pdf(v, n12), "hemisphere",
                    num_samples=200_000, resolution=(40, 20))
    assert not bad.passed


# --------------------------------------------------------------- pdf normalisation


@pytest.mark.parametrize("spec, params", CONTRACT_CASES)
def test_pdf_integrates_to_one(spec, params, enable_x64):
    # midpoint rule in the harness's constant-Jacobian cell coordinates, in float64
    dom = domain_of(spec)
    args = args_of(params, jnp.float64)
    n1, n2 = (4000, 1) if dom.dim == 1 else (400, 2000)
    s1 = (jnp.arange(n1, dtype=jnp.float64) + 0.5) / n1
    s2 = (jnp.arange(n2, dtype=jnp.float64) + 0.5) / n2
    s = jnp.stack(jnp.meshgrid(s1, s2, indexing="ij"), -1).reshape(-1, 2)
    pdf = jax.jit(jax.vmap(lambda si: spec.pdf(dom.from_cell_coords(si), *args)))(s)
    total = float(jnp.sum(pdf)) * dom.jacobian / (n1 * n2)
    if case_id(spec, params) == ("spherical_triangle", 4):
        # Ω ~ 1e-7 sr is below one quadrature cell: the normalisation of the fallback is
        # checked as E[1/pdf] = Ω in test_warp_extremes.py instead
        assert total >= 0
        return
    # ±1e-3: the contract's bound; midpoint error on the discontinuous supports is < 2e-4
    assert abs(total - 1) < 1e-3, total


# ------------------------------------------------------------ the per-case contract

N_RANDOM, N_EDGE, N_ROUND = 4096, 9, 2048


def _contract_fn(spec, params, dtype):
    """One jitted, vmapped evaluation of everything the contract checks for one case."""
    args = args_of(params, dtype)
    samp = sampler(spec, args)
    dom = domain_of(spec)

    def one(u):
        x = samp(u)
        out = {"x": x, "pdf": spec.pdf(x, *args), "inside": dom.in_domain(x)}
        if spec.inverse is not None:
            u_back = spec.inverse(x, *args)
            out["u_back"] = u_back
            out["x_back"] = spec.sample(u_back, *args)  # scalar u for the 1-D tent
        return out

    return one, jax.jit(jax.vmap(one))


def _contract_u(dtype):
    # random u, the 9 extreme combinations, and u kept 1e-3 off the boundaries (where
    # inverses are many-to-one: the pole, the disk centre) for the round trip
    u_round = 1e-3 + (1 - 2e-3) * uniform(N_ROUND, dtype, seed=3)
    return jnp.concatenate([uniform(N_RANDOM, dtype), edge_grid(dtype), u_round])


def _check_contract(spec, params, dtype):
    one, batched = _contract_fn(spec, params, dtype)
    u = _contract_u(dtype)
    out = batched(u)
    x, pdf = out["x"], out["pdf"]
    rnd, edge = slice(0, N_RANDOM), slice(N_RANDOM, N_RANDOM + N_EDGE)
    rt = slice(N_RANDOM + N_EDGE, None)
    # float32 in -> float32 out (float64 under x64), right shapes
    assert x.dtype == dtype and pdf.dtype == dtype
    assert x.shape == ((u.shape[0],) if spec.dim == 1 else (u.shape[0], spec.dim))
    # finite and inside the domain everywhere, u = 0 and 1 − ulp included
    assert bool(jnp.all(jnp.isfinite(x))), np.asarray(u)[~np.all(np.isfinite(
        np.asarray(x).reshape(u.shape[0], -1)), 1)][:5]
    assert bool(jnp.all(out["inside"])), np.asarray(u)[~np.asarray(out["inside"])][:5]
    assert bool(jnp.all(jnp.isfinite(pdf) & (pdf >= 0)))
    # a random sample always has a positive density (else it could never be weighted)
    bad = ~np.asarray(pdf[rnd] > 0)
    assert not bad.any(), np.asarray(x[rnd])[bad][:5]
    if spec.inverse is None:
        return out
    assert out["u_back"].dtype == dtype
    assert bool(jnp.all(jnp.isfinite(out["u_back"][edge])))
    # round trip compared in the warped domain, x(u(x)) = x (the azimuth wraps, x does not):
    # ~1e3 ulps, the inverse trigonometry's amplification near the poles
    # (the spherical triangle included: measured ≤ 1.7e-6 in float32, 5e-15 in x64)
    tol = 1e3 * float(jnp.finfo(dtype).eps)
    err = float(jnp.max(jnp.abs(out["x_back"][rt] - x[rt])))
    assert err < tol, err
    # and u itself comes back for the typical point
    u_rt = u[rt, 0] if spec.dim == 1 else u[rt]
    du = jnp.abs(out["u_back"][rt] - u_rt)
    du = jnp.minimum(du, 1 - du)  # φ/2π is periodic
    assert float(jnp.median(du)) < 1e3 * float(jnp.finfo(dtype).eps)
    return out


# One bound for every warp. The spherical triangle's float32 samples are within 1.8e-6 of x64's
# for every registry triangle, small u₀ included (without the split sampler: up to 3.6e-3 rad
# for u₀ < 1e-3 near a hemisphere, 1.3e-4 elsewhere, which would need looser bounds here).
ATOL_F32 = 3e-5


@pytest.mark.parametrize("spec, params", CONTRACT_CASES)
def test_contract(spec, params):
    out32 = _check_contract(spec, params, jnp.float32)
    with jax.enable_x64(True):
        out64 = _check_contract(spec, params, jnp.float64)
        x64, d64 = np.asarray(out64["x"]), np.asarray(out64["pdf"])
    # float32 agrees with x64 on the same u: points to float32 resolution amplified by at most
    # ~100× by the warp's trigonometry; densities relatively except where float32 rounds a
    # point across a support edge
    atol = ATOL_F32
    rnd = slice(0, N_RANDOM)
    x32 = np.asarray(out32["x"])[rnd]
    x64 = x64[rnd]
    np.testing.assert_allclose(x32, x64, atol=atol)
    d32 = np.asarray(out32["pdf"])[rnd]
    rel = np.abs(d32 - d64[rnd]) / d64[rnd]
    assert np.quantile(rel, 0.99) < 1e-3, np.max(rel)
    # vmap equals a loop of jitted single samples, and jit equals eager
    # (the batched result is the first rows of the contract batch: no extra compile)
    one, _ = _contract_fn(spec, params, jnp.float32)
    u = uniform(3, jnp.float32)
    one_jit = jax.jit(one)
    x_loop = np.stack([np.asarray(one_jit(ui)["x"]) for ui in u])
    x_vmap = np.asarray(out32["x"])[:3]
    x_eager = np.asarray(one(u[0])["x"])
    # XLA fuses and vectorises float ops differently batched or not: a few ulps
    np.testing.assert_allclose(x_vmap, x_loop, rtol=2e-5, atol=max(atol, 2e-6))
    np.testing.assert_allclose(x_eager, x_loop[0], rtol=2e-5, atol=max(atol, 2e-6))
