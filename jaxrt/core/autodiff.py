"""Two derivative rules the estimators use: a value with another expression's derivative, and
arrays whose derivative is refused.

Both are identities in the primal (no operation is added to a program that is not
differentiated: XLA removes the unused surrogate), and change only what ``jax.jvp`` /
``jax.vjp`` / ``jax.grad`` see:

- :func:`with_tangent_of` ``(value, surrogate)``: the number ``value``, the derivative of
  ``surrogate``. The estimators use it where a Monte Carlo weight is evaluated in a closed
  form that is right as a number but whose autodiff derivative is not that of the estimator
  with its sampling held fixed (the GGX sample weight ``F G / G1``: its sampled half vector
  and its density both move with α, see :mod:`jaxrt.rendering.differentiable`).
- :func:`nondifferentiable` ``(x, what)``: ``x``, with a JVP rule that raises a
  ``ValueError`` naming ``what`` when a non-zero tangent reaches it (``symbolic_zeros``: an
  input that is not differentiated passes silently; one that is, even by ``jax.grad`` over a
  whole pytree, raises). Used for geometry, whose derivatives plain autodiff gets wrong.
"""

from __future__ import annotations

from functools import partial

import jax
from jax import Array
from jax.custom_derivatives import SymbolicZero


@jax.custom_jvp
def with_tangent_of(value: Array, surrogate: Array) -> Array:
    """``value`` in the primal; under differentiation, the tangent of ``surrogate``.

    ``d with_tangent_of(v, s) = ds`` (the tangent of ``v`` is discarded). Shapes and dtypes
    of ``value`` and ``surrogate`` must agree. In a program that is not differentiated the
    surrogate is dead code and is removed by XLA, so the primal numbers and speed are those
    of ``value`` alone.
    """
    del surrogate
    return value


@with_tangent_of.defjvp
def _with_tangent_of_jvp(primals, tangents):
    value, _ = primals
    _, d_surrogate = tangents
    return value, d_surrogate


#: The message's advice, shared by every refused array.
_ADVICE = ("gradients w.r.t. geometry (vertices, camera pose, light positions and shapes, "
           "environment rotation) are not supported: visibility makes the image "
           "discontinuous in them and plain autodiff misses the boundary terms, so the "
           "result would be silently wrong. Differentiate w.r.t. material and emission "
           "parameters only (jaxrt.scene_params / jaxrt.with_params), keeping the "
           "geometry a constant closed over by the function you differentiate")


@partial(jax.custom_jvp, nondiff_argnums=(1,))
def nondifferentiable(x: Array, what: str) -> Array:
    """``x`` itself; differentiating through it raises ``ValueError`` naming ``what``.

    The JVP rule runs with symbolic zeros: a tangent that JAX knows to be zero (``x`` not
    among the differentiated inputs) passes; any other tangent — from ``jax.jvp``,
    ``jax.vjp`` or ``jax.grad`` — raises at trace time, before anything is computed.
    """
    del what
    return x


def _nondifferentiable_jvp(what, primals, tangents):
    (x,), (t,) = primals, tangents
    if not isinstance(t, SymbolicZero):
        raise ValueError(f"cannot differentiate w.r.t. {what}: {_ADVICE}")
    return x, t


nondifferentiable.defjvp(_nondifferentiable_jvp, symbolic_zeros=True)
