"""Estimates at one chosen shading point: an estimator run many times, mean ± standard error.

:func:`estimate_at` tests an estimator against :mod:`jaxrt.validation.analytic`;
:func:`samples_at` gives its independent one-sample values (derivative estimators take
their own standard error from them).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.autodiff import nondifferentiable
from jaxrt.core.xla import jit_with_options
from jaxrt.geometry.spawn import default_point_error
from jaxrt.integrators.config import Estimator, make_estimator, prepare_scene
from jaxrt.integrators.techniques import shade
from jaxrt.integrators.terms import Stream
from jaxrt.scene.container import Scene, guard_geometry
from jaxrt.scene.queries import TRIANGLE, SurfaceHit


class Estimate(NamedTuple):
    """A Monte Carlo mean of ``n`` independent estimates and its standard error ``σ/√n``
    (what :func:`estimate_at` and the derivative estimates return; build one with
    :meth:`of`)."""

    mean: Array  # (3,)
    stderr: Array  # (3,)
    n: int

    @classmethod
    def of(cls, values: Array) -> Estimate:
        """The mean over axis 0 of ``values`` (N, ...) and its standard error, with the
        unbiased sample variance (``ddof=1``)."""
        n = values.shape[0]
        return cls(jnp.mean(values, axis=0), jnp.sqrt(jnp.var(values, axis=0, ddof=1) / n),
                   int(n))


def estimate_at(scene: Scene, estimator: str | Estimator, p, n, wo, material: int = 0, *,
                num_samples: int = 1 << 14, seed: int = 0, sampler: str = "independent",
                **params) -> Estimate:
    """Run one estimator many times at a chosen surface point: reflected radiance ± error.

    The point ``p`` (3,) with unit normal ``n`` is shaded with material row ``material`` of the
    scene, seen along ``wo`` (unit, towards the viewer); the scene supplies lights and
    occluders (:func:`jaxrt.scene.container.shading_scene` builds one from a material and lights
    alone).
    Returns the Monte Carlo mean of ``num_samples`` independent estimates
    (:func:`samples_at`) and its standard error ``σ/√N``. Useful to test an estimator against
    :mod:`jaxrt.validation.analytic`.

    Differentiable w.r.t. the scene's material and emission arrays (derivatives with the
    sampling detached, see the module notes); derivatives w.r.t. ``p``, ``n``, ``wo`` or the
    scene's geometry raise (:func:`jaxrt.scene.container.guard_geometry`).

    Raises ValueError when ``wo`` is not above the surface (``n · wo ≤ 0``): BSDFs are
    one-sided about ``n``, and the renderer would shade the other side (flip ``n`` yourself
    to mean that).
    """
    values = samples_at(scene, estimator, p, n, wo, material, num_samples=num_samples,
                        seed=seed, sampler=sampler, **params)
    return Estimate.of(values)


def samples_at(scene: Scene, estimator: str | Estimator, p, n, wo, material: int = 0, *,
               num_samples: int = 1 << 14, seed: int = 0, sampler: str = "independent",
               **params) -> Array:
    """The ``num_samples`` independent one-sample estimates (N, 3) that :func:`estimate_at`
    averages: sample ``k`` uses the stream (seed, pixel 0, index k). Same arguments, errors
    and derivatives as :func:`estimate_at`; per-sample values give derivative estimators
    their own standard error (``jax.jvp`` of this, see
    :func:`jaxrt.rendering.differentiable.derivative_at`)."""
    est = make_estimator(estimator, **params)
    if not isinstance(wo, jax.core.Tracer) and not isinstance(n, jax.core.Tracer):
        cos_o = float(np.dot(np.asarray(n, np.float64), np.asarray(wo, np.float64)))
        if not cos_o > 0:
            raise ValueError(f"wo is not above the surface: n · wo = {cos_o:.3g} ≤ 0 (flip n to "
                             "shade the other side)")
    scene = guard_geometry(prepare_scene(scene, est))
    dtype = scene.triangles.dtype
    # the shading point is geometry too: its derivatives are refused like the scene's
    p, n, wo = (nondifferentiable(jnp.asarray(a, dtype), f"the shading point's {name}")
                for a, name in ((p, "p"), (n, "n"), (wo, "wo")))
    hit = SurfaceHit(t=jnp.asarray(1, dtype), p=p, p_error=default_point_error(p), ng=n,
                     kind=jnp.int32(TRIANGLE), prim=jnp.int32(-1),
                     material=jnp.int32(material), light=jnp.int32(-1))
    return _estimate_at(scene, est, hit, wo, jnp.uint32(seed), sampler, int(num_samples))


@jit_with_options(static_argnames=("est", "sampler", "num_samples"))
def _estimate_at(scene, est, hit, wo, seed, sampler, num_samples):
    def one(k):
        s = Stream.of(sampler, seed, jnp.uint32(0), k, num_samples)
        return shade(scene, est, hit, wo, s)

    return jax.vmap(one)(jnp.arange(num_samples, dtype=jnp.uint32))
