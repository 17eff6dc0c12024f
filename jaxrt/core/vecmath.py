"""Vector maths for one sample, and the vocabulary used throughout jaxrt.

Every function here works on single vectors (shape ``(3,)`` or scalars); batch with
``jax.vmap``. Constants take the dtype of the input, so float32 stays float32 and the
same code is correct under ``jax_enable_x64``.

Vocabulary (pbrt's convention; Nori and Mitsuba name some of these differently):

- ``u``: uniform variates in [0, 1).
- ``wo``: unit direction from the shading point *towards the viewer*.
- ``wi``: unit direction from the shading point *towards the light*. Both leave the surface.
- ``n``: unit normal; ``p``: a point; ``t``: a distance along a ray; ``b1, b2``: barycentrics
  of the second and third vertex (``b0 = 1 - b1 - b2``).
- ``f``: BSDF value; ``le``: emitted radiance; ``li``: incident radiance.
- ``pdf_light``, ``pdf_bsdf``: densities (solid angle unless said otherwise);
  ``w_light``, ``w_bsdf``: multiple-importance-sampling weights.
- Local (shading) frames have +z along the normal: ``cos θ = w[2]``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array


def device_array(x, dtype=None) -> Array:
    """Host data (numbers, lists, numpy arrays) as a JAX array, like ``jnp.asarray(x, dtype)``
    (dtype canonicalised: float32 unless x64), but without compiling anything.

    ``jnp.asarray`` converts through a small jitted program per shape and dtype: building the
    Cornell box compiled 16 of them (0.3–0.4 s of a 2 s start-up). ``jax.device_put`` of a
    numpy array only copies it (a private copy, so the caller may mutate its array).
    """
    a = np.asarray(x)
    dt = jax.dtypes.canonicalize_dtype(a.dtype if dtype is None else dtype)
    return jax.device_put(np.array(a, dtype=dt, copy=True))


@jax.custom_jvp
def computed_once(x: Array) -> Array:
    """``x`` itself, stored by XLA:CPU, so that its consumers read it instead of recomputing it.

    XLA fuses a cheap elementwise producer into every consumer kernel, and into every element
    of a (…, 3) output: a direction used by three kernels, or stacked into a (3,) vector, has
    its whole chain of operations (hash, warp, ``sin``/``cos``, frame change) recomputed in
    each. A reduction's result is stored, not fused into its consumers, so this returns
    ``(−0 + x) + −0`` as a sum-reduction over the pair ``(x, −0)``: the chain is computed once,
    into that reduction (per element of ``x``: a (3,) vector's components still each compute
    the scalars they share), and the consumers read it. Adding −0 is exact for every ``x``
    (NaN, ±0, ±∞ included; subnormals as XLA:CPU's flush-to-zero leaves them); the tangent
    passes through unchanged. Shape of ``x``. (Not a max-reduction with −∞: under the fast
    min/max jaxrt compiles with (:data:`jaxrt.core.xla.COMPILER_OPTIONS`) that turns NaN into
    −∞, and a NaN-propagating max costs more.)

    Use it where a costly value has several consumers in the hot path: the BSDF-sampled
    direction (spawn offset, traversal, the next shading frame, a path's regeneration select)
    and a path step's radiance after next-event estimation (its state and the fold into the
    pixel's four sums): 256² Cornell box path pass 1.04–1.12× and 1.01–1.10× per CPU-second
    for the two (benchmarks/README.md#computed-once).
    """
    pair = jnp.stack([x, jnp.full_like(x, -0.0)])
    return jax.lax.reduce(pair, jnp.asarray(-0.0, pair.dtype), _plus, (0,))


def _plus(a, b):
    # not lax.add: JAX would take (add, −0) for the monoid reduce_sum, whose zero is +0. One
    # function object for every call, so that JAX traces the reduction's body once per dtype
    return a + b


@computed_once.defjvp
def _computed_once_jvp(primals, tangents):
    return computed_once(primals[0]), tangents[0]


def dot(a: Array, b: Array) -> Array:
    """Inner product of two vectors along the last axis: ``Σ a_k b_k``.

    A reduction, not ``a₀b₀ + a₁b₁ + a₂b₂``: under ``vmap`` the per-component form slices the
    minor axis of (N, 3) arrays, and the 256² MIS render runs ~0.7× as fast
    (benchmarks/README.md#vector-type).
    """
    return jnp.sum(a * b, axis=-1)


def dot_components(a, b) -> Array:
    """``a₀b₀ + a₁b₁ + a₂b₂`` of two 3-vectors given as components (tuples, lists or (3,)
    arrays; extra components are ignored), summed left to right.

    The other form of :func:`dot`, for vectors formed per component: there a reduction fuses
    the stack, a transpose and the sum over the axis of 3 into one kernel, which XLA:CPU runs
    ~10× slower per lane than these products (an area light's pdf at a BSDF ray's hit:
    benchmarks/README.md#vector-type). Where the operands are stored (…, 3) arrays,
    :func:`dot` is the faster one.
    """
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Array, b: Array) -> Array:
    """Cross product ``a × b`` of two 3-vectors."""
    return jnp.cross(a, b)


def length(a: Array) -> Array:
    """Euclidean length ``‖a‖``."""
    return jnp.sqrt(dot(a, a))


def normalize(a: Array) -> Array:
    """``a / ‖a‖``; the zero vector maps to zero instead of NaN."""
    n = length(a)
    safe = jnp.where(n > 0, n, jnp.ones_like(n))
    return a / safe[..., None] if a.ndim > 1 else a / safe


def safe_sqrt(x: Array) -> Array:
    """``√max(x, 0)``: square root that tolerates tiny negative round-off."""
    return jnp.sqrt(jnp.maximum(x, jnp.zeros_like(x)))


def coordinate_system(n: Array) -> tuple[Array, Array]:
    """Two unit tangents ``(s, t)`` with ``(s, t, n)`` a right-handed orthonormal frame.

    Branchless construction of Duff et al. 2017, "Building an Orthonormal Basis, Revisited"
    (JCGT 6(1)); continuous everywhere but on the sign flip at ``n_z = 0`` and exact for
    ``n = ±z``. ``n``: unit (3,). Returns two (3,) vectors.
    """
    one = jnp.ones_like(n[2])
    sign = jnp.where(n[2] >= 0, one, -one)
    a = -one / (sign + n[2])
    b = n[0] * n[1] * a
    s = jnp.stack([one + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    t = jnp.stack([b, sign + n[1] * n[1] * a, -n[1]])
    return s, t


def to_local(v: Array, n: Array) -> Array:
    """Express world vector ``v`` in the frame with +z along unit normal ``n``."""
    s, t = coordinate_system(n)
    return jnp.stack([dot(v, s), dot(v, t), dot(v, n)])


def to_world(v: Array, n: Array) -> Array:
    """Inverse of :func:`to_local`: local ``v`` (z along ``n``) to world coordinates."""
    s, t = coordinate_system(n)
    return v[0] * s + v[1] * t + v[2] * n


def reflect(w: Array, n: Array) -> Array:
    """Mirror of ``w`` about unit normal ``n``: ``2 (w·n) n − w`` (both leave the surface)."""
    return 2 * dot(w, n) * n - w


def _taylor(coefficients: list[float], x2: Array) -> Array:
    """``Σ_k x2^k / c_k`` by Horner's rule (``c_k`` the signed factorials)."""
    acc = jnp.asarray(1 / coefficients[-1], x2.dtype)
    for c in coefficients[-2::-1]:
        acc = jnp.asarray(1 / c, x2.dtype) + x2 * acc
    return acc


def cos_sin_octant(s: Array) -> tuple[Array, Array]:
    """``(cos φ, sin φ)`` of ``φ = π s / 4`` for ``|s| ≤ 1`` (an octant), by polynomials.

    Taylor series to the first term below the dtype's rounding on ``|φ| ≤ π/4``: ``φ^9`` for
    sine and ``φ^10`` for cosine in float32 (truncation < 2·10⁻⁹), ``φ^17`` and ``φ^18`` in
    float64 (< 10⁻¹⁸); the result is within a few ulps of the true value. Vector
    arithmetic only: XLA:CPU calls the scalar ``sincosf`` of libm for ``jnp.cos``/``jnp.sin``
    once per element, 4.7 % of the CPU time of the 256² Cornell box MIS pass (perf) for the
    concentric disk map alone. Elementwise: ``s`` of any shape, two arrays of that shape.
    """
    phi = jnp.asarray(np.pi / 4, s.dtype) * s
    x2 = phi * phi
    terms = 5 if s.dtype == jnp.float32 else 9
    sine = [(-1) ** k * float(np.prod(np.arange(1, 2 * k + 2))) for k in range(terms)]
    cosine = [(-1) ** k * float(np.prod(np.arange(1, 2 * k + 1))) for k in range(terms + 1)]
    return _taylor(cosine, x2), phi * _taylor(sine, x2)


def cos_sin_turn(t: Array) -> tuple[Array, Array]:
    """``(cos 2πt, sin 2πt)`` for ``t ∈ [0, 1]`` (a turn), by :func:`cos_sin_octant`.

    ``q = round(4t)`` quarter turns and ``s = 8t − 2q ∈ [−1, 1]`` (exact: a power-of-two
    scaling and a Sterbenz subtraction), so ``2πt = qπ/2 + πs/4`` and the result is the
    octant's pair rotated by ``q`` quarter turns: exactly as accurate. Elementwise: ``t`` of
    any shape, two arrays of that shape.
    """
    q = jnp.round(4 * t)
    c, s = cos_sin_octant(8 * t - 2 * q)
    m = q.astype(jnp.int32) % 4
    return (jnp.where(m == 0, c, jnp.where(m == 1, -s, jnp.where(m == 2, -c, s))),
            jnp.where(m == 0, s, jnp.where(m == 1, c, jnp.where(m == 2, -s, -c))))


def spherical_direction_turn(sin_theta: Array, cos_theta: Array, t: Array) -> Array:
    """:func:`spherical_direction` with ``φ = 2π t`` (``t ∈ [0, 1]``), without ``sin``/``cos``
    (:func:`cos_sin_turn`): the form every warp that draws ``φ = 2π u`` uses. Scalars in,
    unit (3,) out when ``sin²θ + cos²θ = 1``."""
    c, s = cos_sin_turn(t)
    return jnp.stack([sin_theta * c, sin_theta * s, cos_theta])


def spherical_direction(sin_theta: Array, cos_theta: Array, phi: Array) -> Array:
    """Unit vector ``(sinθ cosφ, sinθ sinφ, cosθ)`` in a local frame with +z as the pole."""
    return jnp.stack([sin_theta * jnp.cos(phi), sin_theta * jnp.sin(phi), cos_theta])


def spherical_phi(w: Array) -> Array:
    """Azimuth ``φ ∈ [0, 2π)`` of local direction ``w``."""
    phi = jnp.arctan2(w[1], w[0])
    return jnp.where(phi < 0, phi + 2 * jnp.pi, phi).astype(w.dtype)


def spherical_theta(w: Array) -> Array:
    """Polar angle ``θ ∈ [0, π]`` of unit local direction ``w`` (stable near the poles)."""
    return 2 * jnp.arctan2(length(w - jnp.array([0, 0, 1], w.dtype)),
                           length(w + jnp.array([0, 0, 1], w.dtype)))


def area_to_solid_angle_pdf(pdf_area: Array, dist2: Array, cos_light: Array) -> Array:
    """Change of measure of a density from area to solid angle.

    ``p_ω = p_A · ‖x − y‖² / |cos θ_light|`` (the Jacobian ``dω = |cos θ_light| dA / ‖x − y‖²``).
    Returns 0 where ``cos θ_light == 0`` (the light is seen edge-on and has no solid angle).
    """
    c = jnp.abs(cos_light)
    safe = jnp.where(c > 0, c, jnp.ones_like(c))
    return jnp.where(c > 0, pdf_area * dist2 / safe, jnp.zeros_like(pdf_area))


def solid_angle_to_area_pdf(pdf_solid_angle: Array, dist2: Array, cos_light: Array) -> Array:
    """Inverse change of measure: ``p_A = p_ω · |cos θ_light| / ‖x − y‖²``."""
    safe = jnp.where(dist2 > 0, dist2, jnp.ones_like(dist2))
    return jnp.where(dist2 > 0, pdf_solid_angle * jnp.abs(cos_light) / safe,
                     jnp.zeros_like(pdf_solid_angle))
