"""jaxrt.scene.file.load_scene: valid documents build the scene they describe, and every
malformed document fails with an error that names the FILE and the ENTRY at fault.

Only host-side scene construction runs here (no rendering, no compilation): fast.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from jaxrt.scene import materials as mt
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import FileFormatError, write_exr

DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
QUAD_V = [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]
QUAD_F = [[0, 2, 1], [0, 3, 2]]  # faces +y
CAMERA = {"eye": [0, 1, 4], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40,
          "width": 12, "height": 10}


def _doc(**changes) -> dict:
    """A minimal valid document (one inline quad, one point light) with some keys replaced."""
    doc = {"camera": dict(CAMERA),
           "materials": {"white": {"type": "diffuse", "albedo": 0.7}},
           "meshes": [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"}],
           "lights": [{"type": "point", "position": [0, 2, 0], "intensity": 5}]}
    doc.update(changes)
    return doc


def _write(tmp_path: Path, doc, name: str = "scene.json") -> Path:
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc), encoding="utf-8")
    return path


def _tris(scene) -> np.ndarray:
    return np.asarray(scene.triangles, np.float64)


# ---------------------------------------------------------------------------------------------
# valid documents
# ---------------------------------------------------------------------------------------------


def test_minimal_inline_mesh(tmp_path):
    scene = load_scene(_write(tmp_path, _doc()), accel="brute")
    assert (scene.width, scene.height) == (12, 10)  # camera width/height from the file
    assert scene.num_triangles == 2
    # brute force keeps mesh order: the triangles are the quad's faces, vertex for vertex
    # (float32 storage: 1e-6 relative is a few ulps of coordinates of size 1)
    np.testing.assert_allclose(_tris(scene), np.asarray(QUAD_V)[np.asarray(QUAD_F)], atol=1e-6)
    assert scene.lights.structure.count("point") == 1
    assert scene.material_kinds == (mt.DIFFUSE,)
    # albedo 0.7 reaches the material table exactly up to float32 rounding
    np.testing.assert_allclose(np.asarray(scene.materials.kd)[0], [0.7] * 3, rtol=1e-6)


def test_every_material_and_light_type(tmp_path):
    env = np.full((4, 8, 3), 0.25, np.float32)
    write_exr(tmp_path / "sky.exr", env)
    doc = _doc(
        materials={"d": {"type": "diffuse", "albedo": [0.2, 0.4, 0.6]},
                   "p": {"type": "phong", "kd": 0.5, "ks": 0.3, "exponent": 40},
                   "c": {"type": "conductor", "alpha": 0.1, "ks": [1.0, 0.78, 0.34]},
                   "m": {"type": "mirror", "ks": 0.9}},
        meshes=[{"vertices": QUAD_V, "faces": QUAD_F, "material": k,
                 "transform": {"translate": [0, i, 0]}} for i, k in enumerate("dpcm")],
        lights=[{"type": "point", "position": [0, 2, 0], "intensity": 10},
                {"type": "spot", "position": [0, 3, 0], "axis": [0, -1, 0], "intensity": 10,
                 "inner_angle": 20, "outer_angle": 30},
                {"type": "directional", "direction": [0, 1, 0], "irradiance": 3},
                {"type": "sphere", "center": [1, 2, 0], "radius": 0.1, "radiance": 50},
                {"type": "environment", "file": "sky.exr", "scale": 2.0}])
    scene = load_scene(_write(tmp_path, doc), accel="brute")
    s = scene.lights.structure
    for kind in ("point", "spot", "directional", "sphere"):
        assert s.count(kind) == 1, kind  # exactly the one light of each kind written
    assert s.environment == "map"
    assert scene.material_kinds == tuple(sorted((mt.DIFFUSE, mt.PHONG, mt.CONDUCTOR, mt.MIRROR)))
    m = scene.materials
    # material parameters reach the table (float32 rounding: rtol 1e-6)
    np.testing.assert_allclose(np.asarray(m.kd)[0], [0.2, 0.4, 0.6], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(m.exponent)[1], 40, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(m.alpha)[2], 0.1, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(m.ks)[3], [0.9] * 3, rtol=1e-6)
    # the env map keeps its texels times "scale" (0.25 × 2; float32 exact)
    np.testing.assert_allclose(np.asarray(scene.lights.environment.image).max(), 0.5, rtol=1e-6)
    # the spot's angles are degrees in the file and must not be read as radians: cos(30°)
    sp = scene.lights.spot
    cos_fields = [np.asarray(getattr(sp, f)).ravel()[0] for f in sp._fields if "cos" in f]
    assert cos_fields and min(abs(c - np.cos(np.radians(30))) for c in cos_fields) < 1e-6


def test_constant_environment_and_rgb_scalars(tmp_path):
    doc = _doc(lights=[{"type": "environment", "radiance": [0.1, 0.2, 0.3]}])
    scene = load_scene(_write(tmp_path, doc))
    assert scene.lights.structure.environment == "constant"
    # the RGB triple is stored as given (float32: rtol 1e-6)
    np.testing.assert_allclose(np.asarray(scene.lights.environment.radiance).ravel(),
                               [0.1, 0.2, 0.3], rtol=1e-6)


def test_transform_scale_rotate_translate(tmp_path):
    t = {"scale": 2.0, "rotate": [0, 1, 0, 90], "translate": [0, 1, 0]}
    doc = _doc(meshes=[{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
                        "transform": t}])
    scene = load_scene(_write(tmp_path, doc), accel="brute")
    v = np.asarray(QUAD_V, np.float64) * 2.0
    # right-handed rotation by +90° about +y maps (x, y, z) to (z, y, −x)
    v = np.stack([v[:, 2], v[:, 1], -v[:, 0]], axis=1) + [0, 1, 0]
    # float32 storage of coordinates of size ≤ 3: 1e-6 absolute
    np.testing.assert_allclose(_tris(scene), v[np.asarray(QUAD_F)], atol=1e-6)


def test_inline_emissive_mesh_becomes_triangle_lights(tmp_path):
    doc = _doc(meshes=[{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"},
                       {"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
                        "emission": [4, 5, 6], "two_sided_emission": True,
                        "transform": {"translate": [0, 2, 0]}}], lights=[])
    scene = load_scene(_write(tmp_path, doc), accel="brute")
    tri = scene.lights.triangle
    assert scene.lights.structure.count("triangle") == 2  # the emissive quad only
    np.testing.assert_array_equal(np.asarray(tri.prim), [2, 3])  # its prims, after the floor
    np.testing.assert_allclose(np.asarray(tri.radiance), [[4, 5, 6]] * 2, rtol=1e-6)
    assert np.asarray(tri.two_sided).all()
    np.testing.assert_array_equal(np.asarray(scene.prim_light) >= 0, [False, False, True, True])


def test_obj_with_emissive_ke_material(tmp_path):
    """The example OBJ: Ke in the MTL makes the lamp an emitter, Kd/Ks/Ns pick the BSDFs."""
    scene = load_scene(DATA / "scene.json", accel="brute")
    s = scene.lights.structure
    assert s.count("triangle") == 2 and s.count("sphere") == 1  # lamp quad + one sphere
    # Ke 12 11 9 from room.mtl, exactly (float32)
    np.testing.assert_allclose(np.asarray(scene.lights.triangle.radiance), [[12, 11, 9]] * 2,
                               rtol=1e-6)
    # the lamp is the plane y = 1.9 and faces down (its winding gives normal −y)
    lamp = _tris(scene)[np.asarray(scene.lights.triangle.prim)]
    np.testing.assert_allclose(lamp[..., 1], 1.9, atol=1e-6)
    n = np.cross(lamp[:, 1] - lamp[:, 0], lamp[:, 2] - lamp[:, 0])
    assert np.all(n[:, 1] < 0)
    # room.obj: lamp 2 + red block 10 + white 4 triangles, plus the inline 2-triangle wall
    assert scene.num_triangles == 18
    assert set(scene.material_kinds) == {mt.DIFFUSE, mt.PHONG}  # red has Ks > 0: Phong


def test_obj_material_override_and_emission_override(tmp_path):
    shutil.copy(DATA / "room.obj", tmp_path)
    shutil.copy(DATA / "room.mtl", tmp_path)
    doc = _doc(meshes=[{"file": "room.obj", "material": "white", "emission": 0.0}],
               lights=[{"type": "point", "position": [0, 1, 0], "intensity": 1}])
    scene = load_scene(_write(tmp_path, doc))
    # the override replaces every file material, and emission 0 switches the lamp off: every
    # triangle of the mesh is a declared light (the structure follows the declaration, so a
    # sweep through 0 compiles once) that emits nothing
    assert scene.material_kinds == (mt.DIFFUSE,)
    assert scene.lights.structure.count("triangle") == 16
    assert np.all(np.asarray(scene.lights.triangle.radiance) == 0)


def test_overrides_width_height_accel(tmp_path):
    path = _write(tmp_path, _doc(options={"accel": "brute"}))
    base = load_scene(path)
    assert (base.width, base.height) == (12, 10)
    over = load_scene(path, width=7, height=5, accel="bvh")
    assert (over.width, over.height) == (7, 5)  # the arguments beat the file's camera
    assert type(base.geometry).__name__ == "TriangleSet"  # file option honoured
    assert type(over.geometry).__name__ == "BVH"  # argument beats the file's option


def test_paths_are_relative_to_the_file(tmp_path, monkeypatch):
    sub = tmp_path / "deep" / "dir"
    sub.mkdir(parents=True)
    shutil.copy(DATA / "room.obj", sub)
    shutil.copy(DATA / "room.mtl", sub)
    path = _write(sub, _doc(meshes=[{"file": "room.obj"}]))
    monkeypatch.chdir(tmp_path)  # the working directory must not matter
    assert load_scene(path).num_triangles == 16


# ---------------------------------------------------------------------------------------------
# malformed documents: the error names the file and the entry
# ---------------------------------------------------------------------------------------------


def _expect(tmp_path, doc, *needles, exc=FileFormatError):
    path = _write(tmp_path, doc)
    with pytest.raises(exc) as info:
        load_scene(path)
    msg = str(info.value)
    assert str(path) in msg, msg  # names the file
    for needle in needles:
        assert needle in msg, msg  # names the entry (and the problem)
    return msg


def test_invalid_json(tmp_path):
    _expect(tmp_path, '{"camera": {"eye": [0, 1, 4],,}', "not valid JSON", "line 1")


def test_top_level_not_an_object(tmp_path):
    _expect(tmp_path, "[1, 2, 3]", "top level")


@pytest.mark.parametrize("key", ["meshes", "camera"])
def test_missing_top_level_key(tmp_path, key):
    doc = _doc()
    del doc[key]
    _expect(tmp_path, doc, "top level", repr(key))


def test_missing_camera_eye(tmp_path):
    cam = dict(CAMERA)
    del cam["eye"]
    _expect(tmp_path, _doc(camera=cam), "camera", "'eye'")


def test_empty_meshes(tmp_path):
    _expect(tmp_path, _doc(meshes=[]), "meshes", "non-empty")


def test_missing_inline_faces(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"},
              {"vertices": QUAD_V, "material": "white"}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[1]", "'faces'")


def test_inline_mesh_without_material(tmp_path):
    _expect(tmp_path, _doc(meshes=[{"vertices": QUAD_V, "faces": QUAD_F}]), "meshes[0]",
            "material")


def test_missing_material_parameter(tmp_path):
    _expect(tmp_path, _doc(materials={"white": {"type": "phong", "kd": 0.5, "ks": 0.1}}),
            "materials.white", "'exponent'")


def test_missing_light_key(tmp_path):
    lights = [{"type": "point", "position": [0, 2, 0], "intensity": 1},
              {"type": "sphere", "center": [0, 2, 0], "radiance": 1}]
    _expect(tmp_path, _doc(lights=lights), "lights[1]", "'radius'")


def test_unknown_material_type(tmp_path):
    _expect(tmp_path, _doc(materials={"white": {"type": "velvet"}}), "materials.white",
            "'velvet'")


def test_unknown_light_type(tmp_path):
    lights = [{"type": "point", "position": [0, 2, 0], "intensity": 1}, {"type": "laser"}]
    _expect(tmp_path, _doc(lights=lights), "lights[1]", "'laser'")


def test_unknown_material_reference(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"},
              {"vertices": QUAD_V, "faces": QUAD_F, "material": "gold"}]
    msg = _expect(tmp_path, _doc(meshes=meshes), "meshes[1].material", "'gold'")
    assert "white" in msg  # lists what is defined


def test_bad_transform_value(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
               "transform": {"translate": [0, "up", 0]}}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[0].transform")


def test_bad_rotate_length(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
               "transform": {"rotate": [0, 1, 0]}}]
    msg = _expect(tmp_path, _doc(meshes=meshes), "meshes[0].transform", "rotate")
    # the file is named once, not once per re-wrapping layer
    assert msg.count(str(tmp_path / "scene.json")) == 1, msg


def test_transform_not_an_object(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
               "transform": [1, 0, 0]}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[0].transform")


def test_mesh_entry_not_an_object(tmp_path):
    _expect(tmp_path, _doc(meshes=["room.obj"]), "meshes[0]")


def test_missing_mesh_file(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"},
              {"file": "nowhere.obj"}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[1]", "nowhere.obj",
            exc=(FileFormatError, FileNotFoundError))


def test_missing_environment_file(tmp_path):
    _expect(tmp_path, _doc(lights=[{"type": "environment", "file": "sky.exr"}]), "lights[0]",
            "sky.exr", exc=(FileFormatError, FileNotFoundError))


def test_missing_scene_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_scene(tmp_path / "absent.json")


def test_face_index_out_of_range(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": [[0, 1, 9]], "material": "white"}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[0]")


@pytest.mark.parametrize("light", [
    {"type": "sphere", "center": [0, 2, 0], "radius": 0.1, "radiance": -1},
    {"type": "point", "position": [0, 2, 0], "intensity": [1, -1, 1]},
    {"type": "environment", "radiance": -0.5},
], ids=["sphere", "point", "environment"])
def test_negative_light_radiance(tmp_path, light):
    lights = [{"type": "point", "position": [0, 2, 0], "intensity": 1}, light]
    _expect(tmp_path, _doc(lights=lights), "lights[1]")


def test_negative_mesh_emission(tmp_path):
    meshes = [{"vertices": QUAD_V, "faces": QUAD_F, "material": "white"},
              {"vertices": QUAD_V, "faces": QUAD_F, "material": "white", "emission": -2}]
    _expect(tmp_path, _doc(meshes=meshes), "meshes[1]")


def test_bad_material_value(tmp_path):
    # albedo above 1 breaks energy conservation: rejected, naming the material
    _expect(tmp_path, _doc(materials={"white": {"type": "diffuse", "albedo": 1.5}}),
            "materials.white")


def test_bad_camera_value(tmp_path):
    cam = dict(CAMERA, fov="wide")
    _expect(tmp_path, _doc(camera=cam), "camera")


def test_bad_option(tmp_path):
    _expect(tmp_path, _doc(options={"accel": "octree"}), "octree")


# ---------------------------------------------------------------------------------------------
# almost-right documents: typos are errors with a suggestion, never silently dropped
# ---------------------------------------------------------------------------------------------

TYPOS = {
    "mesh-transfrom": (lambda d: d["meshes"][0].update(transfrom={"scale": 2}),
                       "meshes[0]", "transfrom", "transform"),
    "top-light": (lambda d: d.update(light=d.pop("lights")), "top level", "light", "lights"),
    "camera-fvo": (lambda d: d["camera"].update(fvo=30), "camera", "fvo", "fov"),
    "mesh-emision": (lambda d: d["meshes"][0].update(emision=[1, 1, 1]), "meshes[0]",
                     "emision", "emission"),
    "options-acel": (lambda d: d.update(options={"acel": "bvh"}), "options", "acel", "accel"),
    "material-albdo": (lambda d: d["materials"]["white"].update(albdo=0.5),
                       "materials.white", "albdo", "albedo"),
    "light-positon": (lambda d: d["lights"][0].update(positon=[0, 1, 0]), "lights[0]",
                      "positon", "position"),
    "transform-rotation": (lambda d: d["meshes"][0].update(
        transform={"rotation": [0, 1, 0, 90]}), "meshes[0].transform", "rotation", "rotate"),
}


@pytest.mark.parametrize("case", list(TYPOS))
def test_unknown_keys_are_rejected_with_a_suggestion(tmp_path, case):
    """Typos in keys rendered with exit code 0 and the setting dropped."""
    edit, where, key, suggestion = TYPOS[case]
    doc = _doc()
    edit(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(FileFormatError) as info:
        load_scene(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {where}: unknown key {key!r} "
                          f"(did you mean {suggestion!r}?)"), msg


def test_unknown_key_without_a_close_match_lists_the_allowed(tmp_path):
    doc = _doc()
    doc["camera"]["zzzz"] = 1
    with pytest.raises(FileFormatError, match=r"camera: unknown key 'zzzz'; allowed: eye, "):
        load_scene(_write(tmp_path, doc))


def test_underscore_keys_are_comments(tmp_path):
    doc = _doc(_note="a comment")
    doc["camera"]["_why"] = "wide"
    doc["materials"]["_comment"] = "ignored"
    doc["meshes"][0]["_source"] = "hand-made"
    assert load_scene(_write(tmp_path, doc)).width == 12


@pytest.mark.parametrize("doc, where", [
    (_doc(materials={"grey": {"type": "diffuse"}}), "materials.grey"),
    (_doc(camera={"target": [0, 0, 0]}), "camera"),
])
def test_error_prefix_is_not_doubled(tmp_path, doc, where):
    """It read ``typo_matkey.json: materials.grey: typo_matkey.json: materials.grey: ...``."""
    path = _write(tmp_path, doc, "typo_matkey.json")
    with pytest.raises(FileFormatError) as info:
        load_scene(path)
    msg = str(info.value)
    assert msg.count(str(path)) == 1 and msg.count(f"{where}:") == 1, msg
    assert "missing required key" in msg


def test_build_warnings_name_the_file_and_point_at_the_caller(tmp_path):
    """A zero-area emissive triangle warns (docs/scenes.md); the warning names the scene
    file and is attributed to the line that called load_scene, not to jaxrt's source."""
    v = QUAD_V + [[0, 1, 0], [0, 1, 0], [1, 1, 0]]
    mesh = {"vertices": v, "faces": QUAD_F + [[4, 5, 6]], "material": "white",
            "emission": [1, 1, 1], "name": "lamp"}
    path = _write(tmp_path, _doc(meshes=[mesh]))
    with pytest.warns(UserWarning) as record:
        scene = load_scene(path)
    msgs = [str(w.message) for w in record]
    assert any(m.startswith(f"{path}: mesh 'lamp': 1 zero-area emissive") for m in msgs), msgs
    assert all(w.filename == __file__ for w in record), [w.filename for w in record]
    assert scene.num_triangles == 3


def test_declared_zero_emission_stays_a_light(tmp_path):
    lit = _doc(meshes=[{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
                        "emission": 1.0}])
    dark = _doc(meshes=[{"vertices": QUAD_V, "faces": QUAD_F, "material": "white",
                         "emission": 0.0}])
    a = load_scene(_write(tmp_path, lit, "lit.json")).lights.structure
    b = load_scene(_write(tmp_path, dark, "dark.json")).lights.structure
    assert a == b


def test_file_materials_without_ke_do_not_emit(tmp_path):
    shutil.copy(DATA / "room.obj", tmp_path)
    shutil.copy(DATA / "room.mtl", tmp_path)
    scene = load_scene(_write(tmp_path, _doc(meshes=[{"file": "room.obj"}])))
    # only the Ke lamp (2 triangles) became lights, beside the document's point light
    assert scene.lights.structure.counts == (1, 0, 0, 2, 0, 0)


def test_conductor_fresnel_and_masking_options(tmp_path):
    """Mitsuba 3's roughconductor (F = ks, separable G1·G1) is expressible in a scene file;
    a bad choice names the entry."""
    doc = _doc()
    doc["materials"]["cu"] = {"type": "conductor", "alpha": 0.2, "ks": 0.9, "fresnel": "none",
                              "masking": "separable"}
    doc["meshes"][0]["material"] = "cu"
    scene = load_scene(_write(tmp_path, doc))
    row = int(np.flatnonzero(np.asarray(scene.materials.kind) == mt.CONDUCTOR)[0])
    assert float(scene.materials.fresnel_schlick[row]) == 0.0
    assert float(scene.materials.masking_separable[row]) == 1.0
    doc["materials"]["cu"]["masking"] = "uncorrelated"
    with pytest.raises(ValueError, match="materials.cu.*masking"):
        load_scene(_write(tmp_path, doc, "bad.json"))
