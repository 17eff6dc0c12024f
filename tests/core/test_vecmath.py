"""``computed_once``: an exact identity whose value XLA:CPU stores, not recomputes."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np

from jaxrt.core.vecmath import computed_once, dot, dot_components, to_world
from jaxrt.core.xla import compiler_options

SPECIAL = [0.0, -0.0, 1.0, -2.5, np.inf, -np.inf, np.nan, 1.2e-38, -3.4e38]


def test_computed_once_returns_every_value_bit_for_bit(x64):
    dtype = np.float64 if x64 else np.float32
    x = np.asarray(SPECIAL, dtype)
    # compiled with jaxrt's own options too: under their fast min/max a max-reduction with
    # −∞ (this function's first form) returned −∞ for NaN
    own = jax.jit(jax.vmap(computed_once)).lower(jnp.asarray(x)).compile(compiler_options())
    for f in (computed_once, jax.jit(computed_once), jax.jit(jax.vmap(computed_once)), own):
        y = np.asarray(f(jnp.asarray(x)))
        assert y.dtype == x.dtype
        assert y.tobytes() == x.tobytes()  # −0 stays −0, NaN stays NaN, −∞ stays −∞
    v = np.asarray([[1.0, -0.0, np.nan], [-np.inf, 2.0, 0.0]], dtype)
    assert np.asarray(jax.vmap(computed_once)(jnp.asarray(v))).tobytes() == v.tobytes()
    # subnormals: XLA:CPU flushes them to zero in any arithmetic (FTZ/DAZ), this one included
    tiny = np.asarray([1e-45, -1e-45], np.float32).astype(dtype)
    out = np.asarray(jax.jit(computed_once)(jnp.asarray(tiny)))
    assert np.all((out == tiny) | ((out == 0) & (np.signbit(out) == np.signbit(tiny))))


def test_computed_once_passes_the_tangent_through():
    x, t = jnp.asarray([1.0, -3.0, 0.0]), jnp.asarray([0.5, 2.0, -1.0])
    y, dy = jax.jvp(computed_once, (x,), (t,))
    np.testing.assert_array_equal(y, x)
    np.testing.assert_array_equal(dy, t)
    g = jax.grad(lambda a: jnp.sum(jnp.sin(computed_once(a * a))))(x)
    np.testing.assert_allclose(g, np.cos(x * x) * 2 * x, rtol=1e-6)


def _sine_kernels(f, *args) -> int:
    """How many kernels of the optimised program compute ``sin``."""
    text = jax.jit(jax.vmap(f)).lower(*args).compile(compiler_options()).as_text()
    fusions = re.split(r"\n(?=%?\S+ )", text)  # one block per computation
    return sum(1 for block in fusions if " sine(" in block)


def test_a_direction_used_twice_is_computed_in_one_kernel():
    """What the hot path relies on: a sampled direction (its sin/cos) with two consumers,
    stacked into a (3,) vector, is computed in every consumer's kernel unless it goes through
    ``computed_once``. Fails if XLA simplifies the reduction away."""
    def step(use_once):
        def f(u, n, camera, ended):
            phi = 2 * jnp.pi * u[0]
            r = jnp.sqrt(u[1])
            local = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), jnp.sqrt(1 - u[1])])
            wi = to_world(local, n)
            wi = computed_once(wi) if use_once else wi
            side = jnp.where(jnp.sum(wi * n) > 0, 1.0, -1.0)
            return jnp.where(ended, camera, wi), side * n
        return f

    rng = np.random.default_rng(0)
    n = rng.normal(size=(4096, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    args = (rng.random((4096, 2), np.float32), n, rng.normal(size=(4096, 3)).astype(np.float32),
            rng.random(4096) < 0.2)
    assert _sine_kernels(step(False), *args) >= 2
    assert _sine_kernels(step(True), *args) == 1
    a, b = jax.jit(jax.vmap(step(False)))(*args), jax.jit(jax.vmap(step(True)))(*args)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_cos_sin_octant_is_within_three_ulps_in_both_dtypes(x64):
    """The polynomial cosine and sine of ``π s / 4`` against numpy's float64 (libm), on the
    whole octant and at its ends; under x64 the float64 series (a float32-length series there
    is off by ~10⁻⁹, thousands of ulps: the test would catch it)."""
    from jaxrt.core.vecmath import cos_sin_octant

    dtype = np.float64 if x64 else np.float32
    s = np.concatenate([np.linspace(-1, 1, 100_001), [-1.0, -0.0, 0.0, 1e-30, 1.0]])
    s = s.astype(dtype)
    c, si = (np.asarray(v, np.float64) for v in jax.jit(cos_sin_octant)(jnp.asarray(s)))
    phi = np.pi / 4 * s.astype(np.float64)
    # the result may differ from libm's by the rounding of φ = (π/4)·s in the dtype as well
    ulp = lambda x: np.spacing(np.abs(x).astype(dtype)).astype(np.float64)  # noqa: E731
    assert np.all(np.abs(c - np.cos(phi)) <= 3 * ulp(np.cos(phi)))
    assert np.all(np.abs(si - np.sin(phi)) <= 3 * ulp(np.sin(phi)) + 2 * ulp(phi))
    assert c[-1] < 1 and si[-1] > 0 and si[-4] == 0 and c[-4] == 1  # ends of the octant
    assert np.all(c > 0) and np.all(np.sign(si) == np.sign(s))


def test_the_concentric_disk_map_calls_no_sine_or_cosine():
    """XLA:CPU evaluates ``sin``/``cos`` by a scalar libm call per element, which keeps the
    whole fused kernel from vectorising: the 256² Cornell box MIS pass runs 1.07–1.10× and the
    path pass 1.11× as fast per CPU-second with the polynomial
    (benchmarks/README.md#no-libm-sincos)."""
    from jaxrt.sampling.warp import square_to_cosine_hemisphere, square_to_uniform_disk_concentric

    u = jnp.full((64, 2), 0.3, jnp.float32)
    for f in (square_to_uniform_disk_concentric, square_to_cosine_hemisphere):
        assert _sine_kernels(f, u) == 0
        text = jax.jit(jax.vmap(f)).lower(u).compile(compiler_options()).as_text()
        assert " cosine(" not in text


def test_cos_sin_turn_is_within_three_ulps_and_exact_at_quarter_turns(x64):
    """``(cos 2πt, sin 2πt)`` over the whole turn, the octant boundaries (where the quarter
    turn ``q = round(4t)`` changes) included, against numpy's float64."""
    from jaxrt.core.vecmath import cos_sin_turn

    dtype = np.float64 if x64 else np.float32
    t = np.concatenate([np.linspace(0, 1, 200_001), np.arange(9) / 8]).astype(dtype)
    t = np.concatenate([t, np.nextafter(t, dtype(2)), np.nextafter(t, dtype(-1))])
    t = t[(t >= 0) & (t <= 1)]
    c, s = (np.asarray(v, np.float64) for v in jax.jit(cos_sin_turn)(jnp.asarray(t)))
    phi = 2 * np.pi * t.astype(np.float64)
    eps = np.finfo(dtype).eps
    # absolute error: a few ulps of 1 (the larger of |cos|, |sin| is ≥ 0.7), plus the
    # reference's own error, the rounding of φ = 2πt in float64 (~4·10⁻¹⁶ near a whole turn)
    tol = 3 * eps + np.spacing(phi)
    assert np.all(np.abs(c - np.cos(phi)) <= tol)
    assert np.all(np.abs(s - np.sin(phi)) <= tol)
    quarter = jax.jit(cos_sin_turn)(jnp.asarray(np.arange(5) / 4, dtype))
    np.testing.assert_array_equal(np.asarray(quarter[0]), [1, 0, -1, 0, 1])
    np.testing.assert_array_equal(np.asarray(quarter[1]), [0, 1, 0, -1, 0])


def test_warps_of_an_azimuth_call_no_sine_or_cosine():
    """Every warp that draws ``φ = 2π u`` (or the concentric map's octant angle) does it with
    polynomials: XLA:CPU evaluates ``sin``/``cos`` by a scalar libm call per element, which
    keeps the whole fused kernel from vectorising (256² Cornell box: MIS pass 1.07–1.10×,
    path pass 1.11× per CPU-second with the polynomial; benchmarks/README.md#no-libm-sincos)."""
    from jaxrt.sampling.warp import REGISTRY

    names = {"uniform_disk", "uniform_disk_concentric", "cosine_hemisphere", "uniform_sphere",
             "uniform_hemisphere", "uniform_cone", "phong_lobe", "beckmann", "ggx",
             "ggx_visible"}
    specs = [w for w in REGISTRY if w.name in names]
    assert {w.name for w in specs} == names
    for w in specs:
        args = [jnp.full((64, 2), 0.3, jnp.float32)]
        args += [jnp.broadcast_to(jnp.asarray(p, jnp.float32), (64,) + np.shape(p))
                 for p in w.params[0]]
        text = jax.jit(jax.vmap(w.sample)).lower(*args).compile(compiler_options()).as_text()
        assert " sine(" not in text and " cosine(" not in text, w.name


def test_dot_components_is_the_inner_product_summed_left_to_right():
    # the per-component form of dot: the same inner product, as tuples, lists or arrays, in
    # the order a0 b0 + a1 b1 + a2 b2 (so replacing a hand-written sum keeps results bit for bit)
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal((2, 1000, 3)).astype(np.float32)
    got = np.asarray(jax.vmap(dot_components)(a, b))
    np.testing.assert_array_equal(got, (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) + a[:, 2] * b[:, 2])
    np.testing.assert_allclose(got, np.asarray(jax.vmap(dot)(a, b)), rtol=1e-5, atol=1e-6)
    assert float(dot_components((1.0, 2.0, 3.0), [4.0, 5.0, 6.0, 99.0])) == 32.0
