"""Laws of the kernels, as ``hypothesis`` properties over their inputs.

- The ray–triangle test does not depend on the order of a triangle's vertices (hit or miss
  and ``t`` exactly; barycentrics follow the vertices).
- Closed meshes are watertight, for random star-shaped (non-convex) meshes, random poses and
  random vertex orders, through the public kernel and the brute-force query alike.
- Every warp's inverse undoes it; every pdf is finite, non-negative, and zero outside its support.

Each property compiles once (fixed shapes and dtypes, jitted functions built once per case),
so an example costs a kernel call, not a compile.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxrt.geometry.triangle import closest_hit, intersect_triangle, triangle_set
from jaxrt.sampling import warp as W

# a property's examples share one compile; the deadline would count it against the first
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)

PERMUTATIONS = np.array([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])

coordinate = st.floats(-10, 10, allow_nan=False, width=32)
vec3 = hnp.arrays(np.float32, 3, elements=coordinate)


# ------------------------------------------------------------- intersection: vertex order


@jax.jit
def _all_orders(o, d, tri):
    """``intersect_triangle`` of one ray with the triangle in each of the six vertex orders."""
    return jax.vmap(lambda v: intersect_triangle(o, d, v[0], v[1], v[2], jnp.inf))(
        tri[PERMUTATIONS])


@SETTINGS
@given(tri=hnp.arrays(np.float32, (3, 3), elements=coordinate), origin=vec3,
       b=hnp.arrays(np.float32, 3, elements=st.sampled_from([0.0, 0.25, 1 / 3, 0.5, 1.0])
                    | st.floats(0, 1, width=32)))
def test_intersection_is_invariant_under_vertex_order(tri, origin, b):
    # aimed at a point of the triangle's plane given by weights b (zeros: an edge or a vertex)
    target = (b / b.sum() if b.sum() > 0 else np.full(3, 1 / 3, np.float32)) @ tri
    d = (target - origin).astype(np.float32)
    t, b1, b2 = (np.asarray(a) for a in _all_orders(origin, d, tri))
    # hit or miss and t are the same in every order, bit for bit
    assert np.all(np.isfinite(t) == np.isfinite(t[0])), t
    assert np.all((t == t[0]) | ~np.isfinite(t)), t
    if np.isfinite(t[0]):
        # each vertex keeps its weight bit for bit, whichever position (1 or 2) it is given in
        for vertex in range(3):
            at1, at2 = PERMUTATIONS[:, 1] == vertex, PERMUTATIONS[:, 2] == vertex
            weights = np.concatenate([b1[at1], b2[at2]])
            assert np.all(weights == weights[0]), (vertex, weights)
    else:
        assert np.all(b1 == 0) and np.all(b2 == 0)


# ---------------------------------------------------------------- watertight closed meshes

_SPHERE = trimesh.creation.icosphere(subdivisions=1)  # 42 vertices, 80 faces, 120 edges
_EDGE_FRACTIONS = np.array([0.5, 1 / 3, 1e-3])


def _targets(vertices: np.ndarray) -> np.ndarray:
    """Every vertex, and points at fractions along every edge (float64)."""
    edges = _SPHERE.edges_unique
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    along = a + _EDGE_FRACTIONS[:, None, None] * (b - a)
    return np.concatenate([vertices, along.reshape(-1, 3)])


@jax.jit
def _public_kernel_t(o, d, tris):
    """Nearest ``t`` over every triangle by the public kernel (rays × triangles)."""
    one = lambda dd: jnp.min(jax.vmap(lambda v: intersect_triangle(o, dd, v[0], v[1], v[2],
                                                                   jnp.inf)[0])(tris))
    return jax.vmap(one)(d)


@jax.jit
def _set_t(ts, o, d):
    return jax.vmap(lambda dd: closest_hit(ts, o, dd, jnp.inf).t)(d)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), far=st.sampled_from([0.0, 1e2, 1e4]),
       scale=st.sampled_from([1e-2, 1.0, 1e2]))
def test_random_closed_meshes_are_watertight(seed, far, scale):
    rng = np.random.default_rng(seed)
    # a star-shaped, non-convex closed mesh: the icosphere's vertices pushed in or out
    radii = rng.uniform(0.4, 1.6, len(_SPHERE.vertices))
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    centre = far * rng.normal(size=3)
    verts = (scale * radii[:, None] * _SPHERE.vertices) @ rotation.T + centre
    verts32 = verts.astype(np.float32)
    # each triangle's vertices in a random order (the orientation may flip: a ray must not care)
    order = PERMUTATIONS[rng.integers(0, 6, len(_SPHERE.faces))]
    faces = np.take_along_axis(_SPHERE.faces, order, axis=1)
    tris = verts32[faces]
    o = centre.astype(np.float32)
    d = (_targets(verts32.astype(np.float64)) - o).astype(np.float32)
    # every ray from inside leaves the closed surface: one miss is a crack
    for t in (_public_kernel_t(o, d, tris), _set_t(triangle_set(tris), o, d)):
        t = np.asarray(t)
        assert np.all(np.isfinite(t)), f"{np.sum(~np.isfinite(t))} of {len(t)} rays escaped"


# -------------------------------------------------------------------------------- warps

ROUND_TRIP = [pytest.param(s, id=s.name) for s in W.REGISTRY if s.inverse is not None]
ALL_WARPS = [pytest.param(s, id=s.name) for s in W.REGISTRY]
# u kept 1e-3 off the boundary, where inverses are many-to-one (the pole, the disk centre)
_U_LO, _U_HI = float(np.float32(1e-3)), float(np.float32(1 - 1e-3))
inner_u = hnp.arrays(np.float32, (64, 2), elements=st.floats(_U_LO, _U_HI, width=32))


def _args(spec):
    return tuple(jnp.asarray(p, jnp.float32) for p in spec.params[0])


@functools.cache
def _round_trip(spec):
    args = _args(spec)
    first = (lambda u: u[0]) if spec.dim == 1 else (lambda u: u)

    def one(u):
        x = spec.sample(first(u), *args)
        return x, spec.sample(spec.inverse(x, *args), *args)

    return jax.jit(jax.vmap(one))


@pytest.mark.parametrize("spec", ROUND_TRIP)
@SETTINGS
@given(u=inner_u)
def test_warp_after_its_inverse_is_the_identity(spec, u):
    x, x_back = (np.asarray(a) for a in _round_trip(spec)(u))
    # compared in the warped domain (the azimuth wraps): ~1e3 ulps of inverse trigonometry
    assert np.max(np.abs(x_back - x)) < 1e3 * np.finfo(np.float32).eps


def _outside(spec, x: np.ndarray) -> np.ndarray:
    """Which points ``x`` lie outside the warp's support (for its first parameters), by more
    than a few ulps: on the boundary float32 rounding may go either way, and XLA:CPU flushes
    subnormals to zero (z = −1e-39 is the hemisphere's rim)."""
    eps = 8 * np.finfo(np.float32).eps
    if spec.domain == "disk":
        return np.sum(x * x, -1) > 1 + eps
    if spec.domain == "triangle":
        return (x[:, 0] < -eps) | (x[:, 1] < -eps) | (x[:, 0] + x[:, 1] > 1 + eps)
    if spec.name == "tent":
        return np.abs(x) > 1 + eps
    if spec.name == "tent_2d":
        return np.any(np.abs(x) > 1 + eps, -1)
    if spec.domain == "hemisphere":
        return x[:, 2] < -eps
    if spec.name == "uniform_cone":
        return x[:, 2] < spec.params[0][0] - eps
    if spec.name == "uniform_cone_sin2":  # parametrised by sin²θmax
        return x[:, 2] < np.sqrt(1 - spec.params[0][0]) - eps
    if spec.name == "spherical_triangle":  # outside one of the planes through its edges
        a, b, c = (np.asarray(v) for v in spec.params[0])
        side = []
        for p, q, r in ((a, b, c), (b, c, a), (c, a, b)):
            n = np.cross(p, q)
            n = np.sign(np.dot(n, r)) * n / np.linalg.norm(n)
            side.append(x @ n)
        return np.any(np.stack(side) < -eps, 0)
    assert spec.name == "uniform_sphere", spec.name
    return np.zeros(len(x), bool)


def _points(spec, raw: np.ndarray) -> np.ndarray:
    """Points of the ambient space of the warp's output: the plane, a line, unit vectors."""
    if spec.dim == 1:
        return 2 * raw[:, 0]
    if spec.dim == 2:
        return 2 * raw[:, :2]
    n = np.linalg.norm(raw, axis=-1, keepdims=True)
    return np.where(n > 1e-3, raw / np.maximum(n, 1e-3), np.array([0, 0, 1], np.float32))


@functools.cache
def _pdf(spec):
    args = _args(spec)
    return jax.jit(jax.vmap(lambda x: spec.pdf(x, *args)))


@pytest.mark.parametrize("spec", ALL_WARPS)
@SETTINGS
@given(raw=hnp.arrays(np.float32, (64, 3), elements=st.floats(-1, 1, width=32)))
def test_pdf_is_non_negative_and_zero_outside_its_support(spec, raw):
    x = _points(spec, raw).astype(np.float32)
    pdf = np.asarray(_pdf(spec)(x))
    assert np.all(np.isfinite(pdf) & (pdf >= 0)), pdf
    outside = _outside(spec, x.astype(np.float64))
    assert np.all(pdf[outside] == 0), x[outside & (pdf != 0)][:3]
