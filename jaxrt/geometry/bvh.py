"""Bounding volume hierarchy: a pytree of flat arrays and its stackless traversal in JAX.

The tree is built on the host (:mod:`jaxrt.geometry.bvh_build`, binned SAH) and laid out depth-first
with skip links, so a ray walks it with a single integer cursor and no stack::

    node ← 0
    while node ≠ N:
        if the ray hits box(node) before its current closest t:
            if leaf(node): test its ≤ L triangles one by one, shrink t
            else: node ← node + 1 (the left child); continue
        node ← skip(node)

:meth:`BVH.closest_hit` / :meth:`BVH.any_hit` traverse ONE ray as a ``while_loop`` and are
meant to be called inside ``jax.vmap`` (the polymorphic ``jaxrt.geometry.triangle.closest_hit`` and
``any_hit`` dispatch to them). Each loop step advances a ray by up to ``BOX_STEPS`` box
visits and one leaf test. Under ``vmap`` a custom batching rule (``jax.custom_batching``)
runs the batch in lockstep only until a quarter of its rays still run, then gathers those
into a batch a quarter the size, and so on, so a batch does not pay full width for its
slowest rays.

How it is made fast under XLA:CPU (measured, benchmarks/README.md#bvh-traversal): every array is 1-D
(one gather per coordinate), every loop body has one consumer per costly value (XLA fuses a
value into each consumer's kernel and recomputes it; ``optimization_barrier`` does not stop
it), so the cursor is one integer and the leaf loop is software-pipelined, and the box visits
are a ``fori_loop`` rather than unrolled. A persistent-lane variant (finished lanes take new
rays every few steps) is slower than the plain vmapped loop with those rules; compaction by
quarters costs a gather per stage instead of per few steps.

Reference: Smits 1998, "Efficiency issues for ray tracing" (skip links).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.vecmath import device_array
from jaxrt.geometry.bvh_build import FlatBVH, build_flat_bvh
from jaxrt.geometry.triangle import (
    RayFrame,
    TriangleHit,
    canonical_vertices,
    gamma,
    host_triangles,
    intersect_triangle_t,
    ray_frame,
    winner_hit,
)


@jax.tree_util.register_pytree_node_class
@dataclass(frozen=True)
class BVH:
    """A flat, stackless BVH over ``F`` triangles with ``N`` nodes (a JAX pytree).

    Stored as structure-of-arrays, every field a 1-D array, because under ``vmap`` XLA:CPU
    is far slower on ``(rays, 3)`` arrays sliced along their minor axis than on one
    contiguous vector per coordinate.

    Attributes:
        box: 6 × (N,) node bounds ``(lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)``.
        skip: (N,) int32 node visited after a node's subtree (``N``: done).
        leaf_start, leaf_count: (N,) int32 a leaf's triangle range; ``leaf_count == 0`` marks an
            interior node, whose left child is the next node.
        tri: 9 × (F + L,) vertex coordinates ``(v0x, v0y, v0z, v1x, …, v2z)`` of the triangles
            reordered by leaf, padded with L degenerate triangles (one array per coordinate: a
            gather from it is a contiguous vector per lane batch).
        tri_sorted: 9 × (F + L,) the same triangles with their vertices in the canonical order the
            leaf loop tests them in (:func:`jaxrt.geometry.triangle.canonical_vertices`: watertight
            edges); ``tri`` keeps the given order for the winner's barycentrics.
        prim: (F + L,) int32 original triangle index of each reordered triangle (−1 padding).
        ng: (F + L, 3) unit geometric normals of the reordered triangles (as ``TriangleSet``).
        leaf_size: static ``L``, the most triangles in a leaf (a leaf loop runs L iterations).
    """

    box: tuple
    skip: Array
    leaf_start: Array
    leaf_count: Array
    tri: tuple
    tri_sorted: tuple
    prim: Array
    ng: Array
    leaf_size: int

    def tree_flatten(self):
        children = (self.box, self.skip, self.leaf_start, self.leaf_count, self.tri,
                    self.tri_sorted, self.prim, self.ng)
        return children, self.leaf_size

    @classmethod
    def tree_unflatten(cls, leaf_size, children):
        return cls(*children, leaf_size)

    @property
    def num_nodes(self) -> int:
        return self.skip.shape[0]

    @property
    def num_triangles(self) -> int:
        return self.prim.shape[0] - self.leaf_size

    def closest_hit(self, origin: Array, direction: Array, t_max: Array,
                    stored_barycentrics: bool = False) -> TriangleHit:
        """Closest hit of ONE ray in ``(0, t_max]``: see :func:`closest_hit_ray`."""
        return closest_hit_ray(self, origin, direction, t_max, stored_barycentrics)

    def any_hit(self, origin: Array, direction: Array, t_max: Array) -> Array:
        """Whether ONE ray hits anything in ``(0, t_max]``: see :func:`any_hit_ray`."""
        return any_hit_ray(self, origin, direction, t_max)


def bvh_from_flat(flat: FlatBVH, leaf_size: int) -> BVH:
    """Move a host :class:`FlatBVH` to device arrays (floats in JAX's default precision)."""
    dtype = jnp.result_type(float)
    # Normals and zero-area flags exactly as the brute-force TriangleSet computes them, on the
    # host, then one copy per array (jnp operations would compile a program each)
    stored, ng, valid = host_triangles(flat.triangles)
    tri = stored.astype(dtype)
    # Zero-area triangles never hit: collapse them to a point, whose determinant is exactly
    # 0 in the watertight test, instead of testing a flag per triangle.
    tri = np.where(valid[:, None, None], tri, tri[:, :1])
    tri_sorted = canonical_vertices(tri)
    box = np.concatenate([flat.box_lo, flat.box_hi], axis=1)
    as_int = lambda a: device_array(a, jnp.int32)
    return BVH(
        tuple(device_array(box[:, k], dtype) for k in range(6)),
        as_int(flat.skip), as_int(flat.leaf_start), as_int(flat.leaf_count),
        tuple(device_array(c) for c in tri.reshape(-1, 9).T),
        tuple(device_array(c) for c in tri_sorted.reshape(-1, 9).T), as_int(flat.prim),
        device_array(ng, dtype), leaf_size,
    )


def build_bvh(triangles, leaf_size: int = 2, n_bins: int = 16) -> BVH:
    """Build a binned-SAH BVH over ``triangles`` (F, 3, 3) on the host, return it on device.

    ``leaf_size`` triangles per leaf at most (2 measured fastest: 1.66 Mrays/s on 82k
    triangles against 1.03 / 1.27 / 0.91 for 1 / 4 / 8), ``n_bins`` SAH bins per axis.
    Raises ValueError on non-finite vertices (naming the triangle) or a bad shape.
    """
    return bvh_from_flat(build_flat_bvh(triangles, leaf_size, n_bins), leaf_size)


# Box visits per leaf test in one traversal step (8 / 12 / 16 / 24 measured 1.41 / 1.51 /
# 1.66 / 1.36 Mrays/s on 82k triangles; benchmarks/README.md#bvh-traversal).
BOX_STEPS = 16


class _Ray(NamedTuple):
    """One ray as scalars: its watertight frame and its origin and inverse direction."""

    frame: RayFrame
    o: tuple
    inv_d: tuple


def _make_ray(ox, oy, oz, dx, dy, dz) -> _Ray:
    """Per-ray set-up shared by every node: watertight frame and ``1/d`` (0 ↦ 1/tiny)."""
    frame = ray_frame(jnp.stack([ox, oy, oz]), jnp.stack([dx, dy, dz]))
    tiny = jnp.finfo(dx.dtype).tiny
    # 1/tiny is finite, so the slab test never forms 0 · ∞ = NaN.
    inv = tuple(1 / jnp.where(c == 0, tiny, c) for c in (dx, dy, dz))
    return _Ray(frame, (ox, oy, oz), inv)


def _slab_entry(box, ray: _Ray, t_max: Array) -> Array:
    """Whether the ray meets the box within ``(0, t_max]`` (slab test, one ray, scalars).

    The exit distance is scaled by ``1 + 2γ₃`` so that round-off never culls a box the ray
    touches (PBR book 4th ed. §6.8.2).
    """
    # The cap on t gets more slack (32 ulp): the watertight test computes a triangle's t along
    # another path than the slab's, and a hit exactly at t_max must still be reached.
    t_near, t_far = jnp.zeros_like(t_max), t_max * (1 + gamma(64, t_max.dtype))
    for k in range(3):  # three static axes
        t0 = (box[k] - ray.o[k]) * ray.inv_d[k]
        t1 = (box[k + 3] - ray.o[k]) * ray.inv_d[k]
        t_near = jnp.maximum(t_near, jnp.minimum(t0, t1))
        t_far = jnp.minimum(t_far, jnp.maximum(t0, t1) * (1 + 2 * gamma(3, t_max.dtype)))
    return t_near <= t_far


class _Cursor(NamedTuple):
    """Traversal state of one ray.

    node: ``0 ≤ node < N`` the next node to visit; ``N`` or more: done; negative: the leaf
    ``−1 − node`` was entered and its triangles are still to be tested (traversal then goes
    on at its skip link). One integer, so that a box visit has a single output and XLA
    compiles it to one fused kernel (with a separate ``leaf`` field it fused the slab test
    into both outputs' kernels). t, pos: closest hit so far (``pos`` indexes the reordered
    triangles, −1 before any hit; ``t`` starts at ``t_max``).
    """

    node: Array
    t: Array
    pos: Array


def _initial_cursor(t_max: Array, live) -> _Cursor:
    """Cursor at the root (or already done when not ``live``), no hit yet."""
    minus_one = jnp.full(t_max.shape, -1, jnp.int32)
    node = jnp.where(live, 0, jnp.iinfo(jnp.int32).max).astype(jnp.int32)
    return _Cursor(jnp.broadcast_to(node, t_max.shape), t_max, minus_one)


def _box_step(bvh: BVH, ray: _Ray, c: _Cursor) -> _Cursor:
    """Visit one node's box unless a leaf is pending: descend, skip, or mark the leaf."""
    active = (c.node >= 0) & (c.node < bvh.num_nodes)
    node = jnp.clip(c.node, 0, bvh.num_nodes - 1)
    enter = active & _slab_entry(tuple(b[node] for b in bvh.box), ray, c.t)
    is_leaf = bvh.leaf_count[node] > 0
    # Descend into an entered interior node, mark an entered leaf, else follow the skip link.
    next_node = jnp.where(enter, jnp.where(is_leaf, -1 - node, node + 1), bvh.skip[node])
    return c._replace(node=jnp.where(active, next_node, c.node))


def _leaf_step(bvh: BVH, ray: _Ray, c: _Cursor, stop_at_first: bool) -> _Cursor:
    """Test the pending leaf's triangles one by one and keep the closest hit.

    A ``fori_loop`` over the leaf's ``L`` slots, software-pipelined as
    ``TriangleSet.closest_hit``: iteration i tests slot i and folds slot i−1's distance into
    ``(t, pos)``, so the test's only consumer is the loop carry and XLA computes it once. (A
    vmap over the block followed by ``argmin`` fed the test to several consumers, and XLA
    fused a copy of it into each: the ``optimization_barrier`` meant to stop that is removed
    before fusion.) Slots past the leaf's count belong to the next leaf and are masked.
    """
    pending = c.node < 0
    leaf = jnp.where(pending, -1 - c.node, 0)
    count = jnp.where(pending, bvh.leaf_count[leaf], 0)
    start = bvh.leaf_start[leaf]
    inf = jnp.asarray(jnp.inf, c.t.dtype)

    def fold(t, pos, ti, k):
        # As TriangleSet: strictly closer, but the first hit may sit exactly at t_max.
        closer = (ti < t) | ((pos < 0) & (ti < inf))
        return jnp.where(closer, ti, t), jnp.where(closer, k, pos)

    def body(i, carry):
        t, pos, ti_prev = carry
        k = start + i
        # One gather per coordinate from the SoA table: each a contiguous (lanes,) vector.
        v = [a[k] for a in bvh.tri_sorted]
        ti = jnp.where(i < count,
                       intersect_triangle_t(ray.frame, v[0:3], v[3:6], v[6:9], c.t), inf)
        t, pos = fold(t, pos, ti_prev, k - 1)
        return t, pos, ti

    t, pos, ti = lax.fori_loop(0, bvh.leaf_size, body, (c.t, c.pos, inf))
    t, pos = fold(t, pos, ti, start + bvh.leaf_size - 1)
    node = jnp.where(pending, bvh.skip[leaf], c.node)
    if stop_at_first:
        node = jnp.where(pos != c.pos, bvh.num_nodes, node)
    return _Cursor(node, t, pos)


# A jit of its own: a traversal traces its step once per while_loop (one per compaction stage
# and query, 20 in a BVH scene's MIS pass), and under vmap the step is per ray, so every call
# has the same shapes: traced once per query kind, then only batched, which halves the MIS
# pass's trace on the Cornell box as a BVH; the compiled program and the images are the
# same (XLA inlines the call; benchmarks/README.md#bvh-compaction).
@partial(jax.jit, static_argnums=(3, 4))
def _step(bvh: BVH, ray: _Ray, c: _Cursor, stop_at_first: bool, box_steps: int) -> _Cursor:
    """Up to ``box_steps`` box visits (until a leaf is entered), then that leaf's test.

    A leaf's triangle tests cost several box tests, so a lane walks several boxes per leaf
    test instead of paying for a (masked) leaf at every node. The box visits are a
    ``fori_loop``, not unrolled: unrolled, XLA fuses each visit's gathers into every later
    consumer and recomputes them (4 unrolled visits plus a leaf cost 6× the sum of their parts).
    """
    c = lax.fori_loop(0, box_steps, lambda _, c: _box_step(bvh, ray, c), c)
    return _leaf_step(bvh, ray, c, stop_at_first)


def _running(bvh: BVH, c: _Cursor) -> Array:
    """Whether a cursor still has nodes or a pending leaf (negative ``node``) to visit."""
    return c.node < bvh.num_nodes


def _to_hit(bvh: BVH, frame: RayFrame, t, pos, stored_barycentrics: bool = False) -> TriangleHit:
    """Turn a traversal result into a :class:`TriangleHit` (prim −1, t = inf, zeros on a miss)."""
    found = pos >= 0
    p = jnp.maximum(pos, 0)
    v = [a[p] for a in bvh.tri]
    # barycentrics and hit point of the winner only, once per ray (as TriangleSet does)
    return winner_hit(frame, t, jnp.where(found, bvh.prim[p], -1), v, bvh.ng[p],
                      stored_barycentrics)


def _traverse_one(bvh: BVH, origin, direction, t_max, stop_at_first: bool) -> _Cursor:
    """while_loop over the tree for ONE ray; returns the final cursor."""
    ray = _make_ray(*origin, *direction)
    t_max = jnp.asarray(t_max, origin.dtype)
    return lax.while_loop(
        lambda c: _running(bvh, c),
        lambda c: _step(bvh, ray, c, stop_at_first, BOX_STEPS),
        _initial_cursor(t_max, True),
    )


# Batches are compacted when the running rays fit in a quarter of the lanes, down to this
# many lanes (below it XLA:CPU's fixed cost per kernel call dominates a step).
MIN_COMPACT_LANES = 256


def running_lanes(running: Array, cap: int) -> Array:
    """The indices of the ``True`` lanes of ``running``, in order, padded with 0 to ``(cap,)``.

    What ``jnp.nonzero(running, size=cap, fill_value=0)`` returns when at most ``cap`` lanes
    run (the caller's loop guarantees it; further lanes are dropped), computed as one prefix
    count: lane ``i`` goes to slot ``c_i − 1``, ``c_i = Σ_{j ≤ i} running_j``. The count is two
    small matrix products instead of a scan: the N lanes (padded) as a (N/b, b) matrix times
    the b×b upper-triangular matrix of ones gives the counts within each block, and the
    blocks' totals times the strict upper-triangular (N/b)×(N/b) one their offsets
    (b ≈ √N, so ~N^1.5 multiply-adds: 2·10⁶ for N = 16 384). The products are of 0/1 values
    in float32, whose partial sums are integers below 2²⁴, so they are exact in any order.
    ``jnp.nonzero`` does two cumulative sums (an associative scan of log N levels each) and a
    bincount: in a BVH scene's MIS pass (12 compaction stages) 110 more kernels, 12 more of
    them distinct; this form's XLA compile 0.91× the wall time, 0.95× the CPU time, pass time
    unchanged (benchmarks/README.md#bvh-compaction). Shapes: running (N,) bool -> (cap,) int32.
    """
    n = running.shape[0]
    if n >= 1 << 24:  # float32 counts would no longer be exact
        return jnp.nonzero(running, size=cap, fill_value=0)[0].astype(jnp.int32)
    b = 8 * max(1, -(-int(np.ceil(np.sqrt(n))) // 8))
    nb = -(-n // b)
    ones = jnp.pad(running.astype(jnp.float32), (0, nb * b - n)).reshape(nb, b)
    within = jnp.matmul(ones, jnp.asarray(np.triu(np.ones((b, b), np.float32))),
                        precision="highest")
    before = jnp.matmul(within[:, -1], jnp.asarray(np.triu(np.ones((nb, nb), np.float32), 1)),
                        precision="highest")
    slot = (within + before[:, None]).reshape(-1)[:n].astype(jnp.int32) - 1
    return jnp.zeros((cap,), jnp.int32).at[jnp.where(running, slot, cap)].set(
        jnp.arange(n, dtype=jnp.int32), mode="drop")


def _traverse_batch(bvh: BVH, origins, directions, t_max, stop_at_first: bool):
    """Traverse N rays with compaction; returns per-ray ``(t, pos)`` of shape (N,).

    Every ray takes exactly the steps it takes in :func:`_traverse_one`; only the schedule
    differs. Lanes advance in lockstep until at most a quarter of them still run; those are
    then gathered into a batch a quarter the size, and so on down to ``MIN_COMPACT_LANES``,
    so the batch no longer pays full width for its slowest rays (on 82k triangles an
    incoherent ray needs 4.7 steps on average and the slowest 9; a camera ray 3.1 and 31).
    """
    origins, directions = jnp.asarray(origins), jnp.asarray(directions)
    n = origins.shape[0]
    rays = jax.vmap(_make_ray)(*(origins[:, k] for k in range(3)),
                               *(directions[:, k] for k in range(3)))
    cur = _initial_cursor(t_max, jnp.ones((n,), bool))
    step = jax.vmap(lambda r, c: _step(bvh, r, c, stop_at_first, BOX_STEPS))
    ids = jnp.arange(n, dtype=jnp.int32)
    out_t, out_pos = cur.t, cur.pos
    width = n
    while width // 4 >= MIN_COMPACT_LANES:  # static: the caps are known at trace time
        cap = width // 4
        cur = lax.while_loop(lambda c, cap=cap: jnp.sum(_running(bvh, c)) > cap,
                             lambda c, rays=rays: step(rays, c), cur)
        # every lane's result so far (final for the finished ones) ...
        out_t = out_t.at[ids].set(cur.t, mode="drop")
        out_pos = out_pos.at[ids].set(cur.pos, mode="drop")
        # ... then the running lanes, in order, into a batch of `cap` (the rest: padding)
        running = _running(bvh, cur)
        sel = running_lanes(running, cap)
        pad = jnp.arange(cap) >= jnp.sum(running)
        take = lambda a, sel=sel: a[sel]
        rays, cur = jax.tree_util.tree_map(take, rays), jax.tree_util.tree_map(take, cur)
        cur = cur._replace(node=jnp.where(pad, jnp.iinfo(jnp.int32).max, cur.node))
        ids = jnp.where(pad, n, ids[sel])
        width = cap
    cur = lax.while_loop(lambda c: jnp.any(_running(bvh, c)), lambda c: step(rays, c), cur)
    out_t = out_t.at[ids].set(cur.t, mode="drop")
    out_pos = out_pos.at[ids].set(cur.pos, mode="drop")
    return out_t, out_pos


def _make_traverse(stop_at_first: bool):
    """``(bvh, origin, direction, t_max) -> (t, pos)`` for one ray, whose ``vmap`` compacts.

    Called directly it is :func:`_traverse_one`. Under ``jax.vmap`` over rays (the BVH not
    batched) its batching rule runs :func:`_traverse_batch` instead of a lockstep
    ``while_loop``: same per-ray results; on 82k triangles (2^14 rays, paired) 1.3× faster
    for incoherent rays and 2.9× (closest) / 3.9× (any) for camera rays, whose slowest rays
    graze the silhouette (benchmarks/README.md#bvh-compaction). A batch of BVHs falls back to
    lockstep.
    """

    @jax.custom_batching.custom_vmap
    def traverse(bvh, origin, direction, t_max):
        c = _traverse_one(bvh, origin, direction, t_max, stop_at_first)
        return c.t, c.pos

    @traverse.def_vmap
    def rule(axis_size, in_batched, bvh, origin, direction, t_max):
        bvh_batched, o_b, d_b, t_b = in_batched
        if any(jax.tree_util.tree_leaves(bvh_batched)):
            # a batch of BVHs: plain lockstep traversal
            axes = (jax.tree_util.tree_map(lambda b: 0 if b else None, bvh_batched),
                    0 if o_b else None, 0 if d_b else None, 0 if t_b else None)
            # (the primal, not `traverse`: calling it under this vmap would re-enter the rule)
            def one(g, o, d, t):
                c = _traverse_one(g, o, d, t, stop_at_first)
                return c.t, c.pos

            return jax.vmap(one, axes)(bvh, origin, direction, t_max), (True, True)
        dtype = origin.dtype
        o = origin if o_b else jnp.broadcast_to(origin, (axis_size, 3))
        d = direction if d_b else jnp.broadcast_to(direction, (axis_size, 3))
        t = jnp.asarray(t_max, dtype)
        t = t if t_b else jnp.broadcast_to(t, (axis_size,))
        return _traverse_batch(bvh, o, d, t, stop_at_first), (True, True)

    return traverse


_TRAVERSE = {False: _make_traverse(False), True: _make_traverse(True)}


def closest_hit_ray(bvh: BVH, origin: Array, direction: Array, t_max: Array,
                    stored_barycentrics: bool = False) -> TriangleHit:
    """Closest intersection of ONE ray with the BVH's triangles, ``t ∈ (0, t_max]``.

    Stackless traversal along skip links; boxes are culled against the current closest
    ``t``, so the search shrinks as hits are found. ``origin``, ``direction``: (3,), world
    frame, ``direction`` need not be unit (``t`` is in units of ``‖direction‖``). Returns a
    :class:`TriangleHit` with ``prim = −1`` and ``t = inf`` on a miss. Vmap over rays.
    ``stored_barycentrics`` (static): see :func:`jaxrt.geometry.triangle.winner_hit`.
    """
    t, pos = _TRAVERSE[False](bvh, origin, direction, jnp.asarray(t_max, origin.dtype))
    return _to_hit(bvh, ray_frame(origin, direction), t, pos, stored_barycentrics)


def any_hit_ray(bvh: BVH, origin: Array, direction: Array, t_max: Array) -> Array:
    """Whether ONE ray hits any triangle with ``t ∈ (0, t_max]`` (stops at the first hit).

    Shapes as :func:`closest_hit_ray`; returns a bool scalar.
    """
    return _TRAVERSE[True](bvh, origin, direction, jnp.asarray(t_max, origin.dtype))[1] >= 0
