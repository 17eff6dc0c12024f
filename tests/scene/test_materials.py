"""Contract tests of the BSDFs, driven by one registry of (material, parameters) cases.

Each non-delta BSDF goes through the chi-square harness (its sampler against its own pdf,
over the whole sphere since the Phong lobe and the VNDF reflection can go below the
horizon), then through consistency checks (weight, pdf, reciprocity, white furnace), at
several outgoing angles including grazing ones.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.core.vecmath import dot, normalize, reflect, to_local
from jaxrt.sampling import warp
from jaxrt.scene import materials as mat
from jaxrt.validation.chi2 import chi2_test

# (id, factory): factories run inside the dtype context of the test (float32 or x64)
CASES = {
    "diffuse": lambda: mat.diffuse([0.7, 0.5, 0.2]),
    "phong-n1": lambda: mat.phong(0.3, 0.6, 1.0),
    "phong-n20": lambda: mat.phong([0.5, 0.2, 0.1], [0.4, 0.7, 0.2], 20.0),
    "phong-n1000": lambda: mat.phong(0.1, 0.8, 1000.0),
    "conductor-a0.05": lambda: mat.conductor(0.05, [0.9, 0.6, 0.3]),
    "conductor-a0.3": lambda: mat.conductor(0.3, 0.95),
    "conductor-a1": lambda: mat.conductor(1.0, 0.8),
    # Mitsuba 3's roughconductor: constant F = ks, separable Smith G1·G1
    "conductor-a0.3-mitsuba": lambda: mat.conductor(0.3, [0.9, 0.6, 0.3], fresnel="none",
                                                    masking="separable"),
    "conductor-a0.05-separable": lambda: mat.conductor(0.05, 0.95, masking="separable"),
}
THETAS_DEG = [0.0, 45.0, 80.0, 89.0]
# registry guard: every non-delta kind of the library is covered by some case
assert {int(f().kind) for f in CASES.values()} == {
    k for k, b in mat.REGISTRY.items() if not b.is_delta}


def wo_at(theta_deg, dtype=jnp.float32, phi=0.7):
    """Unit outgoing direction at polar angle θo (degrees) and azimuth φ."""
    t = np.radians(theta_deg)
    return jnp.asarray([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)], dtype)


# one batch size for every _batch call, so each (kind, dtype) compiles once for all tests
N = 1 << 14


def uniforms(n, seed, dtype=jnp.float32):
    return jax.random.uniform(jax.random.PRNGKey(seed), (n, 2), dtype)


@functools.partial(jax.jit, static_argnums=3)
def _batch(m, wo, u, kind):
    """Sample a batch, re-evaluate f and pdf at the sampled wi (one compile per kind)."""
    kinds = (kind,)
    s = jax.vmap(lambda uu: mat.bsdf_sample(m, wo, uu, kinds))(u)
    f = jax.vmap(lambda wi: mat.bsdf_eval(m, wo, wi, kinds))(s.wi)
    pdf = jax.vmap(lambda wi: mat.bsdf_pdf(m, wo, wi, kinds))(s.wi)
    return s, f, pdf


# ---------------------------------------------------------------------------------------------
# Chi-square: the sampler matches its own pdf
# ---------------------------------------------------------------------------------------------

def _chi2(m, wo, *, num_samples, seed, pdf_fn=None, num_tests=1):
    kinds = (int(m.kind),)
    pdf_fn = pdf_fn or (lambda wi: mat.bsdf_pdf(m, wo, wi, kinds))
    return chi2_test(lambda u: mat.bsdf_sample(m, wo, u, kinds).wi, pdf_fn, "sphere",
                     num_samples=num_samples, resolution=(40, 80), seed=seed,
                     num_tests=num_tests)


@pytest.mark.parametrize("case", list(CASES))
def test_chi2_quick(case):
    """Every BSDF at θo = 45° with a modest sample count (fast loop)."""
    r = _chi2(CASES[case](), wo_at(45.0), num_samples=200_000, seed=1, num_tests=len(CASES))
    # 1% significance, Šidák-corrected over the cases of this test
    assert r.passed, (r.statistic, r.dof, r.p_value, r.messages)


@pytest.mark.slow
@pytest.mark.parametrize("theta", THETAS_DEG)
@pytest.mark.parametrize("case", list(CASES))
def test_chi2_all_angles(case, theta):
    """Every BSDF at every outgoing angle, including grazing 80° and 89°, with 5·10^5 samples."""
    n_tests = len(CASES) * len(THETAS_DEG)
    r = _chi2(CASES[case](), wo_at(theta), num_samples=500_000, seed=2, num_tests=n_tests)
    assert r.passed, (r.statistic, r.dof, r.p_value, r.messages)


def _phong_pdf_wrong_exponent(m, wo, wi):
    # a normalised lobe, but with a 10% wrong exponent (integrates to one: only χ² can tell)
    p_spec = mat._phong_spec_prob(m, wo.dtype)
    lobe = warp.square_to_phong_lobe_pdf(to_local(wi, reflect(wo, jnp.array([0.0, 0.0, 1.0]))),
                                         1.1 * m.exponent)
    return (1 - p_spec) * warp.square_to_cosine_hemisphere_pdf(wi) + p_spec * lobe


def _conductor_pdf_not_visible(m, wo, wi):
    # GGX half-vector density D cos θh instead of the visible-normal density
    h = normalize(wo + wi)
    return mat.half_vector_to_reflected_pdf(warp.ggx_d(h, m.alpha) * h[2], dot(wo, h))


def _diffuse_pdf_uniform(m, wo, wi):
    # cosine-sampled but described as uniform over the hemisphere
    return jnp.where(wi[2] > 0, 1 / (2 * jnp.pi), 0.0)


# wrong pdfs that a working harness must reject: name -> (case, θo, broken pdf)
_WRONG = {
    "phong-exponent": ("phong-n20", 45.0, _phong_pdf_wrong_exponent),
    "conductor-not-visible": ("conductor-a0.3", 45.0, _conductor_pdf_not_visible),
    "diffuse-uniform": ("diffuse", 45.0, _diffuse_pdf_uniform),
}


@pytest.mark.parametrize("name", list(_WRONG))
def test_chi2_rejects_wrong_pdf(name):
    """The chi-square test has power: a slightly wrong pdf fails it."""
    case, theta, wrong = _WRONG[name]
    m, wo = CASES[case](), wo_at(theta)
    r = _chi2(m, wo, num_samples=200_000, seed=3, pdf_fn=lambda wi: wrong(m, wo, wi))
    # rejected by the goodness of fit itself (each wrong pdf integrates to one)
    assert not r.passed and any("chi2=" in msg for msg in r.messages), r.messages


# ---------------------------------------------------------------------------------------------
# Consistency: weight, pdf round trip, reciprocity, energy
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("theta", THETAS_DEG)
@pytest.mark.parametrize("case", list(CASES))
def test_weight_and_pdf_consistent(case, theta, x64):
    dt = jnp.float64 if x64 else jnp.float32
    m, wo = CASES[case](), wo_at(theta, dt)
    s, f, pdf = _batch(m, wo, uniforms(N, 5, dt), int(m.kind))
    # relative round-off of re-deriving h from wi (float32: ~1e-7 per op, D amplifies it)
    rtol = 1e-9 if x64 else 2e-4
    ok = np.asarray(s.pdf) > 0
    assert ok.mean() > 0.5  # the sampler produces valid directions most of the time
    # pdf(sampled wi) == sample.pdf
    np.testing.assert_allclose(pdf[ok], s.pdf[ok], rtol=rtol)
    # weight == f |cos θi| / pdf, and 0 where pdf == 0
    expect = np.where(ok[:, None], f * np.abs(s.wi[:, 2:3]) / np.where(ok, s.pdf, 1)[:, None], 0)
    np.testing.assert_allclose(s.weight, expect, rtol=rtol, atol=1e-12)
    # below the horizon: weight 0 (one-sided BSDF)
    assert np.all(np.asarray(s.weight)[np.asarray(s.wi[:, 2]) <= 0] == 0)
    # unit directions, dtype preserved
    np.testing.assert_allclose(np.linalg.norm(s.wi, axis=1), 1, rtol=10 * rtol)
    assert s.wi.dtype == s.pdf.dtype == s.weight.dtype == f.dtype == dt
    assert not s.is_delta.any()


def _random_upper(n, seed, dtype=jnp.float32):
    v = jax.random.normal(jax.random.PRNGKey(seed), (n, 3), dtype)
    v = v.at[:, 2].set(jnp.abs(v[:, 2]))
    return v / jnp.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("case", list(CASES))
def test_reciprocity(case):
    m = CASES[case]()
    kinds = (int(m.kind),)
    wo, wi = _random_upper(2048, 7), _random_upper(2048, 8)
    ev = jax.jit(jax.vmap(lambda a, b: mat.bsdf_eval(m, a, b, kinds)))
    f_ab, f_ba = ev(wo, wi), ev(wi, wo)
    assert np.all(np.isfinite(f_ab)) and np.all(np.asarray(f_ab) >= 0)
    # f(wo, wi) == f(wi, wo) up to float32 round-off of the two evaluation orders
    np.testing.assert_allclose(f_ab, f_ba, rtol=1e-4, atol=1e-6 * float(np.max(f_ab)))


@pytest.mark.parametrize("theta", THETAS_DEG)
@pytest.mark.parametrize("case", list(CASES))
def test_white_furnace(case, theta):
    """Directional albedo ∫ f cos dωi ≤ 1 (energy conservation), estimated with 2^14 samples."""
    m = CASES[case]()
    s, _, _ = _batch(m, wo_at(theta), uniforms(N, 11), int(m.kind))
    w = np.asarray(s.weight, np.float64)
    mean, err = w.mean(0), w.std(0) / np.sqrt(len(w))
    # 1 is the energy bound; 4 standard errors cover MC noise at ~3e-5 two-sided per channel
    assert np.all(mean <= 1 + 4 * err + 1e-6), (mean, err)
    if case == "diffuse":  # the cosine-sampled weight is exactly kd (zero variance)
        np.testing.assert_allclose(mean, m.kd, rtol=1e-6)


@pytest.mark.parametrize("case", ["phong-n1", "phong-n20", "phong-n1000"])
def test_phong_albedo_at_normal_incidence(case):
    """At θo = 0 the lobe lies wholly above the horizon: albedo = kd + ks exactly."""
    m = CASES[case]()
    s, _, _ = _batch(m, wo_at(0.0), uniforms(N, 13), int(m.kind))
    w = np.asarray(s.weight, np.float64)
    mean, err = w.mean(0), w.std(0) / np.sqrt(len(w))
    # 4 standard errors (+ float32 summation slack) around the analytic kd + ks
    np.testing.assert_array_less(np.abs(mean - np.asarray(m.kd + m.ks)), 4 * err + 1e-5)


def test_conductor_albedo_matches_uniform_sphere_estimate():
    """The VNDF-sampled albedo agrees with an independent uniform-sphere estimate of ∫ f cos."""
    m, wo = mat.conductor(0.5, [1.0, 0.7, 0.4]), wo_at(60.0)
    kinds = (mat.CONDUCTOR,)
    s, _, _ = _batch(m, wo, uniforms(N, 17), mat.CONDUCTOR)
    w = np.asarray(s.weight, np.float64)
    a_is, e_is = w.mean(0), w.std(0) / np.sqrt(len(w))
    v = jax.random.normal(jax.random.PRNGKey(19), (1 << 18, 3))
    v = v / jnp.linalg.norm(v, axis=1, keepdims=True)
    g = np.asarray(jax.jit(jax.vmap(lambda wi: mat.bsdf_eval(m, wo, wi, kinds) * wi[2]))(v),
                   np.float64) * 4 * np.pi
    a_u, e_u = g.mean(0), g.std(0) / np.sqrt(len(g))
    # two independent estimates of one integral: within 4 combined standard errors
    np.testing.assert_array_less(np.abs(a_is - a_u), 4 * np.hypot(e_is, e_u))


# ---------------------------------------------------------------------------------------------
# Mirror
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("theta", THETAS_DEG)
def test_mirror(theta, x64):
    dt = jnp.float64 if x64 else jnp.float32
    m, wo = mat.mirror([0.9, 0.8, 0.7]), wo_at(theta, dt)
    s = mat.bsdf_sample(m, wo, jnp.asarray([0.3, 0.6], dt), (mat.MIRROR,))
    # exact: the reflection negates x and y and keeps z
    np.testing.assert_array_equal(s.wi, jnp.stack([-wo[0], -wo[1], wo[2]]))
    np.testing.assert_array_equal(s.weight, m.ks)
    assert bool(s.is_delta) and float(s.pdf) == 1.0 and s.wi.dtype == dt
    assert float(mat.bsdf_pdf(m, wo, s.wi, (mat.MIRROR,))) == 0.0
    assert np.all(np.asarray(mat.bsdf_eval(m, wo, s.wi, (mat.MIRROR,))) == 0)


def test_below_horizon_wo_gives_zero():
    """One-sided BSDFs: a viewer below the surface sees no reflection, nothing is sampled."""
    wo = wo_at(120.0)
    for f in [*CASES.values(), lambda: mat.mirror(0.9)]:
        m = f()
        s, f_val, pdf = _batch(m, wo, uniforms(N, 29), int(m.kind))
        assert np.all(np.asarray(s.weight) == 0) and np.all(np.asarray(f_val) == 0)
        assert np.all(np.asarray(pdf) == 0)


# ---------------------------------------------------------------------------------------------
# Dispatch over a material table
# ---------------------------------------------------------------------------------------------

def test_table_dispatch_matches_direct_calls():
    ms = [CASES["diffuse"](), CASES["phong-n20"](), CASES["conductor-a0.3"](), mat.mirror(0.8)]
    table, kinds = mat.material_table(ms)
    assert kinds == (mat.DIFFUSE, mat.PHONG, mat.CONDUCTOR, mat.MIRROR)
    assert table.kd.shape == (4, 3) and table.kind.dtype == jnp.int32
    wo, wi, u = wo_at(30.0), wo_at(50.0, phi=3.5), jnp.asarray([0.3, 0.8])

    @jax.jit
    def via_table(i):
        row = jax.tree.map(lambda x: x[i], table)
        return (mat.bsdf_eval(row, wo, wi, kinds), mat.bsdf_pdf(row, wo, wi, kinds),
                mat.bsdf_sample(row, wo, u, kinds))

    for i, m in enumerate(ms):
        got = via_table(jnp.int32(i))
        b = mat.REGISTRY[int(m.kind)]
        want = jax.jit(lambda m, b=b: (b.eval(m, wo, wi), b.pdf(m, wo, wi), b.sample(m, wo, u)))(m)
        for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            # same maths, but XLA may fuse differently inside the switch: float32 round-off
            np.testing.assert_allclose(g, w, rtol=1e-5)


def _primitives(fn, *args):
    return {e.primitive.name for e in jax.make_jaxpr(fn)(*args).jaxpr.eqns}


def test_single_kind_compiles_no_switch():
    m, wo, u = mat.diffuse(0.5), wo_at(30.0), jnp.asarray([0.2, 0.3])
    one = _primitives(lambda m: mat.bsdf_sample(m, wo, u, (mat.DIFFUSE,)), m)
    two = _primitives(lambda m: mat.bsdf_sample(m, wo, u, (mat.DIFFUSE, mat.PHONG)), m)
    assert "cond" not in one and "switch" not in one
    assert "cond" in two  # the check above can fail: two kinds do compile a switch


# ---------------------------------------------------------------------------------------------
# Constructors
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad, match", [
    (lambda: mat.diffuse(1.2), "albedo"),
    (lambda: mat.diffuse([0.5, -0.1, 0.2]), "albedo"),
    (lambda: mat.diffuse(np.nan), "finite"),
    (lambda: mat.phong(0.6, 0.5, 10.0), "kd \\+ ks"),
    (lambda: mat.phong(0.3, 0.3, -1.0), "exponent"),
    (lambda: mat.phong(0.3, 0.3, np.inf), "exponent"),
    (lambda: mat.conductor(1.5, 0.9), "alpha"),
    (lambda: mat.conductor(-0.1, 0.9), "alpha"),
    (lambda: mat.conductor(0.3, [1.0, 2.0, 0.5]), "ks"),
    (lambda: mat.mirror(np.inf), "ks"),
    (lambda: mat.material_table([]), "at least one"),
])
def test_constructor_rejects(bad, match):
    with pytest.raises(ValueError, match=match):
        bad()


def test_constructor_clamps_alpha_and_dtypes(x64):
    m = mat.conductor(0.0, 0.9)
    assert float(m.alpha) == pytest.approx(mat.ALPHA_MIN)  # clamped, not rejected
    assert m.kind.dtype == jnp.int32
    assert m.kd.dtype == (jnp.float64 if x64 else jnp.float32)


# ---------------------------------------------------------------------------------------------
# Extremes: tiny roughness, huge exponent, grazing wo, u at 0 and 1 − ulp
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("make", [
    lambda: mat.conductor(1e-3, 0.9), lambda: mat.phong(0.1, 0.9, 1e4), lambda: mat.diffuse(1.0),
    lambda: mat.conductor(1.0, 1.0), lambda: mat.mirror(1.0)], ids=["a1e-3", "n1e4", "diffuse",
                                                                     "a1", "mirror"])
def test_finite_at_extremes(make, x64):
    dt = jnp.float64 if x64 else jnp.float32
    m = make()
    kinds = (int(m.kind),)
    one = 1 - jnp.finfo(dt).epsneg
    us = jnp.asarray([[0, 0], [one, one], [0, one], [one, 0], [0.5, 0.5]], dt)
    us = jnp.concatenate([us, uniforms(N - len(us), 23, dt)])
    wz = jnp.asarray(1e-6, dt)
    for wo in [jnp.stack([jnp.sqrt(1 - wz * wz), 0 * wz, wz]), wo_at(89.0, dt), wo_at(0.0, dt)]:
        s, f, pdf = _batch(m, wo, us, kinds[0])
        for x in (s.wi, s.pdf, s.weight, f, pdf):
            assert np.all(np.isfinite(x)) and x.dtype == dt
        # a single Phong weight may exceed 1 by (n+2)/(n+1); 1% above 1 still catches blow-ups
        assert np.all(np.asarray(s.weight) >= 0) and np.all(np.asarray(s.weight) <= 1.01)


def test_bsdf_albedo_helper():
    """The public furnace helper: the diffuse albedo is kd, with zero standard error."""
    a, e = jax.jit(mat.bsdf_albedo, static_argnums=3)(
        CASES["diffuse"](), wo_at(30.0), uniforms(N, 31), (mat.DIFFUSE,))
    np.testing.assert_allclose(a, [0.7, 0.5, 0.2], rtol=1e-6)  # constant weight kd
    np.testing.assert_array_less(e, 1e-6)
    assert a.dtype == jnp.float32


def test_phong_lobe_pdf_finite_for_slightly_non_unit_directions():
    """At the lobe's horizon a direction a few ulps longer than unit makes ``1 − cos θ``
    exceed 1, where ``log1p(−(1 − cos θ))`` is NaN: the pdf stays finite, ≥ 0, and equal to
    the float64 density within float32 rounding where that is representable."""
    rng = np.random.default_rng(5)
    phi = rng.uniform(0, 2 * np.pi, 4096)
    z = 10.0 ** rng.uniform(-8, -1, 4096)
    s = np.sqrt(1 - z * z) * (1 + 3e-7)  # up to ~3 ulps too long
    v = np.stack([s * np.cos(phi), s * np.sin(phi), z], -1).astype(np.float32)
    for n in (0.0, 1.0, 50.0, 1e4):
        pdf = np.asarray(jax.vmap(lambda w, n=n: warp.square_to_phong_lobe_pdf(
            w, jnp.float32(n)))(jnp.asarray(v)))
        assert np.all(np.isfinite(pdf)) and np.all(pdf >= 0), n
        exact = (n + 1) / (2 * np.pi) * z**n
        # 1 − cos is taken directly below z = ½, so cosⁿ keeps its float32 relative accuracy
        assert np.allclose(pdf, exact, rtol=1e-4 * max(n, 1), atol=1e-30), n


def test_conductor_mitsuba_form_matches_its_formula():
    """fresnel="none", masking="separable": f = ks D(h) G1(wo) G1(wi) / (4 cos θo cos θi), with
    D and G1 written out here in float64 (Walter et al. 2007, eqs. 33–34), not taken from jaxrt;
    and the default (Schlick, height-correlated) differs from it."""
    alpha, ks = 0.3, np.array([0.9, 0.6, 0.3])
    m = mat.conductor(alpha, ks, fresnel="none", masking="separable")
    rng = np.random.default_rng(5)

    def tan2(w):
        return (1 - w[2] ** 2) / w[2] ** 2

    def g1(w):
        return 2 / (1 + np.sqrt(1 + alpha**2 * tan2(w)))

    for _ in range(20):
        wo, wi = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)) * [1, 1, 0.3] + [0, 0, 1])
        h = (wo + wi) / np.linalg.norm(wo + wi)
        d = alpha**2 / (np.pi * h[2] ** 4 * (alpha**2 + tan2(h)) ** 2)
        expect = ks * d * g1(wo) * g1(wi) / (4 * wo[2] * wi[2])
        got = np.asarray(mat.conductor_eval(m, jnp.asarray(wo, jnp.float32),
                                            jnp.asarray(wi, jnp.float32)))
        np.testing.assert_allclose(got, expect, rtol=2e-4)
    # at grazing angles Schlick's F and the correlated G2 differ from ks and G1·G1 by > 5 %
    wo, wi = wo_at(80.0), wo_at(75.0, phi=2.5)
    a, b = (np.asarray(mat.conductor_eval(x, wo, wi))
            for x in (m, mat.conductor(alpha, ks)))
    assert np.all(np.abs(a - b) > 0.05 * a), (a, b)
