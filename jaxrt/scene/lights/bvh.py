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

The tree is built on the host, in float64, when the light table is built
(:mod:`jaxrt.scene.lights.bvh_build`: the lights' bounds and SAOH splits); here are its
layout and the kernels that run at each shading point (:func:`importance`,
:func:`tree_select`, :func:`tree_pmf`, :func:`bvh_select`, :func:`bvh_pmf`). The tree's depth
is static, so the descent is a loop of fixed length and the program is specialised to it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.sampling.distributions import (
    Discrete,
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
