"""BVH construction on the host: binned SAH, built level by level with vectorised numpy.

The build never walks nodes one at a time in Python: every level of the tree is split in one
pass of array operations (per-node reductions with ``np.*.reduceat``, per-bin bounds with
``np.minimum.at``, an in-segment stable partition by prefix sums), so the Python overhead is
per *level*, not per node, and a million triangles build in seconds.

The result is flattened in depth-first order with *skip* (miss) links — a "threaded" BVH
(Smits 1998, "Efficiency issues for ray tracing"): from node ``i``, the next node to visit
is ``i + 1`` (the left child) when the ray hits the box of an interior node, and ``skip[i]``
(the first node after ``i``'s subtree) otherwise, so traversal needs no stack. Leaves hold
at most ``leaf_size`` triangles, stored contiguously in the reordered triangle array, which
is padded with ``leaf_size`` degenerate triangles so a leaf can always be read as a
fixed-size block.

Reference: Wald 2007, "On fast construction of SAH-based bounding volume hierarchies"
(binned SAH); PBR book 4th ed. §7.3.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class FlatBVH(NamedTuple):
    """A BVH flattened in depth-first order (numpy, host side). ``N`` nodes, ``F`` triangles.

    box_lo, box_hi: (N, 3) node bounds (exact min/max of the vertices below the node).
    skip: (N,) int32, the node visited after node ``i`` when its subtree is skipped or
        finished; ``N`` means "traversal done".
    leaf_start: (N,) int32 first triangle (in the reordered array) of a leaf; 0 for interior.
    leaf_count: (N,) int32 triangles in a leaf, 0 for interior nodes.
    triangles: (F + leaf_size, 3, 3) triangles reordered by leaf, plus degenerate padding.
    prim: (F + leaf_size,) int32 original index of each reordered triangle, −1 for padding.
    depth: () int, tree depth (root = 1).
    """

    box_lo: np.ndarray
    box_hi: np.ndarray
    skip: np.ndarray
    leaf_start: np.ndarray
    leaf_count: np.ndarray
    triangles: np.ndarray
    prim: np.ndarray
    depth: int


def validate_triangles(triangles) -> np.ndarray:
    """Check a triangle array (F, 3, 3) and return it as a numpy array.

    Raises ValueError on a wrong shape, an empty set, or a non-finite vertex (naming the
    first offending triangle index).
    """
    tri = np.asarray(triangles)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ValueError(f"triangles must have shape (F, 3, 3), got {tri.shape}")
    if tri.shape[0] == 0:
        raise ValueError("triangles is empty: a BVH needs at least one triangle")
    if not np.issubdtype(tri.dtype, np.floating):
        tri = tri.astype(np.float32)
    bad = ~np.isfinite(tri).all(axis=(1, 2))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"triangle {i} has a non-finite vertex ({int(bad.sum())} bad triangles in total)"
        )
    return tri


def _surface_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Surface area of boxes ``[lo, hi]`` (..., 3); empty boxes (lo > hi) have area 0."""
    e = np.maximum(hi - lo, 0.0)
    e = np.where(np.isfinite(e), e, 0.0)
    return 2.0 * (e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0])


def _segment_ids(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For segments of lengths ``counts``: the segment of every element and segment offsets."""
    offsets = np.cumsum(counts) - counts
    seg = np.repeat(np.arange(len(counts)), counts)
    return seg, offsets


def build_flat_bvh(triangles, leaf_size: int = 4, n_bins: int = 16) -> FlatBVH:
    """Build a binned-SAH BVH over ``triangles`` (F, 3, 3) and flatten it (host, numpy).

    Each node with more than ``leaf_size`` triangles is split by the plane, among
    ``n_bins - 1`` candidates per axis over the node's centroid bounds, that minimises the
    surface area heuristic ``A_L N_L + A_R N_R`` (Goldsmith & Salmon 1987; the common
    factors of the SAH, traversal cost and parent area, do not change the argmin). A node
    whose centroids coincide is split at its median. Nodes with at most ``leaf_size``
    triangles become leaves: traversal tests a leaf as one fixed-size block, so a smaller
    leaf would cost the same.

    Args:
        triangles: (F, 3, 3) vertices, finite.
        leaf_size: maximal triangles per leaf (the block size tested at once), ≥ 1.
        n_bins: SAH bins per axis, ≥ 2.
    Returns:
        A :class:`FlatBVH` whose arrays keep the dtype of ``triangles``.
    """
    tri = validate_triangles(triangles)
    if leaf_size < 1 or n_bins < 2:
        raise ValueError(f"need leaf_size >= 1 and n_bins >= 2, got {leaf_size}, {n_bins}")
    n_tri = tri.shape[0]
    lo = tri.min(axis=1)
    hi = tri.max(axis=1)
    # Centroids of the triangle bounds; the build works in the input precision (float32 halves
    # the memory traffic, and bins need no more).
    cen = 0.5 * lo + 0.5 * hi

    order = np.arange(n_tri, dtype=np.int64)
    # Per level: node start/count and, once known, split children.
    levels_start, levels_count, levels_split = [], [], []
    start = np.zeros(1, np.int64)
    count = np.full(1, n_tri, np.int64)
    while len(start):
        levels_start.append(start)
        levels_count.append(count)
        split = count > leaf_size
        levels_split.append(split)
        if not split.any():
            break
        s_start, s_count = start[split], count[split]
        k = len(s_start)
        seg, offsets = _segment_ids(s_count)
        pos = s_start[seg] + (np.arange(len(seg)) - offsets[seg])
        ids = order[pos]
        c = cen[ids]
        # Centroid bounds per node decide the bins.
        cmin = np.minimum.reduceat(c, offsets, axis=0)
        cmax = np.maximum.reduceat(c, offsets, axis=0)
        extent = cmax - cmin
        scale = np.where(extent > 0, n_bins / np.where(extent > 0, extent, 1), 0).astype(c.dtype)
        b = np.clip(((c - cmin[seg]) * scale[seg]).astype(np.int32), 0, n_bins - 1)
        # Per (node, axis, bin): triangle count and the bounds of their boxes.
        key = (seg[:, None] * 3 + np.arange(3)) * n_bins + b  # (n, 3)
        nkeys = k * 3 * n_bins
        bin_n = np.bincount(key.ravel(), minlength=nkeys).reshape(k, 3, n_bins)
        bin_lo = np.full((3, nkeys), np.inf, tri.dtype)
        bin_hi = np.full((3, nkeys), -np.inf, tri.dtype)
        tlo, thi = lo[ids].T, hi[ids].T
        # Static 3 × 3 loop (binning axis × coordinate) of 1-D scatters, numpy's fast path.
        for axis in range(3):
            for j in range(3):
                np.minimum.at(bin_lo[j], key[:, axis], tlo[j])
                np.maximum.at(bin_hi[j], key[:, axis], thi[j])
        bin_lo = np.moveaxis(bin_lo, 0, -1).reshape(k, 3, n_bins, 3)
        bin_hi = np.moveaxis(bin_hi, 0, -1).reshape(k, 3, n_bins, 3)
        # Sweep: left side = bins [0, i], right side = bins (i, n_bins).
        n_left = np.cumsum(bin_n, axis=2)[:, :, :-1]
        n_right = bin_n.sum(axis=2, keepdims=True) - n_left
        a_left = _surface_area(
            np.minimum.accumulate(bin_lo, axis=2), np.maximum.accumulate(bin_hi, axis=2)
        )[:, :, :-1]
        a_right = _surface_area(
            np.minimum.accumulate(bin_lo[:, :, ::-1], axis=2)[:, :, ::-1],
            np.maximum.accumulate(bin_hi[:, :, ::-1], axis=2)[:, :, ::-1],
        )[:, :, 1:]
        cost = a_left * n_left + a_right * n_right
        cost = np.where((n_left > 0) & (n_right > 0), cost, np.inf).reshape(k, -1)
        best = np.argmin(cost, axis=1)
        has_split = np.isfinite(cost[np.arange(k), best])
        best_axis, best_bin = best // (n_bins - 1), best % (n_bins - 1)
        # Side of every triangle: by its bin on the best axis, or by rank for a median split.
        rank = np.arange(len(seg)) - offsets[seg]
        go_left = np.where(
            has_split[seg],
            b[np.arange(len(seg)), best_axis[seg]] <= best_bin[seg],
            rank < s_count[seg] // 2,
        )
        # Stable partition inside each segment by prefix sums (no sort).
        left_incl = np.cumsum(go_left)
        left_before = left_incl[offsets] - go_left[offsets]
        n_l = np.add.reduceat(go_left.astype(np.int64), offsets)
        rank_l = left_incl - 1 - left_before[seg]
        rank_r = rank - (left_incl - left_before[seg])
        new_pos = s_start[seg] + np.where(go_left, rank_l, n_l[seg] + rank_r)
        order[new_pos] = ids
        # Children of split node j are nodes 2j, 2j+1 of the next level.
        start = np.stack([s_start, s_start + n_l], axis=1).ravel()
        count = np.stack([n_l, s_count - n_l], axis=1).ravel()

    return _flatten(tri, order, levels_start, levels_count, levels_split, leaf_size)


def _flatten(tri, order, levels_start, levels_count, levels_split, leaf_size) -> FlatBVH:
    """Lay the level-ordered tree out depth-first with skip links (vectorised per level)."""
    depth = len(levels_start)
    # Subtree sizes, bottom-up: a split node's children are 2j, 2j+1 among next-level nodes.
    sizes = [None] * depth
    sizes[-1] = np.ones(len(levels_start[-1]), np.int64)
    for d in range(depth - 2, -1, -1):
        size = np.ones(len(levels_start[d]), np.int64)
        child = sizes[d + 1].reshape(-1, 2)
        size[levels_split[d]] += child.sum(axis=1)
        sizes[d] = size
    # Depth-first index, top-down: left child right after its parent, right after the left
    # subtree.
    n_nodes = int(sizes[0][0])
    dfs = [np.zeros(1, np.int64)]
    for d in range(depth - 1):
        parent = dfs[d][levels_split[d]]
        left_size = sizes[d + 1].reshape(-1, 2)[:, 0]
        dfs.append(np.stack([parent + 1, parent + 1 + left_size], axis=1).ravel())
    dfs_all = np.concatenate(dfs)
    size_all = np.concatenate(sizes)
    start_all = np.concatenate(levels_start)
    count_all = np.concatenate(levels_count)
    leaf_all = ~np.concatenate(levels_split)

    # Node bounds: exact min/max over each node's contiguous triangle range.
    lo = tri.min(axis=1)[order]
    hi = tri.max(axis=1)[order]
    box_lo = np.empty((n_nodes, 3), tri.dtype)
    box_hi = np.empty((n_nodes, 3), tri.dtype)
    box_lo[dfs_all] = _range_reduce(np.minimum, lo, start_all, count_all)
    box_hi[dfs_all] = _range_reduce(np.maximum, hi, start_all, count_all)

    skip = np.empty(n_nodes, np.int32)
    skip[dfs_all] = dfs_all + size_all
    leaf_start = np.zeros(n_nodes, np.int32)
    leaf_count = np.zeros(n_nodes, np.int32)
    leaf_start[dfs_all[leaf_all]] = start_all[leaf_all]
    leaf_count[dfs_all[leaf_all]] = count_all[leaf_all]

    # Degenerate padding (all vertices equal) never hits, so a leaf reads as a full block.
    pad = np.broadcast_to(tri[order[-1], :1], (leaf_size, 3, 3))
    triangles = np.concatenate([tri[order], pad], axis=0)
    prim = np.concatenate([order, np.full(leaf_size, -1)]).astype(np.int32)
    return FlatBVH(box_lo, box_hi, skip, leaf_start, leaf_count, triangles, prim, depth)


def _range_reduce(ufunc, values, start, count):
    """``ufunc.reduce(values[s:s+c])`` for every range (ranges may nest), vectorised.

    ``ufunc.reduceat`` over the interleaved indices ``s0, e0, s1, e1, ...`` reduces
    ``values[s_i:e_i]`` at every even position whatever the order of the ranges.
    """
    pairs = np.stack([start, start + count], axis=1).ravel()
    # One extra row so that an end index equal to len(values) is a valid reduceat index.
    padded = np.concatenate([values, values[:1]], axis=0)
    return ufunc.reduceat(padded, pairs, axis=0)[::2]
