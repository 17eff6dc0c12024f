"""Light selection by a light BVH: a light is chosen by its importance at the shading point.

Power selection draws light ``i`` with a pmf that ignores where the shading point is, so in a
room of a thousand lamps most shadow rays go to lamps that are far away or face elsewhere.
The light BVH (in the manner of pbrt-v4's ``BVHLightSampler``; Conty Estevez & Kulla 2018)
groups the lights with a position (point, spot, triangle, sphere) into a tree (up to
:data:`BRANCHING` children per node) whose nodes bound their lights' positions (a box),
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

#: Children per node: each choice of the descent is among up to 16 nodes (four rounds of
#: median splits), so the first choices are made between parts of the scene small enough
#: for their importance to tell them apart; a binary tree makes those choices between
#: halves whose bounding spheres contain the shading point, by power alone. Measured on
#: ``lamp_grid(glossy=False)``, light sampling at 64 spp, MSE: power selection 0.00205;
#: trees of 2 / 8 / 16 / 64 children 0.00058 / 0.00036 / 0.00028 / 0.00025; the importance
#: of every light evaluated one by one 0.00012. 16 children cost 48 importances per choice
#: of one of 1 152 lights (3 levels) and were the most efficient (1/(MSE·CPU-s) 1.25× 8's).
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
    ``w_a`` or within ``t_b`` of ``w_b`` are within ``θ`` of ``w``."""
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


def light_bounds(lights, powers: np.ndarray) -> list[Bounds | None]:
    """Bounds of every light in global-index order (``None`` for directional and environment
    lights); ``powers`` (N,) already carries the selection floor."""
    out: list[Bounds | None] = []
    up = np.array([0.0, 0.0, 1.0])
    half = np.pi / 2
    for kind in ("point", "spot", "directional", "triangle", "sphere", "environment"):
        t = lights.table(kind)
        if t is None:
            continue
        if kind in ("directional", "environment"):
            out.extend([None] * (1 if kind == "environment" else len(t.direction)))
            continue
        if kind == "point":
            for q in np.asarray(t.position, np.float64):
                out.append(Bounds(q, q, 0.0, up, np.pi, half))
        elif kind == "spot":
            for q, w, co in zip(np.asarray(t.position, np.float64), np.asarray(t.axis, np.float64),
                                np.asarray(t.cos_outer, np.float64), strict=True):
                out.append(Bounds(q, q, 0.0, w / np.linalg.norm(w), 0.0,
                                  float(np.arccos(np.clip(co, -1, 1)))))
        elif kind == "triangle":
            v = np.asarray(t.vertices, np.float64)
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            for vi, ni, two in zip(v, n, np.asarray(t.two_sided), strict=True):
                # a two-sided triangle emits around ±n: a cone of half-angle π about n
                out.append(Bounds(vi.min(0), vi.max(0), 0.0, ni, np.pi if two else 0.0, half))
        else:
            for c, r in zip(np.asarray(t.center, np.float64), np.asarray(t.radius, np.float64),
                            strict=True):
                out.append(Bounds(c - r, c + r, 0.0, up, np.pi, half))
    return [None if b is None else b._replace(power=float(p))
            for b, p in zip(out, powers, strict=True)]


def _median_split(bounds: list[Bounds], ids: np.ndarray) -> list[np.ndarray]:
    """``ids`` in two halves at the median of the centroids along their largest extent."""
    cent = np.array([0.5 * (bounds[i].lo + bounds[i].hi) for i in ids])
    ax = int(np.argmax(cent.max(0) - cent.min(0)))
    order = ids[np.argsort(cent[:, ax], kind="stable")]
    return [order[: len(order) // 2], order[len(order) // 2:]]


def _build(bounds: list[Bounds], ids: np.ndarray, nodes: list, trails: dict, trail: int,
           depth: int) -> int:
    """Append the subtree over lights ``ids`` to ``nodes`` (pre-order); return its index.

    A node's lights go to up to :data:`BRANCHING` children by ``log2(BRANCHING)`` rounds of
    median splits (:func:`_median_split`)."""
    me = len(nodes)
    nodes.append(None)
    if len(ids) == 1:
        nodes[me] = (bounds[ids[0]], (-1,) * BRANCHING, int(ids[0]))
        trails[int(ids[0])] = (trail, depth)
        return me
    groups = [ids]
    while len(groups) < BRANCHING and any(len(g) > 1 for g in groups):
        groups = [h for g in groups for h in (_median_split(bounds, g) if len(g) > 1 else [g])]
    shift = BRANCH_BITS * depth
    kids = [_build(bounds, g, nodes, trails, trail | (k << shift), depth + 1)
            for k, g in enumerate(groups)]
    box = nodes[kids[0]][0]
    for k in kids[1:]:
        box = union(box, nodes[k][0])
    nodes[me] = (box, tuple(kids) + (-1,) * (BRANCHING - len(kids)), -1)
    return me


def _row(b: Bounds) -> np.ndarray:
    """A node's row of :attr:`LightBVH.node` (host float64)."""
    e = b.theta_e + ANGLE_SLACK
    cos_e = np.cos(e) if e < np.pi else -2.0  # emits every way: no direction is cut
    return np.concatenate([0.5 * (b.lo + b.hi), b.axis,
                           [0.25 * np.sum((b.hi - b.lo) ** 2), b.power, np.cos(b.theta_o),
                            np.sin(b.theta_o), cos_e]])


def build_light_bvh(lights, powers: np.ndarray, floor: float) -> tuple[LightBVH, int]:
    """The :class:`LightBVH` of a light table and its depth (static: the descent's length).

    ``powers`` (N,): each light's power (:func:`.table.light_powers`); every light's weight
    is its power plus ``floor`` times the mean power (all equal if every power is 0)."""
    powers = np.asarray(powers, np.float64)
    weights = powers + floor * powers.mean() if powers.sum() > 0 else np.ones_like(powers)
    bounds = light_bounds(lights, weights)
    n = len(bounds)
    in_tree = np.array([b is not None for b in bounds])
    ids = np.flatnonzero(in_tree)
    nodes: list = []
    trails: dict = {}
    if ids.size > 1 << 28:  # 7 levels of 4-bit digits: the trail fits an int32
        raise ValueError(f"a light BVH holds at most 2^28 lights, got {ids.size}")
    if ids.size:
        _build(bounds, ids, nodes, trails, 0, 0)
    else:  # no light with a position: one inert node keeps the arrays well formed
        nodes.append((Bounds(np.zeros(3), np.zeros(3), 0.0, np.array([0.0, 0, 1]), 0.0, 0.0),
                      (-1,) * BRANCHING, -1))
    outside = np.flatnonzero(~in_tree)
    group_w = np.concatenate([[weights[in_tree].sum()] if ids.size else [0.0],
                              weights[outside]])
    group = np.zeros(n, np.int32)
    group[outside] = 1 + np.arange(outside.size)
    trail = np.zeros(n, np.int64)
    depth = np.full(n, -1, np.int32)
    for i, (t, d) in trails.items():
        trail[i], depth[i] = t, d
    rows = np.array([_row(nd[0]) for nd in nodes])
    bvh = LightBVH(
        groups=discrete_from_weights(group_w),
        node=device_array(rows, jnp.result_type(float)),
        child=device_array(np.array([nd[1] for nd in nodes], np.int32)),
        leaf_light=device_array(np.array([nd[2] for nd in nodes], np.int32)),
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
    imp = jnp.stack([importance(rows[k], p, n) for k in range(BRANCHING)])
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
        last = BRANCHING - 1 - jnp.argmax((imp > 0)[::-1]).astype(jnp.int32)
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
        k = (trail >> (BRANCH_BITS * level)) & (BRANCHING - 1)
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
