"""Mesh loading: OBJ+MTL, PLY and glTF/GLB written in tmp_path, materials, transforms, bad input."""

import json
import struct
import warnings

import numpy as np
import pytest
import trimesh
from trimesh.visual import TextureVisuals
from trimesh.visual.material import PBRMaterial

from jaxrt.scene.images import FileFormatError
from jaxrt.scene.meshio import MaterialSpec, MeshData, load_meshes

OBJ = """\
mtllib scene.mtl
o floor
v 0 0 0
v 2 0 0
v 2 0 2
v 0 0 2
usemtl white
f 1 2 3 4
o lamp
v 0.5 1.9 0.5
v 1.5 1.9 0.5
v 1.5 1.9 1.5
usemtl light
f 7 6 5
o block
v 0 0.5 0
v 0.2 0.5 0
v 0 0.7 0
usemtl white
f 8 9 10
o shiny
v 0 0 0
v 0 1 0
v 0 0 1
usemtl glossy
f 11 12 13
o bright
v 1 0 0
v 1 1 0
v 1 0 1
usemtl toobright
f 14 15 16
o silver
v 2 0 0
v 2 1 0
v 2 0 1
usemtl silver
f 17 18 19
usemtl glass
f 17 19 18
"""

MTL = """\
# a comment line
newmtl white
Kd 0.7 0.6 0.5
Ks 0 0 0
newmtl light
Kd 0 0 0
Ke 10 10 10
newmtl glossy
Kd 0.5 0.5 0.5
Ks 0.25 0.25 0.25
Ns 50
newmtl toobright
Kd 0.8 0.8 0.8
Ks 0.5 0.5 0.5
Ns 10
newmtl silver
Kd 0 0 0
Ks 0.9 0.9 0.9
illum 3
newmtl glass
Kd 0.2 0.2 0.2
d 0.5
"""


def _by_name(meshes):
    names = [m.name for m in meshes]
    assert len(set(names)) == len(names), names
    return {m.name: m for m in meshes}


def _triangles(mesh: MeshData) -> set:
    """The set of triangles as tuples of vertex positions (independent of indexing/order)."""
    return {tuple(map(tuple, mesh.vertices[f])) for f in mesh.faces}


@pytest.fixture(scope="module")
def obj_meshes(tmp_path_factory):
    root = tmp_path_factory.mktemp("obj")
    (root / "scene.obj").write_text(OBJ)
    (root / "scene.mtl").write_text(MTL)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        meshes = load_meshes(root / "scene.obj")
    # exactly the two expected warnings (energy rescale, ignored transparency), nothing else
    assert len(record) == 2, [str(w.message) for w in record]
    return _by_name(meshes), record


def test_obj_geometry_grouped_by_material(obj_meshes):
    meshes, _ = obj_meshes
    assert set(meshes) == {"white", "light", "glossy", "toobright", "silver", "glass"}
    for m in meshes.values():
        assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32
        assert m.vertices.ndim == 2 and m.vertices.shape[1] == 3 and m.faces.shape[1] == 3
        assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    # floor quad (2 triangles after triangulation) + block triangle share "white"
    white = meshes["white"]
    assert len(white.vertices) == 7 and len(white.faces) == 3
    f32 = np.float32
    block = ((0, 0.5, 0), (0.2, 0.5, 0), (0, 0.7, 0))
    assert tuple(tuple(map(f32, v)) for v in block) in _triangles(white)
    # the quad's two triangles keep its winding (counter-clockwise seen from -y) and cover its
    # area 4: the cross products sum to 2 × 4 along -y, exactly (small integers)
    p = white.vertices[white.faces].astype(np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    floor = np.abs(n[:, 1]) > 0
    assert floor.sum() == 2
    np.testing.assert_array_equal(n[floor].sum(axis=0), [0, -8, 0])
    # lamp: one triangle with the winding as written (7 6 5)
    lamp = meshes["light"]
    assert len(lamp.vertices) == 3 and len(lamp.faces) == 1
    np.testing.assert_array_equal(
        lamp.vertices[lamp.faces[0]],
        np.float32([[1.5, 1.9, 1.5], [1.5, 1.9, 0.5], [0.5, 1.9, 0.5]]),
    )


def test_obj_materials(obj_meshes):
    meshes, record = obj_meshes
    assert meshes["white"].material == MaterialSpec("diffuse", kd=(0.7, 0.6, 0.5))
    light = meshes["light"].material
    assert light.emission == (10.0, 10.0, 10.0) and light.is_emitter
    assert light.kd == (0.0, 0.0, 0.0) and not light.two_sided_emission
    assert not meshes["white"].material.is_emitter
    glossy = meshes["glossy"].material
    assert glossy == MaterialSpec("phong", kd=(0.5,) * 3, ks=(0.25,) * 3, exponent=50.0)
    # 0.8 + 0.5 = 1.3 > 1: both scaled by 1/1.3, exactly one warning for it
    bright = meshes["toobright"].material
    np.testing.assert_allclose(bright.kd, [0.8 / 1.3] * 3, rtol=1e-15)
    np.testing.assert_allclose(bright.ks, [0.5 / 1.3] * 3, rtol=1e-15)
    assert max(np.add(bright.kd, bright.ks)) <= 1 + 1e-12
    assert sum("kd + ks = 1.3 > 1" in str(w.message) for w in record) == 1
    assert meshes["silver"].material == MaterialSpec("mirror", kd=(0, 0, 0), ks=(0.9,) * 3)
    # dissolve d = 0.5 is not modelled: opaque diffuse, and said so
    assert meshes["glass"].material == MaterialSpec("diffuse", kd=(0.2,) * 3)
    assert sum("transparency" in str(w.message) for w in record) == 1


def test_obj_without_mtl_is_grey_diffuse(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (mesh,) = load_meshes(tmp_path / "t.obj")
    assert mesh.material == MaterialSpec("diffuse", kd=(0.5, 0.5, 0.5))
    assert mesh.faces.tolist() == [[0, 1, 2]]


def test_obj_degenerate_faces_removed_with_count(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 3\n"
    (tmp_path / "d.obj").write_text(text)
    with pytest.warns(UserWarning, match=r"2 degenerate triangle\(s\) \(zero area\) of 3"):
        (mesh,) = load_meshes(tmp_path / "d.obj")
    assert len(mesh.faces) == 1
    (tmp_path / "all.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.warns(UserWarning), pytest.raises(FileFormatError, match="every triangle"):
        load_meshes(tmp_path / "all.obj")


@pytest.mark.parametrize(
    "mtl, match",
    [("Kd 0 0 0\nKe -1 2 2\n", "negative emission"), ("Ke a b c\n", "cannot read Ke")],
    ids=["negative-Ke", "garbage-Ke"],
)
def test_obj_bad_material_values(tmp_path, mtl, match):
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl x\nf 1 2 3\n")
    (tmp_path / "m.mtl").write_text("newmtl x\n" + mtl)
    with pytest.raises(FileFormatError, match=f"m.obj.*material 'x'.*{match}"):
        load_meshes(tmp_path / "m.obj")


# ---------------------------------------------------------------------------------------------
# PLY
# ---------------------------------------------------------------------------------------------


def test_ply_plain_and_coloured(tmp_path):
    box = trimesh.creation.box(extents=(1, 2, 3))
    box.export(tmp_path / "plain.ply")
    (mesh,) = load_meshes(tmp_path / "plain.ply")
    assert mesh.vertices.shape == (8, 3) and mesh.faces.shape == (12, 3)
    np.testing.assert_array_equal(mesh.vertices, box.vertices.astype(np.float32))
    np.testing.assert_array_equal(mesh.faces, box.faces)
    assert mesh.material == MaterialSpec()  # grey diffuse 0.5
    # uniform sRGB 128 → linear ((128/255 + 0.055)/1.055)^2.4 = 0.2158605
    box.visual.vertex_colors = np.tile([128, 128, 128, 255], (8, 1))
    box.export(tmp_path / "grey.ply")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # uniform colours: no averaging warning
        (grey,) = load_meshes(tmp_path / "grey.ply")
    np.testing.assert_allclose(grey.material.kd, [0.2158605] * 3, rtol=1e-6)
    colours = np.tile([255, 0, 0, 255], (8, 1))
    colours[4:] = [0, 0, 255, 255]
    box.visual.vertex_colors = colours
    box.export(tmp_path / "rb.ply")
    with pytest.warns(UserWarning, match="colours averaged"):
        (rb,) = load_meshes(tmp_path / "rb.ply")
    np.testing.assert_allclose(rb.material.kd, [0.5, 0.0, 0.5], rtol=1e-12)


PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
)


@pytest.mark.parametrize(
    "body, faces, match",
    [
        ("0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", 1, r"mesh .*1 face\(s\) index outside \[0, 3\)"),
        ("0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", 1, r"mesh .*1 vertex position\(s\) are NaN"),
        ("0 0 0\ninf 0 0\n0 1 0\n3 0 1 2\n", 1, r"NaN or infinite"),
        ("0 0 0\n1 0 0\n0 1 0\n", 0, r"no triangle meshes"),
    ],
    ids=["face-out-of-range", "nan-vertex", "inf-vertex", "no-faces"],
)
def test_ply_bad_geometry(tmp_path, body, faces, match):
    path = tmp_path / "bad.ply"
    path.write_text(PLY_HEADER.format(faces=faces) + body)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a face-less PLY is a point cloud: skipped with a warning
        with pytest.raises(FileFormatError, match=r"bad\.ply.*" + match):
            load_meshes(path)


# ---------------------------------------------------------------------------------------------
# glTF / GLB
# ---------------------------------------------------------------------------------------------


def _pbr_scene():
    lamp = trimesh.creation.box(extents=(1, 0.1, 1))
    lamp.visual = TextureVisuals(
        material=PBRMaterial(
            name="lamp",
            baseColorFactor=[0.2, 0.3, 0.4, 1.0],
            emissiveFactor=[1.0, 0.5, 0.25],
            metallicFactor=0.0,
            roughnessFactor=0.9,
            doubleSided=True,
        )
    )
    ball = trimesh.creation.icosphere(subdivisions=1)
    ball.visual = TextureVisuals(
        material=PBRMaterial(
            name="gold",
            baseColorFactor=[0.9, 0.6, 0.2, 1.0],
            metallicFactor=1.0,
            roughnessFactor=0.3,
        )
    )
    chrome = trimesh.creation.box()
    chrome.visual = TextureVisuals(
        material=PBRMaterial(
            name="chrome",
            baseColorFactor=[1.0, 1.0, 1.0, 1.0],
            metallicFactor=1.0,
            roughnessFactor=0.0,
        )
    )
    move = trimesh.transformations.translation_matrix([0.0, 3.0, 0.0])
    mirror = np.diag([-2.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [5.0, 0.0, 0.0]
    scene = trimesh.Scene()
    scene.add_geometry(lamp, node_name="lamp_node", geom_name="lamp_geom", transform=move)
    scene.add_geometry(ball, node_name="ball_a", geom_name="ball")
    scene.add_geometry(ball, node_name="ball_b", geom_name="ball", transform=mirror)
    scene.add_geometry(chrome, node_name="chrome_node", geom_name="chrome_geom")
    return scene, {"lamp": (lamp, move), "ball": (ball, mirror), "chrome": (chrome, None)}


def _with_emissive_strength(glb: bytes, strength: float) -> bytes:
    """Rewrite a GLB's JSON chunk: material 'lamp' gets KHR_materials_emissive_strength and an
    exact base colour (trimesh exports its 8-bit copy, 0.298 for 0.3)."""
    json_len = struct.unpack("<I", glb[12:16])[0]
    tree = json.loads(glb[20 : 20 + json_len])
    rest = glb[20 + json_len :]
    for mat in tree["materials"]:
        if mat.get("name") == "lamp":
            mat["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
            mat["pbrMetallicRoughness"]["baseColorFactor"] = [0.2, 0.3, 0.4, 1.0]
    tree.setdefault("extensionsUsed", []).append("KHR_materials_emissive_strength")
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    body = struct.pack("<I4s", len(text), b"JSON") + text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _outward(mesh: MeshData, centre) -> bool:
    """Every face normal of a convex closed mesh points away from its centre."""
    p = mesh.vertices.astype(np.float64)[mesh.faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return bool(np.all(np.sum(n * (p.mean(axis=1) - centre), axis=1) > 0))


@pytest.fixture(scope="module")
def glb_meshes(tmp_path_factory):
    root = tmp_path_factory.mktemp("glb")
    scene, originals = _pbr_scene()
    (root / "s.glb").write_bytes(_with_emissive_strength(scene.export(file_type="glb"), 5.0))
    return _by_name(load_meshes(root / "s.glb")), originals


def test_glb_materials(glb_meshes):
    meshes, _ = glb_meshes
    assert set(meshes) == {"lamp", "gold", "chrome"}
    lamp = meshes["lamp"].material
    # exact JSON factors (trimesh would round base colour to 8 bits)
    assert lamp.kind == "diffuse" and lamp.kd == (0.2, 0.3, 0.4)
    # emissiveFactor × emissiveStrength = (1, 0.5, 0.25) × 5
    assert lamp.emission == (5.0, 2.5, 1.25) and lamp.two_sided_emission
    gold = meshes["gold"].material
    assert gold.kind == "conductor" and gold.kd == (0, 0, 0)
    # trimesh's exporter wrote its 8-bit copy of the base colour: within half a level
    np.testing.assert_allclose(gold.ks, [0.9, 0.6, 0.2], rtol=0, atol=0.5 / 255)
    assert gold.alpha == pytest.approx(0.09, rel=1e-15)  # roughness² = 0.3²
    assert not gold.is_emitter and not gold.two_sided_emission
    assert meshes["chrome"].material == MaterialSpec("mirror", kd=(0, 0, 0), ks=(1, 1, 1))


def test_glb_transforms_and_winding(glb_meshes):
    meshes, originals = glb_meshes
    lamp, move = originals["lamp"]
    got = meshes["lamp"]
    assert got.vertices.shape == (8, 3) and got.faces.shape == (12, 3)
    # translated by +3 in y; float32 of the float64 transform result
    np.testing.assert_array_equal(got.vertices, (lamp.vertices + [0, 3, 0]).astype(np.float32))
    ball, _ = originals["ball"]
    gold = meshes["gold"]
    nv, nf = len(ball.vertices), len(ball.faces)
    # two instances of the ball concatenated, each with its own block of vertices and faces
    assert gold.vertices.shape == (2 * nv, 3) and gold.faces.shape == (2 * nf, 3)
    halves = [
        MeshData("h", gold.vertices[:nv], gold.faces[:nf], None),
        MeshData("h", gold.vertices[nv:], gold.faces[nf:] - nv, None),
    ]
    assert all(h.faces.min() == 0 and h.faces.max() == nv - 1 for h in halves)
    # the mirrored instance is the one centred at x = 5 (instance order follows the graph)
    plain, mirrored = sorted(halves, key=lambda h: h.vertices[:, 0].mean())
    np.testing.assert_array_equal(plain.vertices, ball.vertices.astype(np.float32))
    # x' = -2 x + 5 in float64, rounded once to float32
    expected = (ball.vertices * [-2, 1, 1] + [5, 0, 0]).astype(np.float32)
    np.testing.assert_array_equal(mirrored.vertices, expected)
    # the mirror (det < 0) had its winding flipped back: normals still point outwards
    assert _outward(plain, [0, 0, 0]) and _outward(mirrored, [5, 0, 0])
    assert _outward(got, [0, 3, 0])


def test_gltf_text_with_separate_buffer(tmp_path):
    scene, _ = _pbr_scene()
    files = scene.export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (gltf_name,) = [n for n in files if n.endswith(".gltf")]
    meshes = _by_name(load_meshes(tmp_path / gltf_name))
    assert set(meshes) == {"lamp", "gold", "chrome"}
    # no strength extension here: emission is the factor itself
    assert meshes["lamp"].material.emission == (1.0, 0.5, 0.25)


@pytest.mark.parametrize(
    "name, payload, match",
    [
        ("r.glb", b"glTF" + bytes(range(200)), "malformed glTF header|cannot read"),
        ("r.gltf", b"{not json", "malformed glTF header"),
        ("r.ply", bytes(range(256)) * 2, "cannot read mesh file"),
        ("r.obj", b"hello\nworld\n", "no triangle meshes"),
        ("r.stl", b"solid x\nendsolid x\n", "unsupported mesh format"),
        ("r.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
         ":4: face 1 refers to vertex 9, but the file defines 3 vertices"),
    ],
    ids=["random-glb", "bad-json", "random-ply", "text-obj", "stl", "obj-face-out-of-range"],
)
def test_bad_files_raise_named_error(tmp_path, name, payload, match):
    (tmp_path / name).write_bytes(payload)
    with pytest.raises(FileFormatError, match=rf"{name}.*({match})"):
        load_meshes(tmp_path / name)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.obj"):
        load_meshes(tmp_path / "nope.obj")


def test_material_spec_validation():
    spec = MaterialSpec("phong", kd=[0.5, 0.5, 0.5], ks=0.5, exponent=10)
    # sequences and scalars become (3,) float tuples; specs are hashable values
    assert spec.ks == (0.5, 0.5, 0.5) and hash(spec) == hash(MaterialSpec("phong", 0.5, 0.5, 10))
    bad = [
        dict(kind="plastic"),
        dict(kd=(0.7, 0.7, 0.7), ks=(0.5, 0, 0)),  # kd + ks > 1 in red
        dict(kd=(1.2, 0, 0)),
        dict(emission=(-1, 0, 0)),
        dict(exponent=-1.0),
        dict(alpha=2.0),
        dict(kd=(np.nan, 0, 0)),
        dict(kd=(1, 2)),
    ]
    for kwargs in bad:
        with pytest.raises(ValueError):
            MaterialSpec(**kwargs)


def test_glb_unnamed_materials_matched_by_factors(tmp_path):
    # two unnamed materials with the same base colour, told apart by metallic/roughness
    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([3.0, 0.0, 0.0])
    a.visual = TextureVisuals(
        material=PBRMaterial(baseColorFactor=[0.5] * 3 + [1.0], metallicFactor=0.0)
    )
    b.visual = TextureVisuals(
        material=PBRMaterial(
            baseColorFactor=[0.5] * 3 + [1.0], metallicFactor=1.0, roughnessFactor=0.5
        )
    )
    (tmp_path / "u.glb").write_bytes(trimesh.Scene([a, b]).export(file_type="glb"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an unambiguous match: no warning
        meshes = load_meshes(tmp_path / "u.glb")
    kinds = {m.material.kind: m for m in meshes}
    assert set(kinds) == {"diffuse", "conductor"}
    assert kinds["conductor"].vertices[:, 0].min() == 2.5  # the translated box
    assert kinds["conductor"].material.alpha == 0.25  # 0.5²


@pytest.mark.parametrize("text, message", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# two\nf 1 2 99\n",
     r"r\.obj:6: face 2 refers to vertex 99, but the file defines 3 vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
     r"r\.obj:4: face 1 refers to vertex -4, but only 3 vertices precede it"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n",
     r"r\.obj:4: face 1 refers to vertex 0; OBJ indices count from 1"),
    ("v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n",
     r"r\.obj:2: vertex 2: expected 'v x y z' with three numbers, got 'v 1 x 0'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", r"r\.obj:4: face 1: needs at least 3 vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 a/1\n", r"r\.obj:4: face 1: 'a/1' is not a vertex"),
])
def test_obj_errors_name_the_line_and_the_entry(tmp_path, text, message):
    """OBJ errors said ``IndexError: index 98 is out of bounds`` (or, for index 0, rendered
    a wrapped-around face as 'every triangle is degenerate')."""
    (tmp_path / "r.obj").write_text(text)
    with pytest.raises(FileFormatError, match=message):
        load_meshes(tmp_path / "r.obj")


def test_obj_valid_indices_load(tmp_path):
    """Negative (relative) indices and v/vt/vn corners pass the check."""
    (tmp_path / "r.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
                                    "f -3/1/1 -2/1/1 -1/1/1\n")
    (mesh,) = load_meshes(tmp_path / "r.obj")
    assert mesh.faces.tolist() == [[0, 1, 2]]
