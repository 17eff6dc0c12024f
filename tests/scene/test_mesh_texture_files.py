"""Texture coordinates and texture maps from mesh files: one UV convention for OBJ, PLY, glTF
and GLB (``v`` up), MTL ``map_Kd`` and glTF ``baseColorTexture`` bound to the material's
colour, a scene file's explicit ``textures``/``material`` replacing them, and the errors.

Everything here loads small files (a quad, a 2 × 3 image) and builds scenes without
rendering them: the lookups themselves are tested in tests/scene/test_textures.py.
"""

from __future__ import annotations

import json
import re
import struct
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.visual import TextureVisuals
from trimesh.visual.material import PBRMaterial, SimpleMaterial

from jaxrt.scene import textures as tx
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import FileFormatError, read_png, write_png
from jaxrt.scene.meshio import load_meshes

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
FACES = np.array([[0, 1, 2], [0, 2, 3]])
# dyadic, so that every format stores them exactly (glTF: float32, 1 − v too)
UV = np.array([[0.125, 0.25], [0.75, 0.0625], [0.875, 0.9375], [0.0, 0.5]])
# a 2 × 3 sRGB image, every texel different
RGB8 = np.array([[[200, 10, 30], [0, 255, 128], [17, 34, 51]],
                 [[5, 60, 90], [255, 255, 255], [99, 0, 180]]], np.uint8)
LINEAR = tx.srgb_to_linear(RGB8 / 255.0, xp=np)


def _write_png(path):
    write_png(path, LINEAR, tonemap="srgb")
    assert np.array_equal(read_png(path), RGB8)  # the sRGB round trip is exact


def _by_position(md) -> dict:
    return {tuple(v): tuple(t) for v, t in zip(md.vertices.tolist(), md.uv.tolist(), strict=True)}


def _quad(material=None) -> trimesh.Trimesh:
    visual = TextureVisuals(uv=UV, material=material or SimpleMaterial(name="plain"))
    return trimesh.Trimesh(QUAD, FACES, visual=visual, process=False)


def _glb_json_and_bin(path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    length, _ = struct.unpack("<I4s", data[12:20])
    header = json.loads(data[20:20 + length])
    return header, data[20 + length + 8:]


# ------------------------------------------------------------------ one UV convention


def test_uvs_are_exact_and_agree_across_formats(tmp_path):
    expected = {tuple(v): tuple(t) for v, t in zip(QUAD.tolist(), UV.tolist(), strict=True)}
    for suffix in ("obj", "ply", "glb", "gltf"):
        _quad().export(tmp_path / f"q.{suffix}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # glTF: trimesh's default material, PLY: grey
            (md,) = load_meshes(tmp_path / f"q.{suffix}")
        assert md.uv.dtype == np.float64
        assert _by_position(md) == expected, suffix  # exact, v up, as the OBJ's vt lines


def test_gltf_stores_v_down_and_loads_v_up(tmp_path):
    """glTF's TEXCOORD_0 has (0, 0) at the image's top-left: the file holds 1 − v."""
    _quad().export(tmp_path / "q.glb")
    header, binary = _glb_json_and_bin(tmp_path / "q.glb")
    (prim,) = header["meshes"][0]["primitives"]
    accessor = header["accessors"][prim["attributes"]["TEXCOORD_0"]]
    view = header["bufferViews"][accessor["bufferView"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    stored = np.frombuffer(binary[start:start + 8 * accessor["count"]], np.float32).reshape(-1, 2)
    np.testing.assert_array_equal(stored, np.stack([UV[:, 0], 1 - UV[:, 1]], axis=1))
    (md,) = load_meshes(tmp_path / "q.glb")
    assert _by_position(md) == _by_position(_obj_uv(tmp_path))


def _obj_uv(tmp_path):
    (tmp_path / "vt.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        + "".join(f"vt {u} {v}\n" for u, v in UV) + "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    (md,) = load_meshes(tmp_path / "vt.obj")
    return md


# ------------------------------------------------------------------ MTL map_Kd

OBJ = ("mtllib q.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n"
       "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl skin\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")


def _obj_mtl(tmp_path, map_line="map_Kd textures/albedo.png", obj=OBJ, kd="0.5 0.5 0.5"):
    (tmp_path / "textures").mkdir(exist_ok=True)
    _write_png(tmp_path / "textures" / "albedo.png")
    (tmp_path / "q.mtl").write_text(f"newmtl skin\nKd {kd}\n{map_line}\n")
    (tmp_path / "q.obj").write_text(obj)
    return tmp_path / "q.obj"


def test_map_kd_is_bound_to_kd(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # bound, so no "ignored" warning
        (md,) = load_meshes(_obj_mtl(tmp_path))
    (field, tex), = md.textures.items()
    assert field == "kd" and (tex.wrap, tex.filter, tex.encoding) == ("repeat", "bilinear", "auto")
    assert tex.eight_bit and tex.name == "albedo.png"
    np.testing.assert_array_equal(tx.decoded(tex, "kd"), LINEAR)  # sRGB-decoded
    assert md.material.kd == (0.5, 0.5, 0.5)  # the material keeps its Kd
    assert load_meshes(tmp_path / "q.obj", textures=False)[0].textures is None
    (md,) = load_meshes(_obj_mtl(tmp_path, "map_Kd -clamp on -blendu off textures/albedo.png"))
    assert md.textures["kd"].wrap == "clamp"


def test_map_kd_same_texels_as_gltf_base_colour(tmp_path):
    """The same textured quad as OBJ and GLB binds the same texels at the same UVs."""
    _write_png(tmp_path / "a.png")
    image = Image.open(tmp_path / "a.png")
    _quad(SimpleMaterial(name="skin", image=image, diffuse=[255, 255, 255, 255],
                         specular=[0, 0, 0, 255])).export(tmp_path / "q.obj")
    _quad(PBRMaterial(name="skin", baseColorTexture=image, metallicFactor=0.0,
                      baseColorFactor=[1.0, 1.0, 1.0, 1.0])).export(tmp_path / "q.glb")
    (obj,), (glb,) = load_meshes(tmp_path / "q.obj"), load_meshes(tmp_path / "q.glb")
    assert obj.material.kind == glb.material.kind == "diffuse"
    assert _by_position(obj) == _by_position(glb)
    for md in (obj, glb):
        np.testing.assert_array_equal(tx.decoded(md.textures["kd"], "kd"), LINEAR)


def _scene_doc(tmp_path, mesh_entry):
    doc = {"camera": {"eye": [0, 3, 0], "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30,
                      "width": 8, "height": 8},
           "materials": {"white": {"type": "diffuse", "albedo": 0.5}},
           "meshes": [mesh_entry], "lights": [{"type": "environment", "radiance": 1}]}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    return path


def test_scene_file_binds_map_kd(tmp_path):
    _obj_mtl(tmp_path)
    scene = load_scene(_scene_doc(tmp_path, {"file": "q.obj"}))
    assert scene.textures is not None
    (b,) = scene.textures.bindings
    assert (b.field, b.wrap, b.filter) == ("kd", "repeat", "bilinear")
    np.testing.assert_allclose(np.asarray(scene.textures.texels[b.texture]), LINEAR,
                               rtol=1e-6 if scene.textures.texels[0].dtype == np.float32 else 0)


def test_explicit_textures_and_materials_replace_map_kd(tmp_path):
    _obj_mtl(tmp_path)
    (tmp_path / "textures" / "albedo.png").unlink()  # never read: no error
    other = np.full((1, 1, 3), 0.25)
    from jaxrt.scene.images import write_exr

    write_exr(tmp_path / "other.exr", other.astype(np.float32))
    scene = load_scene(_scene_doc(tmp_path, {"file": "q.obj", "textures": {"kd": "other.exr"}}))
    (b,) = scene.textures.bindings
    np.testing.assert_array_equal(np.asarray(scene.textures.texels[b.texture]), other)
    assert load_scene(_scene_doc(tmp_path, {"file": "q.obj", "textures": {}})).textures is None
    assert load_scene(_scene_doc(tmp_path, {"file": "q.obj", "material": "white"})).textures \
        is None
    with pytest.raises(FileNotFoundError):  # but the file's own map is read, and missing
        load_scene(_scene_doc(tmp_path, {"file": "q.obj"}))


# ------------------------------------------------------------------ errors


@pytest.mark.parametrize("case, error, message", [
    ("missing", FileNotFoundError,
     r"q\.obj: material 'skin' \(.*q\.mtl:3: map_Kd nope\.png\): texture image not found"),
    ("no_vt", FileFormatError,
     r"q\.obj: material 'skin' \(.*q\.mtl:3: map_Kd .*\): the mesh has no texture coordinates"),
    ("scale", FileFormatError, r"q\.mtl:3: material 'skin': map_Kd option -s 2 2 is not modelled"),
    ("mirror", FileFormatError, r"q\.obj: material 'skin' .*: a mirror material .* has no kd"),
])
def test_map_kd_errors_name_the_file_and_material(tmp_path, case, error, message):
    obj = OBJ
    if case == "no_vt":
        obj = OBJ.replace("vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n", "")
        for k in "1234":
            obj = obj.replace(f"/{k}", "")
    map_line = {"missing": "map_Kd nope.png",
                "scale": "map_Kd -s 2 2 textures/albedo.png"}.get(case,
                                                                 "map_Kd textures/albedo.png")
    kd = "0 0 0\nKs 0.9 0.9 0.9\nillum 3" if case == "mirror" else "0.5 0.5 0.5"
    path = _obj_mtl(tmp_path, map_line, obj, kd)
    with pytest.raises(error, match=message):
        load_meshes(path)
    if error is FileFormatError:
        assert issubclass(error, ValueError)
    with pytest.raises(error, match=message):  # the scene file passes it on
        load_scene(_scene_doc(tmp_path, {"file": "q.obj"}))
    load_meshes(path, textures=False)  # nothing read: no error


@pytest.mark.parametrize("image", ["albedo.jpg", "albedo.TGA", "textures/albedo.bmp"])
def test_map_kd_not_png_or_exr_warns_and_loads_untextured(tmp_path, image):
    # a downloaded OBJ's JPEG (TGA, BMP) map_Kd: the mesh loads with its Kd, and a warning
    path = _obj_mtl(tmp_path, f"map_Kd {image}")
    (tmp_path / image).write_bytes(b"\xff\xd8\xff")  # never read
    message = (rf"q\.obj: material 'skin' \(.*q\.mtl:3: map_Kd {re.escape(image)}\): only PNG "
               r"and EXR images are read.*the material's Kd is used.*convert the image to PNG")
    with pytest.warns(UserWarning, match=message):
        (md,) = load_meshes(path)
    assert md.textures is None and md.uv is not None
    assert md.material.kind == "diffuse" and md.material.kd == (0.5, 0.5, 0.5)
    with pytest.warns(UserWarning, match=message):  # the scene file passes it on
        scene = load_scene(_scene_doc(tmp_path, {"file": "q.obj"}))
    assert scene.textures is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_meshes(path, textures=False)[0].textures is None  # not even looked at
    (tmp_path / image).unlink()
    with pytest.raises(FileNotFoundError, match=r"q\.obj: material 'skin' .*texture image not "
                       "found"):  # a missing image is still an error, whatever its format
        load_meshes(path)


# ------------------------------------------------------------------ glTF baseColorTexture


def _textured_gltf(tmp_path, suffix="glb", factor=(1.0, 1.0, 1.0, 1.0), metallic=0.0):
    _write_png(tmp_path / "a.png")
    material = PBRMaterial(name="skin", baseColorTexture=Image.open(tmp_path / "a.png"),
                           metallicFactor=metallic, roughnessFactor=0.5,
                           baseColorFactor=list(factor))
    _quad(material).export(tmp_path / f"q.{suffix}")
    return tmp_path / f"q.{suffix}"


@pytest.mark.parametrize("suffix", ["glb", "gltf"])
def test_gltf_base_colour_texture(tmp_path, suffix):
    # trimesh keeps factors in 8 bits: these survive exactly (51 / 255, 102 / 255)
    (md,) = load_meshes(_textured_gltf(tmp_path, suffix, factor=(0.2, 1.0, 0.4, 1.0)))
    tex = md.textures["kd"]
    assert tex.encoding == "linear"  # the factor multiplies the decoded texels
    np.testing.assert_allclose(tx.decoded(tex, "kd"), LINEAR * [0.2, 1.0, 0.4], rtol=1e-12)
    (md,) = load_meshes(_textured_gltf(tmp_path, suffix, metallic=1.0))
    assert md.material.kind == "conductor" and list(md.textures) == ["ks"]
    np.testing.assert_array_equal(tx.decoded(md.textures["ks"], "ks"), LINEAR)
    assert load_meshes(tmp_path / f"q.{suffix}", textures=False)[0].textures is None
    scene = load_scene(_scene_doc(tmp_path, {"file": f"q.{suffix}"}))
    assert [b.field for b in scene.textures.bindings] == ["ks"]


def test_gltf_texture_errors(tmp_path):
    path = _textured_gltf(tmp_path, "gltf")
    doc = json.loads(path.read_text())
    doc["images"] = [{"uri": "a.png"}]  # an external image (trimesh embeds it)
    path.write_text(json.dumps(doc))
    np.testing.assert_array_equal(tx.decoded(load_meshes(path)[0].textures["kd"], "kd"), LINEAR)
    doc["samplers"] = [{"wrapS": 33648, "wrapT": 33648}]
    doc["textures"][0]["sampler"] = 0
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=r"material 'skin': baseColorTexture: sampler "
                                              r"wrap modes \[33648\] are not modelled"):
        load_meshes(path)
    doc["samplers"] = [{"wrapS": 33071, "wrapT": 33071, "magFilter": 9728}]
    path.write_text(json.dumps(doc))
    tex = load_meshes(path)[0].textures["kd"]
    assert (tex.wrap, tex.filter) == ("clamp", "nearest")
    doc["textures"][0]["extensions"] = {}
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] = 1
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match="baseColorTexture: texCoord 1 is not modelled"):
        load_meshes(path)
    del doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"]
    path.write_text(json.dumps(doc))
    (tmp_path / "a.png").unlink()
    with pytest.raises(FileFormatError, match=r"material 'skin': baseColorTexture: trimesh "
                                              r"could not read the image 'a\.png'"):
        load_meshes(path)
