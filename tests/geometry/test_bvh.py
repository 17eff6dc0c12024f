"""BVH: build validity, agreement with brute force (closest and any hit), bad input, auto."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxrt.geometry.accel import AUTO_BVH_THRESHOLD, build_geometry
from jaxrt.geometry.bvh import BVH, build_bvh
from jaxrt.geometry.bvh_build import build_flat_bvh
from jaxrt.geometry.triangle import (
    TriangleSet,
    any_hit,
    closest_hit,
    intersect_triangle,
    triangle_set,
)


def _quad(a, b, c, d):
    """Two triangles (a, b, c) and (a, c, d) of a planar quad."""
    return [[a, b, c], [a, c, d]]


def _box(lo, hi):
    """12 triangles of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    p = [[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return sum((_quad(*(p[i] for i in f)) for f in faces), [])


def cornell_like():
    """36 triangles: a room (6 quads) with two interior boxes, like the Cornell box."""
    room = _box((-1, -1, -1), (1, 1, 1))
    return np.asarray(room + _box((-0.6, -1, -0.5), (-0.1, 0.2, 0.0))
                      + _box((0.1, -1, 0.1), (0.6, -0.4, 0.6)), np.float32)


def soup(n=200, seed=0):
    """Random small triangles in [-1, 1]³, with a few zero-area ones mixed in."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-1, 1, (n, 1, 3))
    tri = c + rng.normal(scale=0.15, size=(n, 3, 3))
    tri[25::50, 2] = tri[25::50, 1]  # degenerate: two equal vertices
    return tri.astype(np.float32)


def plane(k=10):
    """A flat 2k² -triangle grid in the plane z = 0.25."""
    g = np.linspace(-1, 1, k + 1)
    q = [_quad([g[i], g[j], 0.25], [g[i + 1], g[j], 0.25], [g[i + 1], g[j + 1], 0.25],
               [g[i], g[j + 1], 0.25]) for i in range(k) for j in range(k)]
    return np.asarray(sum(q, []), np.float32)


MESHES = {
    "soup": soup(),
    "icosphere": trimesh.creation.icosphere(subdivisions=2).triangles.astype(np.float32),
    "cornell": cornell_like(),
    "one": soup(1, seed=3),
    "two": soup(2, seed=4),
    "identical": np.repeat(soup(1, seed=5), 20, axis=0),
    "plane": plane(),
}


def rays(tri, n=256, seed=1):
    """Rays from inside and outside the mesh bounds: random, and aimed at triangles.

    A third aim at triangle centroids with non-unit directions (sure hits); t_max is ∞ for
    half of the rays and a random finite limit for the others.
    """
    rng = np.random.default_rng(seed)
    lo, hi = tri.min(axis=(0, 1)), tri.max(axis=(0, 1))
    span = np.maximum(hi - lo, 1e-3)
    o = lo - 0.3 * span + rng.uniform(size=(n, 3)) * 1.6 * span
    d = rng.normal(size=(n, 3))
    aim = rng.integers(0, len(tri), n // 3)
    d[: n // 3] = tri[aim].mean(axis=1) - o[: n // 3]
    t_max = np.where(rng.uniform(size=n) < 0.5, np.inf, rng.uniform(0.05, 2.0, n))
    return o.astype(tri.dtype), d.astype(tri.dtype), t_max.astype(tri.dtype)


# Meshes checked in the quick loop; the others run with the slow suite (CI).
QUICK_MESHES = ("soup", "icosphere", "cornell")


@jax.jit
def _queries(bvh, tset, o, d, t_max):
    """Every query on one mesh in one compiled function (so each mesh compiles once)."""
    per_ray = lambda f, g: jax.vmap(f, (None, 0, 0, 0))(g, o, d, t_max)
    return dict(
        brute=per_ray(closest_hit, tset), brute_any=per_ray(any_hit, tset),
        bvh=per_ray(closest_hit, bvh), bvh_any=per_ray(any_hit, bvh),
    )


def _check_closest(tri, o, d, t_max, ref, got):
    """Same t everywhere; same prim unless both triangles are hit at that same t (a tie)."""
    ref = jax.tree_util.tree_map(np.asarray, ref)
    got = jax.tree_util.tree_map(np.asarray, got)
    # Same watertight test on the same vertices: t may differ only by XLA's contraction
    # choices in the two compiled loops: 8 ulp, or 16 ulp of the scene size where t_scaled
    # cancels (a grazing ray measured 1.7e-8 at t = 4e-4 in a unit scene).
    eps = np.finfo(tri.dtype).eps
    atol = 16 * eps * float(np.abs(tri).max())
    np.testing.assert_allclose(got.t, ref.t, rtol=8 * eps, atol=atol)
    np.testing.assert_array_equal(got.prim >= 0, ref.prim >= 0)
    differ = np.flatnonzero(got.prim != ref.prim)
    for i in differ:  # ties only: the BVH's triangle is hit at the brute-force t
        v = tri[got.prim[i]]
        # unbounded: at a boundary t_max the standalone test may round t one ulp the other way
        t_other, _, _ = intersect_triangle(o[i], d[i], v[0], v[1], v[2], np.inf)
        np.testing.assert_allclose(t_other, ref.t[i], rtol=8 * eps, atol=atol)
    same = got.prim == ref.prim
    # Barycentrics and normals of the same triangle: same formulas, a few ulp apart.
    np.testing.assert_allclose(got.b1[same], ref.b1[same], atol=1e-5)
    np.testing.assert_allclose(got.b2[same], ref.b2[same], atol=1e-5)
    np.testing.assert_allclose(got.ng[same], ref.ng[same], atol=1e-6)
    return len(differ)


# Degenerate meshes compile one traversal each: run them with the slow suite (CI).
AGREEMENT_CASES = [
    name if name in QUICK_MESHES else pytest.param(name, marks=pytest.mark.slow)
    for name in MESHES
]


@pytest.mark.parametrize("name", AGREEMENT_CASES)
def test_bvh_matches_brute_force(name):
    tri = MESHES[name]
    o, d, t_max = rays(tri)
    bvh, tset = build_bvh(tri), triangle_set(tri)
    out = _queries(bvh, tset, o, d, t_max)
    # The ray set must exercise both outcomes (a third of the rays aim at triangles).
    assert int(jnp.sum(out["brute"].prim >= 0)) >= 10
    assert int(jnp.sum(out["brute"].prim < 0)) >= 10
    ties = _check_closest(tri, o, d, t_max, out["brute"], out["bvh"])
    # Only overlapping coplanar triangles can tie: the "identical" mesh, and the Cornell box,
    # whose blocks' bottom faces lie on the floor (which one wins depends on visiting order).
    assert name in ("identical", "cornell") or ties == 0
    # Any-hit is an exact boolean: same test, same t_max.
    np.testing.assert_array_equal(out["bvh_any"], out["brute_any"])


@pytest.mark.parametrize("leaf_size", [8, pytest.param(1, marks=pytest.mark.slow),
                                       pytest.param(3, marks=pytest.mark.slow)])
def test_bvh_leaf_sizes_match_brute_force(leaf_size):
    """Other leaf sizes than the default: leaves of 8 hold 1–8 triangles (the loop runs past a
    short leaf's count, masked), leaves of 1 run the pipelined loop once. Teeth: skipping a
    leaf's last slot fails all three sizes, folding with the wrong index fails 3 and 8."""
    tri = MESHES["soup"]
    o, d, t_max = rays(tri)
    out = _queries(build_bvh(tri, leaf_size=leaf_size), triangle_set(tri), o, d, t_max)
    assert _check_closest(tri, o, d, t_max, out["brute"], out["bvh"]) == 0
    np.testing.assert_array_equal(out["bvh_any"], out["brute_any"])


def test_compacted_batches_match_brute_force(monkeypatch):
    """Under vmap the BVH compacts its running rays (4× fewer lanes at each stage): with
    compaction down to 8 lanes, 512 rays go through four compactions and must give brute
    force's answers; so must nested vmaps (a (4, 128) batch) and a batch of BVHs."""
    import jaxrt.geometry.bvh as bvh_mod

    monkeypatch.setattr(bvh_mod, "MIN_COMPACT_LANES", 8)
    tri = MESHES["icosphere"]
    o, d, t_max = rays(tri, n=512, seed=5)
    bvh, tset = build_bvh(tri), triangle_set(tri)
    out = jax.jit(lambda *a: _queries.__wrapped__(*a))(bvh, tset, o, d, t_max)  # fresh trace
    assert _check_closest(tri, o, d, t_max, out["brute"], out["bvh"]) == 0
    np.testing.assert_array_equal(out["bvh_any"], out["brute_any"])
    nested = jax.jit(jax.vmap(jax.vmap(closest_hit, (None, 0, 0, 0)), (None, 0, 0, 0)))(
        bvh, o.reshape(4, 128, 3), d.reshape(4, 128, 3), t_max.reshape(4, 128))
    np.testing.assert_array_equal(np.asarray(nested.prim).ravel(), np.asarray(out["bvh"].prim))
    two = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), bvh)
    per_bvh = jax.jit(jax.vmap(lambda g: jax.vmap(any_hit, (None, 0, 0, 0))(g, o, d, t_max)))(two)
    np.testing.assert_array_equal(np.asarray(per_bvh), np.stack([out["brute_any"]] * 2))
    # vmapped over the BVHs alone (one ray): the rule's lockstep fallback
    one_ray = jax.jit(jax.vmap(closest_hit, (0, None, None, None)))(two, o[0], d[0], t_max[0])
    np.testing.assert_array_equal(np.asarray(one_ray.prim), [out["brute"].prim[0]] * 2)


def test_bvh_is_not_bound_by_the_brute_force_limit(monkeypatch):
    """Brute force refuses 2^24 triangles or more (its loop carries the index as a float32);
    a BVH, the way out the error names, must not inherit that limit (patched down here)."""
    import jaxrt.geometry.triangle as isect

    tri = MESHES["icosphere"]
    o, d, t_max = rays(tri)
    want = _queries(build_bvh(tri), triangle_set(tri), o, d, t_max)
    monkeypatch.setattr(isect, "MAX_BRUTE_FORCE", len(tri) // 2)
    with pytest.raises(ValueError, match="use a BVH"):
        triangle_set(tri)
    got = jax.jit(jax.vmap(closest_hit, (None, 0, 0, 0)))(build_bvh(tri), o, d, t_max)
    np.testing.assert_array_equal(np.asarray(got.prim), np.asarray(want["bvh"].prim))
    np.testing.assert_array_equal(np.asarray(got.t), np.asarray(want["bvh"].t))


@pytest.mark.parametrize("n", [1, 7, 300, 1000, 4096, 16384])
def test_running_lanes_is_nonzero(n):
    """The compaction's prefix count (two float32 matrix products) gives jnp.nonzero's indices
    for masks of every density, sizes that are not a multiple of its block, a full cap and
    no lane at all, and under vmap (a batch of BVHs compacts per BVH)."""
    from jaxrt.geometry.bvh import running_lanes

    rng = np.random.default_rng(n)
    cap = max(1, n // 4)
    masks = [np.zeros(n, bool), np.arange(n) < cap, np.arange(n) >= n - cap]
    for p in (0.01, 0.1, 0.25):
        m = rng.random(n) < p
        m[np.flatnonzero(m)[cap:]] = False  # at most cap lanes run, as the loop guarantees
        masks.append(m)
    for m in masks:
        want = np.asarray(jnp.nonzero(jnp.asarray(m), size=cap, fill_value=0)[0])
        np.testing.assert_array_equal(np.asarray(running_lanes(jnp.asarray(m), cap)), want)
    got = jax.jit(jax.vmap(lambda m: running_lanes(m, cap)))(jnp.asarray(np.stack(masks)))
    want = [np.asarray(jnp.nonzero(jnp.asarray(m), size=cap, fill_value=0)[0]) for m in masks]
    np.testing.assert_array_equal(np.asarray(got), np.stack(want))


@pytest.mark.parametrize("name", list(MESHES))
def test_build_is_valid(name):
    tri = MESHES[name]
    leaf_size = 4
    b = build_flat_bvh(tri, leaf_size=leaf_size)
    n_tri, n_nodes = len(tri), len(b.skip)
    leaves = np.flatnonzero(b.leaf_count > 0)
    # Every triangle sits in exactly one leaf, and leaves respect the size bound.
    cover = np.zeros(n_tri + leaf_size, int)
    for s, c in zip(b.leaf_start[leaves], b.leaf_count[leaves], strict=True):
        cover[s:s + c] += 1
    assert (cover[:n_tri] == 1).all() and (cover[n_tri:] == 0).all()
    assert (b.leaf_count <= leaf_size).all()
    np.testing.assert_array_equal(np.sort(b.prim[:n_tri]), np.arange(n_tri))
    np.testing.assert_array_equal(b.triangles[:n_tri], tri[b.prim[:n_tri]])
    # Leaf boxes contain their triangles; children lie inside their parent.
    for i in leaves:
        t = b.triangles[b.leaf_start[i]:b.leaf_start[i] + b.leaf_count[i]]
        assert (t.min(axis=(0, 1)) >= b.box_lo[i]).all()
        assert (t.max(axis=(0, 1)) <= b.box_hi[i]).all()
    for i in np.flatnonzero(b.leaf_count == 0):
        left, right = i + 1, b.skip[i + 1]
        # Threaded layout: the right child follows the left subtree and shares i's skip.
        assert right < b.skip[i] and b.skip[right] == b.skip[i]
        for child in (left, right):
            assert (b.box_lo[child] >= b.box_lo[i]).all()
            assert (b.box_hi[child] <= b.box_hi[i]).all()
    assert b.skip[0] == n_nodes


def test_sah_beats_median_on_clustered_input():
    """SAH isolates two distant clusters at the root; the root split leaves no mixed child."""
    rng = np.random.default_rng(7)
    a = rng.uniform(0, 0.1, (60, 3, 3))
    b = rng.uniform(0, 0.1, (4, 3, 3)) + 10.0
    flat = build_flat_bvh(np.concatenate([a, b]).astype(np.float32), leaf_size=4)
    right = flat.skip[1]
    # The 4 far triangles form the root's right child, a single leaf.
    assert flat.leaf_count[right] == 4 and flat.box_lo[right].min() >= 10.0


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((0, 3, 3), np.float32), "empty"),
        (np.zeros((4, 3), np.float32), "shape"),
        (np.zeros((3, 3, 2), np.float32), "shape"),
        (np.where(np.arange(9).reshape(1, 3, 3) == 4, np.inf, 0.5), "triangle 0"),
    ],
)
def test_build_rejects_bad_input(bad, match):
    # one check of the user's triangles for both accelerations: the same message
    messages = []
    for build in (build_bvh, triangle_set):
        with pytest.raises(ValueError, match=match) as err:
            build(bad)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_build_names_non_finite_triangle(value):
    tri = soup(10)
    tri[7, 1, 2] = value
    with pytest.raises(ValueError, match="triangle 7"):
        build_bvh(tri)
    with pytest.raises(ValueError, match="leaf_size"):
        build_bvh(soup(10), leaf_size=0)


def test_dtypes_and_x64(x64):
    """float32 in, float32 out; float64 under x64 and the same agreement with brute force."""
    dtype = np.float64 if x64 else np.float32
    tri = MESHES["cornell"].astype(dtype)
    o, d, t_max = rays(tri)  # same shapes as the cornell case: reuses its compilation in f32
    bvh, tset = build_bvh(tri), triangle_set(tri)
    assert bvh.tri[0].dtype == dtype and bvh.box[0].dtype == dtype
    out = _queries(bvh, tset, o, d, t_max)
    assert out["bvh"].t.dtype == dtype and out["bvh"].prim.dtype == jnp.int32
    assert out["bvh"].ng.dtype == dtype and out["bvh"].b1.dtype == dtype
    # every prim that differs is checked to be a tie (the floor under a block's bottom face)
    _check_closest(tri, o, d, t_max, out["brute"], out["bvh"])
    np.testing.assert_array_equal(out["bvh_any"], out["brute_any"])


def test_auto_threshold_picks_class():
    small = soup(AUTO_BVH_THRESHOLD - 1)
    large = soup(AUTO_BVH_THRESHOLD)
    assert isinstance(build_geometry(small), TriangleSet)
    assert isinstance(build_geometry(large), BVH)
    assert isinstance(build_geometry(small, accel="bvh", leaf_size=2), BVH)
    assert isinstance(build_geometry(large, accel="brute"), TriangleSet)
    with pytest.raises(ValueError, match="unknown accel"):
        build_geometry(small, accel="kd-tree")
    with pytest.raises(ValueError, match="options"):
        build_geometry(small, accel="brute", leaf_size=2)


def test_boundary_t_max_agrees_with_brute_force():
    """With ``t_max`` = each ray's own closest ``t`` (the boundary case), the BVH accepts and
    rejects exactly the hits brute force does, in every path. Reuses the cornell compilation."""
    tri = MESHES["cornell"]
    o, d, _ = rays(tri)
    bvh, tset = build_bvh(tri), triangle_set(tri)
    inf = np.full(len(o), np.inf, np.float32)
    first = _queries(bvh, tset, o, d, inf)["brute"]
    hit = np.asarray(first.prim >= 0)
    t_hit = np.where(hit, np.asarray(first.t), 1.0).astype(np.float32)
    at = _queries(bvh, tset, o, d, t_hit)
    # Most boundary hits are kept (t ≤ t_max is inclusive) ...
    assert np.asarray(at["brute"].prim >= 0)[hit].mean() > 0.8
    # ... and the BVH keeps the same ones (it once culled boxes at exactly t_max).
    _check_closest(tri, o, d, t_hit, at["brute"], at["bvh"])
    np.testing.assert_array_equal(at["bvh_any"], at["brute_any"])
