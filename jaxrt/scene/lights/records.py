"""Records shared by every light kind, and the host-side checks their constructors use.

Kernels here are written for one shading point; host helpers run on NumPy before anything
is traced, so bad input fails early with an error that names the light and the field.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxrt.core.vecmath import device_array

# Rec. 709 / sRGB luminance weights, used for power-proportional selection.
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)


class LightSample(NamedTuple):
    """One light sample towards a shading point ``p`` (batch with ``jax.vmap``).

    Attributes:
        wi: (3,) unit direction from ``p`` towards the light, world frame.
        dist: () distance from ``p`` to the sampled point (``inf`` for directional and environment).
        li: (3,) incident radiance along ``wi``; for delta lights the radiance-like value
            (``I/d²`` for point and spot lights, irradiance ``E`` for directional lights) so that an
            estimator always forms ``f · li · |cos θ| / pdf``.
        pdf: () solid-angle density of ``wi`` *including* the light-selection pmf; for delta lights
            the pmf alone (the delta is implied).
        is_delta: () bool, true for point, spot and directional lights (never MIS-weighted).
        light: () int32 global index of the sampled light (see :mod:`jaxrt.scene.lights.table`).
    """

    wi: Array
    dist: Array
    li: Array
    pdf: Array
    is_delta: Array
    light: Array


class KindSample(NamedTuple):
    """What one light kind returns when sampled: a :class:`LightSample` without selection.

    ``pdf`` is the kind's own solid-angle density (1 for delta lights), before the pmf.
    """

    wi: Array
    dist: Array
    li: Array
    pdf: Array


def luminance(rgb: Array) -> Array:
    """Luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` of linear RGB along the last axis."""
    w = jnp.asarray(LUMINANCE_WEIGHTS, dtype=jnp.result_type(rgb, float))
    return jnp.sum(rgb * w, axis=-1)


def luminance_np(rgb: np.ndarray) -> np.ndarray:
    """Host (NumPy, float64) version of :func:`luminance` for table construction."""
    return np.asarray(rgb, np.float64) @ np.asarray(LUMINANCE_WEIGHTS, np.float64)


def safe_div(num: Array, den: Array) -> Array:
    """``num / den`` where ``den > 0``, else 0 (NaN-safe: the unused branch never divides by 0)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, jnp.ones_like(den)), jnp.zeros_like(num))


# ---------------------------------------------------------------------------------------------
# Host-side validation (NumPy, float64): every constructor funnels its inputs through these.


def as_rows(x, width: int, n: int | None, what: str) -> np.ndarray:
    """``x`` as a float64 array of shape ``(n, width)``; a single ``(width,)`` row is broadcast."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{what}: expected shape (N, {width}) or ({width},), got {np.shape(x)}")
    if n is not None and a.shape[0] != n:
        if a.shape[0] != 1:
            raise ValueError(f"{what}: expected {n} rows, got {a.shape[0]}")
        a = np.repeat(a, n, axis=0)
    return a


def check_finite(a: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` naming the first light whose ``what`` is NaN or infinite."""
    bad = ~np.isfinite(a)
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise ValueError(f"{what} of light {i} is not finite: {a[i]}")


def check_emission(a: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` for a non-finite or negative radiance / intensity / irradiance."""
    check_finite(a, what)
    bad = a < 0
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise ValueError(f"{what} of light {i} is negative: {a[i]}")


def unit_rows(a: np.ndarray, what: str) -> np.ndarray:
    """Normalise each row of ``a``; a zero or non-finite row is an error."""
    check_finite(a, what)
    n = np.linalg.norm(a, axis=-1)
    bad = ~(n > 0)
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise ValueError(f"{what} of light {i} is the zero vector")
    return a / n[:, None]


def to_device(a: np.ndarray, dtype=None) -> Array:
    """Host array to a JAX array of the default float dtype (float32, or float64 under x64)."""
    return device_array(a, dtype=dtype if dtype is not None else jnp.result_type(float))
