"""Convex occluders (jaxrt.convex): which meshes form a body; shadow rays see it as triangles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt import lights as lt
from jaxrt import materials as mt
from jaxrt.convex import convex_any_hit
from jaxrt.intersect import any_hit, triangle_set
from jaxrt.occluders import shadow_occluders
from jaxrt.render import render
from jaxrt.scene import build_scene, mesh
from jaxrt.scenes import cornell_box
from jaxrt.scenes.cornell import cornell_camera
from jaxrt.spawn import spawn_ray_to

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
    one = scene.convex._replace(planes=scene.convex.planes[:1], origin=scene.convex.origin[:1])
    assert np.sum(run(scene.replace(convex=one)) - reference) > 0.01 * np.sum(reference)
