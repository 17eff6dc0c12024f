"""Tests of the closest hit for rays that share their origin (camera rays, jaxrt.geometry.eye_rays).

The watertight closed-mesh test and the ties / t_max test of test_intersect.py run this query
too; here: agreement with the watertight test on camera rays, the origin in a triangle's
plane, batched origins, and the render path that uses it.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.geometry.eye_rays import closest_hit_from_origin, eye_planes, origin_planes
from jaxrt.geometry.triangle import closest_hit, triangle_set
from jaxrt.rendering.differentiable import estimate_image
from jaxrt.rendering.driver import render
from jaxrt.scene import builtin as scenes
from jaxrt.scene.builtin.cornell import cornell_meshes
from jaxrt.scene.camera import generate_ray, look_at
from jaxrt.scene.container import build_scene

_general = jax.jit(jax.vmap(closest_hit, in_axes=(None, 0, 0, 0)))
_shared = jax.jit(jax.vmap(closest_hit_from_origin, in_axes=(None, None, 0, 0)))
_batched = jax.jit(jax.vmap(closest_hit_from_origin, in_axes=(None, 0, 0, 0)))


def _edge_distance(b1, b2):
    return np.minimum(np.minimum(b1, b2), 1 - b1 - b2)


@pytest.mark.parametrize("where", ["cornell", "translated_1e5", "scaled_1e-4"])
def test_camera_rays_agree_with_the_watertight_test(where):
    """Jittered camera rays of the Cornell box (262 144 of them): the same triangle as the
    watertight test except within rounding of an edge, where either may win (the inside test
    counts an edge within its rounding margin as inside: module notes)."""
    scene = scenes.cornell_box(256, 256)
    tris = np.asarray(scene.geometry.vertices, np.float64)
    eye = np.asarray(scene.camera.eye, np.float64)
    if where == "translated_1e5":
        shift = np.array([1e5, -3e4, 7e4])
        tris, eye = tris + shift, eye + shift
    elif where == "scaled_1e-4":
        tris, eye = tris * 1e-4, eye * 1e-4
    geometry = triangle_set(tris.astype(np.float32))
    w = scene.width
    px = np.stack(np.meshgrid(np.arange(w), np.arange(w)), -1).reshape(-1, 2).astype(np.int32)
    differ = total = 0
    for k in range(4):
        u = jax.random.uniform(jax.random.PRNGKey(k), (px.shape[0], 2))
        _, d = jax.vmap(lambda p, uu: generate_ray(scene.camera, p, uu))(px, u)
        o = jnp.broadcast_to(jnp.asarray(eye, jnp.float32), d.shape)
        t_max = jnp.full(d.shape[0], jnp.inf)
        a, b = _general(geometry, o, d, t_max), _shared(geometry, o[0], d, t_max)
        same = np.asarray(a.prim == b.prim)
        # the same triangle: the same distance and point (rounding of V / det vs the shear)
        h = same & np.asarray(a.prim >= 0)
        ta, tb = np.asarray(a.t)[h], np.asarray(b.t)[h]
        assert np.max(np.abs(ta - tb) / ta) < 1e-5
        np.testing.assert_array_equal(np.asarray(a.p)[h], np.asarray(b.p)[h])
        # a different one: the ray passes within ~1e-4 (barycentric) of an edge of one of them
        for hit in (a, b):
            assert np.all(_edge_distance(np.asarray(hit.b1), np.asarray(hit.b2))[
                np.asarray(hit.prim >= 0)] > -2e-4)
        near = np.minimum(np.abs(_edge_distance(np.asarray(a.b1), np.asarray(a.b2))),
                          np.abs(_edge_distance(np.asarray(b.b1), np.asarray(b.b2))))
        # or two coplanar triangles at one distance (1e5 away the light quad's float32
        # vertices round onto the ceiling's plane: z-fighting, either is right)
        ta, tb = np.asarray(a.t), np.asarray(b.t)
        tie = np.isfinite(ta) & (np.abs(ta - np.where(np.isfinite(tb), tb, 0)) <= 1e-5 * ta)
        assert np.all((near < 2e-4) | tie)
        differ += int(np.sum(~same & ~tie))
        total += same.size
    assert differ <= 1e-4 * total, f"{differ} of {total} rays hit another triangle"


def test_origin_in_a_triangles_plane_never_hits_it():
    """Rays from a point of a triangle's plane see it edge on: no hit (not one at t ≈ 0 or at a
    random distance from a rounded volume), no NaN, and what lies behind it is found."""
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    flat = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float64) @ q.T  # a rotated plane
    origin = np.array([0.3, 2.0, 0.0]) @ q.T  # in that plane, outside the triangle
    back = flat + 3 * q[:, 2]  # a parallel triangle off the plane
    tris = np.stack([flat, back]).astype(np.float32)
    geometry = triangle_set(tris)
    # n / V per triangle: zero where V is rounding (the in-plane triangle) or padding
    table = np.asarray(origin_planes(geometry, jnp.asarray(origin, jnp.float32)))
    # rays towards points of the in-plane triangle (rounded off its plane) and of the other
    target = np.concatenate([flat[0] + rng.uniform(0, 0.5, (512, 1)) * (flat[1] - flat[0])
                             + rng.uniform(0, 0.5, (512, 1)) * (flat[2] - flat[0]),
                             back.mean(0) + 0.1 * rng.standard_normal((512, 3))])
    d = (target - origin).astype(np.float32)
    hit = _shared(geometry, jnp.asarray(origin, jnp.float32), d, jnp.full(len(d), jnp.inf))
    prim = np.asarray(hit.prim)
    # rows: the in-plane triangle, the parallel one, two never-hit padding triangles
    assert np.all(table[0, 12:] == 0) and np.any(table[1, 12:] != 0)
    assert np.all(table[2:, 12:] == 0)
    assert not np.any(prim[:512] == 0)
    assert np.mean(prim[512:] == 1) > 0.9  # the parallel triangle behind is seen
    assert not np.any(np.isnan(np.asarray(hit.t)))


def test_batched_origins_give_the_same_hits():
    """A batched origin forms the planes per ray: the same triangles as one shared origin."""
    scene = scenes.cornell_box(32, 32)
    rng = np.random.default_rng(5)
    d = rng.standard_normal((1024, 3)).astype(np.float32)
    eye = np.array([0.278, 0.273, 0.3], np.float32)  # inside the box: every ray hits
    t_max = np.where(rng.uniform(size=1024) < 0.5, np.inf, 0.1).astype(np.float32)
    a = _shared(scene.geometry, eye, d, t_max)
    b = _batched(scene.geometry, np.broadcast_to(eye, d.shape), d, t_max)
    np.testing.assert_array_equal(np.asarray(a.prim), np.asarray(b.prim))
    # t = V / det: the per-ray program may contract V or det differently, by an ulp or so
    np.testing.assert_allclose(np.asarray(a.t), np.asarray(b.t), rtol=4 * np.finfo(np.float32).eps)
    assert 0.5 < np.mean(np.isfinite(np.asarray(a.t))) < 0.95  # t_max = 0.1 rejects some


def test_eye_planes_formed_on_the_host_are_the_programs_table():
    """A scene carries its camera's edge-plane table, formed with numpy (every operation
    rounded once): the program's table (which may contract products into FMAs) within the
    normals' own rounding margin, the same triangles kept, None for a BVH or traced arrays."""
    scene = scenes.cornell_box(16, 16)
    host = np.asarray(scene.eye_planes)
    program = np.asarray(jax.jit(origin_planes)(scene.geometry, scene.camera.eye))
    assert host.dtype == program.dtype and host.shape == program.shape == (32, 15)
    margin = np.repeat(host[:, 9:12], 3, axis=1)  # each edge's margin, per normal component
    assert np.all(np.abs(host[:, :9] - program[:, :9]) <= margin)
    # the margins γ₈‖|a| ×ₐ |b|‖: one rounding of the norm apart (measured 1 ulp); a margin
    # 4 ulp off, a γ₇ for the γ₈, or an eye moved by 1e-5 fails this
    np.testing.assert_allclose(host[:, 9:12], program[:, 9:12], rtol=2 * np.finfo(np.float32).eps)
    # n / V: V and n rounded (or contracted) differently, within ~15 ulp of the row's scale
    scale = np.max(np.abs(host[:, 12:]), axis=1, keepdims=True)
    assert np.all(np.abs(host[:, 12:] - program[:, 12:]) <= 1e-5 * scale)
    assert np.array_equal(np.any(host[:, 12:] != 0, 1), np.any(program[:, 12:] != 0, 1))
    assert eye_planes(scenes.cornell_box(16, 16, accel="bvh").geometry, scene.camera) is None
    seen = []
    jax.eval_shape(lambda eye: seen.append(eye_planes(
        scene.geometry, dataclasses.replace(scene.camera, eye=eye))), scene.camera.eye)
    assert seen == [None]


def test_a_new_camera_gets_its_own_eye_planes():
    """``Scene.replace(camera=…)`` forms the table again: the image is the one of a scene built
    with that camera, bit for bit (a stale table would test the triangles from the old eye);
    the table formed in the program instead gives the same image but for rays within
    rounding of an edge."""
    scene = scenes.cornell_box(24, 24)
    other = look_at(eye=[0.4, 0.3, -0.5], target=[0.25, 0.2, 0.3], up=[0, 1, 0], fov_deg=50,
                    width=24, height=24)
    moved = scene.replace(camera=other)
    built = build_scene(cornell_meshes(), other)
    np.testing.assert_array_equal(np.asarray(moved.eye_planes), np.asarray(built.eye_planes))
    assert not np.array_equal(np.asarray(moved.eye_planes), np.asarray(scene.eye_planes))
    image = lambda s: np.asarray(render(s, "mis", spp=4, seed=2, progress=False).image)
    a = image(moved)
    np.testing.assert_array_equal(a, image(built))
    b = image(moved.replace(eye_planes=None))
    assert np.mean(np.any(a != b, axis=-1)) <= 0.01


def test_a_stale_table_is_formed_again_by_the_render():
    """A copy made with ``dataclasses.replace`` keeps the old camera's table; ``render`` and
    ``estimate_image`` form it again from the scene's own camera: the image of
    ``Scene.replace``, bit for bit (the stale table would get 78 % of a 24² image's pixels
    wrong)."""
    scene = scenes.cornell_box(24, 24)
    other = look_at(eye=[0.4, 0.3, -0.5], target=[0.25, 0.2, 0.3], up=[0, 1, 0], fov_deg=50,
                    width=24, height=24)
    stale = dataclasses.replace(scene, camera=other)
    assert np.array_equal(np.asarray(stale.eye_planes), np.asarray(scene.eye_planes))
    image = lambda s: np.asarray(render(s, "mis", spp=4, seed=2, progress=False).image)
    np.testing.assert_array_equal(image(stale), image(scene.replace(camera=other)))
    estimate = lambda s: np.asarray(estimate_image(s, "mis", spp=2, seed=2))
    np.testing.assert_array_equal(estimate(stale), estimate(scene.replace(camera=other)))
    # traced (the scene a jit argument), the table cannot be formed again: kept as passed in
    kept = jax.jit(lambda s: s.with_own_derived_state().eye_planes)(stale)
    np.testing.assert_array_equal(np.asarray(kept), np.asarray(stale.eye_planes))
