"""Domains of the chi-square harness: how a point is binned and how a cell is integrated.

A :class:`Domain` is a NamedTuple of pure functions that map the sampled domain to *cell
coordinates* ``s ∈ [0, 1]^2`` (the histogram grid is uniform in ``s``) and back. Every
built-in parametrisation has a **constant Jacobian** ``dμ = J ds1 ds2`` (μ is the domain's
measure: area on the square, disk and triangle, solid angle on spheres, length on an
interval), so equal cells in ``s`` have equal measure and the pdf is integrated over a cell as
``∫∫ pdf(x(s)) J ds1 ds2``.

| domain | point ``x`` | cell coordinates ``(s1, s2)`` | J |
| --- | --- | --- | --- |
| ``"square"`` | (2,) in [0,1]^2 | ``(x, y)`` | 1 |
| ``"disk"`` | (2,) unit disk | ``(φ / 2π, r²)`` (``dA = r dr dφ = ½ d(r²) dφ``) | π |
| ``"sphere"`` | (3,) unit vector | ``(φ / 2π, (1 + cos θ) / 2)`` (``dω = dcosθ dφ``) | 4π |
| ``"hemisphere"`` | (3,) unit, z ≥ 0 | ``(φ / 2π, cos θ)`` | 2π |
| ``"triangle"`` | (2,) barycentrics (b1, b2) | ``(b1, b2)``, support ``s2 ≤ 1 − s1`` | 1 |
| ``interval_domain(lo, hi)`` | () or (1,) in [lo, hi] | ``((x − lo) / (hi − lo),)`` | hi − lo |

Users add a domain by building a :class:`Domain` of their own. The functions work on ONE point
(the harness vmaps them). ``s2_max`` describes a support that is not the whole square:
``{s2 ≤ s2_max(s1)}`` (the triangle); cells cut by it are integrated over their inside part
only.

Points are accepted within a small floating-point tolerance of the domain (``EPS_INSIDE``,
``EPS_UNIT``) and clamped into the edge cells; farther out (or NaN/inf) they count as outside.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import dot, spherical_phi

# Tolerance for coordinates on a boundary (float32 round-off of warps near u = 1 − ulp).
EPS_INSIDE = 1e-5
# Tolerance on ‖v‖ − 1 for directions (float32 normalisation error is ~1e-7).
EPS_UNIT = 1e-4


class Domain(NamedTuple):
    """A sampling domain for :func:`jaxrt.validation.chi2.chi2_test`: functions of ONE point.

    Attributes:
        name: label used in messages.
        dim: number of cell axes, 2 (or 1 for intervals, where ``s2`` is ignored).
        to_cell_coords: ``x -> s`` (2,), in [0, 1]^2 for points inside the domain.
        from_cell_coords: ``s`` (2,) ``-> x``, the inverse map used by the quadrature.
        jacobian: ``J = dμ / (ds1 ds2)``, a Python float (constant over the domain).
        in_domain: ``x -> bool``; finite and inside up to round-off.
        axis_names: names of ``s1`` and ``s2`` for reports and plots.
        s2_max: optional ``s1 -> upper bound of s2`` on the support (None: the whole square).
    """

    name: str
    dim: int
    to_cell_coords: Callable[[Array], Array]
    from_cell_coords: Callable[[Array], Array]
    jacobian: float
    in_domain: Callable[[Array], Array]
    axis_names: tuple[str, str]
    s2_max: Callable[[Array], Array] | None = None


def _two_pi(x: Array) -> Array:
    return jnp.asarray(2 * jnp.pi, x.dtype)


def _in_unit_box(x: Array) -> Array:
    return jnp.all((x >= -EPS_INSIDE) & (x <= 1 + EPS_INSIDE))


# --- square: identity -------------------------------------------------------------------------
SQUARE = Domain(
    name="square",
    dim=2,
    to_cell_coords=lambda x: x,
    from_cell_coords=lambda s: s,
    jacobian=1.0,
    in_domain=_in_unit_box,
    axis_names=("x", "y"),
)


# --- disk: (φ/2π, r²) has constant Jacobian π --------------------------------------------------
def _disk_to_cell(x: Array) -> Array:
    phi = jnp.arctan2(x[1], x[0])
    phi = jnp.where(phi < 0, phi + _two_pi(x), phi)
    return jnp.stack([phi / _two_pi(x), dot(x, x)])


def _cell_to_disk(s: Array) -> Array:
    r = jnp.sqrt(s[1])
    phi = _two_pi(s) * s[0]
    return jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi)])


DISK = Domain(
    name="disk",
    dim=2,
    to_cell_coords=_disk_to_cell,
    from_cell_coords=_cell_to_disk,
    jacobian=float(jnp.pi),
    in_domain=lambda x: dot(x, x) <= 1 + EPS_INSIDE,
    axis_names=("phi/2pi", "r^2"),
)


# --- sphere and hemisphere: (φ/2π, cos θ) is an equal-area (Archimedes) map -----------------
def _direction(s1: Array, cos_theta: Array) -> Array:
    sin_theta = jnp.sqrt(jnp.maximum(1 - cos_theta * cos_theta, 0))
    phi = _two_pi(s1) * s1
    return jnp.stack([sin_theta * jnp.cos(phi), sin_theta * jnp.sin(phi), cos_theta])


def _is_unit(v: Array) -> Array:
    return jnp.abs(jnp.sqrt(dot(v, v)) - 1) <= EPS_UNIT


SPHERE = Domain(
    name="sphere",
    dim=2,
    to_cell_coords=lambda v: jnp.stack(
        [spherical_phi(v) / _two_pi(v), (1 + jnp.clip(v[2], -1, 1)) / 2]
    ),
    from_cell_coords=lambda s: _direction(s[0], 2 * s[1] - 1),
    jacobian=float(4 * jnp.pi),
    in_domain=_is_unit,
    axis_names=("phi/2pi", "(1+cos theta)/2"),
)

HEMISPHERE = Domain(
    name="hemisphere",
    dim=2,
    to_cell_coords=lambda v: jnp.stack([spherical_phi(v) / _two_pi(v), jnp.clip(v[2], 0, 1)]),
    from_cell_coords=lambda s: _direction(s[0], s[1]),
    jacobian=float(2 * jnp.pi),
    in_domain=lambda v: _is_unit(v) & (v[2] >= -EPS_INSIDE),
    axis_names=("phi/2pi", "cos theta"),
)


# --- triangle: barycentrics of the unit right triangle, support b1 + b2 ≤ 1 ---------------
TRIANGLE = Domain(
    name="triangle",
    dim=2,
    to_cell_coords=lambda b: b,
    from_cell_coords=lambda s: s,
    jacobian=1.0,
    in_domain=lambda b: _in_unit_box(b) & (b[0] + b[1] <= 1 + EPS_INSIDE),
    axis_names=("b1", "b2"),
    s2_max=lambda s1: 1 - s1,
)


def interval_domain(lo: float = 0.0, hi: float = 1.0) -> Domain:
    """The interval ``[lo, hi]`` for 1D samplers: ``s1 = (x − lo) / (hi − lo)``, J = hi − lo.

    The point may be a scalar or a (1,) array; the pdf is per unit length.
    """
    if not hi > lo:
        raise ValueError(f"interval_domain needs lo < hi, got lo={lo}, hi={hi}")
    width = hi - lo
    tol = EPS_INSIDE * width

    def to_cell(x: Array) -> Array:
        x = jnp.reshape(x, (-1,))[0]
        return jnp.stack([(x - lo) / width, jnp.zeros_like(x)])

    def in_domain(x: Array) -> Array:
        x = jnp.reshape(x, (-1,))[0]
        return (x >= lo - tol) & (x <= hi + tol)

    return Domain(
        name=f"interval[{lo:g}, {hi:g}]",
        dim=1,
        to_cell_coords=to_cell,
        from_cell_coords=lambda s: lo + width * s[0],
        jacobian=float(width),
        in_domain=in_domain,
        axis_names=("x", ""),
    )


DOMAINS: dict[str, Domain] = {
    "square": SQUARE,
    "disk": DISK,
    "sphere": SPHERE,
    "hemisphere": HEMISPHERE,
    "triangle": TRIANGLE,
    "interval": interval_domain(0.0, 1.0),
}


def resolve_domain(domain: str | tuple | Domain) -> Domain:
    """A :class:`Domain` from a name in ``DOMAINS``, ``("interval", lo, hi)`` or a Domain."""
    if isinstance(domain, Domain):
        return domain
    if isinstance(domain, tuple) and len(domain) == 3 and domain[0] == "interval":
        return interval_domain(float(domain[1]), float(domain[2]))
    if isinstance(domain, str) and domain in DOMAINS:
        return DOMAINS[domain]
    raise ValueError(
        f"unknown chi-square domain {domain!r}; expected one of {sorted(DOMAINS)}, "
        "('interval', lo, hi) or a jaxrt.validation.domains.Domain"
    )
