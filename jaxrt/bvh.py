"""Bounding volume hierarchy: a pytree of flat arrays and its stackless traversal in JAX.

The tree is built on the host (:mod:`jaxrt.bvh_build`, binned SAH) and laid out depth-first
with skip links, so a ray walks it with a single integer cursor and no stack:

    node ← 0
    while node ≠ N:
        if the ray hits box(node) before its current closest t:
            if leaf(node): test its ≤ L triangles at once, shrink t
            else: node ← node + 1 (the left child); continue
        node ← skip(node)

Two entry points share that step:

- :meth:`BVH.closest_hit` / :meth:`BVH.any_hit` for ONE ray, written as a ``while_loop``
  and meant to be called inside ``jax.vmap`` (the polymorphic ``jaxrt.intersect.closest_hit``
  and ``any_hit`` dispatch to them). Under ``vmap`` every lane waits for the slowest ray.
- :func:`closest_hit_batch` / :func:`any_hit_batch` for a whole batch of rays with
  *persistent lanes*: ``lanes`` rays are traversed together, and every ``refill_every``
  steps a lane that has finished writes its result and takes the next ray, so the batch
  no longer waits for its slowest ray. See benchmarks/README.md for the measurements.

Reference: Smits 1998, "Efficiency issues for ray tracing" (skip links); Aila & Laine 2009,
"Understanding the efficiency of ray traversal on GPUs" (persistent threads).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.bvh_build import FlatBVH, build_flat_bvh
from jaxrt.intersect import (
    Hit,
    RayFrame,
    barycentrics_frame,
    gamma,
    intersect_triangle_t,
    ray_frame,
    triangle_set,
)


@jax.tree_util.register_pytree_node_class
@dataclass(frozen=True)
class BVH:
    """A flat, stackless BVH over ``F`` triangles with ``N`` nodes (a JAX pytree).

    Stored as structure-of-arrays, every field a 1-D array, because under ``vmap`` XLA:CPU
    is far slower on ``(rays, 3)`` arrays sliced along their minor axis than on one
    contiguous vector per coordinate.

    box: 6 × (N,) node bounds ``(lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)``.
    skip: (N,) int32 node visited after a node's subtree (``N``: done).
    leaf_start, leaf_count: (N,) int32 a leaf's triangle range; ``leaf_count == 0`` marks an
        interior node, whose left child is the next node.
    tri: (F + L, 9) vertex coordinates ``(v0x, v0y, v0z, v1x, …, v2z)`` of the triangles
        reordered by leaf, padded with L degenerate triangles.
    prim: (F + L,) int32 original triangle index of each reordered triangle (−1 padding).
    ng: (F + L, 3) unit geometric normals of the reordered triangles (as ``TriangleSet``).
    leaf_size: static ``L``, the block of triangles tested at once in a leaf.
    """

    box: tuple
    skip: Array
    leaf_start: Array
    leaf_count: Array
    tri: tuple
    prim: Array
    ng: Array
    leaf_size: int

    def tree_flatten(self):
        children = (self.box, self.skip, self.leaf_start, self.leaf_count, self.tri, self.prim,
                    self.ng)
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

    def closest_hit(self, origin: Array, direction: Array, t_max: Array) -> Hit:
        """Closest hit of ONE ray in ``(0, t_max]``: see :func:`closest_hit_ray`."""
        return closest_hit_ray(self, origin, direction, t_max)

    def any_hit(self, origin: Array, direction: Array, t_max: Array) -> Array:
        """Whether ONE ray hits anything in ``(0, t_max]``: see :func:`any_hit_ray`."""
        return any_hit_ray(self, origin, direction, t_max)


def bvh_from_flat(flat: FlatBVH, leaf_size: int) -> BVH:
    """Move a host :class:`FlatBVH` to device arrays (floats in JAX's default precision)."""
    dtype = jnp.result_type(float)
    # Normals and zero-area flags exactly as the brute-force TriangleSet computes them.
    tset = triangle_set(flat.triangles)
    tri = jnp.asarray(tset.vertices, dtype)
    # Zero-area triangles never hit: collapse them to a point, whose determinant is exactly
    # 0 in the watertight test, instead of testing a flag per triangle.
    tri = jnp.where(tset.valid[:, None, None], tri, tri[:, :1])
    box = np.concatenate([flat.box_lo, flat.box_hi], axis=1)
    as_int = lambda a: jnp.asarray(a, jnp.int32)
    return BVH(
        tuple(jnp.asarray(box[:, k], dtype) for k in range(6)),
        as_int(flat.skip), as_int(flat.leaf_start), as_int(flat.leaf_count),
        tri.reshape(-1, 9), as_int(flat.prim), jnp.asarray(tset.ng, dtype), leaf_size,
    )


def build_bvh(triangles, leaf_size: int = 4, n_bins: int = 16) -> BVH:
    """Build a binned-SAH BVH over ``triangles`` (F, 3, 3) on the host, return it on device.

    ``leaf_size`` triangles per leaf at most (tested as one block), ``n_bins`` SAH bins per
    axis. Raises ValueError on non-finite vertices (naming the triangle) or a bad shape.
    """
    return bvh_from_flat(build_flat_bvh(triangles, leaf_size, n_bins), leaf_size)


# Box visits per leaf-block test in one traversal step (measured: benchmarks/README.md).
BOX_STEPS = 4


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

    node: next node to visit (``N`` or more when done); leaf: an entered leaf whose
    triangles are still to be tested, or −1; t, pos: closest hit so far (``pos`` indexes
    the reordered triangles, −1 before any hit; ``t`` starts at ``t_max``).
    """

    node: Array
    leaf: Array
    t: Array
    pos: Array


def _initial_cursor(t_max: Array, live) -> _Cursor:
    """Cursor at the root (or already done when not ``live``), no hit yet."""
    minus_one = jnp.full(t_max.shape, -1, jnp.int32)
    node = jnp.where(live, 0, jnp.iinfo(jnp.int32).max).astype(jnp.int32)
    return _Cursor(node, minus_one, t_max, minus_one)


def _box_step(bvh: BVH, ray: _Ray, c: _Cursor) -> _Cursor:
    """Visit one node's box unless a leaf is pending: descend, skip, or mark the leaf."""
    active = (c.leaf < 0) & (c.node < bvh.num_nodes)
    node = jnp.minimum(c.node, bvh.num_nodes - 1)
    enter = active & _slab_entry(tuple(b[node] for b in bvh.box), ray, c.t)
    is_leaf = bvh.leaf_count[node] > 0
    # Descend into an entered interior node, otherwise follow the skip link.
    next_node = jnp.where(enter & ~is_leaf, node + 1, bvh.skip[node])
    return c._replace(
        node=jnp.where(active, next_node, c.node),
        leaf=jnp.where(enter & is_leaf, node, c.leaf),
    )


def _leaf_step(bvh: BVH, ray: _Ray, c: _Cursor, stop_at_first: bool) -> _Cursor:
    """Test the pending leaf's triangles as one block of L and keep the closest hit."""
    leaf = jnp.maximum(c.leaf, 0)
    count = jnp.where(c.leaf >= 0, bvh.leaf_count[leaf], 0)
    idx = bvh.leaf_start[leaf] + jnp.arange(bvh.leaf_size, dtype=jnp.int32)
    # One row gather of 9 floats per triangle, then coordinate-major for the test.
    v = bvh.tri[idx].T
    tt = jax.vmap(intersect_triangle_t, (None, 0, 0, 0, None))(
        ray.frame, (v[0], v[1], v[2]), (v[3], v[4], v[5]), (v[6], v[7], v[8]), c.t
    )
    # Without the barrier XLA fuses the block test into each consumer, recomputing it.
    tt = lax.optimization_barrier(tt)
    # Block entries past the leaf's count belong to the next leaf: mask them.
    tt = jnp.where(jnp.arange(bvh.leaf_size) < count, tt, jnp.inf)
    j = jnp.argmin(tt)
    # As TriangleSet: strictly closer, but the first hit may sit exactly at t_max.
    closer = (tt[j] < c.t) | ((c.pos < 0) & (tt[j] < jnp.inf))
    node = jnp.where(closer, bvh.num_nodes, c.node) if stop_at_first else c.node
    return _Cursor(node, jnp.full_like(c.leaf, -1), jnp.where(closer, tt[j], c.t),
                   jnp.where(closer, idx[j], c.pos))


def _step(bvh: BVH, ray: _Ray, c: _Cursor, stop_at_first: bool, box_steps: int) -> _Cursor:
    """Up to ``box_steps`` box visits (until a leaf is entered), then that leaf's test.

    A block of watertight triangle tests costs ~20 box tests, so a lane walks several
    boxes per leaf block instead of paying for a (masked) block at every node.
    """
    for _ in range(box_steps):  # a few static box visits, unrolled
        c = _box_step(bvh, ray, c)
    return _leaf_step(bvh, ray, c, stop_at_first)


def _running(bvh: BVH, c: _Cursor) -> Array:
    """Whether a cursor still has nodes or a pending leaf to visit."""
    return (c.node < bvh.num_nodes) | (c.leaf >= 0)


def _to_hit(bvh: BVH, frame: RayFrame, t, pos) -> Hit:
    """Turn a traversal result into a :class:`Hit` (prim −1, t = inf, zeros on a miss)."""
    found = pos >= 0
    p = jnp.maximum(pos, 0)
    v = bvh.tri[p]
    # Barycentrics of the winner only, once per ray (as TriangleSet does).
    b1, b2 = barycentrics_frame(frame, v[0:3], v[3:6], v[6:9])
    zero = jnp.zeros_like(t)
    return Hit(jnp.where(found, t, jnp.inf), jnp.where(found, bvh.prim[p], -1).astype(jnp.int32),
               jnp.where(found, b1, zero), jnp.where(found, b2, zero),
               jnp.where(found, bvh.ng[p], jnp.zeros_like(bvh.ng[p])))


def _traverse_one(bvh: BVH, origin, direction, t_max, stop_at_first: bool) -> _Cursor:
    """while_loop over the tree for ONE ray; returns the final cursor."""
    ray = _make_ray(*origin, *direction)
    t_max = jnp.asarray(t_max, origin.dtype)
    return lax.while_loop(
        lambda c: _running(bvh, c),
        lambda c: _step(bvh, ray, c, stop_at_first, BOX_STEPS),
        _initial_cursor(t_max, True),
    )


def closest_hit_ray(bvh: BVH, origin: Array, direction: Array, t_max: Array) -> Hit:
    """Closest intersection of ONE ray with the BVH's triangles, ``t ∈ (0, t_max]``.

    Stackless traversal along skip links; boxes are culled against the current closest
    ``t``, so the search shrinks as hits are found. ``origin``, ``direction``: (3,), world
    frame, ``direction`` need not be unit (``t`` is in units of ``‖direction‖``). Returns a
    :class:`Hit` with ``prim = −1`` and ``t = inf`` on a miss. Vmap over rays; for large
    batches :func:`closest_hit_batch` is faster.
    """
    c = _traverse_one(bvh, origin, direction, t_max, False)
    return _to_hit(bvh, ray_frame(origin, direction), c.t, c.pos)


def any_hit_ray(bvh: BVH, origin: Array, direction: Array, t_max: Array) -> Array:
    """Whether ONE ray hits any triangle with ``t ∈ (0, t_max]`` (stops at the first hit).

    Shapes as :func:`closest_hit_ray`; returns a bool scalar.
    """
    return _traverse_one(bvh, origin, direction, t_max, True).pos >= 0


def _persistent(bvh, origins, directions, t_max, lanes, refill_every, stop_at_first):
    """Traverse R rays on ``lanes`` persistent lanes; returns per-ray ``(t, pos)``."""
    n_rays = origins.shape[0]
    lanes = max(1, min(lanes, n_rays))
    dtype = origins.dtype
    t_max = jnp.broadcast_to(jnp.asarray(t_max, dtype), (n_rays,))
    # Structure of arrays: one contiguous vector per coordinate.
    coords = tuple(origins[:, k] for k in range(3)) + tuple(directions[:, k] for k in range(3))
    step = jax.vmap(lambda ray, c: _step(bvh, ray, c, stop_at_first, BOX_STEPS))

    def load(ray_id):
        # Gather each lane's ray; lanes past the end start (and stay) done.
        r = jnp.minimum(ray_id, n_rays - 1)
        ray = jax.vmap(_make_ray)(*(c[r] for c in coords))
        return ray, _initial_cursor(t_max[r], ray_id < n_rays)

    def outer(carry):
        ray_id, next_id, ray, cur, out = carry
        cur = lax.fori_loop(0, refill_every, lambda _, c: step(ray, c), cur)
        finished = ~_running(bvh, cur)
        # Finished lanes write their result (the others write to a dropped index) ...
        slot = jnp.where(finished & (ray_id < n_rays), ray_id, n_rays)
        res = (cur.t, cur.pos)
        out = tuple(a.at[slot].set(v, mode="drop") for a, v in zip(out, res, strict=True))
        # ... and take the next rays, in lane order.
        new_id = next_id + jnp.cumsum(finished, dtype=jnp.int32) - 1
        ray_id = jnp.where(finished, jnp.minimum(new_id, n_rays), ray_id)
        fresh_ray, fresh = load(ray_id)
        keep = lambda a, b: jnp.where(finished, b, a)
        ray = jax.tree_util.tree_map(keep, ray, fresh_ray)
        cur = jax.tree_util.tree_map(keep, cur, fresh)
        next_id = next_id + jnp.sum(finished, dtype=jnp.int32)
        return ray_id, next_id, ray, cur, out

    ray_id = jnp.arange(lanes, dtype=jnp.int32)
    ray, cur = load(ray_id)
    zeros = jnp.zeros((n_rays,), dtype)
    out = (zeros, jnp.full((n_rays,), -1, jnp.int32))
    carry = (ray_id, jnp.int32(lanes), ray, cur, out)
    carry = lax.while_loop(lambda c: jnp.any(c[0] < n_rays), outer, carry)
    return carry[-1]


def closest_hit_batch(
    bvh: BVH,
    origins: Array,
    directions: Array,
    t_max: Array,
    lanes: int = 256,
    refill_every: int = 8,
) -> Hit:
    """Closest hits of a batch of rays with persistent lanes (fast path for large batches).

    Same result per ray as ``vmap(closest_hit_ray)``, but ``lanes`` rays are in flight at
    once and a lane that finishes takes the next ray every ``refill_every`` steps, so the
    batch does not wait for its slowest ray. ``origins``, ``directions``: (R, 3);
    ``t_max``: () or (R,). Returns a batched :class:`Hit` with leading axis R.
    """
    t, pos = _persistent(bvh, origins, directions, t_max, lanes, refill_every, False)
    return jax.vmap(lambda o, d, t, p: _to_hit(bvh, ray_frame(o, d), t, p))(
        origins, directions, t, pos
    )


def any_hit_batch(
    bvh: BVH,
    origins: Array,
    directions: Array,
    t_max: Array,
    lanes: int = 256,
    refill_every: int = 8,
) -> Array:
    """Occlusion of a batch of rays with persistent lanes: (R,) bool, hit in ``(0, t_max]``."""
    _, pos = _persistent(bvh, origins, directions, t_max, lanes, refill_every, True)
    return pos >= 0
