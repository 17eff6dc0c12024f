"""The Scene pytree: building, validation, static structure, recompilation guard, built-ins."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.scene import builtin as scenes
from jaxrt.scene import camera as cm
from jaxrt.scene import container as sc
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import queries as sq

QUAD = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float64)
QUAD_FACES = [[0, 1, 2], [0, 2, 3]]


def _camera(w=8, h=6):
    return cm.look_at(eye=[0, 1, 3], target=[0, 0, 0], up=[0, 1, 0], fov_deg=40, width=w,
                      height=h)


def test_build_from_numpy_in_a_few_lines():
    floor = sc.mesh(QUAD, QUAD_FACES, mt.diffuse(0.5))
    s = sc.build_scene([floor], _camera(), [lt.point_light([0, 2, 0], [10.0] * 3)])
    assert s.num_triangles == 2
    assert (s.width, s.height) == (8, 6)
    assert s.material_kinds == (mt.DIFFUSE,)
    assert s.lights.structure.count("point") == 1
    assert np.all(np.asarray(s.prim_light) == -1)
    assert "point" in s.summary()


def test_emissive_mesh_becomes_triangle_lights():
    floor = sc.mesh(QUAD, QUAD_FACES, mt.diffuse(0.5))
    lamp = sc.mesh(QUAD + [0, 2, 0], QUAD_FACES, mt.diffuse(0.0), emission=[5, 5, 5])
    s = sc.build_scene([floor, lamp], _camera())
    assert s.lights.structure.count("triangle") == 2
    # the lamp's two triangles (prims 2 and 3) map to lights 0 and 1, the floor to none
    assert np.asarray(s.prim_light).tolist() == [-1, -1, 0, 1]


def test_zero_emission_keeps_the_structure_of_a_light():
    """A sweep of a lamp's radiance through 0 keeps one static structure (one compiled
    program): a declared emission stays a light, which then emits nothing."""
    from jaxrt.rendering.driver import render

    floor = sc.mesh(QUAD, QUAD_FACES, mt.diffuse(0.5))
    built = {e: sc.build_scene([floor, sc.mesh(QUAD + [0, 2, 0], QUAD_FACES, mt.diffuse(0.0),
                                               emission=[e, e, e])], _camera())
             for e in (0.0, 5.0)}
    assert jax.tree.structure(built[0.0]) == jax.tree.structure(built[5.0])
    shapes = lambda t: [np.shape(x) for x in jax.tree.leaves(t)]
    assert shapes(built[0.0]) == shapes(built[5.0])
    assert built[0.0].lights.structure.count("triangle") == 2
    dark = render(built[0.0], "mis", spp=2, progress=False)
    lit = render(built[5.0], "mis", spp=2, progress=False)
    assert np.all(dark.image == 0) and dark.nonfinite == 0 and lit.image.max() > 0


@pytest.mark.parametrize("bad, match", [
    (dict(vertices=QUAD * np.nan), "non-finite"),
    (dict(faces=[[0, 1, 7]]), "outside the vertex array"),
    (dict(faces=[[0, 1]]), "shape"),
    (dict(emission=[-1, 0, 0]), "emission"),
    (dict(emission=[np.inf, 0, 0]), "emission"),
])
def test_mesh_validation_names_the_problem(bad, match):
    args = dict(vertices=QUAD, faces=QUAD_FACES, material=mt.diffuse(0.5), name="thing")
    args.update(bad)
    with pytest.raises(ValueError, match=match) as e:
        sc.mesh(**args)
    assert "thing" in str(e.value)


def test_material_and_light_validation():
    with pytest.raises(ValueError, match="albedo"):
        mt.diffuse(1.2)
    with pytest.raises(ValueError):
        lt.point_light([0, 0, 0], [-1.0] * 3)


def test_zero_area_emissive_triangles_warn():
    tri = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    lamp = sc.mesh(tri, [[0, 1, 2], [3, 4, 5]], mt.diffuse(0.0), emission=1.0, name="lamp")
    with pytest.warns(UserWarning, match="zero-area emissive"):
        s = sc.build_scene([lamp], _camera())
    assert s.lights.structure.count("triangle") == 1


def test_no_lights_warns_and_renders_black():
    from jaxrt.rendering.driver import render

    floor = sc.mesh(QUAD, QUAD_FACES, mt.diffuse(0.5))
    with pytest.warns(UserWarning, match="no lights"):
        s = sc.build_scene([floor], _camera(4, 4))
    r = render(s, "mis", spp=2, progress=False)
    assert np.all(r.image == 0)


def test_scene_is_a_pytree_with_static_structure():
    s = scenes.cornell_box(width=8, height=8)
    leaves, treedef = jax.tree.flatten(s)
    assert all(isinstance(x, jax.Array) for x in leaves)
    s2 = jax.tree.unflatten(treedef, leaves)
    assert s2.material_kinds == s.material_kinds


def test_changing_numbers_compiles_nothing():
    """Recompilation guard: a new albedo or radiance re-uses the compiled kernel."""
    from jaxrt.integrators.config import make_estimator
    from jaxrt.integrators.techniques import camera_sample

    est = make_estimator("mis")

    @jax.jit
    def f(scene):
        return camera_sample(scene, est, jnp.int32(5), jnp.uint32(0), jnp.uint32(0))

    s = scenes.cornell_box(width=8, height=8)
    f(s)
    before = f._cache_size()
    brighter = s.replace(materials=s.materials._replace(kd=s.materials.kd * 0.5))
    tri = s.lights.triangle
    relit = s.replace(lights=s.lights.__class__(
        **{**{k: getattr(s.lights, k) for k in lt.KINDS},
           "triangle": tri._replace(radiance=tri.radiance * 2),
           "selection": s.lights.selection, "structure": s.lights.structure}))
    f(brighter)
    f(relit)
    assert f._cache_size() == before
    # a structural change (another BSDF kind) does compile a new program
    f(scenes.cornell_box_glossy(width=8, height=8))
    assert f._cache_size() == before + 1


def test_diffuse_only_scene_compiles_no_glossy_code():
    """Model only what a scene requires: the jaxpr of a diffuse scene has no switch."""
    from jaxrt.integrators.config import make_estimator
    from jaxrt.integrators.techniques import camera_sample

    est = make_estimator("bsdf")
    for build, expect_switch in [(scenes.cornell_box, False), (scenes.cornell_box_glossy, True)]:
        s = build(width=4, height=4)
        jaxpr = jax.make_jaxpr(lambda sc_: camera_sample(sc_, est, jnp.int32(0), jnp.uint32(0),
                                                          jnp.uint32(0)))(s)
        assert ("cond" in str(jaxpr)) == expect_switch


@pytest.mark.parametrize("name", sorted(scenes.BUILTIN))
def test_builtin_scenes_build(name):
    s = scenes.by_name(name, width=16, height=12)
    assert s.width == 16 and s.height == 12
    assert s.lights.structure.num_lights >= 1
    assert np.all(np.isfinite(np.asarray(s.triangles)))


def test_cornell_box_orientation():
    """Walls face the inside, blocks face outwards, the light faces down."""
    meshes = {m.name: m for m in scenes.cornell.cornell_meshes()}
    centre = scenes.cornell.BOX_CENTRE

    def normals(m):
        t = m.vertices[m.faces]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return n / np.linalg.norm(n, axis=1, keepdims=True), t.mean(1)

    for wall in ["floor", "ceiling", "back", "red_wall", "green_wall"]:
        n, c = normals(meshes[wall])
        assert np.all(np.sum(n * (centre - c), axis=1) > 0), wall
    n, _ = normals(meshes["light"])
    assert np.allclose(n, [0, -1, 0], atol=1e-9)
    assert meshes["light"].emission is not None


def test_unknown_builtin_scene():
    with pytest.raises(ValueError, match="cornell_box"):
        scenes.by_name("nope")


def test_intersect_finds_triangles_and_spheres():
    s = scenes.veach_mis(width=8, height=8)
    # straight at the first sphere light from far away
    c = np.asarray(s.lights.sphere.center[0])
    o = jnp.asarray(c + [0, 0, 50.0], s.triangles.dtype)
    d = jnp.asarray([0, 0, -1.0], s.triangles.dtype)
    hit = sq.intersect(s, o, d, jnp.inf)
    assert int(hit.kind) == sq.SPHERE
    assert float(hit.t) == pytest.approx(50 - float(s.lights.sphere.radius[0]), rel=1e-5)
    assert np.allclose(np.asarray(hit.ng), [0, 0, 1], atol=1e-4)
    le = sq.emitted(s, hit, -d)
    assert np.all(np.asarray(le) > 0)
    # and a miss sees the (absent) environment: black
    miss = sq.intersect(s, o, -d, jnp.inf)
    assert int(miss.kind) == sq.MISS
    assert np.all(np.asarray(sq.emitted(s, miss, d)) == 0)


def test_no_warnings_building_builtins():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scenes.cornell_box(width=4, height=4)


def test_lamp_grid_has_many_lamps_facing_down():
    """2 rows² emissive triangles, every lamp facing the floor, the far row 100× the near."""
    s = scenes.lamp_grid(16, 12, rows=6)
    tri = s.lights.table("triangle")
    assert s.lights.structure.count("triangle") == 2 * 6 * 6
    assert np.allclose(np.asarray(tri.normal), [0, -1, 0], atol=1e-6)
    radiance = np.asarray(tri.radiance).max(-1)
    assert np.isclose(radiance.max() / radiance.min(), 100, rtol=1e-5)
    assert scenes.lamp_grid(16, 12).lights.structure.count("triangle") == 1152
    with pytest.raises(ValueError, match="rows"):
        scenes.lamp_grid(rows=0)
