"""Triangle meshes from OBJ (+MTL), PLY and glTF/GLB files, through trimesh, with plain materials.

``load_meshes(path)`` returns one ``MeshData`` per material: every geometry instance of the
file's scene graph with its node transform applied (mirroring transforms flip the winding so
normals keep their side), triangulated, concatenated by material, float32 vertices and int32
faces. Materials come back as ``MaterialSpec``, a plain dataclass; mapping it to
``jaxrt.scene.materials`` constructors is the scene loader's job.

Material mapping
----------------
OBJ / MTL (values read from the MTL as trimesh parses it, exact floats):
  - ``Kd`` → ``kd``, ``Ks`` → ``ks``, ``Ns`` → ``exponent`` (Phong), ``Ke`` → ``emission``.
  - kind ``"phong"`` when any ``Ks`` > 0, else ``"diffuse"``; ``"mirror"`` (``ks = Ks``) for
    ``illum`` 3 or 5 with ``Kd = 0``.
  - energy: ``kd + ks ≤ 1`` per channel is enforced by scaling both by ``1 / max(kd + ks)``,
    with a warning; a negative ``Ns`` becomes 0, with a warning.
  - ``map_Kd image`` → ``MeshData.textures = {"kd": Texture}``
    (:mod:`jaxrt.scene.mesh_textures`).
  - transparency (``d`` < 1, ``Tr`` > 0) and refraction (``illum`` 4, 6, 7, 9) are not
    modelled: ignored, with a warning. Other maps (``map_Ks``, ``bump``, ...) are ignored.
glTF / GLB (factors read from the file's JSON: exact, and trimesh drops the extension):
  - ``metallicFactor < 0.5``: ``"diffuse"``, ``kd = baseColorFactor.rgb``;
    otherwise ``"conductor"`` with ``ks = baseColorFactor.rgb`` and ``alpha = roughness²``
    (the usual perceptual-roughness → GGX alpha map), ``"mirror"`` when ``alpha = 0``.
    Missing factors take the glTF defaults (base colour 1, metallic 1, roughness 1).
  - ``emission = emissiveFactor × KHR_materials_emissive_strength.emissiveStrength`` (radiance).
  - ``two_sided_emission = doubleSided``. ``baseColorTexture`` is bound (mesh_textures);
    ``metallicRoughnessTexture`` and ``emissiveTexture`` are ignored, with a warning;
    normal and occlusion maps are ignored.
PLY, and any geometry without a material (OBJ without MTL, glTF primitive without material):
  grey diffuse ``kd = 0.5``, unless the file has vertex (or face) colours: then ``kd`` is their
  mean, decoded from 8-bit sRGB to linear, with a warning when they vary (one albedo per mesh:
  per-vertex colour is not modelled).

OBJ has no two-sided emitters: ``two_sided_emission = False``.

Texture coordinates (OBJ ``vt``, PLY ``s``/``t`` or ``u``/``v``, glTF ``TEXCOORD_0``) come
back per vertex as ``MeshData.uv``, in one convention for every format, OBJ's and
:mod:`jaxrt.scene.textures`': ``u`` along the image's width, ``v`` up its height (``v = 0``
the image's bottom row). OBJ and PLY store that convention; glTF stores ``v`` down (its
``(0, 0)`` is the image's top-left corner) and trimesh returns ``1 − v``, so the same quad
exported as OBJ, PLY, glTF or GLB gives the same ``uv`` (tests/scene/test_mesh_texture_files.py).

Texture maps (MTL ``map_Kd``, glTF ``baseColorTexture``): see :mod:`jaxrt.scene.mesh_textures`.

Nothing is dropped silently: degenerate triangles (a repeated index or zero area) are removed
with a warning giving their count; non-triangle geometry (lines, points) is skipped with a
warning. Bad input raises: a missing file ``FileNotFoundError``; an unreadable or malformed
file, a file without triangles, an empty mesh, non-finite vertices or faces out of range
``jaxrt.scene.images.FileFormatError`` (a ``ValueError``) naming the file and the mesh. Loaders
never execute code: trimesh parses the geometry, ``json`` the glTF header.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import struct
import warnings
from typing import NamedTuple

import numpy as np
import trimesh

from jaxrt.scene.images import FileFormatError
from jaxrt.scene.mesh_textures import _mtl_texture_maps, _with_gltf_texture, _with_texture_map

__all__ = ["MaterialSpec", "MeshData", "load_meshes"]

KINDS = ("diffuse", "phong", "conductor", "mirror")
SUFFIXES = (".obj", ".ply", ".gltf", ".glb")
# slack for kd + ks ≤ 1 after rescaling (a few ulps of float64)
_ENERGY_SLACK = 1e-9


def _rgb(name: str, value) -> tuple[float, float, float]:
    """A scalar or 3-sequence as a finite (3,) tuple of floats, else ValueError."""
    v = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v.tolist()}")
    return tuple(float(c) for c in v)


@dataclasses.dataclass(frozen=True)
class MaterialSpec:
    """A surface material as read from a file: plain floats, no JAX (hashable, comparable).

    Attributes:
      kind: "diffuse" | "phong" | "conductor" | "mirror".
      kd: (3,) diffuse albedo in [0, 1] (Lambertian part; 0 for conductors and mirrors).
      ks: (3,) specular albedo in [0, 1] (Phong lobe weight, or conductor/mirror reflectance F0).
      exponent: Phong exponent n ≥ 0 (lobe ∝ cosⁿ of the angle to the mirror direction).
      alpha: GGX roughness in [0, 1] for conductors (0 for the others).
      emission: (3,) emitted radiance Le ≥ 0 (W sr⁻¹ m⁻² per channel; 0 if not an emitter).
      two_sided_emission: whether the surface emits from both sides (else the front side only).

    Invariants checked at construction: ``kd + ks ≤ 1`` per channel, everything finite.
    """

    kind: str = "diffuse"
    kd: tuple[float, float, float] = (0.5, 0.5, 0.5)
    ks: tuple[float, float, float] = (0.0, 0.0, 0.0)
    exponent: float = 0.0
    alpha: float = 0.0
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)
    two_sided_emission: bool = False

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"MaterialSpec.kind must be one of {KINDS}, got {self.kind!r}")
        for field in ("kd", "ks", "emission"):
            object.__setattr__(self, field, _rgb(field, getattr(self, field)))
        for field in ("exponent", "alpha"):
            value = float(getattr(self, field))
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"MaterialSpec.{field} must be finite and >= 0, got {value}")
            object.__setattr__(self, field, value)
        object.__setattr__(self, "two_sided_emission", bool(self.two_sided_emission))
        kd, ks = np.array(self.kd), np.array(self.ks)
        if kd.min() < 0 or ks.min() < 0 or kd.max() > 1 or ks.max() > 1:
            raise ValueError(f"MaterialSpec kd, ks must lie in [0, 1], got {self.kd}, {self.ks}")
        if np.max(kd + ks) > 1 + _ENERGY_SLACK:
            raise ValueError(f"MaterialSpec kd + ks must be <= 1 per channel, got {kd + ks}")
        if self.alpha > 1:
            raise ValueError(f"MaterialSpec.alpha must be <= 1, got {self.alpha}")
        if min(self.emission) < 0:
            raise ValueError(f"MaterialSpec.emission must be >= 0, got {self.emission}")

    @property
    def is_emitter(self) -> bool:
        """True when any channel of ``emission`` is positive."""
        return max(self.emission) > 0


class MeshData(NamedTuple):
    """One triangle mesh with one material, in world space.

    Attributes:
      name: the material's name in the file (else the first geometry's name).
      vertices: (V, 3) float32 numpy positions (transforms applied).
      faces: (F, 3) int32 numpy vertex indices, counter-clockwise seen from the front.
      material: its ``MaterialSpec``.
      uv: (V, 2) float64 texture coordinates per vertex (OBJ ``vt``, PLY ``s``/``t`` or
        ``u``/``v``, glTF ``TEXCOORD_0``; ``v`` up in every format, see the module docstring),
        or None when the file has none (for any part of the mesh).
      textures: ``{field: jaxrt.scene.textures.Texture}`` the file's material binds (an MTL
        ``map_Kd`` → ``"kd"``), or None. Always None when loaded with ``textures=False``.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    material: MaterialSpec
    uv: np.ndarray | None = None
    textures: dict | None = None


# ---------------------------------------------------------------------------------------------
# Materials
# ---------------------------------------------------------------------------------------------


def _warn(msg: str) -> None:
    warnings.warn(msg, UserWarning, stacklevel=3)


def _floats(where: str, key: str, value) -> np.ndarray:
    """An MTL value (float, list of floats or of strings) as a (3,) float array."""
    try:
        v = np.asarray(value if np.ndim(value) else [value], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        raise FileFormatError(f"{where}: cannot read {key} = {value!r} as numbers") from err
    if v.size not in (1, 3) or not np.all(np.isfinite(v)):
        raise FileFormatError(f"{where}: {key} must be 1 or 3 finite numbers, got {value!r}")
    return np.broadcast_to(v, (3,)).copy()


def _energy_scaled(where: str, kd: np.ndarray, ks: np.ndarray):
    """Clip negatives, then scale kd and ks down together so that max(kd + ks) ≤ 1 (warns)."""
    if kd.min() < 0 or ks.min() < 0:
        _warn(f"{where}: negative Kd/Ks clipped to 0")
        kd, ks = np.maximum(kd, 0), np.maximum(ks, 0)
    total = float(np.max(kd + ks))
    if total > 1:
        _warn(f"{where}: kd + ks = {total:.4g} > 1 (energy gain); both scaled by 1/{total:.4g}")
        kd, ks = kd / total, ks / total
    return kd, ks


def _emission(where: str, value) -> np.ndarray:
    if np.min(value) < 0:
        raise FileFormatError(f"{where}: negative emission {np.asarray(value).tolist()}")
    return value


def _mtl_material(where: str, mat) -> MaterialSpec:
    """MaterialSpec of a trimesh SimpleMaterial parsed from an MTL file (see module docs)."""
    raw = {k.lower(): v for k, v in getattr(mat, "kwargs", {}).items()}
    if "kd" in raw:
        kd = _floats(where, "Kd", raw["kd"])
    elif getattr(mat, "diffuse", None) is not None:  # trimesh without the raw value: 8-bit
        kd = np.asarray(mat.diffuse, np.float64)[:3] / 255.0
    else:
        kd = np.full(3, 0.5)
    ks = _floats(where, "Ks", raw["ks"]) if "ks" in raw else np.zeros(3)
    ke = _emission(where, _floats(where, "Ke", raw["ke"])) if "ke" in raw else np.zeros(3)
    exponent = float(_floats(where, "Ns", raw["ns"])[0]) if "ns" in raw else 0.0
    if exponent < 0:
        _warn(f"{where}: negative Ns = {exponent} set to 0")
        exponent = 0.0
    illum = int(_floats(where, "illum", raw["illum"])[0]) if "illum" in raw else None
    dissolve = float(_floats(where, "d", raw["d"])[0]) if "d" in raw else 1.0
    transmit = float(_floats(where, "Tr", raw["tr"])[0]) if "tr" in raw else 0.0
    if illum in (4, 6, 7, 9) or dissolve < 1 or transmit > 0:
        _warn(f"{where}: transparency/refraction (d, Tr, illum {illum}) ignored: opaque")
    if illum in (3, 5) and not kd.any() and ks.any():
        ks = np.clip(ks, 0, 1)
        return MaterialSpec("mirror", kd=np.zeros(3), ks=ks, emission=ke)
    kd, ks = _energy_scaled(where, kd, ks)
    kind = "phong" if ks.any() else "diffuse"
    return MaterialSpec(kind, kd=kd, ks=ks, exponent=exponent, emission=ke)


def _gltf_json(path: str) -> dict:
    """The JSON header of a .gltf or .glb file (parsed with ``json``: no code runs)."""
    with open(path, "rb") as f:
        data = f.read()
    try:
        if data[:4] == b"glTF":  # GLB: 12-byte header, then the JSON chunk (length, type, bytes)
            length, kind = struct.unpack("<I4s", data[12:20])
            if kind != b"JSON":
                raise ValueError("first GLB chunk is not JSON")
            data = data[20 : 20 + length]
        return json.loads(data.decode("utf-8"))
    except (ValueError, struct.error, UnicodeDecodeError) as err:
        raise FileFormatError(f"{path}: malformed glTF header ({err})") from err


def _gltf_spec(where: str, entry: dict) -> MaterialSpec:
    """MaterialSpec of one glTF material JSON entry (metallic-roughness model, see module docs)."""
    pbr = entry.get("pbrMetallicRoughness", {})
    base = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), np.float64)[:3]
    metallic = float(pbr.get("metallicFactor", 1.0))
    roughness = float(pbr.get("roughnessFactor", 1.0))
    strength = entry.get("extensions", {}).get("KHR_materials_emissive_strength", {})
    emission = np.asarray(entry.get("emissiveFactor", [0.0, 0.0, 0.0]), np.float64)
    emission = _emission(where, emission * float(strength.get("emissiveStrength", 1.0)))
    # baseColorTexture is bound by load_meshes (textures=True): mesh_textures._with_gltf_texture
    ignored = [k for k in ("metallicRoughnessTexture",) if k in pbr] + [
        k for k in ("emissiveTexture",) if k in entry]
    if ignored:
        _warn(f"{where}: {', '.join(ignored)} ignored, using the material's factors")
    if base.min() < 0 or base.max() > 1 or not 0 <= roughness <= 1:
        _warn(f"{where}: factors outside [0, 1] clipped")
        base, roughness = np.clip(base, 0, 1), min(max(roughness, 0.0), 1.0)
    two_sided = bool(entry.get("doubleSided", False))
    if metallic < 0.5:
        return MaterialSpec("diffuse", kd=base, emission=emission, two_sided_emission=two_sided)
    alpha = roughness**2
    kind = "conductor" if alpha > 0 else "mirror"
    return MaterialSpec(
        kind, kd=np.zeros(3), ks=base, alpha=alpha, emission=emission, two_sided_emission=two_sided
    )


def _gltf_entry_for(where: str, mat, entries: list[dict]) -> dict | None:
    """The JSON entry trimesh built ``mat`` from: same name and factors (trimesh keeps base
    colour in 8 bits, so it is compared to within one level). None if nothing matches."""

    def matches(entry: dict) -> bool:
        pbr = entry.get("pbrMetallicRoughness", {})
        base = np.asarray(pbr.get("baseColorFactor", [1.0] * 4), np.float64)
        ours = getattr(mat, "baseColorFactor", None)
        same_base = ours is None or np.all(np.abs(base * 255 - np.asarray(ours)[: base.size]) <= 1)
        emissive = getattr(mat, "emissiveFactor", None)
        same_emissive = np.allclose(
            entry.get("emissiveFactor", [0.0] * 3), [0.0] * 3 if emissive is None else emissive
        )
        # trimesh keeps these scalars as given (None when the JSON omits them)
        same_scalars = all(
            getattr(mat, key, None) in (None, pbr.get(key)) or pbr.get(key) is None
            for key in ("metallicFactor", "roughnessFactor")
        )
        same_name = entry.get("name") == getattr(mat, "name", None)
        return same_name and same_base and same_emissive and same_scalars

    found = [e for e in entries if matches(e)]
    specs = {json.dumps(e, sort_keys=True, default=str) for e in found}
    if len(specs) > 1:
        _warn(f"{where}: {len(found)} glTF materials match; using the first")
    return found[0] if found else None


def _vertex_colour_spec(where: str, visual) -> MaterialSpec:
    """Grey diffuse, or the mean of per-vertex/face colours (8-bit sRGB → linear)."""
    kind = getattr(visual, "kind", None)
    if kind not in ("vertex", "face"):
        return MaterialSpec()
    colours = np.asarray(visual.vertex_colors if kind == "vertex" else visual.face_colors)
    srgb = colours[:, :3].astype(np.float64) / 255.0
    # sRGB EOTF (inverse of the OETF), IEC 61966-2-1
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    if np.ptp(colours[:, :3], axis=0).max() > 0:
        _warn(f"{where}: per-{kind} colours averaged into one diffuse albedo")
    return MaterialSpec("diffuse", kd=linear.mean(axis=0))


def _material_of(
    where: str, geometry, gltf_entries: list[dict] | None
) -> tuple[str | None, MaterialSpec, dict | None]:
    """(material name, MaterialSpec, its glTF JSON entry or None) of one trimesh geometry."""
    visual = geometry.visual
    mat = getattr(visual, "material", None) if visual.kind != "vertex" else None
    if isinstance(mat, trimesh.visual.material.PBRMaterial) and gltf_entries is not None:
        entry = _gltf_entry_for(where, mat, gltf_entries)
        if entry is not None:
            spec = _gltf_spec(f"{where}, material {entry.get('name')!r}", entry)
            return entry.get("name"), spec, entry
    if isinstance(mat, trimesh.visual.material.PBRMaterial):
        # no JSON entry (not from a glTF file): trimesh's own, 8-bit, factors
        _warn(f"{where}: material {mat.name!r} not found in the glTF JSON; using trimesh's values")
        entry = {
            "pbrMetallicRoughness": {
                k: v
                for k, v in (
                    (
                        "baseColorFactor",
                        None
                        if mat.baseColorFactor is None
                        else (np.asarray(mat.baseColorFactor) / 255.0).tolist(),
                    ),
                    ("metallicFactor", mat.metallicFactor),
                    ("roughnessFactor", mat.roughnessFactor),
                )
                if v is not None
            },
            "doubleSided": bool(mat.doubleSided),
        }
        if mat.emissiveFactor is not None:
            entry["emissiveFactor"] = np.asarray(mat.emissiveFactor).tolist()
        return mat.name, _gltf_spec(where, entry), None
    if isinstance(mat, trimesh.visual.material.SimpleMaterial):
        return mat.name, _mtl_material(f"{where}, material {mat.name!r}", mat), None
    return None, _vertex_colour_spec(where, visual), None


# ---------------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------------


def _instance(where: str, geometry, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-space float32 vertices and int32 faces of one geometry instance, validated."""
    vertices = np.asarray(geometry.vertices, np.float64)
    faces = np.asarray(geometry.faces)
    if faces.size == 0 or vertices.size == 0:
        raise FileFormatError(f"{where}: empty mesh ({len(vertices)} vertices, {len(faces)} faces)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise FileFormatError(f"{where}: faces have shape {faces.shape}, expected (F, 3)")
    bad = (faces < 0) | (faces >= len(vertices))
    if bad.any():
        raise FileFormatError(
            f"{where}: {int(bad.any(axis=1).sum())} face(s) index outside [0, {len(vertices)})"
        )
    if not np.all(np.isfinite(vertices)):
        count = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise FileFormatError(f"{where}: {count} vertex position(s) are NaN or infinite")
    linear, offset = transform[:3, :3], transform[:3, 3]
    world = (vertices @ linear.T + offset).astype(np.float32)
    if not np.all(np.isfinite(world)):
        raise FileFormatError(f"{where}: vertices overflow float32 after the node transform")
    faces = faces.astype(np.int32)
    # a mirroring transform turns counter-clockwise faces clockwise: swap two corners back
    if np.linalg.det(linear) < 0:
        faces = faces[:, [0, 2, 1]]
    return world, faces


def _nondegenerate(where: str, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with three distinct indices and non-zero area; warns with the count removed."""
    p = vertices.astype(np.float64)[faces]
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    repeated = (
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    )
    keep = (area2 > 0) & ~repeated
    dropped = int((~keep).sum())
    if dropped:
        _warn(f"{where}: {dropped} degenerate triangle(s) (zero area) of {len(faces)} removed")
    if not keep.any():
        raise FileFormatError(f"{where}: every triangle is degenerate")
    return faces[keep]


# a face corner whose vertex index is 0: "f ... 0 ..." or "f ... 0/..."
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t](?:[^\n]*[ \t])?0(?:[/ \t\r\n]|$)", re.M)


def _check_obj(path: str) -> None:
    """Check an OBJ's ``v`` and ``f`` lines, so that an error names the line and the entry in
    the file's own 1-based numbering (trimesh reports ``IndexError: index 98 is out of
    bounds``, or silently wraps index 0 to the last vertex).

    Positive vertex indices must lie in 1 … (vertices in the file); negative ones count back
    from the vertices defined before the face (OBJ spec, "Referencing vertex data").
    """
    with open(path, encoding="utf-8", errors="replace") as f:
        lines = f.readlines()
    totals = [0, 0, 0]
    for line in lines:
        tag = line[:3].split()[:1]
        if tag and tag[0] in ("v", "vt", "vn"):
            totals[("v", "vt", "vn").index(tag[0])] += 1
    seen = [0, 0, 0]
    face = 0
    for lineno, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        tag, where = parts[0], f"{path}:{lineno}"
        if tag in ("v", "vt", "vn"):
            k = ("v", "vt", "vn").index(tag)
            seen[k] += 1
            if tag == "v":
                try:
                    if len(parts) < 4:
                        raise ValueError
                    [float(x) for x in parts[1:4]]
                except ValueError:
                    raise FileFormatError(f"{where}: vertex {seen[0]}: expected 'v x y z' with "
                                          f"three numbers, got {line.strip()!r}") from None
        elif tag == "f":
            face += 1
            if len(parts) < 4:
                raise FileFormatError(f"{where}: face {face}: needs at least 3 vertices, got "
                                      f"{line.strip()!r}")
            # only vertex indices matter here (texture and normal indices are not used)
            for corner in parts[1:]:
                text = corner.split("/")[0]
                try:
                    i = int(text)
                except ValueError:
                    raise FileFormatError(f"{where}: face {face}: {corner!r} is not a vertex "
                                          "index") from None
                if i == 0:
                    raise FileFormatError(f"{where}: face {face} refers to vertex 0; OBJ "
                                          "indices count from 1 (or back from -1)")
                if i > 0 and i > totals[0]:
                    raise FileFormatError(f"{where}: face {face} refers to vertex {i}, but the "
                                          f"file defines {_count(totals[0], 'vertex')}")
                if i < 0 and -i > seen[0]:
                    raise FileFormatError(f"{where}: face {face} refers to vertex {i}, but only "
                                          f"{_count(seen[0], 'vertex')} precede it")


def _count(n: int, what: str) -> str:
    return f"{n} {what if n == 1 else 'vertices'}"


def _load_scene(path: str) -> trimesh.Scene:
    try:
        # process=False: trimesh would otherwise drop NaN vertices and merge silently
        return trimesh.load(path, force="scene", process=False)
    except Exception as err:  # trimesh raises many types on bad bytes
        raise FileFormatError(
            f"{path}: cannot read mesh file ({type(err).__name__}: {err})"
        ) from err


def load_meshes(path: str | os.PathLike, textures: bool = True) -> list[MeshData]:
    """Load every triangle mesh of an OBJ (+MTL), PLY, glTF or GLB file, grouped by material.

    Each geometry instance of the scene graph gets its world transform; instances sharing a
    material (same name and same ``MaterialSpec``) are concatenated into one ``MeshData``, in
    order of first appearance. Polygons are triangulated by trimesh. See the module docstring
    for the material mapping and the warnings and errors, and :mod:`jaxrt.scene.mesh_textures`
    for the texture maps (an MTL ``map_Kd`` image that is not PNG or EXR is skipped with a
    warning: the material's ``Kd`` is used).

    Args:
      path: a file with suffix .obj, .ply, .gltf or .glb (MTL files and glTF buffers are found
        relative to it).
      textures: read the images the file's materials bind (MTL ``map_Kd``) into
        ``MeshData.textures``; False skips them (and their errors), e.g. when the caller
        replaces the file's materials or textures.

    Returns:
      A non-empty list of ``MeshData``: (V, 3) float32 vertices, (F, 3) int32 faces.

    Raises:
      FileNotFoundError: no such file, or (``textures``) no such ``map_Kd`` image.
      FileFormatError: unsupported suffix, unreadable or malformed file, no triangles, an empty
        mesh, non-finite vertices, faces out of range (the message names file and mesh); with
        ``textures``, a ``map_Kd`` on a mesh without UVs, an unreadable PNG or EXR image or
        an option not modelled (naming the OBJ file and the material).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such mesh file")
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in SUFFIXES:
        raise FileFormatError(f"{path}: unsupported mesh format {suffix!r} (use one of {SUFFIXES})")
    gltf = None
    if suffix in (".gltf", ".glb"):
        gltf = _gltf_json(path)
    if suffix != ".obj":
        meshes = _load_meshes(path, None if gltf is None else gltf.get("materials", []))
        if gltf is None or not textures:
            return [md for md, *_ in meshes]
        return [_with_gltf_texture(path, gltf, md, entry, mat) for md, _, entry, mat in meshes]
    # trimesh wraps vertex index 0 (invalid in OBJ) around to the last vertex
    with open(path, "rb") as f:
        if _OBJ_ZERO_INDEX.search(f.read()):
            _check_obj(path)
    maps = _mtl_texture_maps(path) if textures else {}
    try:
        meshes = _load_meshes(path, None)
    except FileFormatError:
        _check_obj(path)  # a message naming the line, if the fault is one it knows
        raise
    cache: dict = {}
    return [_with_texture_map(path, md, maps.get(name), cache) for md, name, *_ in meshes]


def _load_meshes(path: str, gltf_entries: list | None) -> list[tuple]:
    """``(MeshData, material name or None, glTF JSON entry or None, trimesh material)`` per
    material group."""
    scene = _load_scene(path)

    groups: dict[tuple, list] = {}
    skipped = []
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        where = f"{path}: mesh {geometry_name!r}"
        if not isinstance(geometry, trimesh.Trimesh):
            skipped.append(f"{geometry_name} ({type(geometry).__name__})")
            continue
        vertices, faces = _instance(where, geometry, np.asarray(transform, np.float64))
        faces = _nondegenerate(where, vertices, faces)
        material_name, spec, entry = _material_of(where, geometry, gltf_entries)
        group = groups.setdefault((material_name, spec), [(
            material_name or geometry_name, entry, getattr(geometry.visual, "material", None))])
        uv = getattr(geometry.visual, "uv", None) if geometry.visual.kind == "texture" else None
        uv = None if uv is None or len(uv) != len(vertices) else np.asarray(uv, np.float64)
        group.append((vertices, faces, uv))
    if skipped:
        _warn(f"{path}: {len(skipped)} non-triangle geometr(y/ies) skipped: {', '.join(skipped)}")
    if not groups:
        raise FileFormatError(f"{path}: no triangle meshes found")

    meshes = []
    for (material_name, spec), ((name, entry, mat), *parts) in groups.items():
        # offset each part's indices by the vertices that precede it
        offsets = np.cumsum([0] + [len(v) for v, _, _ in parts[:-1]])
        vertices = np.concatenate([v for v, _, _ in parts])
        faces = np.concatenate([f + np.int32(o)
                                for (_, f, _), o in zip(parts, offsets, strict=True)])
        uv = (None if any(t is None for _, _, t in parts)
              else np.concatenate([t for _, _, t in parts]))
        meshes.append((MeshData(str(name), vertices, faces.astype(np.int32), spec, uv),
                       material_name, entry, mat))
    return meshes
