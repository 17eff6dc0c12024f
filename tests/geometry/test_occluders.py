"""Shadow rays skip the triangles that cannot block them (jaxrt.geometry.occluders), and nothing
changes."""

import dataclasses

import numpy as np
import pytest

from jaxrt.geometry.occluders import one_sided_faces, shadow_occluders
from jaxrt.rendering.differentiable import estimate_image
from jaxrt.rendering.driver import render
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import cornell_box
from jaxrt.scene.builtin.cornell import cornell_camera, cornell_meshes
from jaxrt.scene.container import build_scene, mesh


def _box(lo, hi):
    """12 triangles of an axis-aligned box (vertices, faces)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, np.array([[q[0], q[k], q[k + 1]] for q in quads for k in (1, 2)], np.int32)


def _tested(scene):
    """The triangles a shadow ray must test (before convex bodies take theirs:
    jaxrt.geometry.convex)."""
    return shadow_occluders(scene.geometry, scene.triangles, scene.lights)


def _room(extra_lights=(), inner=True):
    """A closed unit room (12 walls) with a small box inside and a small light quad."""
    meshes = [mesh(*_box((0, 0, 0), (1, 1, 1)), mt.diffuse(0.5), name="room")]
    if inner:
        meshes.append(mesh(*_box((0.3, 0, 0.3), (0.6, 0.4, 0.6)), mt.diffuse(0.5), name="block"))
    lv = np.array([[0.4, 0.99, 0.4], [0.6, 0.99, 0.4], [0.6, 0.99, 0.6], [0.4, 0.99, 0.6]])
    meshes.append(mesh(lv, np.array([[0, 2, 1], [0, 3, 2]]), mt.diffuse(0.0), emission=[5.0] * 3,
                       name="light"))
    cam = cornell_camera(16, 16)
    return build_scene(meshes, cam, extra_lights, accel="brute")


def test_the_walls_of_a_room_are_one_sided_and_what_stands_inside_is_not():
    tri = np.asarray(_room().triangles)
    one = one_sided_faces(tri)
    assert one[:12].all()  # the room's walls
    # the block's bottom lies on the floor (the whole scene above it); its other faces and
    # the light have vertices on both sides
    bottom = np.all(tri[12:, :, 1] == 0, axis=1)
    assert bottom.sum() == 2
    assert np.array_equal(one[12:], bottom)


def test_the_cornell_box_skips_its_five_walls_and_its_light():
    scene = cornell_box(16, 16)
    kept = np.asarray(_tested(scene))
    walls = 10  # floor, ceiling, back, green and red walls: two triangles each, first
    light = 2  # the light quad, last: every shadow ray ends in its plane
    assert kept.tolist() == list(range(walls, scene.num_triangles - light))
    # the two blocks left are convex bodies, tested by their five face planes each
    assert scene.occluders.shape == (0,)
    assert "shadow rays test 0 of them and 2 convex bodies (10 planes)" in scene.summary()


@pytest.mark.parametrize("light, kept", [
    ([], 10),  # the quad alone: its two triangles hold every light end
    ([lt.point_light([0.5, 0.99, 0.5], [1.0] * 3)], 10),  # a point light in the quad's plane
    ([lt.point_light([0.5, 0.98, 0.5], [1.0] * 3)], 12),  # 0.01 below it: the quad can block
    ([lt.sphere_light([0.5, 0.5, 0.5], 0.05, [1.0] * 3)], 12),  # a ball has no plane
])
def test_triangles_in_the_plane_of_every_light_end_are_skipped(light, kept):
    """12 walls and the block's bottom are skipped in every case; the light quad's two
    triangles too when every point a light samples lies in their plane."""
    from jaxrt.geometry.occluders import coplanar_faces

    occluders = np.asarray(_tested(_room(light)))
    assert occluders.size == kept
    assert ({24, 25} <= set(occluders.tolist())) == (kept == 12)
    tri = np.array([[[0, 1, 0], [1, 1, 0], [0, 1, 1]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    assert coplanar_faces(tri, np.array([[5.0, 1.0, -3.0], [0.2, 1.0, 0.7]])).tolist() == [
        True, False]
    assert coplanar_faces(tri, np.array([[5.0, 1.0 + 1e-9, -3.0]])).tolist() == [False, False]
    assert coplanar_faces(tri, np.zeros((0, 3))).tolist() == [False, False]


@pytest.mark.parametrize("light, kept", [
    (lt.point_light([0.5, 0.5, 0.5], [1.0] * 3), 12),  # inside: the walls still cannot block
    (lt.point_light([0.5, 0.5, 1.5], [1.0] * 3), 14),  # behind the z = 1 wall: it can, so it stays
    (lt.sphere_light([0.5, 0.5, 0.5], 0.2, [1.0] * 3), 12),
    (lt.sphere_light([0.5, 0.5, 0.95], 0.2, [1.0] * 3), 14),  # the ball pokes through z = 1
])
def test_lights_inside_keep_the_walls_skipped_and_lights_outside_do_not(light, kept):
    """24 of the 26 triangles can be skipped or not: 12 walls + the block's bottom skipped
    leaves 12; a light beyond the z = 1 wall (2 triangles) keeps that wall."""
    occluders = np.asarray(_tested(_room([light])))
    assert occluders.size == kept
    assert (set(range(10, 12)) <= set(occluders.tolist())) == (kept == 14)


@pytest.mark.parametrize("light", [lt.directional_light([0, -1, 0], [1.0] * 3),
                                   lt.constant_environment([1.0, 1.0, 1.0])])
def test_light_from_outside_the_scene_tests_every_triangle(light):
    scene = _room([light])
    assert scene.occluders is None and scene.convex is None


def test_new_lights_or_geometry_test_every_triangle_unless_told():
    scene = _room()
    sky = lt.light_table([lt.constant_environment([1.0] * 3)])
    assert scene.replace(lights=sky).occluders is None  # the walls now block the sky
    assert scene.replace(lights=sky).convex is None
    again = scene.replace(triangles=scene.triangles)  # found again: the same list
    assert np.array_equal(np.asarray(again.occluders), np.asarray(scene.occluders))
    assert np.array_equal(np.asarray(again.convex.planes), np.asarray(scene.convex.planes))
    assert scene.replace(lights=sky, occluders=scene.occluders).occluders is scene.occluders
    assert scene.replace(camera=scene.camera).occluders is scene.occluders
    # render prepares the scene (how triangle lights are sampled) and keeps them
    from jaxrt.integrators.config import make_estimator, prepare_scene
    assert prepare_scene(scene, make_estimator("mis")).occluders is scene.occluders


def test_a_bvh_scene_keeps_its_own_shadow_rays():
    scene = cornell_box(16, 16, accel="bvh")
    assert scene.occluders is None and scene.convex is None


@pytest.mark.parametrize("estimator", ["mis", "path"])
def test_skipping_them_changes_no_pixel(estimator):
    """The Cornell box renders the same bits with and without the skip; skipping a triangle
    that can block (the tall block's faces) changes the image: the test can see a wrong skip."""
    scene = cornell_box(24, 24)
    scene = scene.replace(occluders=_tested(scene), convex=None)  # triangles only
    run = lambda s: np.asarray(render(s, estimator, spp=4, seed=3, progress=False).image)
    image = run(scene)
    assert np.array_equal(image, run(scene.replace(occluders=None)))
    blocks = np.asarray(scene.occluders)
    wrong = scene.replace(occluders=blocks[:len(blocks) // 2])  # half the blocks skipped too
    assert not np.array_equal(image, run(wrong))


def test_a_copy_with_other_triangles_finds_its_own_shadow_blockers():
    """``dataclasses.replace(scene, geometry=…, triangles=…)`` keeps the original's occluders
    and convex bodies (the short block's old face planes); ``render`` and ``estimate_image``
    form them again from the copy's own triangles (``Scene.with_own_derived_state``): the
    images of the scene built with the block there, bit for bit (with the old planes, 102 of
    a 24² image's 1 728 values differ)."""
    def cornell(shift):
        meshes = [m._replace(vertices=m.vertices + [shift, 0, 0]) if m.name == "short_block"
                  else m for m in cornell_meshes()]
        return build_scene(meshes, cornell_camera(24, 24))

    here, there = cornell(0.0), cornell(-0.08)
    assert here.convex.count == 2
    stale = dataclasses.replace(here, geometry=there.geometry, triangles=there.triangles,
                                eye_planes=there.eye_planes)  # only the shadow rays' are stale
    image = lambda s: np.asarray(render(s, "mis", spp=4, seed=1, progress=False).image)
    np.testing.assert_array_equal(image(stale), image(there))
    estimate = lambda s: np.asarray(estimate_image(s, "mis", spp=2, seed=1))
    np.testing.assert_array_equal(estimate(stale), estimate(there))
    # what Scene.replace is told is kept (here: every triangle tested one by one)
    assert there.replace(occluders=None).with_own_derived_state().occluders is None
