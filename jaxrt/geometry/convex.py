"""Convex bodies: rays test a closed convex body by its face planes, not its triangles.

A segment meets a convex body ``{x : n_k · x ≤ c_k}`` iff, clipped against every face plane in
turn, something is left (Cyrus & Beck 1978): the largest entering distance
``t = (c_k − n_k · o) / (n_k · d)`` over planes with ``n_k · d < 0`` stays below the smallest
leaving distance over planes with ``n_k · d > 0`` and below ``t_max``. A box is six planes
where its triangles are twelve watertight tests, each several times a plane's cost; and a
body has no edges, so nothing can leak between its faces.

Which triangles form such a body is decided once per scene on the host
(:func:`convex_bodies`), among the triangles shadow rays must test
(:mod:`jaxrt.geometry.occluders`): a connected set of triangles (sharing vertices exactly) that is

- convex: every one of its vertices lies on one side of each of its faces' planes, and the
  vertices span a volume;
- closed, or closed by a plane that every segment stays on one side of: each edge belongs to
  two of its triangles, or the edges that belong to one all lie in one plane with every scene
  vertex, light point and light ball on the body's side (the Cornell box's blocks, whose
  open bottoms stand on the floor);
- free of emitters, with every other scene vertex, light point and ball outside its
  interior (so no segment starts or ends inside it, other than on its own faces);
- one material per face (a closest hit knows the face, not which of its triangles).

Shadow rays ask whether a segment meets a body (:func:`convex_any_hit`); every other ray of
a path asks which face it meets first (:func:`convex_closest_hit`, through
:func:`jaxrt.scene.queries.intersect`): the plane it enters by, or from inside the one it leaves by,
as the body's two-sided triangles would be hit. On the 256² Cornell box the path pass runs
1.06× as fast as with the blocks' 20 triangles in its closest-hit loop, the clipping being
one kernel with one output (benchmarks/README.md#convex-bodies).

Robustness. A shadow ray starts on a surface, offset off it by the point's error bound
(:mod:`jaxrt.geometry.spawn`), often on the body's own face. ``c − n · (o − v)``, with ``v`` a
vertex of the body that the plane's ``c`` is relative to, is computed with an error of at most
``γ₈ (|c| + ‖o − v‖₁)`` (``o − v`` rounds once, relative to the difference; the unit normal
and ``c`` are rounded from float64; three products and sums; a margin covers the plane's
distance from the float vertices too), and an
origin within that of a plane counts as on it: leaving through that plane it is outside
(``t_out = 0``), entering through it it is inside from ``t = 0``. So a ray that leaves a
body's face is never blocked by that body, whatever the rounding, and one that enters it is.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core.vecmath import computed_once
from jaxrt.geometry.triangle import gamma

#: Relative tolerance (of the scene's extent) of the host's side tests, in float64 (also
#: :mod:`jaxrt.geometry.occluders`'): a vertex that pokes through a plane by less is taken as on it.
SIDE_TOL = 64 * np.finfo(np.float64).eps


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
        caps: (B, 5) the plane that closes an open body (no triangle lies in it), as a row of
            ``planes``; a padding row for a closed body. Closest hits clip against it too
            (:func:`convex_closest_hit`); shadow rays need not (no segment crosses it).
        faces: (B, P) int32, a scene triangle in each face plane (its material is the face's:
            every triangle of a face has the same one); −1 for padding.
        triangles: (T,) int32, the scene triangles the bodies replace (for summaries and tests).
        others: (R,) int32, the scene triangles not in a body (what closest hits still test
            one by one).
    """

    planes: Array
    origin: Array
    caps: Array
    faces: Array
    triangles: Array
    others: Array

    @property
    def count(self) -> int:
        """Number of bodies ``B`` (static)."""
        return self.planes.shape[0]


def _relative(o: Array, ref: Array) -> tuple[tuple, Array]:
    """``o − ref`` per component (rounds once, relative to the difference) and the slack
    ``γ₈ ‖o − ref‖₁`` within which a point counts as on a plane of the body (module notes)."""
    rel = (o[0] - ref[0], o[1] - ref[1], o[2] - ref[2])
    return rel, gamma(8, o.dtype) * (jnp.abs(rel[0]) + jnp.abs(rel[1]) + jnp.abs(rel[2]))


def _clip(r: Array, rel: tuple, slack: Array, d: Array) -> tuple[Array, Array, Array]:
    """One plane row against the ray: where it crosses the plane, ``t = a / b`` with ``b > 0``
    (``a = ±num``, ``b = |den|``, ``num = c − n · (o − ref)``, 0 for an origin on the plane,
    ``den = n · d``), and ``den``: ``(a, b, den)``.

    Distances stay fractions: a kernel divided per plane is stored per plane (XLA does not
    recompute a division for each of its two users, ``t_in`` and ``t_out``), so a plane would
    cost as much as a watertight triangle test; compared as ``a₁ b₂ < a₂ b₁`` they fuse."""
    num = r[3] - (r[0] * rel[0] + r[1] * rel[1] + r[2] * rel[2])
    num = jnp.where(jnp.abs(num) <= r[4] + slack, 0, num)  # on the plane
    den = r[0] * d[0] + r[1] * d[1] + r[2] * d[2]
    return jnp.where(den < 0, -num, num), jnp.abs(den), den


def _before(a1: Array, b1: Array, a2: Array, b2: Array) -> Array:
    """``a1 / b1 < a2 / b2`` for ``b1, b2 > 0`` (``a2 = inf``: any finite ``a1 / b1`` is before)."""
    return a1 * b2 < a2 * b1


class _Interval(NamedTuple):
    """The part ``(t_in, t_out)`` of a ray inside one body, as fractions ``t = a / b``
    (:func:`_clip`), with the rows it enters and leaves by (−1: none) and whether it runs
    outside a plane it is parallel to (then it is never inside)."""

    a_in: Array
    b_in: Array
    a_out: Array
    b_out: Array
    k_in: Array
    k_out: Array
    outside: Array

    @property
    def nonempty(self) -> Array:
        """``t_in < t_out`` and not outside a parallel plane."""
        return ~self.outside & _before(self.a_in, self.b_in, self.a_out, self.b_out)


def _clip_body(rows, rel: tuple, slack: Array, d: Array, t_max: Array) -> _Interval:
    """Cyrus–Beck: ``(0, t_max)`` clipped by each plane row of ``rows`` in turn (a row the ray
    crosses going in raises ``t_in``, going out lowers ``t_out``); unrolled over the rows."""
    dtype = d.dtype
    zero, one, none = jnp.zeros((), dtype), jnp.ones((), dtype), jnp.asarray(-1, dtype)
    c = _Interval(zero, one, t_max, one, none, none, d[0] != d[0])  # outside: False, batched
    for k, row in enumerate(rows):
        a, bb, den = _clip(row, rel, slack, d)
        enter = (den < 0) & _before(c.a_in, c.b_in, a, bb)
        leave = (den > 0) & _before(a, bb, c.a_out, c.b_out)
        c = _Interval(jnp.where(enter, a, c.a_in), jnp.where(enter, bb, c.b_in),
                      jnp.where(leave, a, c.a_out), jnp.where(leave, bb, c.b_out),
                      jnp.where(enter, k, c.k_in), jnp.where(leave, k, c.k_out),
                      c.outside | ((den == 0) & (a < 0)))
    return c


def _key(t: Array, row, bits: int) -> Array:
    """``t ≥ 0`` and a row index ``< 2^bits`` as one float ordered by ``t`` (to within
    ``2^bits`` ulps), then by row: t's bits, clamped to the normal finite floats, with the
    lowest ``bits`` replaced by the row (a float: an int32 key runs 4× slower)."""
    info = jnp.finfo(t.dtype)
    t = jnp.clip(t, info.tiny, info.max)
    itype = jnp.int32 if t.dtype == jnp.float32 else jnp.int64
    key = (lax.bitcast_convert_type(t, itype) & ~((1 << bits) - 1)) | row
    return lax.bitcast_convert_type(key.astype(itype), t.dtype)


def _row_of(key: Array, bits: int) -> Array:
    """The row index :func:`_key` put in ``key``."""
    itype = jnp.int32 if key.dtype == jnp.float32 else jnp.int64
    return (lax.bitcast_convert_type(key, itype) & ((1 << bits) - 1)).astype(jnp.int32)


# a jit of its own: a direct estimator calls it twice per sample (shadow ray, BSDF ray), and
# under vmap the second call reuses the first's trace, batching and lowering (the same
# optimised program; with the camera hit's jit, jaxrt.rendering.passes.lane_sums, the pass
# traces in less time: benchmarks/README.md#trace-once)
@jax.jit
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

    def one_body(b, found):
        rel, slack = _relative(o, origins[b])
        rows = [table[b, k] for k in range(table.shape[1])]
        return found | _clip_body(rows, rel, slack, d, t_max).nonempty

    # unrolled into one kernel, its one result stored (not fused into every consumer): the
    # path pass 1.056× as fast as a loop over the bodies (the MIS pass the same). Unrolled in
    # Python, not by fori_loop(unroll=True): the same optimised program, without a loop body
    # traced and then batched again under vmap
    found = d[0] != d[0]  # False, a value of the ray: batched under vmap from the start
    for b in range(table.shape[0]):
        found = one_body(b, found)
    return computed_once(jnp.where(found, 1, 0).astype(dtype)) > 0


class ConvexFaceHit(NamedTuple):
    """The face of a body a ray meets first (:func:`convex_closest_hit`); one ray."""

    t: Array  # () distance in units of ‖d‖ (inf: none)
    prim: Array  # () int32 a scene triangle of the face (−1: none)
    ng: Array  # (3,) the face's outward unit normal (0: none)
    p: Array  # (3,) o + t d
    p_error: Array  # (3,) bound on p's distance from the face's plane, every component


def convex_closest_hit(bodies: ConvexBodies, o: Array, d: Array, t_max: Array) -> ConvexFaceHit:
    """The first face of any body that ``o + t d`` meets with ``0 < t < t_max`` (one ray).

    Clipping the ray against a body's face planes and cap (Cyrus–Beck) gives the interval
    ``(t_in, t_out)`` it spends inside. Seen from outside, the face hit is the last plane it
    enters by (``t = t_in > 0``); from inside (``t_in = 0``: the origin inside, or on a face
    plane and heading in, as a watertight test misses a face closer than its δt) the first
    plane it leaves by, ``t = t_out``, as a two-sided triangle's inside is hit. A cap has no
    triangle: a ray that enters through it (from beyond the plane that closes an open body,
    where only a camera may be) meets the face it leaves by, one that leaves through it none.
    Ties between bodies keep the first.

    The hit point ``p = o + t d`` lies within ``e`` of the face's plane, per component of
    ``p_error``: ``e = m + γ₈ (‖o − v‖₁ + ‖o‖₁ + |t| ‖d‖₁)`` with ``m`` the plane's margin
    (its ``γ₈ |c|``, which covers its distance from the float vertices) and ``v`` the
    body's origin vertex: the numerator's error (as in the on-plane test), the quotient's and
    the denominator's relative errors times ``|t| ‖d‖₁``, and the rounding of ``o + t d``
    (pbrt-v4 §6.8 bounds a ray–plane point the same way). So
    :func:`jaxrt.geometry.spawn.spawn_ray`'s offset ``|n| · p_error ≥ e`` puts the next ray's origin
    on the face's side of its plane.

    Args:
        bodies: the bodies; o: (3,) origin; d: (3,) direction (any length); t_max: ().
    Returns:
        :class:`ConvexFaceHit` (``prim = −1``, ``t = inf`` when no face is met before ``t_max``).
    """
    dtype = d.dtype
    rows = jnp.concatenate([bodies.planes, bodies.caps[:, None]], axis=1).astype(dtype)
    faces = jnp.concatenate([bodies.faces, jnp.full((bodies.count, 1), -1, jnp.int32)], 1)
    width = rows.shape[1]
    origins = bodies.origin.astype(dtype)
    inf = jnp.asarray(jnp.inf, dtype)
    t_max = jnp.asarray(t_max, dtype)

    def one_body(b, best):
        rel, slack = _relative(o, origins[b])
        c = _clip_body([rows[b, k] for k in range(width)], rel, slack, d, inf)
        # entering through a face (not the cap): that face; else the face it leaves by
        by_face = (c.k_in >= 0) & (c.k_in < width - 1)
        a, bb, k = (jnp.where(by_face, c.a_in, c.a_out), jnp.where(by_face, c.b_in, c.b_out),
                    jnp.where(by_face, c.k_in, c.k_out))
        t = a / bb  # one division per body, in the body's kernel
        better = (c.nonempty & (k >= 0) & (k < width - 1)
                  & (_key(t, b * width + k.astype(jnp.int32), bits) < best))
        return jnp.where(better, _key(t, b * width + k.astype(jnp.int32), bits), best)

    # ONE value out of the unrolled clipping: t's bits (t ≥ 0: ordered as integers and as
    # floats) with the row's index in the lowest ones (_key). XLA fuses the clipping into the
    # kernel that stores it; each further output (t and the index apart) would be a further
    # kernel that computes all of it again, and a complex (t, index) or an int32 key does not
    # vectorise (the path pass is then slower than with the blocks' triangles)
    count = bodies.count * width
    bits = count.bit_length()  # row index `count` (all ones or less): none
    start = _key(jnp.where(d[0] == d[0], t_max, t_max), (1 << bits) - 1, bits)
    best = start  # unrolled in Python (as in convex_any_hit)
    for b in range(bodies.count):
        best = one_body(b, best)
    best = computed_once(best)
    index = _row_of(best, bits)
    # the winning row's plane, margin and triangle, and its body's origin, by selects over the
    # few rows (cheaper than gathers per lane); t again, exactly, from that row alone
    r, ref, prim = jnp.zeros(5, dtype), jnp.zeros(3, dtype), jnp.int32(-1)
    for b in range(bodies.count):
        for k in range(width - 1):
            row = index == b * width + k
            r, ref = jnp.where(row, rows[b, k], r), jnp.where(row, origins[b], ref)
            prim = jnp.where(row, faces[b, k], prim)
    rel, slack = _relative(o, ref)
    num = r[3] - (r[0] * rel[0] + r[1] * rel[1] + r[2] * rel[2])
    den = r[0] * d[0] + r[1] * d[1] + r[2] * d[2]
    t = num / jnp.where(den != 0, den, 1)
    hit = (prim >= 0) & (t < t_max)
    p = o + t * d
    l1 = lambda v: jnp.abs(v[0]) + jnp.abs(v[1]) + jnp.abs(v[2])  # noqa: E731
    e = r[4] + slack + gamma(8, dtype) * (l1(o) + jnp.abs(t) * l1(d))
    zero3 = jnp.zeros(3, dtype)
    return ConvexFaceHit(t=jnp.where(hit, t, inf), prim=jnp.where(hit, prim, -1),
                   ng=jnp.where(hit, r[:3], zero3), p=jnp.where(hit, p, zero3),
                   p_error=jnp.where(hit, jnp.broadcast_to(e, (3,)), zero3))


class Found(NamedTuple):
    """What :func:`convex_bodies` found (host arrays; :class:`ConvexBodies` holds them)."""

    planes: np.ndarray  # (B, P, 5)
    origin: np.ndarray  # (B, 3)
    caps: np.ndarray  # (B, 5)
    faces: np.ndarray  # (B, P) int
    members: np.ndarray  # (T,) the triangles the bodies replace
    kept: np.ndarray  # the candidates left to test as triangles (sorted)


def _row(plane: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """A plane ``(n, c)`` (4,) as a table row (5,): ``c`` relative to ``origin``, its margin."""
    c = plane[3] - plane[:3] @ origin  # in float64
    return np.concatenate([plane[:3], [c, 8 * np.finfo(np.float32).eps * abs(c)]])


_PAD = np.array([0.0, 0.0, 0.0, 1.0, 0.0])  # n = 0, c = 1: every point inside


def convex_bodies(triangles: np.ndarray, candidates: np.ndarray, emissive: np.ndarray,
                  points: np.ndarray, balls: np.ndarray, materials: np.ndarray) -> Found:
    """Find the convex bodies among ``candidates`` (host, float64).

    Args:
        triangles: (F, 3, 3) the scene's stored triangles.
        candidates: (K,) indices of the triangles shadow rays test.
        emissive: (F,) bool, emissive triangles (never part of a body).
        points: (Q, 3) light points (point and spot lights); balls: (S, 4) sphere lights.
        materials: (F,) material index per triangle: a body's face must have one material
            (a closest hit knows the face, not which of its triangles).
    Returns:
        :class:`Found` (B may be 0).
    """
    tri = np.asarray(triangles, np.float64)
    cand = np.asarray(candidates, np.int64)
    extent = max(np.max(np.abs(tri)), np.finfo(np.float64).tiny)
    if points.size:
        extent = max(extent, np.max(np.abs(points)))
    tol = SIDE_TOL * extent
    bodies, members = [], []
    for comp in _components(tri, cand):
        if np.any(emissive[comp]):
            continue
        found = _body_planes(tri, comp, tol)
        if found is None:
            continue
        planes, face_of, cap = found
        if any(len(np.unique(materials[comp[face_of == k]])) > 1 for k in range(len(planes))):
            continue  # a face of two materials
        others = np.setdiff1d(np.arange(len(tri)), comp)
        outside = np.concatenate([tri[others].reshape(-1, 3), points.reshape(-1, 3)])
        if not _outside(planes, outside, balls, tol):
            continue
        # an open body is closed by its cap only if no segment reaches the cap's far side:
        # every scene vertex, light point and ball on the body's side (then the cap itself
        # need not be tested by shadow rays)
        if cap is not None and not _inside_half_space(cap, tri.reshape(-1, 3), points, balls,
                                                      tol):
            continue
        first = [int(comp[np.flatnonzero(face_of == k)[0]]) for k in range(len(planes))]
        bodies.append((planes, cap, first))
        members.append(comp)
    kept = np.setdiff1d(cand, np.concatenate(members)) if members else cand
    width = max([len(p) for p, _, _ in bodies], default=1)
    table = np.tile(_PAD, (len(bodies), width, 1))
    caps = np.tile(_PAD, (len(bodies), 1))
    faces = np.full((len(bodies), width), -1, np.int64)
    origins = np.stack([tri[m[0], 0] for m in members]) if members else np.zeros((0, 3))
    for b, (planes, cap, first) in enumerate(bodies):  # origins: stored vertices, exact
        table[b, :len(planes)] = [_row(p, origins[b]) for p in planes]
        faces[b, :len(planes)] = first
        if cap is not None:
            caps[b] = _row(cap, origins[b])
    members = np.concatenate(members) if members else np.zeros(0, np.int64)
    return Found(table, origins, caps, faces, members, kept)


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
    """``(planes, face_of, cap)`` of a convex, closed (``cap`` None) or cap-closed set, else
    None.

    ``planes`` (P, 4): the outward face planes, one per distinct plane; ``face_of`` (len(comp),)
    the plane of each triangle; ``cap`` (4,): the outward plane through the edges that belong
    to one triangle, not among ``planes``.
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
    merged, face_of = _merge(planes, tol)
    return merged, face_of, cap


def _cap_plane(ends: np.ndarray, verts: np.ndarray, tol: float) -> np.ndarray | None:
    """The plane (4,) through the open edges' ends, outward from the body's vertices."""
    centre = ends.mean(0)
    vt = np.linalg.svd(ends - centre)[2]
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


def _merge(planes: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """One row per distinct plane (a quad's two triangles give one), and each input row's."""
    out, which = [], []
    for p in planes:
        same = [j for j, q in enumerate(out)
                if np.all(np.abs(p[:3] - q[:3]) <= 1e-12) and abs(p[3] - q[3]) <= tol]
        if not same:
            out.append(p)
        which.append(same[0] if same else len(out) - 1)
    return np.asarray(out), np.asarray(which)


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
