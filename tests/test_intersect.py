"""Tests of the watertight ray–triangle intersection and the brute-force queries."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.intersect import intersect_triangle

_intersect_batch = jax.jit(jax.vmap(intersect_triangle, in_axes=(0, 0, 0, 0, 0, None)))


def moller_trumbore64(o, d, v0, v1, v2):
    """Reference: Möller–Trumbore in float64 on float64 copies of the inputs (batched numpy)."""
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(d, e2)
    det = np.sum(e1 * p, -1)
    s = o - v0
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = np.sum(s * p, -1) / det
        q = np.cross(s, e1)
        b2 = np.sum(d * q, -1) / det
        t = np.sum(e2 * q, -1) / det
    hit = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 0) & (det != 0)
    return np.where(hit, t, np.inf), b1, b2


def edge_distance(v0, v1, v2, b1, b2):
    """Distance of the barycentric point to the nearest edge, in units of the triangle's size."""
    return np.minimum(np.minimum(np.abs(b1), np.abs(b2)), np.abs(1 - b1 - b2))


def test_agrees_with_float64_reference(x64):
    rng = np.random.default_rng(1)
    n = 20000
    dtype = np.float64 if x64 else np.float32
    o = rng.uniform(-2, 2, (n, 3)).astype(dtype)
    tri = rng.uniform(-1, 1, (n, 3, 3)).astype(dtype)
    d = (rng.uniform(-1, 1, (n, 3)) - o).astype(dtype)
    t, b1, b2 = map(np.asarray, _intersect_batch(o, d, tri[:, 0], tri[:, 1], tri[:, 2], jnp.inf))
    assert t.dtype == dtype and b1.dtype == dtype
    tr, r1, r2 = moller_trumbore64(*(x.astype(np.float64) for x in (o, d, tri[:, 0], tri[:, 1],
                                                                     tri[:, 2])))
    hit, hit_ref = np.isfinite(t), np.isfinite(tr)
    # hit/miss may differ only within 1e-4 (barycentric) of an edge: float32 rounding is ~1e-6
    near_edge = edge_distance(None, None, None, r1, r2) < 1e-4
    assert np.all((hit == hit_ref) | near_edge)
    assert hit.sum() > n // 20  # the random set really exercises hits
    both = hit & hit_ref
    tol = 1e-12 if x64 else 1e-4  # relative, ~1000 ulp: conditioning of random triangles
    assert np.all(np.abs(t[both] - tr[both]) <= tol * np.abs(tr[both]))
    btol = 1e-11 if x64 else 1e-4
    assert np.all(np.abs(b1[both] - r1[both]) <= btol)
    assert np.all(np.abs(b2[both] - r2[both]) <= btol)


def test_degenerate_triangles_never_hit():
    # zero area, collinear (exactly representable), repeated vertex
    tris = np.array([[[0, 0, 0], [0, 0, 0], [0, 0, 0]],
                     [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                     [[0, 0, 0], [1, 1, 0], [1, 1, 0]],
                     [[-1, -1, 0], [1, 1, 0], [0.5, 0.5, 0]]], np.float32)
    # rays aimed straight at the degenerate segment's points, from several directions
    n = len(tris)
    for d in ([0, 0, -1], [0.3, -0.2, -1], [0, 1, 0], [1, 0, 0]):
        d = np.asarray(d, np.float32)
        target = tris.mean(1)
        o = target - 2 * d
        t, b1, b2 = _intersect_batch(o, np.broadcast_to(d, (n, 3)), tris[:, 0], tris[:, 1],
                                     tris[:, 2], jnp.inf)
        assert np.all(np.isinf(np.asarray(t)))
        assert not np.any(np.isnan(np.asarray(b1))) and not np.any(np.isnan(np.asarray(b2)))


def test_axis_aligned_directions_no_nan():
    tri = np.array([[-1, -1, -1], [1, -1, 0.5], [0, 1, 1]], np.float32)
    axes = np.concatenate([np.eye(3), -np.eye(3)]).astype(np.float32)
    o = -3 * axes
    # a triangle containing the origin is crossed by every axis ray from ±3
    t, b1, b2 = map(np.asarray, _intersect_batch(o, axes, *np.broadcast_to(tri, (6, 3, 3))
                                                 .transpose(1, 0, 2), jnp.inf))
    assert np.all(np.isfinite(t))
    assert np.all((t > 2) & (t < 4))  # origin at distance 3, triangle within ±1 of it
    assert np.all((b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1))
    # zero direction: a miss, not a NaN
    tz, *_ = intersect_triangle(np.zeros(3, np.float32), np.zeros(3, np.float32), *tri, np.inf)
    assert np.isinf(tz)


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
def test_tiny_and_huge_triangles(scale):
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32) * np.float32(scale)
    o = np.array([0.1, 0.1, 2], np.float32) * np.float32(scale)
    t, b1, b2 = intersect_triangle(o, np.array([0, 0, -1], np.float32), *tri, np.inf)
    assert abs(float(t) / scale - 2) < 1e-6  # relative: a few ulp
    tm, *_ = intersect_triangle(o, np.array([0, 0, 1], np.float32), *tri, np.inf)
    assert np.isinf(tm)  # pointing away
