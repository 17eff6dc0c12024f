"""``computed_once``: an exact identity whose value XLA:CPU stores, not recomputes."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np

from jaxrt.estimators import compiler_options
from jaxrt.vecmath import computed_once, to_world

SPECIAL = [0.0, -0.0, 1.0, -2.5, np.inf, -np.inf, np.nan, 1.2e-38, -3.4e38]


def test_computed_once_returns_every_value_bit_for_bit(x64):
    dtype = np.float64 if x64 else np.float32
    x = np.asarray(SPECIAL, dtype)
    for f in (computed_once, jax.jit(computed_once), jax.jit(jax.vmap(computed_once))):
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
