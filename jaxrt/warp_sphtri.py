"""Uniform sampling of the solid angle subtended by a triangle (Arvo 1995), never NaN.

A triangle with vertices ``a, b, c`` given *relative to the shading point* (any length)
subtends the spherical triangle of directions ``{normalize(b0 a + b1 b + b2 c)}``. Arvo's
method samples it uniformly: pick the sub-triangle of area ``u₀ Ω`` by solving for its third
vertex ``c'`` on the arc ``a c``, then pick a point on the arc ``b c'`` so that the result is
uniform. Density ``1/Ω`` per steradian.

Degenerate cases, all handled without NaN:

- ``Ω < min_solid_angle(dtype)`` (a tiny or far triangle; the threshold is 1e-6 sr in float64
  and larger in float32, where Arvo's trigonometry loses its digits first): the sampler falls
  back to uniform *area* sampling of the planar triangle, projected to a direction. That is
  nearly uniform in solid angle for a small triangle, and :func:`square_to_spherical_triangle_pdf`
  returns the exact solid-angle density of what was done, ``p_ω = dist² / (area |cos θ_l|)``,
  so the sampler/pdf pair stays consistent whichever branch ran.
- A zero-area triangle or a shading point exactly in the triangle's plane: Ω = 0 (all the
  directions lie on a great circle, a set of measure zero); the sampler returns a direction
  towards the (degenerate) triangle, or the zero vector if every vertex sits at the shading
  point, and the pdf is 0.
- Ω close to 2π (the shading point just above the triangle's interior): Arvo's formulas are
  clamped to their valid ranges.

Precision (known gap): in float32, Arvo's ``cos b'`` of the sub-triangle's new vertex loses
digits through ``√(1 − cos²b')`` when that vertex is close to ``a`` (small ``u₀``): the direction
is then off by up to ~3e-4 rad at ``u₀ = 4.5e-5`` for a typical triangle and ~4e-3 rad near a
hemisphere (elsewhere ~1e-5). The samples stay inside the triangle and the density stays
``1/Ω``; only the stratification of ``u₀ → 0`` is blurred.

References: Arvo 1995, "Stratified sampling of spherical triangles" (SIGGRAPH); Van Oosterom
& Strackee 1983, "The solid angle of a plane triangle" (IEEE TBME); pbrt-v4 §6.5.4.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxrt.vecmath import cross, dot, length, normalize, safe_sqrt

SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE = {"float32": 1e-4, "float64": 1e-6}
"""Solid angle (sr) below which the sampler falls back to area sampling, per dtype."""


def _min_solid_angle(dtype) -> float:
    return SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE.get(jnp.dtype(dtype).name, 1e-4)


def _rescale(a: Array, b: Array, c: Array) -> tuple[Array, Array, Array]:
    """Divide the three vertices by their largest |component| (no overflow or underflow)."""
    s = jnp.max(jnp.abs(jnp.stack([a, b, c])))
    safe = jnp.where(s > 0, s, jnp.ones_like(s))
    return a / safe, b / safe, c / safe


def _triple(a: Array, b: Array, c: Array) -> Array:
    """``a · ((b − a) × (c − a)) = a · (b × c)``, accurate for far, thin triangles."""
    return dot(a, cross(b - a, c - a))


def _omega(a: Array, b: Array, c: Array) -> Array:
    """Van Oosterom–Strackee solid angle of rescaled vertices; 0 exactly in the plane.

    ``tan(Ω/2) = |a·(b×c)| / (|a||b||c| + (a·b)|c| + (a·c)|b| + (b·c)|a|)``.
    """
    la, lb, lc = length(a), length(b), length(c)
    triple = _triple(a, b, c)
    denom = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la
    omega = 2 * jnp.arctan2(jnp.abs(triple), denom)
    # exactly in the plane the directions form a great-circle arc: measure zero
    return jnp.where(triple == 0, jnp.zeros_like(omega), omega)


def spherical_triangle_solid_angle(a: Array, b: Array, c: Array) -> Array:
    """Solid angle (sr) subtended at the origin by the triangle ``a, b, c``.

    Van Oosterom & Strackee's ``Ω = 2 atan2(|a·(b×c)|, |a||b||c| + (a·b)|c| + (a·c)|b| +
    (b·c)|a|)``, with the triple product formed from edge vectors (exact for far, thin
    triangles) after rescaling (any vertex length). In [0, 2π]; exactly 0 when the origin is
    in the triangle's plane. ``a, b, c``: (3,) relative to the shading point.
    """
    return _omega(*_rescale(a, b, c))


def _inside(v: Array, a: Array, b: Array, c: Array) -> Array:
    """Whether direction ``v`` passes through the triangle (rescaled vertices)."""
    sigma = jnp.sign(_triple(a, b, c))
    # edge-plane normals from edge vectors: accurate for thin far triangles
    d_ab = dot(v, normalize(cross(a, b - a)))
    d_bc = dot(v, normalize(cross(b, c - b)))
    d_ca = dot(v, normalize(cross(c, a - c)))
    # a few ulps of slack: samples on an edge round to either side of it
    tol = 8 * jnp.finfo(v.dtype).eps
    return (sigma * d_ab >= -tol) & (sigma * d_bc >= -tol) & (sigma * d_ca >= -tol) & (
        sigma != 0)


def _area_sample(u: Array, a: Array, b: Array, c: Array) -> Array:
    """Direction to a uniform-by-area point of the planar triangle."""
    su0 = jnp.sqrt(u[0])
    b1, b2 = 1 - su0, u[1] * su0
    return normalize(a + b1 * (b - a) + b2 * (c - a))


def _area_pdf(v: Array, a: Array, b: Array, c: Array) -> Array:
    """Solid-angle density of :func:`_area_sample`: ``dist²/(area |cos|) = 2 (n·a)² / |n·v|³``.

    With ``n = (b − a) × (c − a)`` unnormalised; invariant to the vertex scale.
    """
    n = cross(b - a, c - a)
    nv = jnp.abs(dot(n, v))
    na = dot(n, a)
    safe = jnp.where(nv > 0, nv, jnp.ones_like(nv))
    return jnp.where(nv > 0, 2 * na * na / (safe * safe * safe), jnp.zeros_like(nv))


def _arvo(u: Array, a: Array, b: Array, c: Array, omega: Array) -> Array:
    """Arvo's sampler on unit vertices ``a, b, c`` with solid angle ``omega``."""
    zero = jnp.zeros_like(omega)
    one = jnp.ones_like(omega)
    # great-circle normals through each edge, and the inner angle α at vertex a
    n_ab = normalize(cross(a, b - a))
    n_ca = normalize(cross(c, a - c))
    cos_alpha = jnp.clip(-dot(n_ab, n_ca), -one, one)
    sin_alpha = length(cross(n_ab, n_ca))
    cos_c = dot(a, b)
    # area of the sub-triangle (a, b, c') to hit
    area = u[0] * omega
    alpha_ang = jnp.arctan2(sin_alpha, cos_alpha)
    s = jnp.sin(area - alpha_ang)
    t = jnp.cos(area - alpha_ang)
    # Arvo's u = t − cos α, without cancellation for small areas
    uu = 2 * jnp.sin(alpha_ang - area / 2) * jnp.sin(area / 2)
    vv = s + sin_alpha * cos_c
    num = (vv * t - uu * s) * cos_alpha - vv
    den = (vv * s + uu * t) * sin_alpha
    safe_den = jnp.where(den != 0, den, one)
    # cos of the arc a→c' (Arvo's q), clamped: round-off pushes it past ±1 near Ω = 2π
    q = jnp.clip(jnp.where(den != 0, num / safe_den, one), -one, one)
    c_perp = normalize(c - dot(c, a) * a)
    c_prime = q * a + safe_sqrt(1 - q * q) * c_perp
    # point on the arc b→c' so that the density is uniform
    one_minus_cos_bc = jnp.maximum(1 - dot(c_prime, b), zero)
    z = 1 - u[1] * one_minus_cos_bc
    w_perp = normalize(c_prime - dot(c_prime, b) * b)
    return z * b + safe_sqrt(1 - z * z) * w_perp


def square_to_spherical_triangle(u: Array, a: Array, b: Array, c: Array) -> Array:
    """Direction uniformly distributed over the solid angle of triangle ``a, b, c``.

    Arvo's method (module docstring); for ``Ω`` below the dtype's threshold, uniform area
    sampling of the planar triangle instead. The matching density is
    :func:`square_to_spherical_triangle_pdf` (``1/Ω``, or the area-sampling density in the
    fallback). Args: ``u`` (2,); ``a, b, c`` (3,) vertices relative to the shading point.
    Returns a unit (3,) direction (the zero vector only if all vertices are at the origin).
    """
    a, b, c = _rescale(a, b, c)
    omega = _omega(a, b, c)
    fallback = _area_sample(u, a, b, c)
    w = _arvo(u, normalize(a), normalize(b), normalize(c), omega)
    use_arvo = (omega >= _min_solid_angle(u.dtype)) & jnp.all(jnp.isfinite(w))
    return jnp.where(use_arvo, normalize(w), fallback)


def square_to_spherical_triangle_pdf(v: Array, a: Array, b: Array, c: Array) -> Array:
    """Solid-angle density of :func:`square_to_spherical_triangle` at direction ``v``.

    ``1/Ω`` inside the spherical triangle when ``Ω`` is above the dtype's threshold; below
    it, the density of the area-sampling fallback, ``2 (n·a)² / |n·v|³`` with ``n = (b − a) ×
    (c − a)`` (``= dist² / (area |cos θ_light|)``); 0 outside the triangle and when Ω = 0.
    Args: ``v`` unit (3,); ``a, b, c`` (3,) relative to the shading point.
    """
    a, b, c = _rescale(a, b, c)
    omega = _omega(a, b, c)
    inside = _inside(v, a, b, c) & (omega > 0)
    use_arvo = omega >= _min_solid_angle(v.dtype)
    safe = jnp.where(omega > 0, omega, jnp.ones_like(omega))
    pdf = jnp.where(use_arvo, 1 / safe, _area_pdf(v, a, b, c))
    return jnp.where(inside, pdf, jnp.zeros_like(pdf))


def spherical_triangle_to_square(v: Array, a: Array, b: Array, c: Array) -> Array:
    """Inverse of :func:`square_to_spherical_triangle` for ``v`` inside the triangle.

    Arvo branch: ``c'`` is where the great circle through ``b, v`` meets the arc ``a c``;
    ``u₀ = Ω(a, b, c')/Ω``, ``u₁ = (1 − v·b)/(1 − c'·b)`` (pbrt-v4
    ``InvertSphericalTriangleSample``). Fallback branch: intersect the ray with the plane and
    invert the barycentric warp. Returns (2,) in [0, 1]^2.
    """
    a, b, c = _rescale(a, b, c)
    omega = _omega(a, b, c)
    one = jnp.ones_like(omega)
    zero = jnp.zeros_like(omega)
    ua, ub, uc = normalize(a), normalize(b), normalize(c)
    # Arvo: the sub-triangle (a, b, c') and the position along the arc b → c'
    cp = normalize(cross(cross(ub, v), cross(uc, ua)))
    cp = jnp.where(dot(cp, ua + uc) < 0, -cp, cp)
    safe_omega = jnp.where(omega > 0, omega, one)
    u0 = _omega(ua, ub, cp) / safe_omega
    den = 1 - dot(cp, ub)
    u1 = jnp.where(den > 0, (1 - dot(v, ub)) / jnp.where(den > 0, den, one), zero)
    u_arvo = jnp.stack([u0, u1])
    # fallback: ray-plane hit, barycentrics, inverse of b1 = 1 − √u₀, b2 = u₁ √u₀
    n = cross(b - a, c - a)
    nv = dot(n, v)
    t = dot(n, a) / jnp.where(nv != 0, nv, one)
    p = t * v - a
    nn = dot(n, n)
    safe_nn = jnp.where(nn > 0, nn, one)
    b1 = dot(cross(p, c - a), n) / safe_nn
    b2 = dot(cross(b - a, p), n) / safe_nn
    su0 = 1 - b1
    u_area = jnp.stack([su0 * su0, jnp.where(su0 > 0, b2 / jnp.where(su0 > 0, su0, one), zero)])
    use_arvo = omega >= _min_solid_angle(v.dtype)
    u = jnp.where(use_arvo, u_arvo, u_area)
    return jnp.clip(jnp.where(jnp.isfinite(u), u, zero), 0, 1)
