"""Convex occluders (jaxrt.geometry.convex): which meshes form a body; shadow rays see it as
triangles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.geometry.convex import convex_any_hit, convex_closest_hit
from jaxrt.geometry.occluders import shadow_occluders
from jaxrt.geometry.spawn import spawn_ray, spawn_ray_to
from jaxrt.geometry.triangle import any_hit, closest_hit, gamma, triangle_set
from jaxrt.rendering.driver import render
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import cornell_box
from jaxrt.scene.builtin.cornell import cornell_camera
from jaxrt.scene.container import build_scene, mesh
from jaxrt.scene.queries import intersect

_convex_batch = jax.jit(jax.vmap(convex_any_hit, in_axes=(None, 0, 0, None)))
_any_batch = jax.jit(jax.vmap(any_hit, in_axes=(None, 0, 0, None)))


def _box(lo, hi, bottom=True):
    """Triangles of an axis-aligned box (vertices, faces); without its y = lo face if asked."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    if not bottom:
        quads.remove((0, 4, 5, 1))  # the y = lo face
    return v, np.array([[q[0], q[k], q[k + 1]] for q in quads for k in (1, 2)], np.int32)


def _scene(*extra, lights=()):
    """A closed unit room, a small light quad under its ceiling, and ``extra`` meshes."""
    room_v, room_f = _box((0, 0, 0), (1, 1, 1))
    meshes = [mesh(room_v, room_f, mt.diffuse(0.5), name="room"), *extra]
    lv = np.array([[0.4, 0.99, 0.4], [0.6, 0.99, 0.4], [0.6, 0.99, 0.6], [0.4, 0.99, 0.6]])
    meshes.append(mesh(lv, np.array([[0, 2, 1], [0, 3, 2]]), mt.diffuse(0.0), emission=[5.0] * 3,
                       name="light"))
    return build_scene(meshes, cornell_camera(16, 16), lights, accel="brute")


def _block(lo, hi, bottom=True, **kw):
    return mesh(*_box(lo, hi, bottom), mt.diffuse(0.5), **kw)


def _l_shape():
    """A non-convex prism: an L in x–z, 0.2 high, standing on the floor."""
    outline = np.array([[0.2, 0.2], [0.7, 0.2], [0.7, 0.4], [0.4, 0.4], [0.4, 0.7], [0.2, 0.7]])
    n = len(outline)
    v = np.array([[x, y, z] for y in (0.0, 0.2) for x, z in outline])
    sides = [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    faces = [[q[0], q[1], q[2]] for q in sides] + [[q[0], q[2], q[3]] for q in sides]
    top = [[n + 0, n + 1, n + 2], [n + 0, n + 2, n + 3], [n + 0, n + 3, n + 4],
           [n + 0, n + 4, n + 5]]
    return mesh(v, np.array(faces + top, np.int32), mt.diffuse(0.5), name="L")


def test_the_cornell_blocks_are_two_bodies_of_five_planes():
    scene = cornell_box(16, 16)
    assert scene.convex.count == 2
    # the blocks' 20 triangles, closed by the floor they stand on (their bottoms are open)
    assert sorted(np.asarray(scene.convex.triangles).tolist()) == list(range(10, 30))
    planes = np.asarray(scene.convex.planes)
    assert np.all(np.any(planes[..., :3] != 0, axis=-1))  # 5 real planes each, no padding
    assert np.allclose(np.linalg.norm(planes[..., :3], axis=-1), 1, atol=1e-6)


@pytest.mark.parametrize("extra, bodies", [
    ([_block((0.3, 0, 0.3), (0.6, 0.4, 0.6))], 1),  # closed, on the floor
    ([_block((0.3, 0, 0.3), (0.6, 0.4, 0.6), bottom=False)], 1),  # open bottom on the floor
    ([_block((0.3, 0.2, 0.3), (0.6, 0.4, 0.6))], 1),  # closed, floating
    ([_block((0.3, 0.2, 0.3), (0.6, 0.4, 0.6), bottom=False)], 0),  # open in mid-air
    ([_l_shape()], 0),  # not convex
    ([_block((0.3, 0, 0.3), (0.6, 0.4, 0.6), emission=[1.0] * 3)], 0),  # an emitter
    ([_block((0.1, 0, 0.1), (0.3, 0.2, 0.3)), _block((0.6, 0, 0.6), (0.9, 0.3, 0.9))], 2),
])
def test_which_meshes_become_bodies(extra, bodies):
    scene = _scene(*extra)
    assert (0 if scene.convex is None else scene.convex.count) == bodies
    # the triangles left to test one by one are the rest of what shadow rays must test
    tested = set(np.asarray(shadow_occluders(scene.geometry, scene.triangles,
                                             scene.lights)).tolist())
    taken = set() if scene.convex is None else set(np.asarray(scene.convex.triangles).tolist())
    assert set(np.asarray(scene.occluders).tolist()) == tested - taken
    assert taken <= tested


def test_a_light_inside_a_block_keeps_it_triangles():
    point = lt.point_light([0.45, 0.2, 0.45], [1.0] * 3)  # inside the block
    assert _scene(_block((0.3, 0, 0.3), (0.6, 0.4, 0.6)), lights=[point]).convex is None
    outside = lt.point_light([0.45, 0.6, 0.45], [1.0] * 3)
    assert _scene(_block((0.3, 0, 0.3), (0.6, 0.4, 0.6)), lights=[outside]).convex.count == 1


@pytest.mark.parametrize("scale, shift", [(1.0, 0.0), (1e-4, 0.0), (1e5, 0.0), (1.0, 1e5)])
def test_shadow_rays_see_the_bodies_as_their_triangles(scale, shift):
    """Segments from points on the Cornell box's surfaces (the blocks' faces included, spawned
    off them as a render does) to points of the light: the bodies block the same segments as
    their triangles, at every scale and placement; a segment that leaves a block's face is
    never blocked by that block."""
    base = cornell_box(16, 16)
    tris = np.asarray(base.triangles, np.float64) * scale + shift
    tri32 = tris.astype(np.float32)
    scene = base.replace(triangles=jnp.asarray(tri32), geometry=triangle_set(tri32))
    assert scene.convex is not None and scene.convex.count == 2
    bodies = np.asarray(scene.convex.triangles)
    rng = np.random.default_rng(1)
    n = 20000
    f = rng.integers(0, 30, n)  # walls and blocks
    b = rng.dirichlet(np.ones(3), n)
    p = np.einsum("nk,nkc->nc", b, tris[f])
    light = tris[30:32].reshape(-1, 3)
    q = light[[0, 1, 2]].mean(0) + (rng.uniform(-0.4, 0.4, (n, 1)) * (light[1] - light[0])
                                    + rng.uniform(-0.4, 0.4, (n, 1)) * (light[2] - light[1]))
    ng = np.cross(tris[f, 1] - tris[f, 0], tris[f, 2] - tris[f, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ng = np.where(np.sum(ng * (q - p), 1, keepdims=True) < 0, -ng, ng)  # towards the light
    n_q = np.broadcast_to(np.array([0.0, -1.0, 0.0]), (n, 3))
    o, d, t_max = jax.vmap(spawn_ray_to)(*(jnp.asarray(a, jnp.float32) for a in (p, ng, q, n_q)))
    by_planes = np.asarray(_convex_batch(scene.convex, o, d, t_max[0]))
    blocks = triangle_set(tri32[bodies])
    by_triangles = np.asarray(_any_batch(blocks, o, d, t_max[0]))
    assert 0.05 < by_triangles.mean() < 0.6  # both outcomes exercised
    differ = by_planes != by_triangles
    # only segments that graze a block's edge may differ: a few in 10⁴
    assert differ.mean() <= 5e-4, f"{differ.sum()} of {n} differ"
    # leaving a block's face: never blocked by it (f in the blocks, ng towards the light)
    on_block = (f >= 10) & (f < 30)
    assert not np.any(by_planes[on_block] & ~by_triangles[on_block])
    if shift:
        return  # 1e5 away a float32 point of a face is up to 0.004 off it: only spawned rays
    # even from the point itself, not spawned off the face (within rounding of its plane)
    p32 = jnp.asarray(p, jnp.float32)
    raw_d = jnp.asarray(q, jnp.float32) - p32
    raw_planes = np.asarray(_convex_batch(scene.convex, p32, raw_d, t_max[0]))
    raw_triangles = np.asarray(_any_batch(blocks, p32, raw_d, t_max[0]))
    assert not np.any(raw_planes[on_block] & ~raw_triangles[on_block])


@pytest.mark.parametrize("estimator", ["mis", "path"])
def test_renders_agree_with_the_triangles_and_a_missing_body_shows(estimator):
    scene = cornell_box(24, 24)
    run = lambda s: np.asarray(render(s, estimator, spp=4, seed=3, progress=False).image)
    image = run(scene)
    triangles = scene.replace(occluders=shadow_occluders(scene.geometry, scene.triangles,
                                                         scene.lights), convex=None)
    reference = run(triangles)
    # the same samples: equal to rounding (the blocks' edges aside, no sample changes)
    assert np.max(np.abs(image - reference)) <= 1e-5 * np.max(reference)
    # one block forgotten: its shadow goes (the floor brightens by far more than noise)
    c = scene.convex  # the second block's triangles back to be tested one by one
    one = c._replace(planes=c.planes[:1], origin=c.origin[:1], caps=c.caps[:1],
                     faces=c.faces[:1], triangles=c.triangles[:10],
                     others=jnp.concatenate([c.others, c.triangles[10:]]))
    assert np.sum(run(scene.replace(convex=one)) - reference) > 0.01 * np.sum(reference)


_closest_batch = jax.jit(jax.vmap(convex_closest_hit, in_axes=(None, 0, 0, None)))
_tri_closest = jax.jit(jax.vmap(closest_hit, in_axes=(None, 0, 0, None)))


def _placed(scale, shift):
    """The Cornell box scaled and moved, stored in float32 (triangles and bodies)."""
    base = cornell_box(16, 16)
    tris = np.asarray(base.triangles, np.float64) * scale + shift
    tri32 = tris.astype(np.float32)
    return base.replace(triangles=jnp.asarray(tri32), geometry=triangle_set(tri32)), tri32


@pytest.mark.parametrize("scale, shift", [(1.0, 0.0), (1e-4, 0.0), (1e5, 0.0), (1.0, 1e5)])
def test_closest_hits_by_planes_are_the_triangles_hits(scale, shift):
    """Rays from every kind of point — spawned off the walls and the blocks' faces as a path
    continues, and from anywhere in the room, inside the blocks included — find the same
    face by the planes as by the blocks' triangles (a two-sided triangle's inside is hit from
    inside), at every scale and placement: same material, same distance to rounding, and a
    hit point within its error bound of the face's plane."""
    scene, tri32 = _placed(scale, shift)
    bodies = scene.convex
    members = np.asarray(bodies.triangles)
    tris = tri32.astype(np.float64)
    rng = np.random.default_rng(2)
    n = 20000
    f = rng.integers(0, 30, n)
    p = np.einsum("nk,nkc->nc", rng.dirichlet(np.ones(3), n), tris[f])
    ng = np.cross(tris[f, 1] - tris[f, 0], tris[f, 2] - tris[f, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ng = np.where(np.sum(ng * d, 1, keepdims=True) < 0, -ng, ng)  # leaving on d's side
    room = rng.uniform(tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0), (n, 3))
    p_err = np.asarray(gamma(7, jnp.float32)) * np.abs(p) * 3
    spawned = jax.vmap(spawn_ray)(*(jnp.asarray(a, jnp.float32) for a in (p, ng, d, p_err)))[0]
    for o in (spawned, jnp.asarray(room, jnp.float32)):
        dd = jnp.asarray(d, jnp.float32)
        got = _closest_batch(bodies, o, dd, jnp.float32(jnp.inf))
        ref = _tri_closest(triangle_set(tri32[members]), o, dd, jnp.float32(jnp.inf))
        ref_prim = np.where(np.asarray(ref.prim) >= 0, members[np.maximum(ref.prim, 0)], -1)
        prim = np.asarray(got.prim)
        assert 0.1 < np.mean(prim >= 0) < 0.9  # both outcomes exercised
        mat = np.asarray(scene.prim_material)
        same = (prim >= 0) == (ref_prim >= 0)
        same[prim >= 0] &= mat[prim[prim >= 0]] == mat[ref_prim[prim >= 0]]
        # only rays that graze an edge, or start within rounding of a face, may differ
        assert np.mean(~same) <= 5e-4, f"{np.sum(~same)} of {n} differ"
        both = same & (prim >= 0)
        t, t_ref = np.asarray(got.t)[both], np.asarray(ref.t)[both]
        assert np.all(np.abs(t - t_ref) <= 1e-4 * np.maximum(np.abs(t_ref), scale)), \
            np.max(np.abs(t - t_ref))
        # the point is within its bound of the face's plane (float64, the stored vertices)
        v = tris[prim[prim >= 0]]
        n64 = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        n64 /= np.linalg.norm(n64, axis=1, keepdims=True)
        off = np.abs(np.sum((np.asarray(got.p, np.float64)[prim >= 0] - v[:, 0]) * n64, 1))
        assert np.all(off <= np.asarray(got.p_error)[prim >= 0, 0]), np.max(
            off / np.asarray(got.p_error)[prim >= 0, 0])


@pytest.mark.parametrize("scale, shift", [(1.0, 0.0), (1e-4, 0.0), (1e5, 0.0), (1.0, 1e5)])
def test_a_ray_leaving_a_face_never_meets_its_body_again(scale, shift):
    """A path's next ray, spawned off a block's face with the hit's error bound, whichever
    side of the face it leaves on (outwards: as reflected; the face's normal as shaded), is
    not hit by that body again at any scale — no self-intersection."""
    scene, tri32 = _placed(scale, shift)
    bodies = scene.convex
    rng = np.random.default_rng(4)
    n = 20000
    # first hits on the blocks from points in the room above them
    lo, hi = tri32.reshape(-1, 3).min(0), tri32.reshape(-1, 3).max(0)
    o = rng.uniform(lo, hi, (n, 3))
    o[:, 1] = lo[1] + (0.8 + 0.15 * rng.uniform(size=n)) * (hi[1] - lo[1])
    d = rng.normal(size=(n, 3))
    d[:, 1] = -np.abs(d[:, 1]) - 0.5
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    first = _closest_batch(bodies, jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32),
                           jnp.float32(jnp.inf))
    on = np.asarray(first.prim) >= 0
    assert on.mean() > 0.1
    ng = np.asarray(first.ng)[on]
    wi = rng.normal(size=(on.sum(), 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wi = np.where(np.sum(wi * ng, 1, keepdims=True) < 0, -wi, wi)  # back out of the face
    wi = jnp.asarray(wi, jnp.float32)
    o2 = jax.vmap(spawn_ray)(first.p[on], jnp.asarray(ng), wi, first.p_error[on])[0]
    again = _closest_batch(bodies, o2, wi, jnp.float32(jnp.inf))
    prim = np.asarray(again.prim)
    body_of = {int(t): b for b in range(bodies.count)
               for t in np.asarray(bodies.triangles)[10 * b:10 * b + 10]}
    same_body = np.array([p >= 0 and body_of[p] == body_of[int(q)]
                          for p, q in zip(prim, np.asarray(first.prim)[on], strict=True)])
    assert not np.any(same_body), f"{same_body.sum()} rays met their body again"


def test_from_inside_and_through_the_cap():
    """Inside an open block standing on the floor, a ray meets the face it leaves by (as the
    triangles' insides), or, leaving through the open bottom, none (the floor takes it)."""
    scene = _scene(_block((0.3, 0, 0.3), (0.6, 0.4, 0.6), bottom=False))
    assert scene.convex.count == 1 and np.asarray(scene.convex.caps)[0, 1] == -1
    o = jnp.asarray([[0.45, 0.2, 0.45]] * 3, jnp.float32)
    d = jnp.asarray([[0, 1, 0], [1, 0, 0], [0, -1, 0]], jnp.float32)
    hit = _closest_batch(scene.convex, o, d, jnp.float32(jnp.inf))
    np.testing.assert_allclose(np.asarray(hit.t)[:2], [0.2, 0.15], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(hit.ng)[:2], [[0, 1, 0], [1, 0, 0]], atol=1e-6)
    assert int(hit.prim[2]) == -1 and np.isinf(hit.t[2])
    # and the scene's intersect finds the floor there, as with the triangles
    full = jax.vmap(lambda o, d: intersect(scene, o, d, jnp.float32(jnp.inf)))(o, d)
    tri = jax.vmap(lambda o, d: intersect(scene.replace(convex=None), o, d,
                                          jnp.float32(jnp.inf)))(o, d)
    np.testing.assert_allclose(np.asarray(full.t), np.asarray(tri.t), rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(full.material), np.asarray(tri.material))


def test_a_face_of_two_materials_is_no_body():
    v, f = _box((0.3, 0, 0.3), (0.6, 0.4, 0.6))
    one = [mesh(v, f[:1], mt.diffuse(0.2), name="a"), mesh(v, f[1:], mt.diffuse(0.5), name="b")]
    assert _scene(*one).convex is None  # the first face's two triangles differ
    same = [mesh(v, f[:2], mt.diffuse(0.2), name="a"), mesh(v, f[2:], mt.diffuse(0.5), name="b")]
    assert _scene(*same).convex.count == 1  # a face per material: a body
