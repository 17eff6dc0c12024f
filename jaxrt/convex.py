"""Convex occluders: shadow rays test a closed convex body by its face planes, not its triangles.

A segment meets a convex body ``{x : n_k · x ≤ c_k}`` iff, clipped against every face plane in
turn, something is left (Cyrus & Beck 1978): the largest entering distance
``t = (c_k − n_k · o) / (n_k · d)`` over planes with ``n_k · d < 0`` stays below the smallest
leaving distance over planes with ``n_k · d > 0`` and below ``t_max``. A box is six planes
where its triangles are twelve watertight tests, each several times a plane's cost; and a
body has no edges, so nothing can leak between its faces.

Which triangles form such a body is decided once per scene on the host
(:func:`convex_bodies`), among the triangles shadow rays must test (:mod:`jaxrt.occluders`):
a connected set of triangles (sharing vertices exactly) that is

- convex: every one of its vertices lies on one side of each of its faces' planes, and the
  vertices span a volume;
- closed, or closed by a plane that every segment stays on one side of: each edge belongs to
  two of its triangles, or the edges that belong to one all lie in one plane with every scene
  vertex, light point and light ball on the body's side (the Cornell box's blocks, whose
  open bottoms stand on the floor);
- free of emitters, with every other scene vertex, light point and ball outside its
  interior (so no segment starts or ends inside it, other than on its own faces).

Robustness. A shadow ray starts on a surface, offset off it by the point's error bound
(:mod:`jaxrt.spawn`), often on the body's own face. ``c − n · (o − v)``, with ``v`` a vertex
of the body that the plane's ``c`` is relative to, is computed with an error of at most
``γ₈ (|c| + ‖o − v‖₁)`` (``o − v`` rounds once, relative to the difference; the unit normal
and ``c`` are rounded from float64; three products and sums; a margin covers the plane's
distance from the float vertices too), and an
origin within that of a plane counts as on it: leaving through that plane it is outside
(``t_out = 0``), entering through it it is inside from ``t = 0``. So a ray that leaves a
body's face is never blocked by that body, whatever the rounding, and one that enters it is.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.intersect import gamma, loop_unroll

#: Relative tolerance (of the scene's extent) of the host's side tests, in float64.
_TOL = 64 * np.finfo(np.float64).eps


class ConvexBodies(NamedTuple):
    """Convex occluders as face planes (a pytree; built by :func:`convex_bodies`).

    Attributes:
        planes: (B, P, 5) per body and face plane: the outward unit normal ``n`` (3), the offset
            ``c`` relative to the body's ``origin`` (inside is ``n · (x − origin) ≤ c``) and
            ``γ₈ |c|``; bodies with fewer than ``P`` planes are padded with ``n = 0, c = 1``
            (every point inside: no constraint).
        origin: (B, 3) a vertex of each body (as stored): planes relative to it keep their
            precision wherever the scene is placed (``x − origin`` rounds once, relative to
            the difference; 1e5 from the world's origin, ``n · x`` would lose all of it).
        triangles: (T,) int32, the scene triangles the bodies replace (host metadata for
            tests and summaries; not read by the kernel).
    """

    planes: Array
    origin: Array
    triangles: Array

    @property
    def count(self) -> int:
        """Number of bodies ``B`` (static)."""
        return self.planes.shape[0]


def convex_any_hit(bodies: ConvexBodies, o: Array, d: Array, t_max: Array) -> Array:
    """Whether the segment ``o + t d``, ``0 < t < t_max``, passes through any body (one ray).

    Args:
        bodies: the bodies; o: (3,) origin; d: (3,) direction (any length); t_max: ().
    Returns:
        () bool. An origin within rounding of a face plane counts as on it (module notes).
    """
    dtype = d.dtype
    table, origins = bodies.planes.astype(dtype), bodies.origin.astype(dtype)
    t_max = jnp.asarray(t_max, dtype)
    d0, d1, d2 = d[0], d[1], d[2]
    zero = jnp.zeros((), dtype)

    def one_body(b, found):
        rows, ref = table[b], origins[b]
        # relative to the body's vertex: rounds once, relative to the difference
        o0, o1, o2 = o[0] - ref[0], o[1] - ref[1], o[2] - ref[2]
        slack = gamma(8, dtype) * (jnp.abs(o0) + jnp.abs(o1) + jnp.abs(o2))
        t_in, t_out, outside = zero, t_max, d0 != d0  # (False, batched like the ray)
        for k in range(table.shape[1]):
            r = rows[k]
            num = r[3] - (r[0] * o0 + r[1] * o1 + r[2] * o2)
            num = jnp.where(jnp.abs(num) <= r[4] + slack, zero, num)  # on the plane
            den = r[0] * d0 + r[1] * d1 + r[2] * d2
            t = num / jnp.where(den != 0, den, 1)
            t_in = jnp.where(den < 0, jnp.maximum(t_in, t), t_in)
            t_out = jnp.where(den > 0, jnp.minimum(t_out, t), t_out)
            outside = outside | ((den == 0) & (num < 0))
        return found | (~outside & (t_in < t_out))

    start = d0 != d0  # False, a value of the ray: batched under vmap from the start
    return lax.fori_loop(0, table.shape[0], one_body, start,
                         unroll=loop_unroll(table.shape[0]))


def convex_bodies(triangles: np.ndarray, candidates: np.ndarray, emissive: np.ndarray,
                  points: np.ndarray, balls: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    """Find the convex bodies among ``candidates`` (host, float64).

    Args:
        triangles: (F, 3, 3) the scene's stored triangles.
        candidates: (K,) indices of the triangles shadow rays test.
        emissive: (F,) bool, emissive triangles (never part of a body).
        points: (Q, 3) light points (point and spot lights); balls: (S, 4) sphere lights.
    Returns:
        ``(planes, origins, members, kept)``: planes (B, P, 5) and origins (B, 3) as
        :class:`ConvexBodies` holds them (B may be 0), members (T,) the triangles the bodies
        replace, kept the candidates left to test as triangles (sorted).
    """
    tri = np.asarray(triangles, np.float64)
    cand = np.asarray(candidates, np.int64)
    extent = max(np.max(np.abs(tri)), np.finfo(np.float64).tiny)
    if points.size:
        extent = max(extent, np.max(np.abs(points)))
    tol = _TOL * extent
    bodies, members = [], []
    for comp in _components(tri, cand):
        if np.any(emissive[comp]):
            continue
        found = _body_planes(tri, comp, tol)
        if found is None:
            continue
        planes, cap = found
        others = np.setdiff1d(np.arange(len(tri)), comp)
        outside = np.concatenate([tri[others].reshape(-1, 3), points.reshape(-1, 3)])
        if not _outside(planes, outside, balls, tol):
            continue
        # an open body is closed by its cap only if no segment reaches the cap's far side:
        # every scene vertex, light point and ball on the body's side (then the cap itself
        # need not be tested)
        if cap is not None and not _inside_half_space(cap, tri.reshape(-1, 3), points, balls,
                                                      tol):
            continue
        bodies.append(planes)
        members.append(comp)
    kept = np.setdiff1d(cand, np.concatenate(members)) if members else cand
    if not bodies:
        return np.zeros((0, 1, 5)), np.zeros((0, 3)), np.zeros(0, np.int64), kept
    width = max(len(p) for p in bodies)
    table = np.tile(np.array([0.0, 0.0, 0.0, 1.0, 0.0]), (len(bodies), width, 1))
    origins = np.stack([tri[m[0], 0] for m in members])  # a stored vertex: exact
    for b, p in enumerate(bodies):
        c = p[:, 3] - p[:, :3] @ origins[b]  # relative to the body's origin, in float64
        table[b, :len(p), :3] = p[:, :3]
        table[b, :len(p), 3] = c
        table[b, :len(p), 4] = 8 * np.finfo(np.float32).eps * np.abs(c)
    return table, origins, np.concatenate(members), kept


def _components(tri: np.ndarray, cand: np.ndarray) -> list[np.ndarray]:
    """Connected sets of candidate triangles (sharing a vertex, exactly), as index arrays."""
    keys = {}
    parent = list(range(len(cand)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, f in enumerate(cand):
        for v in tri[f]:
            j = keys.setdefault(tuple(v), i)
            a, b = find(i), find(j)
            if a != b:
                parent[a] = b
    groups = {}
    for i, f in enumerate(cand):
        groups.setdefault(find(i), []).append(f)
    return [np.asarray(g, np.int64) for g in groups.values()]


def _body_planes(tri: np.ndarray, comp: np.ndarray,
                 tol: float) -> tuple[np.ndarray, np.ndarray | None] | None:
    """``(planes, cap)`` of a convex, closed (``cap`` None) or cap-closed set, else None.

    ``planes`` (P, 4): the outward face planes, one per distinct plane; ``cap`` (4,): the
    outward plane through the edges that belong to one triangle, not among ``planes``.
    """
    t = tri[comp]
    verts = np.unique(t.reshape(-1, 3), axis=0)
    if len(verts) < 4 or np.linalg.svd(verts - verts.mean(0), compute_uv=False)[-1] <= tol:
        return None  # flat: no volume
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    norm = np.linalg.norm(n, axis=1)
    if np.any(norm == 0):
        return None
    n = n / norm[:, None]
    c = np.sum(n * t[:, 0], axis=1)
    s = verts @ n.T - c  # (V, faces)
    below, above = np.all(s <= tol, axis=0), np.all(s >= -tol, axis=0)
    if not np.all(below | above):
        return None  # not convex
    sign = np.where(below, 1.0, -1.0)  # outward: the vertices on the ≤ side
    planes = np.concatenate([n * sign[:, None], (c * sign)[:, None]], axis=1)
    # edges used once: none (closed), or all in one plane that closes the body (module notes)
    edges = {}
    for f in t:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            key = tuple(sorted((tuple(f[a]), tuple(f[b]))))
            edges[key] = edges.get(key, 0) + 1
    if any(k > 2 for k in edges.values()):
        return None  # not a manifold surface
    open_ends = np.array([p for key, k in edges.items() if k == 1 for p in key]).reshape(-1, 3)
    cap = None
    if open_ends.size:
        cap = _cap_plane(open_ends, verts, tol)
        if cap is None:
            return None
    return _merge(planes, tol), cap


def _cap_plane(ends: np.ndarray, verts: np.ndarray, tol: float) -> np.ndarray | None:
    """The plane (4,) through the open edges' ends, outward from the body's vertices."""
    centre = ends.mean(0)
    _, sv, vt = np.linalg.svd(ends - centre)
    n = vt[-1]
    c = n @ centre
    if np.max(np.abs(ends @ n - c)) > tol:
        return None  # the open edges are not in one plane
    s = verts @ n - c
    if np.all(s <= tol):
        return np.concatenate([n, [c]])
    if np.all(s >= -tol):
        return np.concatenate([-n, [-c]])
    return None


def _merge(planes: np.ndarray, tol: float) -> np.ndarray:
    """One row per distinct plane (a quad's two triangles give one)."""
    out = []
    for p in planes:
        if not any(np.all(np.abs(p[:3] - q[:3]) <= 1e-12) and abs(p[3] - q[3]) <= tol
                   for q in out):
            out.append(p)
    return np.asarray(out)


def _inside_half_space(plane: np.ndarray, points: np.ndarray, more: np.ndarray,
                       balls: np.ndarray, tol: float) -> bool:
    """Every point (and every ball, wholly) on the inner side ``n · x ≤ c`` of ``plane``."""
    pts = np.concatenate([points.reshape(-1, 3), more.reshape(-1, 3)])
    ok = bool(np.all(pts @ plane[:3] - plane[3] <= tol))
    if balls.size:
        ok &= bool(np.all(balls[:, :3] @ plane[:3] - plane[3] + balls[:, 3] <= tol))
    return ok


def _outside(planes: np.ndarray, points: np.ndarray, balls: np.ndarray, tol: float) -> bool:
    """No point in the body's open interior, no ball overlapping it (conservatively)."""
    if points.size and np.any(np.all(points @ planes[:, :3].T - planes[:, 3] < -tol, axis=1)):
        return False
    if balls.size:
        # a ball is outside if some plane has it wholly on the outer side
        dist = balls[:, :3] @ planes[:, :3].T - planes[:, 3]
        if np.any(np.all(dist - balls[:, 3:4] < tol, axis=1)):
            return False
    return True
