"""Tests of the watertight ray–triangle intersection and the brute-force queries."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxrt.geometry.bvh import build_bvh
from jaxrt.geometry.eye_rays import closest_hit_from_origin
from jaxrt.geometry.triangle import (
    TriangleHit,
    TriangleSet,
    any_hit,
    closest_hit,
    intersect_triangle,
    triangle_set,
)

_intersect_batch = jax.jit(jax.vmap(intersect_triangle, in_axes=(0, 0, 0, 0, 0, None)))
_intersect_one = jax.jit(intersect_triangle)
# the geometry is an argument, not a closure: one compilation per (F, dtype), shared by tests
_closest_batch = jax.jit(jax.vmap(closest_hit, in_axes=(None, 0, 0, 0)))
_any_batch = jax.jit(jax.vmap(any_hit, in_axes=(None, 0, 0, 0)))
_from_origin_batch = jax.jit(jax.vmap(closest_hit_from_origin, in_axes=(None, None, 0, 0)))


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


def edge_distance(b1, b2):
    """Barycentric distance of a point of the plane to the nearest edge line (0 on an edge)."""
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
    near_edge = edge_distance(r1, r2) < 1e-4
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
    tz, *_ = _intersect_one(np.zeros(3, np.float32), np.zeros(3, np.float32), *tri, np.inf)
    assert np.isinf(tz)


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
def test_tiny_and_huge_triangles(scale):
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32) * np.float32(scale)
    o = np.array([0.1, 0.1, 2], np.float32) * np.float32(scale)
    t, b1, b2 = _intersect_one(o, np.array([0, 0, -1], np.float32), *tri, np.inf)
    assert abs(float(t) / scale - 2) < 1e-6  # relative: a few ulp
    tm, *_ = _intersect_one(o, np.array([0, 0, 1], np.float32), *tri, np.inf)
    assert np.isinf(tm)  # pointing away


def test_grazing_and_parallel_rays(x64):
    dtype = np.float64 if x64 else np.float32
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype)
    n = 64
    # grazing: elevation angles 1e-1 … 1e-7 rad, aimed at a point well inside the triangle
    ang = np.geomspace(1e-1, 1e-7, n)
    target = np.array([0.05, -0.2, 0.0])
    d = np.stack([np.cos(ang), np.zeros(n), -np.sin(ang)], 1)
    o = target - 10 * d
    tris = np.broadcast_to(tri, (n, 3, 3)).transpose(1, 0, 2)
    t, b1, b2 = map(np.asarray, _intersect_batch(o.astype(dtype), d.astype(dtype), *tris, jnp.inf))
    assert not np.any(np.isnan(t)) and not np.any(np.isnan(b1))
    hit = np.isfinite(t)
    # pbrt's conservative δt grows like 1/angle: in float32 rays grazing below ~5e-6 rad are
    # rejected (as in pbrt-v4); above 1e-5 rad (and always in float64) every ray must hit
    assert np.all(hit[ang >= (1e-5 if not x64 else 0)])
    # t = 10 to float rounding (the target point is exact; o is rounded at ~1e-6 relative)
    assert np.all(np.abs(t[hit] - 10) <= (1e-9 if x64 else 1e-5) * 10)
    # parallel: in the plane (coplanar) and above it; never a hit, never NaN
    dpar = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0], [-1, 0.3, 0]], dtype)
    for z in (0.0, 1e-3):
        opar = np.array([[-5, 0, z], [0, -5, z], [-5, -5, z], [5, -0.5, z]], dtype)
        tp, c1, c2 = map(np.asarray, _intersect_batch(opar, dpar,
                                                      *np.broadcast_to(tri, (4, 3, 3))
                                                      .transpose(1, 0, 2), jnp.inf))
        assert np.all(np.isinf(tp)) and not np.any(np.isnan(c1 + c2))


def cornell_like():
    """36 triangles: a closed room and two blocks (the benchmark scene)."""
    room = trimesh.creation.box(extents=(2, 2, 2))
    tall = trimesh.creation.box(extents=(0.6, 1.2, 0.6))
    tall.apply_translation((-0.35, -0.4, -0.3))
    short = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    short.apply_translation((0.35, -0.7, 0.35))
    return np.concatenate([m.vertices[m.faces] for m in (room, tall, short)])


@pytest.fixture(scope="module")
def scene_rays():
    rng = np.random.default_rng(7)
    n = 4096
    o = rng.uniform(-0.95, 0.95, (n, 3))
    d = rng.standard_normal((n, 3))
    t_max = rng.choice([np.inf, 0.3, 1.0], n)
    return o, d, t_max


def test_closest_and_any_hit_agree_with_per_triangle_reference(x64, scene_rays):
    dtype = np.float64 if x64 else np.float32
    tris = cornell_like().astype(dtype)
    ts = triangle_set(tris)
    assert isinstance(ts, TriangleSet) and ts.vertices.dtype == dtype
    o, d, t_max = (x.astype(dtype) for x in scene_rays)
    hit = _closest_batch(ts, o, d, t_max)
    occluded = np.asarray(_any_batch(ts, o, d, t_max))
    assert isinstance(hit, TriangleHit)
    assert hit.t.dtype == dtype and hit.prim.dtype == np.int32 and hit.ng.dtype == dtype
    # reference: every ray against every triangle with the single-triangle kernel, then argmin
    all_t = np.asarray(jax.jit(jax.vmap(jax.vmap(intersect_triangle,
                                                 in_axes=(None, None, 0, 0, 0, None)),
                                        in_axes=(0, 0, None, None, None, 0)))(
        o, d, tris[:, 0], tris[:, 1], tris[:, 2], t_max)[0])
    t_ref = all_t.min(1)
    prim, t = np.asarray(hit.prim), np.asarray(hit.t)
    np.testing.assert_array_equal(prim >= 0, np.isfinite(t_ref))
    h = prim >= 0
    # the blocks stand on the floor (coplanar faces), so the winner may be either of two
    # triangles at equal t, and the two compilations round t differently: allow 16 ulp of
    # the scene's coordinates (size ~1, |d| ~ 1), the scale of t's rounding error
    tol = 16 * np.finfo(dtype).eps * (1 + t_ref[h])
    t_chosen = all_t[np.arange(len(prim)), np.maximum(prim, 0)]
    assert np.all(np.abs(t_chosen[h] - t_ref[h]) <= tol)
    assert np.all(np.abs(t[h] - t_ref[h]) <= tol)
    # any_hit ⇔ closest t ≤ t_max (a hit exists in range)
    np.testing.assert_array_equal(occluded, t <= t_max)
    assert 0.2 < occluded.mean() < 0.98  # both outcomes exercised (t_max mixes 0.3, 1, inf)
    # TriangleHit: barycentrics reproduce the hit point, ng is the unit face normal
    v = tris[np.asarray(hit.prim)[h]]
    b1, b2 = np.asarray(hit.b1)[h], np.asarray(hit.b2)[h]
    p_bary = (1 - b1 - b2)[:, None] * v[:, 0] + b1[:, None] * v[:, 1] + b2[:, None] * v[:, 2]
    p_ray = o[h] + np.asarray(hit.t)[h, None] * d[h]
    tol = 1e-10 if x64 else 2e-5  # absolute, scene of size 2: float32 rounding of t·d
    assert np.max(np.abs(p_bary - p_ray)) < tol
    n_ref = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    assert np.max(np.abs(np.asarray(hit.ng)[h] - n_ref)) < (1e-12 if x64 else 1e-6)
    # misses: t = inf, prim = -1, zero barycentrics and normal
    assert np.all(np.isinf(np.asarray(hit.t)[~h]))
    assert np.all(np.asarray(hit.ng)[~h] == 0) and np.all(np.asarray(hit.b1)[~h] == 0)


@pytest.mark.parametrize("accel", ["brute", "bvh"])
def test_stored_barycentrics_give_the_same_hit(scene_rays, accel):
    # stored_barycentrics only changes where XLA keeps b1 and b2 (a path's next vertex, see
    # winner_hit): every field of the TriangleHit must be the same, bit for bit
    tris = cornell_like().astype(np.float32)
    geometry = triangle_set(tris) if accel == "brute" else build_bvh(tris, leaf_size=4)
    o, d, t_max = (x.astype(np.float32) for x in scene_rays)
    plain, stored = (jax.jit(jax.vmap(lambda o, d, t, s=s: closest_hit(
        geometry, o, d, t, stored_barycentrics=s)))(o, d, t_max) for s in (False, True))
    assert np.mean(np.asarray(plain.prim) >= 0) > 0.5
    for name, a, b in zip(TriangleHit._fields, plain, stored, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)


def _from_origin(ts, o, d, t_max):
    """closest_hit_from_origin on rays that share the first ray's origin."""
    assert np.all(o == o[0])
    return _from_origin_batch(ts, o[0], d, t_max)


@pytest.mark.parametrize("query", [_closest_batch, _from_origin], ids=["watertight", "origin"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_closest_hit_ties_go_to_the_lowest_index_and_t_max_is_inclusive(x64, dtype, query):
    """The loop keeps the smallest t, ties to the lowest index (duplicates of one triangle at
    indices 1 and 3 behind a far one at 0 and in front of one at 2), a hit exactly at t_max
    counts, and one ulp less misses: the (t, prim) pair carried as one complex number must
    keep both exact."""
    if dtype == np.float64 and not x64:
        pytest.skip("float64 needs x64")
    tri = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype)
    tris = np.stack([tri + [0, 0, 5], tri + [0, 0, 2], tri + [0, 0, 3], tri + [0, 0, 2]])
    ts = triangle_set(tris)
    o = np.array([[0.1, 0.0, -1.0]] * 3, dtype)
    d = np.array([[0.0, 0.0, 1.0]] * 3, dtype)
    inf = np.inf
    hit = query(ts, o, d, np.array([inf, inf, inf], dtype))
    np.testing.assert_array_equal(np.asarray(hit.prim), [1, 1, 1])
    t = np.asarray(hit.t)[0]
    if query is _closest_batch:
        assert t == 3  # z = 2 from z = −1 along +z
    else:  # V / det from the rounded v − o (o = 0.1 is not exact): within a few ulp
        assert abs(t - 3) <= 4 * np.finfo(dtype).eps * 3
    below = np.nextafter(t, dtype(0))
    hit = query(ts, o, d, np.array([t, below, 2.5], dtype))
    np.testing.assert_array_equal(np.asarray(hit.prim), [1, -1, -1])
    np.testing.assert_array_equal(np.asarray(hit.t), [t, inf, inf])


def test_triangle_set_validation():
    tris = cornell_like().astype(np.float32)
    tris[5, 1, 2] = np.nan
    with pytest.raises(ValueError, match="triangle 5"):
        triangle_set(tris)
    tris[5, 1, 2] = np.inf
    with pytest.raises(ValueError, match="triangle 5"):
        triangle_set(tris)
    with pytest.raises(ValueError, match="shape"):
        triangle_set(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="empty"):
        triangle_set(np.zeros((0, 3, 3)))
    # the closest-hit loop carries the index as a float32: exact below 2^24 (a view, no copy)
    with pytest.raises(ValueError, match="use a BVH"):
        triangle_set(np.broadcast_to(np.float32(0), (2**24, 3, 3)))
    # degenerate triangles are kept (indices stable) but flagged and never hit
    deg = np.array([[[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[-1, -1, 0], [1, -1, 0], [0, 1, 0]]])
    ts = triangle_set(deg.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(ts.valid), [False, True])
    h = _closest_batch(ts, np.array([[0.5, 0.0, 1.0]], np.float32),
                       np.array([[0.0, 0.0, -1.0]], np.float32), np.array([np.inf], np.float32))
    assert int(h.prim[0]) == 1


def test_triangle_set_columns_are_the_winners_record():
    # finish_hit gathers the winner's vertices and normal from twelve (F,) columns: they must
    # be the stored vertices (v0, v1, v2 by x, y, z) and normals, in that order
    tris = cornell_like().astype(np.float32)
    ts = triangle_set(tris)
    record = np.stack([np.asarray(c) for c in ts.columns], axis=1)
    assert len(ts.columns) == 12 and record.dtype == np.float32
    np.testing.assert_array_equal(record[:, :9], np.asarray(ts.vertices).reshape(-1, 9))
    np.testing.assert_array_equal(record[:, 9:], np.asarray(ts.ng))


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return q


def _edge_and_vertex_targets(mesh_vertices, faces):
    """Vertices, and points at fractions along every shared edge (midpoints included)."""
    tm = trimesh.Trimesh(mesh_vertices, faces, process=False)
    a, b = mesh_vertices[tm.edges_unique[:, 0]], mesh_vertices[tm.edges_unique[:, 1]]
    fr = np.array([0.5, 1 / 3, 0.1, 0.9, 1e-3])[:, None, None]
    return np.concatenate([mesh_vertices, (a + fr * (b - a)).reshape(-1, 3)])


@pytest.mark.parametrize("shape", ["icosphere", "cube"])
@pytest.mark.parametrize("placement", ["origin", "rotated_far"])
def test_watertight_closed_meshes(x64, shape, placement):
    dtype = np.float64 if x64 else np.float32
    if shape == "icosphere":
        m = trimesh.creation.icosphere(subdivisions=2)
    else:
        m = trimesh.creation.box(extents=(2, 2, 2)).subdivide().subdivide()
    verts = np.asarray(m.vertices, np.float64)
    center = np.zeros(3)
    if placement == "rotated_far":
        verts = verts * 10 @ _rotation(3).T
        center = np.array([1e5, -3e4, 7e4])  # ~1.3e5 from the origin; float32 ulp there ~ 0.008
        verts = verts + center
    verts = verts.astype(dtype)
    tris = verts[m.faces]
    ts = triangle_set(tris)
    assert bool(np.all(np.asarray(ts.valid)))  # no triangle lost to rounding: mesh stays closed
    targets = _edge_and_vertex_targets(verts.astype(np.float64), m.faces).astype(dtype)
    # from the centre (axis-aligned directions for the cube) and from an off-centre inside point
    scale = 10.0 if placement == "rotated_far" else 1.0
    for inside in (center, center + scale * np.array([0.21, -0.13, 0.37])):
        o = np.broadcast_to(inside.astype(dtype), targets.shape)
        d = targets - o
        t_max = np.full(len(o), np.inf, dtype)
        # the watertight test, and the edge planes through the rays' shared origin (camera rays)
        for hit in (_closest_batch(ts, o, d, t_max), _from_origin_batch(ts, o[0], d, t_max)):
            t = np.asarray(hit.t)
            # every ray leaves a closed surface: a single miss is a crack
            assert np.all(np.isfinite(t)), f"{np.sum(~np.isfinite(t))} rays escaped"
            # and it leaves at the aimed point (t = 1) to within the float rounding of the target
            assert np.max(np.abs(t - 1)) < (1e-9 if x64 else 1e-3)
