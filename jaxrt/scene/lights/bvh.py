"""Light selection by a light BVH: a light is chosen by its importance at the shading point.

Power selection draws light ``i`` with a pmf that ignores where the shading point is, so in a
room of a thousand lamps most shadow rays go to lamps that are far away or face elsewhere.
The light BVH (in the manner of pbrt-v4's ``BVHLightSampler``; Conty Estevez & Kulla 2018)
groups the lights with a position (point, spot, triangle, sphere) into a tree (up to
:data:`BRANCHING` children per node, split by the surface area orientation heuristic, SAOH)
whose nodes bound their lights' positions (a box),
emitted power ``Φ`` and emission directions (a cone of normals ``(w, θ_o)`` widened by the
spread ``θ_e`` of each light's emission).

Selection at ``p`` descends from the root: at a node it goes to child ``k`` with probability
``I_k / Σ_j I_j``, where the importance of a node is

    I(p) = Φ · cos θ' / max(d², r²)     if θ' < θ_e, else 0,
    θ' = max(0, θ_w − θ_o − θ_b),

times ``cos θ'_i = cos(max(0, θ_i − θ_b))`` at a receiver of normal ``n``, where ``θ_i`` is
the angle between ``±n`` and the direction to the centre (a weight, never a cut: the BSDF
decides what the receiver reflects); ``d`` is the distance from ``p`` to the box's centre,
``r`` the radius of the box's bounding sphere, ``θ_w`` the angle between the cone axis ``w``
and the direction from the centre to ``p``, and ``θ_b`` the half-angle the bounding sphere
subtends at ``p`` (π inside it). ``θ'`` bounds from below the angle between any emitter
normal of the node and the direction to ``p``, so a node gets importance 0 only where none of
its lights sends light towards ``p``: the pmf is positive wherever a light's contribution can
be. The cosine factor is floored at
:data:`MIN_COS` inside the cone, which keeps that true under float round-off.

The pmf of light ``i`` is the product of the choices along its root-to-leaf path (stored as a
trail of child digits per light), so ``pmf(i | p)`` is exact and evaluated for any light at any
``p`` (multiple importance sampling of BSDF-sampled emitter hits needs it); it sums to one over
the lights at every ``p`` where some node is important. Lights without a position (directional,
environment) are chosen beside the tree: a discrete choice between the tree (weight: the total
power of its lights) and each of them (weight: its power), with the selection floor of
:mod:`.table`. Sampling and pmf take the same receiver normal: the estimators pass the shading
normal at the vertex to both.

Everything here except :func:`bvh_select` and :func:`bvh_pmf` runs on the host, in float64,
when the light table is built; the tree's depth is static, so the descent is a loop of fixed
length and the program is specialised to it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.vecmath import device_array
from jaxrt.sampling.distributions import (
    Discrete,
    discrete_from_weights,
    discrete_pmf,
    discrete_sample,
)

#: Inside its cone a node's cosine factor is at least this: round-off near the cone's edge
#: never zeroes a node that holds a light able to reach ``p``.
MIN_COS = 1e-3

#: Angular slack (radians) added to ``θ_e`` in the importance's cut-off, for the same reason.
ANGLE_SLACK = 1e-4

#: Children per node (the default of :func:`build_light_bvh`'s ``branch_bits``): each choice
#: of the descent is among up to 16 nodes (four rounds of binary splits), so the first
#: choices are made between parts of the scene small enough for their importance to tell
#: them apart; a binary tree makes those choices between halves whose bounding spheres
#: contain the shading point, by power alone. On ``lamp_grid``, paired with 8 children, 16
#: are 1.29× as efficient with median splits and 1.04× with SAOH splits (diffuse floor;
#: glossy 0.93–1.04×; benchmarks/README.md#light-bvh). The
#: kernels read the branching off ``LightBVH.child``'s (static) shape.
BRANCHING = 16
BRANCH_BITS = 4  # log2(BRANCHING): the trail's digits

#: The squared distance in the importance is at least this: a shading point on a point light
#: keeps finite importances (and a pmf that sums to one) where ``Φ/d²`` would overflow.
MIN_DISTANCE2 = 1e-12

#: Columns of :attr:`LightBVH.node`: centre (3), axis (3), r², Φ, cos θ_o, sin θ_o, cos θ_e.
NODE_WIDTH = 11


class LightBVH(NamedTuple):
    """A light BVH and the choice beside it (shapes: ``K`` nodes, ``N`` lights in all, ``G``
    groups = 1 + the number of lights without a position).

    Attributes:
        groups: :class:`~jaxrt.sampling.distributions.Discrete` over (G,): entry 0 is the tree,
            entry ``1 + k`` the ``k``-th light without a position (in global index order).
        node: (K, NODE_WIDTH) one row per node, read by one gather: the box's centre (3),
            the cone axis ``w`` (3), the squared radius ``r²`` of the box's bounding sphere,
            the lights' total power ``Φ`` (with the selection floor), ``cos θ_o``,
            ``sin θ_o`` and ``cos(θ_e + ANGLE_SLACK)`` (θ_o: the cone's half-angle over the
            normals; θ_e: the spread of emission around each normal, both in [0, π]).
        child: (K, BRANCHING) int32 children (-1 where absent; all -1 at a leaf).
        leaf_light: (K,) int32 global light index at a leaf, -1 elsewhere.
        trail: (N,) int32 digit ``k`` (bits ``4k … 4k+3``) is the child taken at depth ``k``
            on the way to the light.
        depth: (N,) int32 length of the light's path (-1 for lights outside the tree).
        group: (N,) int32 the light's entry of ``groups``.
    """

    groups: Discrete
    node: Array
    child: Array
    leaf_light: Array
    trail: Array
    depth: Array
    group: Array


class Bounds(NamedTuple):
    """Host bounds of one light (float64): the box, power, normal cone and emission spread."""

    lo: np.ndarray
    hi: np.ndarray
    power: float
    axis: np.ndarray
    theta_o: float
    theta_e: float


# ---------------------------------------------------------------------------------------------
# Host: the bounds of each light and of their unions.


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))


def cone_union(w_a, t_a, w_b, t_b) -> tuple[np.ndarray, float]:
    """The smallest cone ``(w, θ)`` of the two's union: the directions within ``t_a`` of
    ``w_a`` or within ``t_b`` of ``w_b`` are within ``θ`` of ``w``. (The build bounds a set's
    normals at once instead: their mean axis and widest offset, :func:`_segment_rows`.)"""
    if t_a >= np.pi or t_b >= np.pi:
        return w_a, np.pi
    d = _angle(w_a, w_b)
    if min(d + t_b, np.pi) <= t_a:
        return w_a, t_a
    if min(d + t_a, np.pi) <= t_b:
        return w_b, t_b
    t = 0.5 * (t_a + d + t_b)
    if t >= np.pi:
        return w_a, np.pi
    rot = t - t_a  # rotate w_a towards w_b by this angle, about w_a × w_b
    k = np.cross(w_a, w_b)
    nk = np.linalg.norm(k)
    if nk < 1e-12:  # opposite axes (d ≈ π): the union covers the sphere
        return w_a, np.pi
    k /= nk
    w = w_a * np.cos(rot) + np.cross(k, w_a) * np.sin(rot) + k * np.dot(k, w_a) * (1 - np.cos(rot))
    return w / np.linalg.norm(w), t


def union(a: Bounds, b: Bounds) -> Bounds:
    """The bounds of two nodes together."""
    w, t_o = cone_union(a.axis, a.theta_o, b.axis, b.theta_o)
    return Bounds(np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi), a.power + b.power, w, t_o,
                  max(a.theta_e, b.theta_e))


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


def _row(b: Bounds) -> np.ndarray:
    """A node's row of :attr:`LightBVH.node` (host float64)."""
    e = b.theta_e + ANGLE_SLACK
    cos_e = np.cos(e) if e < np.pi else -2.0  # emits every way: no direction is cut
    return np.concatenate([0.5 * (b.lo + b.hi), b.axis,
                           [0.25 * np.sum((b.hi - b.lo) ** 2), b.power, np.cos(b.theta_o),
                            np.sin(b.theta_o), cos_e]])


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
        rows = _row(Bounds(np.zeros(3), np.zeros(3), 0.0, np.array([0.0, 0, 1]), 0.0, 0.0))[None]
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


# ---------------------------------------------------------------------------------------------
# Kernels (one shading point).


def _cos_sub(cos_a: Array, sin_a: Array, cos_b: Array, sin_b: Array) -> tuple[Array, Array]:
    """``(cos, sin)`` of ``max(0, a − b)`` for angles ``a, b ∈ [0, π]`` from their cosines and
    sines (no inverse trigonometry: ``a ≤ b`` exactly when ``cos a ≥ cos b``)."""
    inside = cos_a >= cos_b
    return (jnp.where(inside, 1.0, cos_a * cos_b + sin_a * sin_b),
            jnp.where(inside, 0.0, sin_a * cos_b - cos_a * sin_b))


def importance(row: Array, p: Array, n: Array | None) -> Array:
    """Importance ``I(p, n)`` of the node whose :attr:`LightBVH.node` row is ``row`` (module
    notes), () ≥ 0; 0 only where none of the node's lights emits towards ``p``. ``n`` (3,):
    the receiver normal, or ``None`` (or the zero vector) for no receiver factor."""
    tiny = jnp.finfo(p.dtype).tiny
    c, w, r2, power = row[0:3], row[3:6], row[6], row[7]
    cos_o, sin_o, cos_e = row[8], row[9], row[10]
    v = p - c
    d2 = jnp.sum(v * v)
    inv_d = lax.rsqrt(jnp.maximum(d2, tiny))
    cos_w = jnp.where(d2 > 0, jnp.clip(jnp.dot(w, v) * inv_d, -1.0, 1.0), 1.0)
    sin_w = jnp.sqrt(jnp.maximum(1 - cos_w * cos_w, 0.0))
    # the cone the bounding sphere subtends at p: half-angle θ_b (π from inside)
    inside = d2 <= r2
    sin2_b = jnp.where(inside, 0.0, r2 / jnp.maximum(d2, tiny))
    sin_b = jnp.sqrt(sin2_b)
    cos_b = jnp.where(inside, -1.0, jnp.sqrt(jnp.maximum(1 - sin2_b, 0.0)))
    # θ' = max(0, θ_w − θ_o − θ_b)
    cos_x, sin_x = _cos_sub(cos_w, sin_w, cos_o, sin_o)
    cos_t, _ = _cos_sub(cos_x, sin_x, cos_b, sin_b)
    lit = cos_t > cos_e
    dist2 = jnp.maximum(jnp.maximum(d2, r2), MIN_DISTANCE2)
    value = power * jnp.maximum(cos_t, MIN_COS) / dist2
    if n is not None:
        # |cos| at the receiver, widened by the node's extent: a weight, never a cut
        cos_i = jnp.minimum(jnp.abs(jnp.dot(n, v)) * inv_d, 1.0)
        sin_i = jnp.sqrt(jnp.maximum(1 - cos_i * cos_i, 0.0))
        cos_ti, _ = _cos_sub(cos_i, sin_i, cos_b, sin_b)
        value = value * jnp.where(jnp.dot(n, n) > 0, jnp.maximum(cos_ti, MIN_COS), 1.0)
    return jnp.where(lit, value, 0.0)


def _children(bvh: LightBVH, node: Array, p: Array, n: Array | None) -> tuple[Array, Array]:
    """The importances (BRANCHING,) of ``node``'s children (0 for absent ones) and their sum."""
    child = bvh.child[node]
    rows = bvh.node[jnp.clip(child, 0, None)]  # (BRANCHING, NODE_WIDTH): one gather
    imp = jnp.stack([importance(rows[k], p, n) for k in range(child.shape[0])])
    imp = jnp.where(child >= 0, imp, 0.0)
    return imp, jnp.sum(imp)


def tree_select(bvh: LightBVH, depth: int, p: Array, n: Array | None,
                u: Array) -> tuple[Array, Array]:
    """Descend the tree at ``p`` (receiver normal ``n``) with ``u`` ∈ [0, 1): (global light
    index, its pmf in the tree).

    At each node child ``k`` is taken with probability ``I_k / Σ_j I_j`` (inverting their
    cumulative sum with ``u``, which is then rescaled to [0, 1) within the child's share).
    The pmf is 0 when no node is important at ``p`` (no light of the tree reaches it)."""
    one_minus = jnp.nextafter(jnp.ones((), u.dtype), jnp.zeros((), u.dtype))

    def step(_, carry):
        node, pmf, u = carry
        leaf = bvh.child[node, 0] < 0
        imp, total = _children(bvh, node, p, n)
        ok = total > 0
        cum = jnp.cumsum(imp)
        target = u * total
        # the last child with I > 0 takes what round-off leaves past the cumulative sum
        last = bvh.child.shape[1] - 1 - jnp.argmax((imp > 0)[::-1]).astype(jnp.int32)
        k = jnp.minimum(jnp.sum((cum <= target).astype(jnp.int32)), last)
        below = cum[k] - imp[k]
        u_next = jnp.clip((target - below) / jnp.where(imp[k] > 0, imp[k], 1.0), 0.0, one_minus)
        prob = jnp.where(ok, imp[k] / jnp.where(ok, total, 1.0), 0.0)
        return (jnp.where(leaf, node, bvh.child[node, k]), jnp.where(leaf, pmf, pmf * prob),
                jnp.where(leaf, u, u_next))

    node, pmf, _ = lax.fori_loop(0, depth, step, (jnp.int32(0), jnp.ones((), p.dtype), u))
    return bvh.leaf_light[node], pmf


def tree_pmf(bvh: LightBVH, depth: int, p: Array, n: Array | None, light: Array) -> Array:
    """Probability that :func:`tree_select` at ``(p, n)`` returns ``light`` (0 for lights outside
    the tree): the product of the choices along the light's trail of child digits."""
    light = jnp.clip(light, 0, bvh.trail.shape[0] - 1)
    trail, length = bvh.trail[light], bvh.depth[light]

    def step(level, carry):
        node, pmf = carry
        imp, total = _children(bvh, node, p, n)
        branching = bvh.child.shape[1]  # static: 2 ** bits
        k = (trail >> (branching.bit_length() - 1) * level) & (branching - 1)
        prob = jnp.where(total > 0, imp[k] / jnp.where(total > 0, total, 1.0), 0.0)
        on_path = level < length
        return (jnp.where(on_path, bvh.child[node, k], node),
                jnp.where(on_path, pmf * prob, pmf))

    _, pmf = lax.fori_loop(0, depth, step, (jnp.int32(0), jnp.ones((), p.dtype)))
    return jnp.where(length >= 0, pmf, 0.0)


def bvh_select(bvh: LightBVH, depth: int, outside: np.ndarray, p: Array, n: Array | None,
               u: Array) -> tuple[Array, Array]:
    """Choose a light at ``p`` (receiver normal ``n`` or ``None``) from ``u`` ∈ [0, 1):
    (global index int32, pmf).

    ``outside`` (static, host): the global indices of the lights without a position, in the
    order of ``groups`` entries 1, 2, …"""
    g, pg, u_tree = discrete_sample(bvh.groups, u)
    light, pmf = tree_select(bvh, depth, p, n, u_tree.astype(p.dtype))
    if len(outside) == 0:
        return light, pg.astype(p.dtype) * pmf
    ids = jnp.asarray(np.concatenate([[0], outside]).astype(np.int32))
    return (jnp.where(g == 0, light, ids[g]),
            pg.astype(p.dtype) * jnp.where(g == 0, pmf, 1.0))


def bvh_pmf(bvh: LightBVH, depth: int, p: Array, n: Array | None, light: Array) -> Array:
    """``pmf(light | p, n)`` of :func:`bvh_select`; 0 outside ``[0, N)``."""
    count = bvh.group.shape[0]
    inside = (light >= 0) & (light < count)
    j = jnp.clip(light, 0, count - 1)
    g = bvh.group[j]
    pg = discrete_pmf(bvh.groups, g).astype(p.dtype)
    in_tree = jnp.where(g == 0, tree_pmf(bvh, depth, p, n, j), 1.0)
    return jnp.where(inside, pg * in_tree, 0.0)
