"""Building the light BVH (host, float64): each light's bounds, the splits, the node rows.

A node bounds its lights by a box, their total power (with the selection floor), a cone of
their normals (the normalised mean axis and the widest offset of a member's cone from it)
and the widest emission spread, stored as one row of
:attr:`jaxrt.scene.lights.bvh.LightBVH.node`. A node's children come from ``branch_bits``
rounds of binary splits, each chosen by the surface area orientation heuristic (SAOH: power
× box area × the cone's orientation measure ``M_Ω`` over both sides, :data:`SAOH_BUCKETS` planes
per axis) among the planes that keep the tree as deep as median splits would
(``split="saoh"``, the default), or at the median (``"median"``), or by SAOH at any depth
(``"saoh-free"``). The whole tree is built level by level with index arrays, every node of a
level split at once.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxrt.core.vecmath import device_array
from jaxrt.sampling.distributions import discrete_from_weights
from jaxrt.scene.lights.bvh import ANGLE_SLACK, BRANCH_BITS, LightBVH


class LightSet(NamedTuple):
    """Host bounds of the lights in the tree (float64, one row per light): boxes ``lo``/``hi``
    (M, 3), powers (M,), normal cones ``axis`` (M, 3) / ``theta_o`` (M,), emission spreads
    ``theta_e`` (M,)."""

    lo: np.ndarray
    hi: np.ndarray
    power: np.ndarray
    axis: np.ndarray
    theta_o: np.ndarray
    theta_e: np.ndarray

    def take(self, ids: np.ndarray) -> LightSet:
        return LightSet(*(a[ids] for a in self))


def light_bounds(lights, powers: np.ndarray) -> tuple[LightSet, np.ndarray]:
    """Bounds of the lights with a position and their global indices (M,), in global-index
    order (directional and environment lights are left out); ``powers`` (N,) already carries
    the selection floor."""
    lo, hi, axis, t_o, t_e = [], [], [], [], []
    up = np.array([0.0, 0.0, 1.0])
    half = np.pi / 2
    keep = []
    for kind in ("point", "spot", "directional", "triangle", "sphere", "environment"):
        t = lights.table(kind)
        if t is None:
            continue
        if kind in ("directional", "environment"):
            keep.append(np.zeros(1 if kind == "environment" else len(t.direction), bool))
            continue
        if kind in ("point", "spot"):
            q = np.asarray(t.position, np.float64).reshape(-1, 3)
            lo.append(q)
            hi.append(q)
            if kind == "point":
                axis.append(np.broadcast_to(up, q.shape))
                t_o.append(np.full(len(q), np.pi))
                t_e.append(np.full(len(q), half))
            else:
                w = np.asarray(t.axis, np.float64).reshape(-1, 3)
                axis.append(w / np.linalg.norm(w, axis=1, keepdims=True))
                t_o.append(np.zeros(len(q)))
                t_e.append(np.arccos(np.clip(np.asarray(t.cos_outer, np.float64).ravel(), -1, 1)))
        elif kind == "triangle":
            v = np.asarray(t.vertices, np.float64).reshape(-1, 3, 3)
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            axis.append(n / np.linalg.norm(n, axis=1, keepdims=True))
            lo.append(v.min(1))
            hi.append(v.max(1))
            # a two-sided triangle emits around ±n: a cone of half-angle π about n
            t_o.append(np.where(np.asarray(t.two_sided).ravel(), np.pi, 0.0))
            t_e.append(np.full(len(v), half))
        else:
            c = np.asarray(t.center, np.float64).reshape(-1, 3)
            r = np.asarray(t.radius, np.float64).reshape(-1, 1)
            lo.append(c - r)
            hi.append(c + r)
            axis.append(np.broadcast_to(up, c.shape))
            t_o.append(np.full(len(c), np.pi))
            t_e.append(np.full(len(c), half))
        keep.append(np.ones(len(lo[-1]), bool))
    ids = np.flatnonzero(np.concatenate(keep))
    if not lo:
        e = np.zeros((0, 3))
        return LightSet(e, e, np.zeros(0), e, np.zeros(0), np.zeros(0)), ids
    return LightSet(np.concatenate(lo), np.concatenate(hi), np.asarray(powers, np.float64)[ids],
                    np.concatenate(axis), np.concatenate(t_o), np.concatenate(t_e)), ids


def orientation_measure(theta_o, theta_e):
    """``M_Ω``: the solid angle of emission a cone ``θ_o`` of normals with spread ``θ_e``
    covers, each direction weighted by the cosine to its nearest normal (array-wise)."""
    theta_w = np.minimum(theta_o + theta_e, np.pi)
    so, co = np.sin(theta_o), np.cos(theta_o)
    return (2 * np.pi * (1 - co) + 0.5 * np.pi * (2 * theta_w * so - np.cos(theta_o - 2 * theta_w)
                                                  - 2 * theta_o * so + co))


#: Buckets per axis of a SAOH split.
SAOH_BUCKETS = 12


def _segments(seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and sizes of the runs of a non-decreasing label array."""
    start = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    return start, np.diff(np.r_[start, len(seg)])


def _median_sides(s: LightSet, seg: np.ndarray, start, size) -> np.ndarray:
    """Each light's side (0/1) when every segment splits in halves at the median of its
    centroids along their largest extent."""
    cent = 0.5 * (s.lo + s.hi)
    ext = np.maximum.reduceat(cent, start) - np.minimum.reduceat(cent, start)
    ax = np.argmax(ext, 1)
    order = np.lexsort((cent[np.arange(len(seg)), ax[seg]], seg))
    rank = np.empty(len(seg), np.int64)
    rank[order] = np.arange(len(seg))
    return (rank - start[seg] >= size[seg] // 2).astype(np.int64)


def _side_costs(s: LightSet, seg, b, nseg, nb):
    """SAOH cost (S, nb−1) of the lights in buckets ``≤ k`` of each segment, and their count."""
    key = seg * nb + b
    blo = np.full((nseg * nb, 3), np.inf)
    bhi = np.full((nseg * nb, 3), -np.inf)
    np.minimum.at(blo, key, s.lo)
    np.maximum.at(bhi, key, s.hi)
    bte = np.full(nseg * nb, -np.inf)
    np.maximum.at(bte, key, s.theta_e)
    box_lo = np.minimum.accumulate(blo.reshape(nseg, nb, 3), 1)[:, :-1]
    box_hi = np.maximum.accumulate(bhi.reshape(nseg, nb, 3), 1)[:, :-1]
    d = np.maximum(box_hi - box_lo, 0.0)
    area = 2 * (d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0])
    phi = np.cumsum(np.bincount(key, s.power, nseg * nb).reshape(nseg, nb), 1)[:, :-1]
    count = np.cumsum(np.bincount(key, minlength=nseg * nb).reshape(nseg, nb), 1)[:, :-1]
    te = np.maximum.accumulate(bte.reshape(nseg, nb), 1)[:, :-1]
    sums = np.stack([np.bincount(key, s.axis[:, k], nseg * nb) for k in range(3)], 1)
    w = np.cumsum(sums.reshape(nseg, nb, 3), 1)[:, :-1]  # (S, nb−1, 3)
    nw = np.linalg.norm(w, axis=2)
    w = w / np.maximum(nw, 1e-300)[..., None]
    ang = np.arccos(np.clip(np.einsum("nk,nsk->ns", s.axis, w[seg]), -1.0, 1.0))
    ang = np.where(b[:, None] <= np.arange(nb - 1), ang + s.theta_o[:, None], -np.inf)
    start, size = _segments(seg)
    t = np.maximum.reduceat(ang, start)
    t = np.where((nw < 1e-9 * size[:, None]) | (t >= np.pi), np.pi, np.minimum(t, np.pi))
    cost = phi * area * orientation_measure(t, np.maximum(te, 0.0))
    return np.where(count > 0, cost, np.inf), count


def _saoh_sides(s: LightSet, seg: np.ndarray, start, size, cap) -> np.ndarray:
    """Each light's side when every segment splits by the surface area orientation heuristic:
    of the planes between :data:`SAOH_BUCKETS` buckets of its centroids along each axis, the
    one that minimises ``Σ_side Φ · area(box) · M_Ω(cone)`` (times the box's longest extent
    over its extent along the axis, against thin slabs), among those that leave at most
    ``cap`` (per segment) lights on either side; median halves where no plane does."""
    nseg, nb = len(start), SAOH_BUCKETS
    cent = 0.5 * (s.lo + s.hi)
    cmin, cmax = np.minimum.reduceat(cent, start), np.maximum.reduceat(cent, start)
    diag = np.maximum.reduceat(s.hi, start) - np.minimum.reduceat(s.lo, start)
    costs, buckets = [], []
    for ax in range(3):
        ext = (cmax - cmin)[:, ax]
        pos = (cent[:, ax] - cmin[seg, ax]) / np.where(ext > 0, ext, 1.0)[seg]
        b = np.minimum((nb * pos).astype(np.int64), nb - 1)
        left, n_left = _side_costs(s, seg, b, nseg, nb)
        right, n_right = _side_costs(s, seg, nb - 1 - b, nseg, nb)
        thin = np.where(ext > 0, diag.max(1) / np.maximum(diag[:, ax], 1e-300), 1.0)
        cost = (left + right[:, ::-1]) * thin[:, None]
        ok = (ext[:, None] > 0) & (n_left <= cap[:, None]) & (n_right[:, ::-1] <= cap[:, None])
        costs.append(np.where(ok, cost, np.inf))
        buckets.append(b)
    cost = np.stack(costs, 1).reshape(nseg, -1)  # (S, 3 (nb − 1))
    best = np.argmin(cost, 1)
    found = np.isfinite(cost[np.arange(nseg), best])
    ax, k = best // (nb - 1), best % (nb - 1)
    side = (np.stack(buckets)[ax[seg], np.arange(len(seg))] > k[seg]).astype(np.int64)
    median = ~found[seg]
    if median.any():
        side = np.where(median, _median_sides(s, seg, start, size), side)
    return side


def _segment_rows(s: LightSet, seg: np.ndarray) -> np.ndarray:
    """The :attr:`LightBVH.node` rows of the lights of each segment together (S, NODE_WIDTH):
    the box, the power, a cone of the normals (mean axis, widest offset) and the spread."""
    start, size = _segments(seg)
    lo, hi = np.minimum.reduceat(s.lo, start), np.maximum.reduceat(s.hi, start)
    w = np.add.reduceat(s.axis, start)
    nw = np.linalg.norm(w, axis=1)
    w = np.where((nw > 1e-9 * size)[:, None], w / np.maximum(nw, 1e-300)[:, None], s.axis[start])
    t = np.maximum.reduceat(np.arccos(np.clip(np.sum(s.axis * w[seg], 1), -1, 1)) + s.theta_o,
                            start)
    wide = (nw <= 1e-9 * size) | (np.maximum.reduceat(s.theta_o, start) >= np.pi) | (t >= np.pi)
    t = np.where(wide, np.pi, t)
    return _rows(LightSet(lo, hi, np.add.reduceat(s.power, start), w, t,
                          np.maximum.reduceat(s.theta_e, start)))


def _rows(s: LightSet) -> np.ndarray:
    """Rows of :attr:`LightBVH.node` (host float64, (M, NODE_WIDTH)) of bounds ``s``."""
    e = s.theta_e + ANGLE_SLACK
    cos_e = np.where(e < np.pi, np.cos(e), -2.0)  # emits every way: no direction is cut
    return np.concatenate([0.5 * (s.lo + s.hi), s.axis,
                           np.stack([0.25 * np.sum((s.hi - s.lo) ** 2, 1), s.power,
                                     np.cos(s.theta_o), np.sin(s.theta_o), cos_e], 1)], 1)


#: ``split`` of :func:`build_light_bvh`: (SAOH or median, whether the tree keeps the depth of
#: median splits)
SPLITS = {"median": ("median", True), "saoh": ("saoh", True), "saoh-free": ("saoh", False)}


def _build(s: LightSet, bits: int, split: str, max_depth: int, budget: int | None):
    """The tree over the lights of ``s``, level by level (every node of a level at once, by
    index arrays): node rows (K, NODE_WIDTH), children (K, 2**bits), each node's light (-1
    inside), each light's trail and depth.

    A node's lights go to up to ``2**bits`` children by ``bits`` rounds of binary splits. With
    a ``budget`` (levels), no split leaves more lights on a side than the levels below can
    hold, so that the tree is as deep as one of median splits; without, median splits take
    over in nodes where the tree would otherwise outgrow ``max_depth`` levels."""
    m, branching = len(s.power), 1 << bits
    perm = np.arange(m)  # lights in the order of their node
    seg = np.zeros(m, np.int64)
    rows, child, leaf = [_segment_rows(s, seg)], [], []
    trail, depth = np.zeros(m, np.int64), np.zeros(m, np.int32)
    count, d = 1, 0
    while True:
        start, size = _segments(seg)
        single = size == 1
        lit = perm[start]
        leaf.append(np.where(single, lit, -1))
        kids = np.full((len(start), branching), -1, np.int64)
        child.append(kids)
        if single.all():
            break
        sub = perm  # the level's lights, in segment order
        seg_sub = seg.copy()
        levels = np.ceil(np.log(size) / np.log(branching) - 1e-9)
        if budget is None:
            use_saoh = (levels < max_depth - d)[seg]
            below = np.full(len(seg), np.inf)
        else:
            use_saoh = np.ones(len(seg), bool)
            below = np.full(len(seg), float(branching) ** (budget - d - 1))
        for r in range(bits):
            st, sz = _segments(seg_sub)
            ss = s.take(sub)
            side = _median_sides(ss, seg_sub, st, sz)
            # two lights split one each either way: SAOH only weighs segments of 3 or more
            big = np.flatnonzero(use_saoh & (sz[seg_sub] > 2)) if split == "saoh" else []
            if len(big):
                seg_b = np.cumsum(np.r_[0, seg_sub[big][1:] != seg_sub[big][:-1]])
                st_b, sz_b = _segments(seg_b)
                cap = (below[big] * (1 << (bits - r - 1)))[st_b]
                side[big] = _saoh_sides(ss.take(big), seg_b, st_b, sz_b, cap)
            side = np.where(sz[seg_sub] > 1, side, 0)
            order = np.lexsort((side, seg_sub))  # stable within each side
            label = 2 * seg_sub[order] + side[order]
            sub, use_saoh, below = sub[order], use_saoh[order], below[order]
            seg_sub = np.cumsum(np.r_[0, label[1:] != label[:-1]])
        # the children: the sub-segments of each node, in order; a node's segment is `seg`
        st, _ = _segments(seg_sub)
        parent = np.searchsorted(start, st, side="right") - 1  # segments keep their order
        digit = np.arange(len(st)) - np.searchsorted(parent, parent, side="left")
        inner = ~single[parent]
        ids = np.full(len(st), -1, np.int64)
        ids[inner] = count + np.arange(inner.sum())
        count += int(inner.sum())
        kids[parent[inner], digit[inner]] = ids[inner]
        # lights of leaves stay put; the others move to their child's segment
        lid = sub
        light_child = np.repeat(np.arange(len(st)), np.diff(np.r_[st, len(sub)]))
        on = inner[light_child]
        trail[lid[on]] |= digit[light_child[on]] << (bits * d)
        depth[lid[on]] = d + 1
        perm = lid[on]
        seg = np.cumsum(np.r_[0, light_child[on][1:] != light_child[on][:-1]])
        rows.append(_segment_rows(s.take(perm), seg))
        d += 1
    child = np.concatenate(child)
    return (np.concatenate(rows), child, np.concatenate(leaf), trail, depth)


def build_light_bvh(lights, powers: np.ndarray, floor: float, *, branch_bits: int = BRANCH_BITS,
                    split: str = "saoh") -> tuple[LightBVH, int]:
    """The :class:`LightBVH` of a light table and its depth (static: the descent's length).

    ``powers`` (N,): each light's power (:func:`.table.light_powers`); every light's weight
    is its power plus ``floor`` times the mean power (all equal if every power is 0).
    ``branch_bits``: log2 of the children per node; ``split``: ``"saoh"`` (SAOH splits within
    the depth of median splits), ``"median"`` or ``"saoh-free"`` (SAOH splits, any depth)."""
    powers = np.asarray(powers, np.float64)
    weights = powers + floor * powers.mean() if powers.sum() > 0 else np.ones_like(powers)
    s, tree_ids = light_bounds(lights, weights)
    n = len(weights)
    branching = 1 << branch_bits
    max_depth = 31 // branch_bits  # the trail's digits fit an int32
    in_tree = np.zeros(n, bool)
    in_tree[tree_ids] = True
    if tree_ids.size > branching ** max_depth:
        raise ValueError(f"a light BVH of {branching} children holds at most "
                         f"{branching ** max_depth} lights, got {tree_ids.size}")
    trail = np.zeros(n, np.int64)
    depth = np.full(n, -1, np.int32)
    if tree_ids.size:
        cut, keep_depth = SPLITS[split]
        # the depth of median splits: the fewest levels of `branching` children for the lights
        budget = (max(1, int(np.ceil(np.log(tree_ids.size) / np.log(branching) - 1e-9)))
                  if keep_depth else None)
        rows, child, leaf, t, d = _build(s, branch_bits, cut, max_depth, budget)
        leaf = np.where(leaf >= 0, tree_ids[np.maximum(leaf, 0)], -1)
        trail[tree_ids], depth[tree_ids] = t, d
    else:  # no light with a position: one inert node keeps the arrays well formed
        rows = _rows(LightSet(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1),
                              np.array([[0.0, 0, 1]]), np.zeros(1), np.zeros(1)))
        child = np.full((1, branching), -1)
        leaf = np.full(1, -1)
    outside = np.flatnonzero(~in_tree)
    group_w = np.concatenate([[weights[in_tree].sum()] if tree_ids.size else [0.0],
                              weights[outside]])
    group = np.zeros(n, np.int32)
    group[outside] = 1 + np.arange(outside.size)
    bvh = LightBVH(
        groups=discrete_from_weights(group_w),
        node=device_array(rows, jnp.result_type(float)),
        child=device_array(child.astype(np.int32)),
        leaf_light=device_array(leaf.astype(np.int32)),
        trail=device_array(trail.astype(np.int32)),
        depth=device_array(depth),
        group=device_array(group),
    )
    return bvh, int(depth.max(initial=0))


