"""Uniform sampling of the solid angle subtended by a triangle (Arvo 1995), never NaN.

A triangle with vertices ``a, b, c`` given *relative to the shading point* (any length)
subtends the spherical triangle of directions ``{normalize(b0 a + b1 b + b2 c)}``. It is split
at its point ``g`` closest to the shading point into ``(a, g, b), (b, g, c), (c, g, a)``; ``u₀``
picks one of them in proportion to its solid angle and is reused inside it, where Arvo's
method samples uniformly: pick the sub-triangle ``(x, g, c')`` of area ``u₀' Ω_k`` by solving
for ``c'`` on the arc ``x y``, then pick a point on the arc ``g c'`` so that the result is
uniform. The union is uniform: density ``1/Ω`` per steradian.

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
- Ω close to 2π (the shading point just above the triangle's interior) or close to π (just
  beside an edge): every inner angle of the whole triangle tends to π and some of its arcs to
  antipodal ends, where Arvo's formulas divide by ``sin α ≈ 0`` and the arcs' planes are
  ill-defined; float32 Arvo on the whole triangle gives E[cos θ] = 0.31 instead of 0.50 at
  1e-4 under a unit triangle, 0.02 at 1e-5, and put up to 37% of the samples outside the
  triangle beside an edge. The split avoids all of it: every direction of the triangle is
  within 90° of ``g`` (``g·x ≥ |g|²`` for every point ``x`` of it), so the final arc ``g → c'``
  is short; Arvo's ``cos b'`` is used in a half-angle form without ``1/sin α`` or
  ``√(1 − cos²)``; edge planes come from nearly exact cross products (:func:`_xcross`), and
  ``g`` is placed on them when it lies on an edge.

Precision (measured): float32 samples agree with float64 ones on the same ``u`` to ≤ 2e-6 rad
for the registry triangles (small ``u₀`` included; without the split: 3.6e-3 rad near a
hemisphere), for shading points 1e-6…1e-2 above a unit triangle's interior and to ≤ 1e-5 rad
1e-4 above it just beside an edge, in any orientation; E[cos θ] of 1.3e5 float32 samples
matches Lambert's Φ/Ω within 0.2σ there, with every sample inside. Two float32 limits remain,
both for nearly degenerate views. (i) An edge passing within ~1e-4 |x| of the shading point
with the point's foot inside the triangle: the sub-triangle that edge bounds has
near-antipodal ends and its solid angle loses ``~eps / |x̂ + ŷ|`` (relative 2e-4 seen), which
shifts the mapping (4e-5 rad 1e-4 inside such an edge, 4e-4 rad 1e-6 inside, rotated) but
neither the support nor, beyond that relative amount, the density. (ii) A triangle seen
nearly edge-on (its vertices close to one plane through the shading point): the
Van Oosterom Ω of :func:`spherical_triangle_solid_angle`, and with it the pdf ``1/Ω``, loses up
to a few percent (5e-2 in a random sweep; the sum of the split's sub-triangle solid angles
stays within 3e-4 there), and the inverse may pick the wrong sub-triangle.

References: Arvo 1995, "Stratified sampling of spherical triangles" (SIGGRAPH); Van Oosterom
& Strackee 1983, "The solid angle of a plane triangle" (IEEE TBME); pbrt-v4 §6.5.4.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxrt.core.vecmath import dot_components

SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE = {"float32": 1e-4, "float64": 1e-6}
"""Solid angle (sr) below which the sampler falls back to area sampling, per dtype."""


def _min_solid_angle(dtype) -> float:
    return SPHERICAL_TRIANGLE_MIN_SOLID_ANGLE.get(jnp.dtype(dtype).name, 1e-4)


# ------------------------------------------------------------------ 3-vectors as 3 scalars
# Inside this module a vector is a tuple (x, y, z) of same-shape arrays. Under jit(vmap) on
# CPU every operation is then elementwise over the batch and XLA fuses the whole sampler into
# a few loops; with (..., 3) arrays each cross product or stack is a concatenate and each dot
# a minor-axis reduction, which split it into dozens of memory passes (3-4× slower).

Vec = tuple[Array, Array, Array]


def _vec(a: Array) -> Vec:
    return a[..., 0], a[..., 1], a[..., 2]


def _arr(p: Vec) -> Array:
    return jnp.stack(p, axis=-1)


def _add(p: Vec, q: Vec) -> Vec:
    return p[0] + q[0], p[1] + q[1], p[2] + q[2]


def _sub(p: Vec, q: Vec) -> Vec:
    return p[0] - q[0], p[1] - q[1], p[2] - q[2]


def _mul(s: Array, p: Vec) -> Vec:
    return s * p[0], s * p[1], s * p[2]


_dot = dot_components


def _cross(p: Vec, q: Vec) -> Vec:
    return p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]


def _length(p: Vec) -> Array:
    return jnp.sqrt(_dot(p, p))


def _unit(p: Vec) -> Vec:
    """``p / |p|``, and the zero vector for ``p = 0`` (never NaN)."""
    n2 = _dot(p, p)
    inv = jax.lax.rsqrt(jnp.where(n2 > 0, n2, jnp.ones_like(n2)))
    return _mul(inv, p)


def _select(c: Array, p: Vec, q: Vec) -> Vec:
    return jnp.where(c, p[0], q[0]), jnp.where(c, p[1], q[1]), jnp.where(c, p[2], q[2])


def _all_equal(p: Vec, q: Vec) -> Array:
    return (p[0] == q[0]) & (p[1] == q[1]) & (p[2] == q[2])


def _safe_sqrt(x: Array) -> Array:
    return jnp.sqrt(jnp.maximum(x, jnp.zeros_like(x)))


# ----------------------------------------------------------------------- geometry


def _rescale(a: Array, b: Array, c: Array) -> tuple[Vec, Vec, Vec]:
    """The vertices divided by a power of two near their largest |component|, as vectors.

    Exact (a power of two only shifts exponents), so everything downstream sees the caller's
    geometry unperturbed; no overflow or underflow for any vertex scale.
    """
    s = jnp.max(jnp.abs(jnp.stack([a, b, c])))
    _, e = jnp.frexp(s)
    scale = jnp.ldexp(jnp.ones_like(s), e)
    inv = 1 / jnp.where(s > 0, scale, jnp.ones_like(s))
    return _mul(inv, _vec(a)), _mul(inv, _vec(b)), _mul(inv, _vec(c))


def _split_bits(x: Array) -> tuple[Array, Array]:
    """``x = hi + lo`` exactly, each with at most half the significand bits (bit mask).

    Products of halves are then exact in the same precision. A mask, not Veltkamp's
    ``(2^s + 1) x`` trick, so that no fused multiply-add can change the split.
    """
    # keep the top ⌊p/2⌋ of the p significand bits (float32: 12 of 24, float64: 26 of 53)
    p = jnp.finfo(x.dtype).nmant + 1
    bits = 8 * x.dtype.itemsize
    ui = {16: jnp.uint16, 32: jnp.uint32, 64: jnp.uint64}[bits]
    mask = ui(((1 << bits) - 1) ^ ((1 << (p - p // 2)) - 1))
    hi = jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(x, ui) & mask, x.dtype)
    return hi, x - hi


def _xcross(p: Vec, q: Vec) -> Vec:
    """``p × q`` of two float vectors, accurate even when they are nearly (anti)parallel.

    A plain cross product of such vectors (an edge far away, or one passing close to the
    shading point) has relative error ``~eps |p||q| / |p × q|``; here each component
    ``p_i q_j − p_j q_i`` is summed from the exact half-products (:func:`_split_bits`), largest
    first, which leaves ``~2⁻¹² eps |p||q| / |p × q|`` (measured in float32 on pairs tilted by
    1e-7…1: 99th percentile 8e-6 against 0.36 for the plain product).
    """
    (p0h, p0l), (p1h, p1l), (p2h, p2l) = (_split_bits(x) for x in p)
    (q0h, q0l), (q1h, q1l), (q2h, q2l) = (_split_bits(x) for x in q)
    ph, pl, qh, ql = (p0h, p1h, p2h), (p0l, p1l, p2l), (q0h, q1h, q2h), (q0l, q1l, q2l)
    return _add(_add(_cross(ph, qh), _add(_cross(ph, ql), _cross(pl, qh))), _cross(pl, ql))


def _triple(a: Vec, b: Vec, c: Vec) -> Array:
    """``a · ((b − a) × (c − a)) = a · (b × c)``, accurate for far, thin triangles."""
    return _dot(a, _cross(_sub(b, a), _sub(c, a)))


def _omega(a: Vec, b: Vec, c: Vec) -> Array:
    """Van Oosterom–Strackee solid angle of rescaled vertices; 0 exactly in the plane.

    ``tan(Ω/2) = |a·(b×c)| / (|a||b||c| + (a·b)|c| + (a·c)|b| + (b·c)|a|)``.
    """
    la, lb, lc = _length(a), _length(b), _length(c)
    triple = _triple(a, b, c)
    denom = la * lb * lc + _dot(a, b) * lc + _dot(a, c) * lb + _dot(b, c) * la
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


def _edge_crosses(a: Vec, b: Vec, c: Vec) -> tuple[Vec, Vec, Vec]:
    """``a × b, b × c, c × a`` (unnormalised edge-plane normals), nearly exact."""
    return _xcross(a, b), _xcross(b, c), _xcross(c, a)


def _inside(v: Vec, a: Vec, b: Vec, c: Vec, m) -> Array:
    """Whether direction ``v`` passes through the triangle (rescaled vertices).

    ``m``: the edge crosses ``a × b, b × c, c × a`` (:func:`_edge_crosses`).
    """
    sigma = jnp.sign(_triple(a, b, c))
    d = [sigma * _dot(v, _unit(mm)) for mm in m]
    # a few ulps of slack: samples on an edge round to either side of it
    tol = 8 * jnp.finfo(v[0].dtype).eps
    return (d[0] >= -tol) & (d[1] >= -tol) & (d[2] >= -tol) & (sigma != 0)


def _area_sample(u: Array, a: Vec, b: Vec, c: Vec) -> Vec:
    """Direction to a uniform-by-area point of the planar triangle."""
    su0 = jnp.sqrt(u[0])
    b1, b2 = 1 - su0, u[1] * su0
    return _unit(_add(a, _add(_mul(b1, _sub(b, a)), _mul(b2, _sub(c, a)))))


def _area_pdf(v: Vec, a: Vec, b: Vec, c: Vec) -> Array:
    """Solid-angle density of :func:`_area_sample`: ``dist²/(area |cos|) = 2 (n·a)² / |n·v|³``.

    With ``n = (b − a) × (c − a)`` unnormalised; invariant to the vertex scale.
    """
    n = _cross(_sub(b, a), _sub(c, a))
    nv = jnp.abs(_dot(n, v))
    na = _dot(n, a)
    safe = jnp.where(nv > 0, nv, jnp.ones_like(nv))
    return jnp.where(nv > 0, 2 * na * na / (safe * safe * safe), jnp.zeros_like(nv))


# ------------------------------------------------------------------ split and sampling


def _sub_omega(x: Vec, g: Vec, y: Vec, m_xy: Vec) -> Array:
    """Solid angle of ``(x, g, y)`` given ``m_xy ∝ x × y``, where ``x, y`` may be near-antipodal.

    Van Oosterom–Strackee with ``[x, g, y] = −g·(x × y)`` and the cancelling pair of the
    denominator written as ``|x||y| + x·y = |x||y| |x̂ + ŷ|²/2``.
    """
    lx, lg, ly = _length(x), _length(g), _length(y)
    s = _add(_unit(x), _unit(y))
    denom = 0.5 * lg * lx * ly * _dot(s, s) + _dot(x, g) * ly + _dot(g, y) * lx
    return 2 * jnp.arctan2(jnp.abs(_dot(g, m_xy)), denom)


def _split(a: Vec, b: Vec, c: Vec, m):
    """Split point ``g`` and the solid angles of ``(a, g, b), (b, g, c), (c, g, a)``.

    ``g`` is the point of the planar triangle closest to the origin, as a direction (only
    directions matter on the sphere). If the foot of the perpendicular lies in the triangle
    (``n·(a×b), n·(b×c), n·(c×a) ≥ 0``, ``n = (b − a) × (c − a)``), ``g = sign(n·a) n̂``;
    otherwise the nearest of the edges' closest points, ``p`` or ``q`` when the projection
    ``t = −p·d/|d|²`` (``d = q − p``) is clamped, else ``d × (p × q) / |d|²``, which lies in
    the computed edge plane to rounding. Every direction of the triangle is then within 90° of
    ``g`` (``g·x ≥ |g|²`` for each point ``x`` of the planar triangle). The sub-triangles that
    ``g`` makes degenerate (it lies on their outer edge) get exactly Ω = 0. ``m``: the edge
    crosses ``a × b, b × c, c × a``.
    """
    m_ab, m_bc, m_ca = m
    zero = jnp.zeros_like(a[0])
    one = jnp.ones_like(a[0])
    n = _cross(_sub(b, a), _sub(c, a))
    foot_in = (_dot(n, m_ab) >= 0) & (_dot(n, m_bc) >= 0) & (_dot(n, m_ca) >= 0)
    foot = _mul(jnp.sign(_dot(a, n)), _unit(n))

    def on_segment(p, q, m_pq):
        d = _sub(q, p)
        dd = _dot(d, d)
        inv = 1 / jnp.where(dd > 0, dd, one)
        t = -_dot(p, d) * inv
        x = _select(t <= 0, p, _select(t >= 1, q, _mul(inv, _cross(d, m_pq))))
        return x, _dot(x, x)

    (e_ab, d_ab), (e_bc, d_bc), (e_ca, d_ca) = (
        on_segment(a, b, m_ab), on_segment(b, c, m_bc), on_segment(c, a, m_ca))
    pick_ab = d_ab <= jnp.minimum(d_bc, d_ca)
    pick_bc = ~pick_ab & (d_bc <= d_ca)
    pick_ca = ~pick_ab & ~pick_bc
    g = _select(foot_in, foot, _select(pick_ab, e_ab, _select(pick_bc, e_bc, e_ca)))
    at_a, at_b, at_c = _all_equal(g, a), _all_equal(g, b), _all_equal(g, c)
    flat_ab = ~foot_in & (pick_ab | at_a | at_b)
    flat_bc = ~foot_in & (pick_bc | at_b | at_c)
    flat_ca = ~foot_in & (pick_ca | at_c | at_a)
    o0 = jnp.where(flat_ab, zero, _sub_omega(a, g, b, m_ab))
    o1 = jnp.where(flat_bc, zero, _sub_omega(b, g, c, m_bc))
    o2 = jnp.where(flat_ca, zero, _sub_omega(c, g, a, m_ca))
    return g, (o0, o1, o2)


def _arvo(u: Array, x: Vec, g: Vec, y: Vec, n_xy: Vec, omega: Array) -> Vec:
    """Arvo's sampler on the sub-triangle ``(A, B, C) = (x, g, y)`` of solid angle ``omega``.

    ``x, g, y`` any lengths; ``n_xy`` the unit normal ``∝ x × y``. First the point ``c'`` on
    the arc ``x → y`` such that ``(x, g, c')`` has area ``Â = u₀ Ω``. With ``α`` the inner
    angle at ``x`` and ``c`` the arc ``x → g``, Arvo's ``cos b'`` of the arc ``b' = x → c'``
    is, in half-angle form (product-to-sum on his numerator and denominator),

        tan(b'/2) = sin(Â/2) cos(c/2) / (sin(α − Â/2) sin(c/2)) = p / q,

    so ``c' ∝ (q² − p²) x̂ + 2pq t̂`` (``t̂`` the tangent at ``x̂`` towards ``y``), with
    ``p = sin(Â/2) |x̂ + ĝ|``, ``q = sin(α − Â/2) |x̂ − ĝ|``: no division by ``sin α`` and no
    ``√(1 − cos²)``, accurate at both ends of the arc (``sin(α − Â/2) > 0`` because
    ``Ω < 2α`` for every spherical triangle). ``c'`` is held at ``y`` if rounding carries it
    past (``p |x̂ + ŷ| ≥ q |x̂ − ŷ|``). Then the point at ``1 − cos = u₁ (1 − cos(g, c'))``
    on the arc ``g → c'`` (at most 90° long), with ``1 − cos`` as half squared chords, so
    nothing cancels near ``g``.
    """
    a, b, ch = _unit(x), _unit(g), _unit(y)
    n_ab = _unit(_cross(x, g))
    # inner angle α at a between the tangents n × a of the two arcs; tangent towards c
    sin_alpha = _length(_cross(n_ab, n_xy))
    cos_alpha = _dot(n_ab, n_xy)
    t_c = _cross(n_xy, a)
    half = u[0] * omega / 2
    s_h, c_h = jnp.sin(half), jnp.cos(half)
    a_plus_b, a_minus_b = _add(a, b), _sub(a, b)
    p = s_h * _length(a_plus_b)
    q = (sin_alpha * c_h - cos_alpha * s_h) * _length(a_minus_b)  # sin(α − Â/2) |a − b|
    c_prime = _unit(_add(_mul(q * q - p * p, a), _mul(2 * p * q, t_c)))
    # rounding of Ω may ask for a little more than the sub-triangle: stop at y. Half-angle
    # tangents, tan(b'/2) = p/q against tan(θ_xy/2) = |x̂ − ŷ|/|x̂ + ŷ|, resolve both ends
    # (1 − cos θ_xy ≈ 2 would lose the deficit of a near-antipodal arc to rounding)
    past_y = p * _length(_add(a, ch)) >= q * _length(_sub(a, ch))
    c_prime = _select(past_y, ch, c_prime)
    # the arc b → c' (b = g): 1 − cos of the target point = u₁ (1 − c'·b)
    d = _sub(c_prime, b)
    t = u[1] * 0.5 * _dot(d, d)
    w_perp = _unit(_sub(d, _mul(_dot(d, b), b)))
    return _add(_mul(1 - t, b), _mul(_safe_sqrt(t * (2 - t)), w_perp))


def square_to_spherical_triangle(u: Array, a: Array, b: Array, c: Array) -> Array:
    """Direction uniformly distributed over the solid angle of triangle ``a, b, c``.

    The triangle is split at its point ``g`` closest to the shading point into ``(a, g, b),
    (b, g, c), (c, g, a)`` of solid angles ``Ω₀, Ω₁, Ω₂`` (sum ``Ω``). ``u₀ Ω`` picks
    sub-triangle ``k = [u₀Ω ≥ Ω₀] + [u₀Ω ≥ Ω₀ + Ω₁]`` (never one of zero solid angle) and is
    reused as ``u₀' = (u₀Ω − Ω₀ − … − Ω_{k−1})/Ω_k``; Arvo's method then samples that
    sub-triangle uniformly (module docstring), so the union is uniform with density ``1/Ω``.
    For ``Ω`` below the dtype's threshold, uniform area sampling of the planar triangle
    instead. The matching density is :func:`square_to_spherical_triangle_pdf`. Args: ``u``
    (2,) in [0, 1)²; ``a, b, c`` (3,) vertices relative to the shading point. Returns a unit
    (3,) direction (the zero vector only if all vertices are at the origin).
    """
    a, b, c = _rescale(a, b, c)
    omega = _omega(a, b, c)
    fallback = _area_sample(u, a, b, c)
    m = _edge_crosses(a, b, c)
    g, (o0, o1, o2) = _split(a, b, c, m)
    one = jnp.ones_like(omega)
    c1 = o0 + o1
    t = u[0] * (c1 + o2)
    k1 = (t >= o0) & ((o1 > 0) | (o2 > 0))
    k2 = (t >= c1) & (o2 > 0)
    x = _select(k2, c, _select(k1, b, a))
    y = _select(k2, a, _select(k1, c, b))
    m_xy = _select(k2, m[2], _select(k1, m[1], m[0]))
    om_k = jnp.where(k2, o2, jnp.where(k1, o1, o0))
    cum = jnp.where(k2, c1, jnp.where(k1, o0, jnp.zeros_like(o0)))
    u0 = (t - cum) / jnp.where(om_k > 0, om_k, one)
    u0 = jnp.clip(u0, 0, jnp.nextafter(one, jnp.zeros_like(one)))
    w = _arvo(jnp.stack([u0, u[1]]), x, g, y, _unit(m_xy), om_k)
    finite = jnp.isfinite(w[0]) & jnp.isfinite(w[1]) & jnp.isfinite(w[2])
    use_arvo = (omega >= _min_solid_angle(u.dtype)) & finite
    return _arr(_select(use_arvo, _unit(w), fallback))


def square_to_spherical_triangle_pdf(v: Array, a: Array, b: Array, c: Array, *,
                                     assume_inside: bool = False) -> Array:
    """Solid-angle density of :func:`square_to_spherical_triangle` at direction ``v``.

    ``1/Ω`` inside the spherical triangle when ``Ω`` is above the dtype's threshold; below
    it, the density of the area-sampling fallback, ``2 (n·a)² / |n·v|³`` with ``n = (b − a) ×
    (c − a)`` (``= dist² / (area |cos θ_light|)``); 0 outside the triangle and when Ω = 0.
    ``assume_inside`` (static) skips the inside test for a caller that knows ``v`` passes
    through the triangle (a sample of this warp, or a ray that hit it): in float32 far from
    the origin the test can say "no" near the edges, and a light pdf of 0 there zeroes an
    MIS weight. Args: ``v`` unit (3,); ``a, b, c`` (3,) relative to the shading point.
    """
    a, b, c = _rescale(a, b, c)
    v = _vec(v)
    omega = _omega(a, b, c)
    inside = omega > 0
    if not assume_inside:
        inside = inside & _inside(v, a, b, c, _edge_crosses(a, b, c))
    use_arvo = omega >= _min_solid_angle(v[0].dtype)
    safe = jnp.where(omega > 0, omega, jnp.ones_like(omega))
    pdf = jnp.where(use_arvo, 1 / safe, _area_pdf(v, a, b, c))
    return jnp.where(inside, pdf, jnp.zeros_like(pdf))


def spherical_triangle_to_square(v: Array, a: Array, b: Array, c: Array) -> Array:
    """Inverse of :func:`square_to_spherical_triangle` for ``v`` inside the triangle.

    Arvo branch: the sub-triangle ``(x, g, y)`` of the split that contains ``v`` (largest
    worst-edge margin ``min σ v·n_edge``); ``c'`` is where the great circle through ``g, v``
    meets the arc ``x y``; ``u₀ = (Ω₀ + … + Ω_{k−1} + Ω(x, g, c'))/Ω``, ``u₁ = |v − ĝ|² /
    |c' − ĝ|²`` (``= (1 − v·ĝ)/(1 − c'·ĝ)``). Fallback branch: intersect the ray with the
    plane and invert the barycentric warp. Args: ``v`` unit (3,); ``a, b, c`` (3,) relative
    to the shading point. Returns (2,) in [0, 1]².
    """
    a, b, c = _rescale(a, b, c)
    v = _vec(v)
    omega = _omega(a, b, c)
    one = jnp.ones_like(omega)
    zero = jnp.zeros_like(omega)
    m = _edge_crosses(a, b, c)
    g, (o0, o1, o2) = _split(a, b, c, m)
    gu = _unit(g)
    # which sub-triangle holds v: edge planes shared by neighbours are exact negatives
    va, vb, vc = (_dot(v, _unit(_cross(p, g))) for p in (a, b, c))
    n_ab, n_bc, n_ca = _unit(m[0]), _unit(m[1]), _unit(m[2])

    def margin(om, m_xy, d_xg, d_yg, d_xy):
        sigma = -jnp.sign(_dot(g, m_xy))  # [x, g, y] = −g·(x × y)
        mg = jnp.minimum(jnp.minimum(sigma * d_xg, -sigma * d_yg), -sigma * d_xy)
        return jnp.where((sigma != 0) & (om > 0), mg, jnp.full_like(mg, -jnp.inf)), sigma

    m0, s0 = margin(o0, m[0], va, vb, _dot(v, n_ab))
    m1, s1 = margin(o1, m[1], vb, vc, _dot(v, n_bc))
    m2, s2 = margin(o2, m[2], vc, va, _dot(v, n_ca))
    k2 = (m2 > m0) & (m2 > m1)
    k1 = ~k2 & (m1 > m0)
    x = _select(k2, c, _select(k1, b, a))
    n_xy = _select(k2, n_ca, _select(k1, n_bc, n_ab))
    sigma = jnp.where(k2, s2, jnp.where(k1, s1, s0))
    cum = jnp.where(k2, o0 + o1, jnp.where(k1, o0, zero))
    total = o0 + o1 + o2
    # (g × v) × (x × y) = x [g, v, y] − y [g, v, x] = −σ (a positive combination of x and y)
    # for v inside (x, g, y) of orientation σ = sign [x, g, y]: the point on the arc x → y
    cp = _mul(-sigma, _unit(_cross(_cross(gu, v), n_xy)))
    u0 = (cum + _sub_omega(x, g, cp, _cross(x, cp))) / jnp.where(total > 0, total, one)
    cg, vg = _sub(cp, gu), _sub(v, gu)
    den = _dot(cg, cg)
    u1 = jnp.where(den > 0, _dot(vg, vg) / jnp.where(den > 0, den, one), zero)
    u_arvo = jnp.stack([u0, u1])
    # fallback: ray-plane hit, barycentrics, inverse of b1 = 1 − √u₀, b2 = u₁ √u₀
    ba, ca = _sub(b, a), _sub(c, a)
    n = _cross(ba, ca)
    nv = _dot(n, v)
    tt = _dot(n, a) / jnp.where(nv != 0, nv, one)
    p = _sub(_mul(tt, v), a)
    nn = _dot(n, n)
    safe_nn = jnp.where(nn > 0, nn, one)
    b1 = _dot(_cross(p, ca), n) / safe_nn
    b2 = _dot(_cross(ba, p), n) / safe_nn
    su0 = 1 - b1
    u_area = jnp.stack([su0 * su0, jnp.where(su0 > 0, b2 / jnp.where(su0 > 0, su0, one), zero)])
    use_arvo = omega >= _min_solid_angle(v[0].dtype)
    u = jnp.where(use_arvo, u_arvo, u_area)
    return jnp.clip(jnp.where(jnp.isfinite(u), u, zero), 0, 1)
