"""Scene description files (JSON): meshes, materials, lights and camera in one document.

``load_scene(path)`` reads a JSON file and builds a :class:`jaxrt.scene.container.Scene`. Paths
inside it are relative to the file. Nothing is executed (``json`` only); every error names the file
and the entry at fault, e.g. ``scene.json: meshes[2].material: unknown material 'gold'``.

Schema (all lengths in scene units, radiance in linear RGB; a scalar is accepted wherever an
RGB triple is)::

    {
      "camera": {"eye": [x, y, z], "target": [x, y, z], "up": [0, 1, 0],
                 "fov": 40.0,                       # field of view, degrees, across
                 "fov_axis": "y",                   # "y" (default), "x", "diagonal",
                                                    # "smaller" or "larger" image side
                 "width": 256, "height": 256},
      "materials": {                                # named materials
        "white": {"type": "diffuse", "albedo": 0.7},
        "plastic": {"type": "phong", "kd": 0.5, "ks": 0.3, "exponent": 40},
        "gold": {"type": "conductor", "alpha": 0.1, "ks": [1.0, 0.78, 0.34]},
        "copper": {"type": "conductor", "alpha": 0.2, "ks": [0.95, 0.64, 0.54],
                   "fresnel": "none", "masking": "separable"},   # as Mitsuba 3's
        "chrome": {"type": "mirror", "ks": 0.9}
      },
      "meshes": [
        {"file": "bunny.obj"},                      # materials (and Ke emission) from the file
        {"file": "lamp.ply", "material": "white", "emission": [10, 10, 10],
         "two_sided_emission": false,
         "transform": {"scale": 2.0, "rotate": [0, 1, 0, 90], "translate": [0, 1, 0]}},
        {"vertices": [[...], ...], "faces": [[0, 1, 2], ...], "material": "white"},
        {"file": "floor.obj", "material": "white",  # UVs from the file (vt lines)
         "textures": {"kd": "checker.png",          # or {"file": ..., "wrap": "clamp",
                      "alpha": {"file": "rough.exr", "wrap": "repeat"}}},
                                                    #     "filter", "encoding"}
        {"vertices": [...], "faces": [...], "uv": [[0, 0], ...], "material": "white",
         "textures": {"kd": "checker.png"}}
      ],
      "lights": [
        {"type": "point", "position": [0, 2, 0], "intensity": 10},
        {"type": "spot", "position": [...], "axis": [...], "intensity": 10,
         "inner_angle": 20, "outer_angle": 30},     # degrees
        {"type": "directional", "direction": [0, 1, 0], "irradiance": 3},  # towards the light
        {"type": "sphere", "center": [...], "radius": 0.1, "radiance": 50},
        {"type": "environment", "radiance": 0.2},   # or "file": "sky.exr" (lat-long map)
      ],
      "options": {"accel": "auto", "triangle_sampling": "area",
                  "light_selection": "power"}
    }

``transform`` applies scale, then a rotation (axis x, y, z and angle in degrees), then a
translation. A mesh's ``material`` overrides the file's materials; its ``emission`` overrides
the file's emission (``Ke`` in MTL, emissive factor in glTF).

``textures`` bind material fields (``kd``, ``ks``, ``alpha``) of a mesh, or the radiance
of an emissive one (``emission``: it emits ``emission`` times the image), to PNG or EXR
images (:mod:`jaxrt.scene.textures`): ``wrap`` "repeat" (default) or "clamp", ``filter``
"bilinear" (default) or "nearest", ``encoding`` "auto" (default: 8-bit colour maps are
sRGB, the rest linear), "srgb" or "linear". The same file with the same options is one
texture (one array of texels) wherever it is used. A mesh file's own texture maps (an MTL's
``map_Kd``, a glTF ``baseColorTexture``) are bound unless the entry gives ``textures`` (even
``{}``) or a ``material``. A textured mesh needs UVs (its file's,
or ``uv`` of an inline mesh); a missing texture file, a bad option or missing UVs is a
``FileFormatError`` (a ValueError) naming the entry, raised before the scene is built.

Unknown keys are an error at every level (``meshes[0]: unknown key 'transfrom' (did you mean
'transform'?)``), so a typo cannot silently drop a setting; keys that start with ``_`` are
ignored (comments, e.g. ``"_note": "..."``). Warnings raised while the scene is built (a
zero-area emissive triangle, no light at all) name the file.
"""

from __future__ import annotations

import difflib
import json
import os
import warnings
from pathlib import Path

import numpy as np

from jaxrt.scene import camera as cm
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx
from jaxrt.scene.container import Scene, build_scene, mesh
from jaxrt.scene.images import FileFormatError, read_exr
from jaxrt.scene.meshio import MaterialSpec, load_meshes

# the keys each object may hold (beyond comments "_..."), by kind where the kind decides
_TOP_KEYS = ("camera", "materials", "meshes", "lights", "options")
_CAMERA_KEYS = ("eye", "target", "up", "fov", "fov_axis", "width", "height")
_MATERIAL_KEYS = {"diffuse": ("albedo",), "phong": ("kd", "ks", "exponent"),
                  "conductor": ("alpha", "ks", "fresnel", "masking"), "mirror": ("ks",)}
_MESH_KEYS = {"file": ("file", "material", "emission", "two_sided_emission", "transform",
                       "textures"),
              "inline": ("vertices", "faces", "material", "emission", "two_sided_emission",
                         "transform", "name", "uv", "textures")}
_TEXTURE_KEYS = ("file", "wrap", "filter", "encoding")
_TRANSFORM_KEYS = ("scale", "rotate", "translate")
_LIGHT_KEYS = {"point": ("position", "intensity"),
               "spot": ("position", "axis", "intensity", "inner_angle", "outer_angle"),
               "directional": ("direction", "irradiance"),
               "sphere": ("center", "radius", "radiance"),
               "environment": ("radiance", "file", "scale")}
_OPTION_KEYS = ("accel", "triangle_sampling", "light_selection")


class _Ctx:
    """Error context: the file and the JSON path of the entry being read."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, where: str, msg: str):
        raise FileFormatError(f"{self.path}: {where}: {msg}")

    def check_keys(self, obj, allowed, where: str, what: str = "an object"):
        """Fail on a key that is not in ``allowed``, suggesting the closest one."""
        if not isinstance(obj, dict):
            self.fail(where, f"expected {what}, got {json.dumps(obj)[:60]}")
        for key in obj:
            if key in allowed or (isinstance(key, str) and key.startswith("_")):
                continue
            close = difflib.get_close_matches(key, allowed, n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            self.fail(where, f"unknown key {key!r}{hint}; allowed: {', '.join(allowed)}")

    def get(self, obj: dict, key: str, where: str, default=...):
        if not isinstance(obj, dict):
            self.fail(where, f"expected an object, got {type(obj).__name__}")
        if key not in obj:
            if default is ...:
                self.fail(where, f"missing required key {key!r}")
            return default
        return obj[key]


def _material(ctx: _Ctx, spec: dict, where: str) -> mt.Material:
    kind = ctx.get(spec, "type", where)
    if kind in _MATERIAL_KEYS:
        ctx.check_keys(spec, ("type",) + _MATERIAL_KEYS[kind], where)
    g = lambda k, d=...: ctx.get(spec, k, where, d)  # noqa: E731
    try:
        if kind == "diffuse":
            return mt.diffuse(g("albedo"))
        if kind == "phong":
            return mt.phong(g("kd"), g("ks"), g("exponent"))
        if kind == "conductor":
            return mt.conductor(g("alpha"), g("ks"), g("fresnel", "schlick"),
                                g("masking", "correlated"))
        if kind == "mirror":
            return mt.mirror(g("ks", 1.0))
    except FileFormatError:  # already names the file and the entry
        raise
    except (ValueError, TypeError) as e:
        ctx.fail(where, str(e))
    ctx.fail(where, f"unknown material type {kind!r} (diffuse, phong, conductor, mirror)")


def material_from_spec(spec: MaterialSpec) -> mt.Material:
    """Map a file material (:class:`jaxrt.scene.meshio.MaterialSpec`) to a
    :mod:`jaxrt.scene.materials` one."""
    if spec.kind == "phong":
        return mt.phong(spec.kd, spec.ks, spec.exponent)
    if spec.kind == "conductor":
        return mt.conductor(spec.alpha, spec.ks)
    if spec.kind == "mirror":
        return mt.mirror(spec.ks)
    return mt.diffuse(spec.kd)


def _rotation(axis, degrees) -> np.ndarray:
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    t = np.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


def _transform(ctx: _Ctx, t: dict | None, v: np.ndarray, where: str) -> np.ndarray:
    if t is None:
        return v
    if not isinstance(t, dict):
        ctx.fail(where, f"expected an object with scale/rotate/translate, got {t!r}")
    ctx.check_keys(t, _TRANSFORM_KEYS, where)
    try:
        s = np.broadcast_to(np.asarray(t.get("scale", 1.0), np.float64), (3,))
        v = v * s
        if "rotate" in t:
            r = list(t["rotate"])
            if len(r) != 4:
                ctx.fail(where, "rotate must be [axis_x, axis_y, axis_z, degrees]")
            v = v @ _rotation(r[:3], r[3]).T
        return v + np.asarray(t.get("translate", [0, 0, 0]), np.float64)
    except FileFormatError:
        raise
    except (TypeError, ValueError) as e:
        ctx.fail(where, f"bad transform: {e}")


def _textures(ctx: _Ctx, spec, where: str, base: Path, cache: dict) -> dict:
    """``{field: Texture}`` of a mesh's ``textures`` entry (files read once per options)."""
    if spec is None:
        return {}
    if not isinstance(spec, dict):
        ctx.fail(where, f"expected an object of textures by field, got {json.dumps(spec)[:60]}")
    out = {}
    for field, entry in spec.items():
        if field.startswith("_"):
            continue
        at = f"{where}.{field}"
        if field not in tx.FIELDS and field != tx.EMISSION:
            ctx.fail(at, f"cannot texture {field!r}; textured fields: "
                     f"{', '.join([*tx.FIELDS, tx.EMISSION])}")
        entry = {"file": entry} if isinstance(entry, str) else entry
        ctx.check_keys(entry, _TEXTURE_KEYS, at, "a file name or an object")
        name = ctx.get(entry, "file", at)
        options = tuple(str(entry.get(k, d)) for k, d in
                        (("wrap", "repeat"), ("filter", "bilinear"), ("encoding", "auto")))
        path = base / str(name)
        key = (str(path.resolve()), options)
        if key not in cache:
            if not path.is_file():
                ctx.fail(at, f"texture file not found: {path}")
            try:
                cache[key] = tx.load_texture(path, *options)
            except ValueError as e:  # a FileFormatError too: unreadable image, bad option
                ctx.fail(at, str(e))
        out[field] = cache[key]
    return out


def _missing(ctx: _Ctx, where: str, what: str, path: Path):
    raise FileNotFoundError(f"{ctx.path}: {where}: {what} not found: {path}")


def _meshes(ctx: _Ctx, entry: dict, where: str, materials: dict, base: Path,
            cache: dict) -> list:
    if not isinstance(entry, dict):
        ctx.fail(where, f"expected a mesh object, got {entry!r}")
    ctx.check_keys(entry, _MESH_KEYS["file" if "file" in entry else "inline"], where)
    textures = _textures(ctx, entry.get("textures"), f"{where}.textures", base, cache)
    override = None
    if "material" in entry:
        name = entry["material"]
        if name not in materials:
            ctx.fail(f"{where}.material", f"unknown material {name!r}; defined: "
                     f"{', '.join(sorted(materials)) or 'none'}")
        override = materials[name]
    emission = entry.get("emission")
    two_sided = bool(entry.get("two_sided_emission", False))
    out = []
    try:
        if "file" in entry:
            path = base / entry["file"]
            if not path.exists():
                _missing(ctx, where, "mesh file", path)
            # the file's own texture maps (MTL map_Kd) belong to its materials: an explicit
            # "textures" (even {}) or "material" replaces them (and their images are not read)
            explicit = entry.get("textures") is not None
            for md in load_meshes(path, textures=not explicit and override is None):
                v = _transform(ctx, entry.get("transform"), md.vertices.astype(np.float64),
                               f"{where}.transform")
                mat = override if override is not None else material_from_spec(md.material)
                # a file's material emits only if its Ke/emissive factor is positive; an
                # "emission" written in the scene file is the user's declaration, even 0
                e = (emission if emission is not None
                     else md.material.emission if md.material.is_emitter else None)
                two = two_sided or md.material.two_sided_emission
                if textures and md.uv is None:
                    ctx.fail(f"{where}.textures", f"{entry['file']} (mesh {md.name!r}) has no "
                             "texture coordinates (vt lines, PLY s/t or u/v, glTF TEXCOORD_0)")
                out.append(mesh(v, md.faces, mat, emission=e, two_sided_emission=two,
                                name=f"{entry['file']}:{md.name}", uv=md.uv,
                                textures=textures if explicit else md.textures))
        else:
            v = np.asarray(ctx.get(entry, "vertices", where), np.float64)
            f = np.asarray(ctx.get(entry, "faces", where))
            if override is None:
                ctx.fail(where, "an inline mesh needs a 'material'")
            v = _transform(ctx, entry.get("transform"), v, f"{where}.transform")
            if textures and "uv" not in entry:
                ctx.fail(f"{where}.textures", "a textured inline mesh needs 'uv' (one [u, v] "
                         "per vertex)")
            uv = np.asarray(entry["uv"], np.float64) if "uv" in entry else None
            out.append(mesh(v, f, override, emission=emission, two_sided_emission=two_sided,
                            name=entry.get("name", where), uv=uv, textures=textures))
    except FileFormatError:
        raise
    except (ValueError, TypeError) as e:
        ctx.fail(where, str(e))
    return out


def _rgb(value) -> np.ndarray:
    """A scalar or an RGB triple as an RGB triple."""
    return np.broadcast_to(np.asarray(value, np.float64), (3,))


def _light(ctx: _Ctx, spec: dict, where: str, base: Path):
    kind = ctx.get(spec, "type", where)
    if kind in _LIGHT_KEYS:
        ctx.check_keys(spec, ("type",) + _LIGHT_KEYS[kind], where)
    g = lambda k, d=...: ctx.get(spec, k, where, d)  # noqa: E731
    try:
        if kind == "point":
            return lt.point_light(g("position"), _rgb(g("intensity")))
        if kind == "spot":
            return lt.spot_light(g("position"), g("axis"), _rgb(g("intensity")),
                                 np.radians(g("inner_angle")), np.radians(g("outer_angle")))
        if kind == "directional":
            return lt.directional_light(g("direction"), _rgb(g("irradiance")))
        if kind == "sphere":
            return lt.sphere_light(g("center"), g("radius"), _rgb(g("radiance")))
        if kind == "environment":
            if "file" in spec:
                if not (base / spec["file"]).exists():
                    _missing(ctx, where, "environment map", base / spec["file"])
                image, _ = read_exr(base / spec["file"])
                return lt.environment_map(image * float(spec.get("scale", 1.0)))
            return lt.constant_environment(_rgb(g("radiance")))
    except FileFormatError:
        raise
    except (ValueError, TypeError) as e:
        ctx.fail(where, str(e))
    ctx.fail(where, f"unknown light type {kind!r} (point, spot, directional, sphere, "
             "environment)")


def load_scene(path: str | os.PathLike, *, accel: str | None = None, width: int | None = None,
               height: int | None = None, params: dict | None = None) -> Scene:
    """Read a JSON scene description (schema in this module's docstring) into a Scene.

    ``accel``, ``width`` and ``height`` override the file's options and camera. A path ending
    in ``.xml`` is a Mitsuba 3 scene (:mod:`jaxrt.scene.mitsuba`), whose ``<default>`` values
    ``params`` override. Raises ``FileNotFoundError`` for a missing file and
    :class:`jaxrt.scene.images.FileFormatError` (a ValueError) naming the file and the entry for
    anything malformed.
    """
    path = Path(path)
    if path.suffix.lower() == ".xml":
        from jaxrt.scene.mitsuba import load_mitsuba

        return load_mitsuba(path, accel=accel, width=width, height=height, params=params)
    if params:
        raise TypeError(f"{path}: params apply to Mitsuba XML scenes only")
    ctx = _Ctx(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError) as e:
        raise FileFormatError(f"{path}: cannot read: {e}") from e
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise FileFormatError(f"{path}: not valid JSON: {e}") from e
    if not isinstance(doc, dict):
        ctx.fail("top level", "expected a JSON object")
    ctx.check_keys(doc, _TOP_KEYS, "top level")
    base = path.parent

    materials = {}
    mats = doc.get("materials") or {}
    if not isinstance(mats, dict):
        ctx.fail("materials", "expected an object of named materials")
    for name, spec in mats.items():
        if name.startswith("_"):
            continue
        materials[name] = _material(ctx, spec, f"materials.{name}")
    entries = ctx.get(doc, "meshes", "top level")
    if not isinstance(entries, list) or not entries:
        ctx.fail("meshes", "expected a non-empty list of meshes")
    meshes, cache = [], {}
    for i, entry in enumerate(entries):
        meshes += _meshes(ctx, entry, f"meshes[{i}]", materials, base, cache)
    light_specs = doc.get("lights") or []
    if not isinstance(light_specs, list):
        ctx.fail("lights", "expected a list of lights")
    lights = [_light(ctx, spec, f"lights[{i}]", base) for i, spec in enumerate(light_specs)]

    c = ctx.get(doc, "camera", "top level")
    ctx.check_keys(c, _CAMERA_KEYS, "camera")
    try:
        camera = cm.look_at(eye=ctx.get(c, "eye", "camera"), target=ctx.get(c, "target", "camera"),
                            up=c.get("up", [0, 1, 0]), fov_deg=float(c.get("fov", 40.0)),
                            fov_axis=c.get("fov_axis", "y"),
                            width=int(width or c.get("width", 256)),
                            height=int(height or c.get("height", 256)))
    except FileFormatError:
        raise
    except (ValueError, TypeError) as e:
        ctx.fail("camera", str(e))
    opts = doc.get("options") or {}
    ctx.check_keys(opts, _OPTION_KEYS, "options")
    try:
        # warnings (zero-area emitters, no light) name this file and point at the caller
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            scene = build_scene(meshes, camera, lights, accel=accel or opts.get("accel", "auto"),
                                triangle_sampling=opts.get("triangle_sampling", "area"),
                                light_selection=opts.get("light_selection", "power"))
    except (ValueError, TypeError) as e:
        ctx.fail("scene", str(e))
    for w in caught:
        warnings.warn(f"{path}: {w.message}", w.category, stacklevel=2)
    return scene
