"""Mitsuba 3 XML scene files, for the subset jaxrt models (``load_scene("scene.xml")``).

Supported: shapes ``obj``, ``ply`` (``filename`` relative to the XML file), ``rectangle`` (the
[-1, 1]² square in z = 0, normal +z), ``cube`` ([-1, 1]³, normals outwards) and ``sphere`` as an
emitter only (an ``area`` emitter inside it makes a sphere light); ``to_world`` of ``matrix``
(16 or 9 numbers, row-major), ``translate``, ``rotate``, ``scale`` and ``lookat``, composed as
Mitsuba does (each one left-multiplies the ones before it); ``flip_normals``. BSDFs
``diffuse``, ``conductor`` (smooth: a mirror), ``roughconductor`` (``distribution="ggx"``) and
``twosided`` (its nested BSDF: jaxrt reflects on both sides anyway), inline or declared at the
top level with an ``id`` and used through ``<ref id="..."/>``. Textures: a nested
``<texture type="bitmap">`` (``filename`` a PNG or EXR, ``filter_type`` "bilinear" or
"nearest", ``wrap_mode`` "repeat" or "clamp", ``raw``) as a diffuse ``reflectance``, a
conductor's ``specular_reflectance`` or a roughconductor's ``alpha``, on ``obj``, ``ply``
and ``rectangle`` shapes (:mod:`jaxrt.scene.textures`; as Mitsuba, 8-bit images are
sRGB-decoded unless ``raw``, EXR images are linear; the rectangle's UVs are Mitsuba's, the
files' as trimesh reads them). Emitters ``area``, ``point``,
``spot``, ``directional``, ``constant`` and ``envmap`` (an EXR). A ``perspective`` sensor with
``fov``/``fov_axis`` or ``focal_length`` and an ``hdrfilm`` (an ``rfilter``, if given, must be
``box``). ``<default>`` and ``$name`` substitution. ``integrator`` and ``sampler`` elements are
accepted and ignored, ``sampleCount`` included (the estimator and its samples are chosen at
render time).

Everything else — an unknown tag, plugin type or property, a missing file, a malformed value,
an unresolved ``$name``, a bad reference — is a :class:`~jaxrt.scene.images.FileFormatError` (a
``ValueError``) naming the file, the line and the element:
``scene.xml: line 12: <shape type="sphere">: a sphere is only a light in jaxrt ...``.
"""

from __future__ import annotations

import os
import re
import warnings
import xml.parsers.expat
from pathlib import Path

import numpy as np

from jaxrt.scene import camera as cm
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx
from jaxrt.scene.container import Scene, build_scene, mesh
from jaxrt.scene.images import FileFormatError, read_exr
from jaxrt.scene.meshio import load_meshes

_PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector",
                  "transform")
_PLUGIN_TAGS = ("shape", "bsdf", "emitter", "sensor", "film", "integrator", "sampler", "rfilter",
                "texture", "medium", "phase", "volume")
# from Mitsuba's local frame (y up, u = atan2(x, -z) / 2π, v = acos(y) / π) to jaxrt's (z up)
_DOLLAR = r"\$([A-Za-z_]\w*)"
_ENV_FRAME = np.array([[0.0, 1, 0], [0, 0, 1], [-1, 0, 0]])


class _Node:
    __slots__ = ("tag", "attrs", "line", "children")

    def __init__(self, tag, attrs, line):
        self.tag, self.attrs, self.line, self.children = tag, dict(attrs), line, []

    def __str__(self):
        kind = f' type="{self.attrs["type"]}"' if "type" in self.attrs else ""
        name = f' name="{self.attrs["name"]}"' if "name" in self.attrs and not kind else ""
        return f"<{self.tag}{kind}{name}>"


class _Ctx:
    def __init__(self, path: Path):
        self.path = path

    def fail(self, node: _Node, msg: str):
        raise FileFormatError(f"{self.path}: line {node.line}: {node}: {msg}")

    def attr(self, node: _Node, key: str, default=...):
        if key not in node.attrs:
            if default is ...:
                self.fail(node, f"missing attribute {key!r}")
            return default
        return node.attrs[key]

    def floats(self, node: _Node, text: str, counts=None) -> np.ndarray:
        try:
            v = np.array([float(s) for s in re.split(r"[,\s]+", text.strip()) if s], np.float64)
        except ValueError:
            self.fail(node, f"expected numbers, got {text!r}")
        if counts is not None and len(v) not in counts:
            want = " or ".join(str(c) for c in counts)
            self.fail(node, f"expected {want} numbers, got {len(v)} ({text!r})")
        return v

    def file(self, node: _Node, name: str, what: str) -> Path:
        p = self.path.parent / name
        if not p.is_file():
            self.fail(node, f"{what} not found: {p}")
        return p


def _parse(path: Path, params: dict) -> _Node:
    """Parse with expat (every node keeps its line), then substitute ``$name``."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as e:
        raise FileFormatError(f"{path}: cannot read: {e}") from e
    parser = xml.parsers.expat.ParserCreate()
    stack = [_Node("document", {}, 1)]

    def start(tag, attrs):
        node = _Node(tag, attrs, parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise FileFormatError(f"{path}: line {e.lineno}: not well-formed XML: "
                              f"{xml.parsers.expat.ErrorString(e.code)}") from e
    ctx = _Ctx(path)
    root = stack[0].children[0]
    if root.tag != "scene":
        ctx.fail(root, "the root element must be <scene>")
    values, used = {}, set()
    for d in root.children:
        if d.tag == "default":
            values[ctx.attr(d, "name")] = ctx.attr(d, "value")
            used.add(d.attrs["name"])
    for k, v in params.items():
        values[k] = str(v).lower() if isinstance(v, bool) else str(v)

    def substitute(node):
        for k, v in node.attrs.items():
            for name in re.findall(_DOLLAR, v):
                used.add(name)
                if name not in values:
                    ctx.fail(node, f"unresolved parameter ${name} in {k}={v!r} "
                             "(declare it with <default> or pass it to load_scene)")
            node.attrs[k] = re.sub(_DOLLAR, lambda m: values[m.group(1)], v)
        for c in node.children:
            substitute(c)

    substitute(root)
    unknown = sorted(set(params) - used)
    if unknown:
        raise FileFormatError(f"{path}: parameter(s) {', '.join(unknown)} not used by the file "
                              "(no <default> or $name of them)")
    return root


def _rotation(axis, degrees) -> np.ndarray:
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = np.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


def _vec(ctx: _Ctx, node: _Node, default: float = 0.0) -> np.ndarray:
    """``value="x, y, z"`` (one number: all three) or ``x=``/``y=``/``z=`` attributes."""
    if "value" in node.attrs:
        v = ctx.floats(node, node.attrs["value"], (1, 3))
        return np.broadcast_to(v, (3,)).copy()
    return np.array([float(ctx.floats(node, node.attrs.get(k, str(default)), (1,))[0])
                     for k in "xyz"])


def _transform(ctx: _Ctx, node: _Node) -> np.ndarray:
    m = np.eye(4)
    for t in node.children:
        step = np.eye(4)
        if t.tag == "matrix":
            v = ctx.floats(t, ctx.attr(t, "value"), (16, 9))
            if len(v) == 16:
                step = v.reshape(4, 4)
            else:
                step[:3, :3] = v.reshape(3, 3)
        elif t.tag == "translate":
            step[:3, 3] = _vec(ctx, t)
        elif t.tag == "scale":
            step[:3, :3] = np.diag(_vec(ctx, t, 1.0))
        elif t.tag == "rotate":
            axis = _vec(ctx, t)
            if not np.any(axis):
                ctx.fail(t, "the rotation axis is zero (give x, y, z or value)")
            step[:3, :3] = _rotation(axis, float(ctx.floats(t, ctx.attr(t, "angle"), (1,))[0]))
        elif t.tag == "lookat":
            o = ctx.floats(t, ctx.attr(t, "origin"), (3,))
            d = ctx.floats(t, ctx.attr(t, "target"), (3,)) - o
            up = ctx.floats(t, t.attrs.get("up", "0, 1, 0"), (3,))
            left = np.cross(up, d)
            if np.linalg.norm(d) == 0 or np.linalg.norm(left) <= 1e-9 * np.linalg.norm(d):
                ctx.fail(t, "origin equals target, or up is parallel to the view direction")
            d, left = d / np.linalg.norm(d), left / np.linalg.norm(left)
            step[:3, :4] = np.stack([left, np.cross(d, left), d, o], axis=1)
        else:
            ctx.fail(t, "unknown transform (matrix, translate, rotate, scale, lookat)")
        m = step @ m
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-12:
        ctx.fail(node, "the transform is singular or not finite")
    return m


def _value(ctx: _Ctx, node: _Node):
    tag = node.tag
    if tag == "transform":
        return _transform(ctx, node)
    if tag in ("point", "vector"):
        return _vec(ctx, node)
    text = ctx.attr(node, "value")
    if tag == "string":
        return text
    if tag == "boolean":
        if text.lower() not in ("true", "false"):
            ctx.fail(node, f"expected true or false, got {text!r}")
        return text.lower() == "true"
    if tag == "spectrum" and ":" in text:
        ctx.fail(node, "only a uniform spectrum (one number) is supported: jaxrt renders RGB")
    v = ctx.floats(node, text, (1, 3) if tag == "rgb" else (1,))
    return np.broadcast_to(v, (3,)).copy() if tag in ("rgb", "spectrum") else float(v[0])


class _Props:
    """The named properties of a plugin element, and its nested plugins."""

    def __init__(self, ctx: _Ctx, node: _Node, allowed, nested=(), ignored=(), textured=()):
        self.ctx, self.node, self.values, self.where, self.plugins = ctx, node, {}, {}, []
        for c in node.children:
            if c.tag == "texture" and textured:
                name = ctx.attr(c, "name")
                if name not in textured:
                    ctx.fail(c, f"a texture as {name!r} is not modelled for {node} (textured: "
                             f"{', '.join(textured)})")
                self.values[name], self.where[name] = _bitmap(ctx, c), c
            elif c.tag in _PROPERTY_TAGS:
                name = ctx.attr(c, "name")
                if name in ignored:
                    continue
                if name not in allowed:
                    ctx.fail(c, f"property {name!r} is not supported for {node} "
                             f"(supported: {', '.join(allowed) or 'none'})")
                self.values[name], self.where[name] = _value(ctx, c), c
            elif c.tag in nested or (c.tag == "ref" and "bsdf" in nested):
                self.plugins.append(c)
            elif c.tag in _PLUGIN_TAGS or c.tag == "ref":
                ctx.fail(c, f"not supported inside {node}")
            else:
                ctx.fail(c, "unknown element")

    def get(self, name, default=..., kind=None):
        if name not in self.values:
            if default is ...:
                self.ctx.fail(self.node, f"missing property {name!r}")
            return default
        v = self.values[name]
        if isinstance(v, tx.Texture):
            return v
        want = {"float": float, "rgb": np.ndarray, "string": str, "bool": bool,
                "matrix": np.ndarray}.get(kind)
        if kind == "rgb" and isinstance(v, float):
            v = np.full(3, v)
        if want is not None and not isinstance(v, want) or (
                kind == "matrix" and np.shape(v) != (4, 4)):
            self.ctx.fail(self.where[name], f"{name!r} must be a {kind}")
        return v


def _try(ctx: _Ctx, node: _Node, make):
    try:
        return make()
    except FileFormatError:
        raise
    except (ValueError, TypeError) as e:
        ctx.fail(node, str(e))


def _bitmap(ctx: _Ctx, node: _Node) -> tx.Texture:
    """A ``<texture type="bitmap">`` as a :class:`jaxrt.scene.textures.Texture`."""
    if ctx.attr(node, "type") != "bitmap":
        ctx.fail(node, "only the bitmap texture is modelled")
    p = _Props(ctx, node, ("filename", "filter_type", "wrap_mode", "raw"))
    path = ctx.file(p.where.get("filename", node), p.get("filename", kind="string"),
                    "texture file")
    wrap = p.get("wrap_mode", "repeat", "string")
    if wrap not in tx.WRAPS:
        ctx.fail(p.where["wrap_mode"], f"wrap_mode {wrap!r} is not modelled (repeat, clamp)")
    filt = p.get("filter_type", "bilinear", "string")
    if filt not in tx.FILTERS:
        ctx.fail(p.where["filter_type"], f"filter_type {filt!r} is not modelled (bilinear, "
                 "nearest)")
    # Mitsuba decodes an 8-bit (sRGB) bitmap to linear unless raw; EXR data is linear
    linear = p.get("raw", False, "bool") or path.suffix.lower() == ".exr"
    return _try(ctx, node, lambda: tx.load_texture(path, wrap, filt,
                                                   "linear" if linear else "srgb"))


def _split(values: dict) -> tuple[dict, dict]:
    """(plain values, textures) of a BSDF's arguments."""
    return ({k: v for k, v in values.items() if not isinstance(v, tx.Texture)},
            {k: v for k, v in values.items() if isinstance(v, tx.Texture)})


def _bsdf(ctx: _Ctx, node: _Node, named: dict) -> tuple[mt.Material, dict]:
    """The material of a BSDF element and its textures ``{field: Texture}``."""
    if node.tag == "ref":
        ref = ctx.attr(node, "id")
        if ref not in named:
            ctx.fail(node, f"no BSDF with id {ref!r} (declared: {', '.join(named) or 'none'})")
        return named[ref]
    kind = ctx.attr(node, "type")
    if kind == "twosided":
        p = _Props(ctx, node, (), ("bsdf",))
        if len(p.plugins) != 1:
            ctx.fail(node, "twosided takes exactly one nested BSDF")
        return _bsdf(ctx, p.plugins[0], named)
    if kind == "diffuse":
        p = _Props(ctx, node, ("reflectance",), textured=("reflectance",))
        kd = p.get("reflectance", 0.5, "rgb")
        if isinstance(kd, tx.Texture):
            return _try(ctx, node, lambda: mt.diffuse(0.5)), {"kd": kd}
        return _try(ctx, node, lambda: mt.diffuse(kd)), {}
    if kind in ("conductor", "roughconductor"):
        rough = kind == "roughconductor"
        p = _Props(ctx, node, ("specular_reflectance", "material", "eta", "k")
                   + (("alpha", "alpha_u", "alpha_v", "distribution") if rough else ()),
                   ignored=("sample_visible",),
                   textured=("specular_reflectance",) + (("alpha",) if rough else ()))
        for key in ("eta", "k"):
            if key in p.values:
                ctx.fail(p.where[key], "a complex IOR is not modelled: jaxrt's conductor takes "
                         "an RGB specular_reflectance (material='none')")
        if p.get("material", "none", "string") != "none":
            ctx.fail(p.where["material"], "only material='none' (with specular_reflectance) "
                     "is modelled")
        ks = p.get("specular_reflectance", 1.0, "rgb")
        textures = {"ks": ks} if isinstance(ks, tx.Texture) else {}
        ks = 1.0 if textures else ks
        if not rough:
            return _try(ctx, node, lambda: mt.mirror(ks)), textures
        if p.get("distribution", "beckmann", "string") != "ggx":
            ctx.fail(node, "only distribution='ggx' is modelled (Mitsuba's default is beckmann)")
        a = p.get("alpha", 0.1, "float")
        if isinstance(a, tx.Texture):
            textures["alpha"], a = a, 0.1
        au, av = p.get("alpha_u", a, "float"), p.get("alpha_v", a, "float")
        if au != av:
            ctx.fail(node, "anisotropic roughness (alpha_u != alpha_v) is not modelled")
        return _try(ctx, node, lambda: mt.conductor(au, ks, fresnel="none",
                                                    masking="separable")), textures
    ctx.fail(node, f"unsupported BSDF type {kind!r} (diffuse, conductor, roughconductor, "
             "twosided)")


_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
# two triangles per face, wound so their normals point out of the cube
_CUBE_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
_RECT = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
# Mitsuba's (0, 0), (1, 0), (1, 1), (0, 1), whose v runs down the image: jaxrt's v runs up
_RECT_UV = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float64)


def _shape(ctx: _Ctx, node: _Node, named: dict, meshes: list, lights: list):
    kind = ctx.attr(node, "type")
    allowed = {"obj": ("filename", "to_world", "flip_normals", "face_normals"),
               "ply": ("filename", "to_world", "flip_normals", "face_normals"),
               "rectangle": ("to_world", "flip_normals"), "cube": ("to_world", "flip_normals"),
               "sphere": ("to_world", "flip_normals", "center", "radius")}
    if kind not in allowed:
        ctx.fail(node, f"unsupported shape type {kind!r} (obj, ply, rectangle, cube, sphere)")
    p = _Props(ctx, node, allowed[kind], ("bsdf", "emitter"), ignored=("flip_tex_coords",))
    bsdfs = [c for c in p.plugins if c.tag in ("bsdf", "ref")]
    emitters = [c for c in p.plugins if c.tag == "emitter"]
    if len(bsdfs) > 1 or len(emitters) > 1:
        ctx.fail(node, "a shape takes at most one BSDF and one emitter")
    radiance = None
    if emitters:
        e = emitters[0]
        if ctx.attr(e, "type") != "area":
            ctx.fail(e, "a shape's emitter must be of type 'area'")
        radiance = _Props(ctx, e, ("radiance",), textured=("radiance",)).get("radiance",
                                                                             kind="rgb")
    m = p.get("to_world", np.eye(4), "matrix")
    flip = p.get("flip_normals", False, "bool")
    if kind == "sphere":
        if isinstance(radiance, tx.Texture):
            ctx.fail(emitters[0], "a textured sphere light is not modelled")
        if radiance is None:
            ctx.fail(node, "a sphere is only a light in jaxrt (it reflects nothing): give it an "
                     "area emitter, or use a mesh")
        if flip:
            ctx.fail(node, "a sphere light with flip_normals (emitting inwards) is not modelled")
        c, r = p.get("center", np.zeros(3)), p.get("radius", 1.0, "float")
        local = np.diag([r, r, r, 1.0])
        local[:3, 3] = c
        m = m @ local  # Mitsuba: to_world · translate(center) · scale(radius)
        lin = m[:3, :3]
        rad = np.cbrt(abs(np.linalg.det(lin)))
        if not np.allclose(lin @ lin.T, rad ** 2 * np.eye(3), rtol=1e-6, atol=1e-9 * rad ** 2):
            ctx.fail(node, "a sphere's to_world must scale uniformly (no ellipsoids)")
        if bsdfs:
            warnings.warn(f"{ctx.path}: line {node.line}: {node}: a sphere light reflects "
                          "nothing: its BSDF is ignored", stacklevel=4)
        lights.append(_try(ctx, node, lambda: lt.sphere_light(m[:3, 3], rad, radiance)))
        return
    mat, textures = _bsdf(ctx, bsdfs[0], named) if bsdfs else (mt.diffuse(0.5), {})
    if isinstance(radiance, tx.Texture):  # a bitmap radiance: jaxrt's emission texture
        textures, radiance = {**textures, tx.EMISSION: radiance}, np.ones(3)
    if kind in ("obj", "ply"):
        path = ctx.file(p.where.get("filename", node), p.get("filename", kind="string"),
                        "mesh file")
        # the file's own materials (MTL, glTF) and their images are Mitsuba's to ignore too
        parts = _try(ctx, node, lambda: [(d.vertices, d.faces, d.uv)
                                         for d in load_meshes(path, textures=False)])
    elif kind == "rectangle":
        parts = [(_RECT, np.array([[0, 1, 2], [0, 2, 3]]), _RECT_UV)]
    else:
        parts = [(_CUBE, _CUBE_FACES, None)]
    if textures and any(uv is None for _, _, uv in parts):
        ctx.fail(node, f"a textured {kind} needs texture coordinates"
                 + (" (the file has none)" if kind in ("obj", "ply") else
                    ": textures on a cube are not modelled"))
    # the normal follows to_world as a normal (inverse transpose), as Mitsuba's does:
    # a mirroring transform turns the winding over
    turn = flip != (np.linalg.det(m[:3, :3]) < 0)
    for i, (v, f, uv) in enumerate(parts):
        v = np.asarray(v, np.float64) @ m[:3, :3].T + m[:3, 3]
        f = np.asarray(f)[:, ::-1] if turn else f
        meshes.append(_try(ctx, node, lambda v=v, f=f, i=i, uv=uv: mesh(
            v, f, mat, emission=radiance, name=f"{ctx.path.name}:{node.line}:{kind}{i}",
            uv=uv if textures else None, textures=textures)))


def _emitter(ctx: _Ctx, node: _Node, lights: list):
    kind = ctx.attr(node, "type")
    allowed = {"point": ("position", "to_world", "intensity"),
               "spot": ("to_world", "intensity", "cutoff_angle", "beam_width"),
               "directional": ("direction", "to_world", "irradiance"),
               "constant": ("radiance",), "envmap": ("filename", "scale", "to_world")}
    if kind not in allowed:
        hint = " (an area emitter goes inside a shape)" if kind == "area" else ""
        ctx.fail(node, f"unsupported emitter type {kind!r}{hint} (point, spot, directional, "
                 "constant, envmap)")
    p = _Props(ctx, node, allowed[kind])
    m = p.get("to_world", np.eye(4), "matrix")
    if kind == "point":
        pos = p.get("position", m[:3, 3])
        light = lambda: lt.point_light(pos, p.get("intensity", kind="rgb"))  # noqa: E731
    elif kind == "spot":
        cutoff = p.get("cutoff_angle", 20.0, "float")
        beam = p.get("beam_width", 0.75 * cutoff, "float")
        light = lambda: lt.spot_light(m[:3, 3], m[:3, 2], p.get("intensity", kind="rgb"),  # noqa: E731
                                      np.radians(min(beam, cutoff)), np.radians(cutoff))
    elif kind == "directional":
        d = p.get("direction", m[:3, :3] @ [0.0, 0, 1])  # the way the light travels
        light = lambda: lt.directional_light(-np.asarray(d), p.get("irradiance", kind="rgb"))  # noqa: E731
    elif kind == "constant":
        light = lambda: lt.constant_environment(p.get("radiance", 1.0, "rgb"))  # noqa: E731
    else:
        name = p.get("filename", kind="string")
        path = ctx.file(p.where["filename"], name, "environment map")
        if path.suffix.lower() != ".exr":
            ctx.fail(p.where["filename"], "only OpenEXR environment maps are read")
        lin = m[:3, :3]
        if not np.allclose(lin @ lin.T, np.eye(3), atol=1e-6):
            ctx.fail(node, "an envmap's to_world must be a rotation")
        image = read_exr(path)[0] * p.get("scale", 1.0, "float")
        light = lambda: lt.environment_map(image, lin @ _ENV_FRAME)  # noqa: E731
    lights.append(_try(ctx, node, light))


def _sensor(ctx: _Ctx, node: _Node, width, height) -> cm.Camera:
    if ctx.attr(node, "type") != "perspective":
        ctx.fail(node, "only the perspective sensor is supported")
    p = _Props(ctx, node, ("fov", "fov_axis", "focal_length", "to_world"), ("film", "sampler"),
               ignored=("near_clip", "far_clip"))
    w, h = 768, 576  # hdrfilm's defaults
    for c in p.plugins:
        if c.tag == "film":
            if ctx.attr(c, "type") != "hdrfilm":
                ctx.fail(c, "only the hdrfilm film is supported")
            f = _Props(ctx, c, ("width", "height"), ("rfilter",), ignored=(
                "pixel_format", "component_format", "file_format", "sample_border", "banner"))
            w, h = int(f.get("width", w, "float")), int(f.get("height", h, "float"))
            for r in f.plugins:  # jaxrt averages the samples inside each pixel's square
                if ctx.attr(r, "type") != "box":
                    ctx.fail(r, "only the box reconstruction filter is modelled (jaxrt "
                             "averages the samples in each pixel's square)")
                _Props(ctx, r, ())
    w, h = int(width or w), int(height or h)
    if "fov" in p.values:
        if "focal_length" in p.values:
            ctx.fail(node, "give fov or focal_length, not both")
        fov, axis = p.get("fov", kind="float"), p.get("fov_axis", "x", "string")
    else:  # a 35 mm film's diagonal (36 × 24 mm), as Mitsuba converts it
        text = p.values.get("focal_length", "50mm")
        focal = ctx.floats(p.where.get("focal_length", node), str(text).removesuffix("mm"), (1,))
        fov, axis = float(np.degrees(2 * np.arctan(np.hypot(36, 24) / (2 * focal[0])))), \
            "diagonal"
    m = p.get("to_world", np.eye(4), "matrix")
    if np.linalg.det(m[:3, :3]) < 0:
        ctx.fail(node, "a mirroring camera to_world (negative determinant) is not modelled")
    # Mitsuba's camera looks along its local +z with +y up (+x to the image's left)
    return _try(ctx, node, lambda: cm.look_at(eye=m[:3, 3], target=m[:3, 3] + m[:3, 2],
                                              up=m[:3, 1], fov_deg=fov, fov_axis=axis,
                                              width=w, height=h))


def load_mitsuba(path: str | os.PathLike, *, accel: str | None = None, width: int | None = None,
                 height: int | None = None, params: dict | None = None) -> Scene:
    """Read a Mitsuba 3 XML scene (the subset in this module's docstring) into a Scene.

    ``params`` override the file's ``<default>`` values (as Mitsuba's ``load_file(path,
    **params)``); ``width``/``height`` the film's size; ``accel`` is build_scene's.
    """
    path = Path(path)
    ctx = _Ctx(path)
    root = _parse(path, dict(params or {}))
    named, meshes, lights, camera = {}, [], [], None
    for node in root.children:
        if node.tag == "bsdf":
            if "id" not in node.attrs:
                ctx.fail(node, "a top-level BSDF needs an id to be referenced by")
            named[node.attrs["id"]] = _bsdf(ctx, node, named)
        elif node.tag == "shape":
            _shape(ctx, node, named, meshes, lights)
        elif node.tag == "emitter":
            _emitter(ctx, node, lights)
        elif node.tag == "sensor":
            if camera is not None:
                ctx.fail(node, "more than one sensor")
            camera = _sensor(ctx, node, width, height)
        elif node.tag not in ("default", "integrator", "sampler"):
            ctx.fail(node, "unsupported element at the top level" if node.tag in _PLUGIN_TAGS
                     or node.tag == "include" else "unknown element")
    if camera is None:
        ctx.fail(root, "no <sensor>: jaxrt needs a perspective camera")
    if not meshes:
        ctx.fail(root, "no mesh shape (rectangle, cube, obj, ply): jaxrt needs triangles")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            scene = build_scene(meshes, camera, lights, accel=accel or "auto")
    except (ValueError, TypeError) as e:
        raise FileFormatError(f"{path}: scene: {e}") from e
    for w in caught:
        warnings.warn(f"{path}: {w.message}", w.category, stacklevel=3)
    return scene
