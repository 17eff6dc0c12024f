"""Texture maps from mesh files: an MTL ``map_Kd`` and a glTF ``baseColorTexture`` bound as
the ``kd`` or ``ks`` texture of the mesh's material.

:func:`jaxrt.scene.meshio.load_meshes` (``textures=True``, the default) calls in here once
its meshes are grouped by material, and gets each ``MeshData`` back with
``MeshData.textures = {field: jaxrt.scene.textures.Texture}`` set, or unchanged;
``textures=False`` skips all of this, and its warnings and errors (for a caller that replaces
the file's materials).

Conventions: a texture is looked up at the mesh's per-vertex ``MeshData.uv``, ``u`` along the
image's width and ``v`` up its height (``v = 0`` the image's bottom row) in every format (see
:mod:`jaxrt.scene.meshio`); 8-bit images are sRGB (``encoding="auto"``), EXR images linear.

  - OBJ: a material's ``map_Kd`` is read from the MTL text (trimesh keeps no file name for an
    image it fails to open and drops it silently, so the MTL is parsed here: the first
    ``mtllib`` line, as trimesh reads it), relative to the MTL's folder, with
    :func:`jaxrt.scene.textures.load_texture` (PNG or EXR; ``encoding="auto"``: 8-bit images
    are sRGB), and bound to ``kd``; the texture replaces ``Kd`` (which stays the material's
    value elsewhere, e.g. for the ``kd + ks ≤ 1`` check). ``-clamp on`` → ``wrap="clamp"``;
    ``-blendu``, ``-blendv``, ``-boost``, ``-cc``, ``-texres`` change nothing here; ``-o``,
    ``-s``, ``-t``, ``-mm``, ``-bm`` other than the identity and ``-imfchan`` raise.
  - glTF/GLB: ``baseColorTexture`` (the image trimesh decodes, embedded or by URI) times
    ``baseColorFactor`` (in linear), bound to ``kd`` of a diffuse material or ``ks`` of a
    conductor or mirror; sampler ``REPEAT``/``CLAMP_TO_EDGE`` → ``wrap``, ``magFilter``
    ``NEAREST`` → ``filter="nearest"``. ``texCoord`` > 0, ``KHR_texture_transform`` and
    mirrored or mixed wrap modes raise.

Errors and warnings: a texture map on a mesh without UVs, a missing image
(``FileNotFoundError``), an image that cannot be read (a PNG variant
:func:`jaxrt.scene.images.read_png` refuses), or a map on a material without the field (an
MTL mirror) raise ``jaxrt.scene.images.FileFormatError`` (a ``ValueError``), naming the mesh
file and the material. An MTL ``map_Kd`` image that is neither PNG nor EXR (``.jpg``,
``.tga``, ``.bmp``, ...) is not read: a warning names the OBJ, the material, the MTL line and
the image, and the mesh keeps the material's ``Kd``, untextured (convert the image to PNG to
texture it). A file's texture is never dropped silently.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, NamedTuple

import numpy as np

from jaxrt.scene.images import FileFormatError

#: A :class:`jaxrt.scene.meshio.MeshData` (meshio imports this module, so its type is not
#: imported here: the layering allows no cycle, not even for type checking).
MeshData = Any

# image suffixes jaxrt.scene.textures.load_texture reads
_IMAGE_SUFFIXES = (".png", ".exr")


def _warn(msg: str) -> None:
    # as jaxrt.scene.meshio._warn: the same category, pointing past the loader's helpers
    warnings.warn(msg, UserWarning, stacklevel=3)


# ---------------------------------------------------------------------------------------------
# MTL map_Kd
# ---------------------------------------------------------------------------------------------

# map_Kd options (MTL spec) and how many arguments each takes (-o, -s, -t: 1 to 3 numbers)
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1}
# options that do not change what a bilinear lookup returns, with any value
_HARMLESS_OPTIONS = ("-blendu", "-blendv", "-boost", "-cc", "-texres")
# options that change it, and their default (identity) values: anything else is refused
_IDENTITY_OPTIONS = {"-o": (0.0, 0.0, 0.0), "-s": (1.0, 1.0, 1.0), "-t": (0.0, 0.0, 0.0),
                     "-mm": (0.0, 1.0), "-bm": (1.0,)}


class _TextureMap(NamedTuple):
    """One ``map_Kd`` line: the MTL it is in (and its line number), the image, the wrap."""

    mtl: str
    line: int
    image: str
    wrap: str


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _map_statement(where: str, rest: str) -> tuple[str, str]:
    """(file name, wrap) of the text after ``map_Kd``: options first, then the file name (which
    may contain spaces). Options that would change the lookup (``-o``, ``-s``, ``-t``, ``-mm``,
    ``-bm`` other than the identity, ``-imfchan``) raise FileFormatError; ``-clamp on`` is
    ``wrap="clamp"``."""
    tokens = rest.split()
    wrap, i = "repeat", 0
    while i < len(tokens) and tokens[i].lower() in _MAP_OPTIONS:
        option, i = tokens[i].lower(), i + 1
        args = []
        while (i < len(tokens) and len(args) < _MAP_OPTIONS[option]
               and (option in ("-clamp", "-blendu", "-blendv", "-cc", "-imfchan")
                    or _is_number(tokens[i]))):
            args.append(tokens[i])
            i += 1
        if option == "-clamp":
            wrap = "clamp" if [a.lower() for a in args] == ["on"] else "repeat"
        elif option in _IDENTITY_OPTIONS:
            values = tuple(float(a) for a in args)
            default = _IDENTITY_OPTIONS[option]
            if not args or values != default[: len(values)]:
                raise FileFormatError(f"{where}: map_Kd option {option} {' '.join(args)} is not "
                                      "modelled (only -clamp; remove it or bake it into the "
                                      "image or the UVs)")
        elif option not in _HARMLESS_OPTIONS:
            raise FileFormatError(f"{where}: map_Kd option {option} is not modelled")
    name = " ".join(tokens[i:])
    if not name:
        raise FileFormatError(f"{where}: map_Kd without a file name")
    return name, wrap


def _mtl_texture_maps(path: str) -> dict[str, _TextureMap]:
    """``{material name: _TextureMap}`` of the ``map_Kd`` lines in the OBJ's MTL file.

    trimesh reads only the first ``mtllib`` line (its rest is the MTL's path, relative to the
    OBJ), loads a ``map_Kd`` image with PIL when it can and drops it silently when it cannot,
    and keeps no file name for an image it could not load; so the MTL text is read here, the
    same file trimesh reads. Image paths are relative to the MTL's folder.
    """
    with open(path, encoding="utf-8", errors="replace") as f:
        mtllib = next((line.split(None, 1)[1].strip() for line in f
                       if line.split()[:1] == ["mtllib"] and len(line.split()) > 1), None)
    if mtllib is None:
        return {}
    mtl = os.path.join(os.path.dirname(path), mtllib)
    if not os.path.isfile(mtl):
        return {}  # trimesh loads no materials either: the meshes are grey diffuse
    maps, material = {}, None
    with open(mtl, encoding="utf-8", errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            split = line.strip().split(None, 1)
            if len(split) < 2:
                continue
            key = split[0].lower()
            if key == "newmtl":
                material = " ".join(split[1].split())  # as trimesh names it
            elif key == "map_kd" and material is not None:
                where = f"{mtl}:{lineno}: material {material!r}"
                image, wrap = _map_statement(where, split[1])
                maps[material] = _TextureMap(mtl, lineno, image, wrap)
    return maps


def _map_image(tmap: _TextureMap) -> str:
    """The path of ``tmap``'s image: relative to the MTL's folder, ``\\`` read as a folder
    separator when the name as written is not a file (an MTL written on Windows)."""
    image = os.path.join(os.path.dirname(tmap.mtl), tmap.image)
    if not os.path.isfile(image) and "\\" in tmap.image:  # a Windows path
        image = os.path.join(os.path.dirname(tmap.mtl), *tmap.image.split("\\"))
    return image


def _load_map(path: str, material: str, tmap: _TextureMap, cache: dict):
    """The kd :class:`jaxrt.scene.textures.Texture` of ``tmap`` (read once per image and wrap).

    Raises FileNotFoundError for a missing image, FileFormatError for one that cannot be read
    (a PNG variant :func:`jaxrt.scene.images.read_png` refuses; images that are not PNG or EXR
    are skipped with a warning before this, by :func:`_with_texture_map`), naming the OBJ file,
    the material and the MTL line."""
    from jaxrt.scene.textures import load_texture

    where = f"{path}: material {material!r} ({tmap.mtl}:{tmap.line}: map_Kd {tmap.image})"
    image = _map_image(tmap)
    key = (os.path.realpath(image), tmap.wrap)
    if key not in cache:
        if not os.path.isfile(image):
            raise FileNotFoundError(f"{where}: texture image not found: {image}")
        try:
            cache[key] = load_texture(image, wrap=tmap.wrap, encoding="auto")
        except ValueError as err:  # FileFormatError too
            raise FileFormatError(f"{where}: {err}") from err
    return cache[key]


def _with_texture_map(path: str, md: MeshData, tmap: _TextureMap | None,
                      cache: dict) -> MeshData:
    """``md`` with the ``map_Kd`` texture of its material (if any) bound to ``kd``.

    An image that is neither PNG nor EXR (a JPEG, TGA, BMP, ...) is not read: ``md`` comes
    back untextured, with its material's ``Kd``, and a warning naming the OBJ file, the
    material, the MTL line and the image (a missing one is still a FileNotFoundError)."""
    if tmap is None:
        return md
    where = f"{path}: material {md.name!r} ({tmap.mtl}:{tmap.line}: map_Kd {tmap.image})"
    suffix = os.path.splitext(tmap.image)[1].lower()
    if suffix not in _IMAGE_SUFFIXES:
        image = _map_image(tmap)
        if not os.path.isfile(image):
            raise FileNotFoundError(f"{where}: texture image not found: {image}")
        _warn(f"{where}: only PNG and EXR images are read, not {suffix or 'no suffix'!r}; the "
              "material's Kd is used instead (convert the image to PNG to texture it)")
        return md
    if md.uv is None:
        raise FileFormatError(f"{where}: the mesh has no texture coordinates (vt lines) to look "
                              "the image up with")
    if md.material.kind not in ("diffuse", "phong"):
        raise FileFormatError(f"{where}: a {md.material.kind} material (illum 3 or 5 with Kd "
                              "0) has no kd to texture")
    return md._replace(textures={"kd": _load_map(path, md.name, tmap, cache)})


# ---------------------------------------------------------------------------------------------
# glTF baseColorTexture
# ---------------------------------------------------------------------------------------------

# glTF sampler codes (glTF 2.0 spec, "Samplers")
_GLTF_WRAP = {10497: "repeat", 33071: "clamp"}  # MIRRORED_REPEAT (33648) is not modelled
_GLTF_NEAREST = 9728


def _with_gltf_texture(path: str, gltf: dict, md: MeshData, entry: dict | None,
                       mat) -> MeshData:
    """``md`` with its glTF material's ``baseColorTexture`` bound to ``kd`` (diffuse) or ``ks``
    (conductor, mirror): the image trimesh decoded (PIL; glTF images may be embedded), times
    ``baseColorFactor`` (linear, as the glTF spec multiplies them), with the sampler's wrap
    and magnification filter. Raises FileFormatError for what is not modelled (``texCoord`` >
    0, ``KHR_texture_transform``, mirrored or mixed wrap modes), an image trimesh could not
    read, or a mesh without ``TEXCOORD_0``."""
    info = (entry or {}).get("pbrMetallicRoughness", {}).get("baseColorTexture")
    if info is None:
        return md
    where = f"{path}: material {entry.get('name')!r}: baseColorTexture"
    if int(info.get("texCoord", 0)) != 0:
        raise FileFormatError(f"{where}: texCoord {info['texCoord']} is not modelled (only "
                              "TEXCOORD_0)")
    if info.get("extensions"):
        raise FileFormatError(f"{where}: extensions {', '.join(info['extensions'])} are not "
                              "modelled")
    if md.uv is None:
        raise FileFormatError(f"{where}: the mesh has no TEXCOORD_0 to look the image up with")
    try:
        tex = gltf["textures"][int(info["index"])]
        sampler = gltf.get("samplers", [])[tex["sampler"]] if "sampler" in tex else {}
    except (KeyError, IndexError, TypeError, ValueError) as err:
        raise FileFormatError(f"{where}: bad texture or sampler reference ({err})") from err
    wraps = {sampler.get("wrapS", 10497), sampler.get("wrapT", 10497)}
    if len(wraps) != 1 or next(iter(wraps)) not in _GLTF_WRAP:
        raise FileFormatError(f"{where}: sampler wrap modes {sorted(wraps)} are not modelled "
                              "(REPEAT 10497 or CLAMP_TO_EDGE 33071, the same on both axes)")
    wrap = _GLTF_WRAP[next(iter(wraps))]
    filter = "nearest" if sampler.get("magFilter") == _GLTF_NEAREST else "bilinear"
    image = getattr(mat, "baseColorTexture", None)
    if image is None:
        source = gltf.get("images", [{}] * (tex.get("source", 0) + 1))[tex.get("source", 0)]
        raise FileFormatError(f"{where}: trimesh could not read the image "
                              f"{source.get('uri', source.get('name', ''))[:80]!r} (missing, "
                              "or a format PIL does not decode)")
    from jaxrt.scene.textures import srgb_to_linear, texture

    texels = np.asarray(image.convert("RGB"), np.uint8)
    name = f"{os.path.basename(path)}:{entry.get('name')}:baseColorTexture"
    factor = np.asarray(entry["pbrMetallicRoughness"].get("baseColorFactor", [1.0] * 4),
                        np.float64)[:3]
    if np.all(factor == 1):
        t = texture(texels, wrap=wrap, filter=filter, encoding="auto", name=name)
    else:  # sRGB-decoded texels times the factor, linear
        linear = srgb_to_linear(texels / 255.0, xp=np) * np.clip(factor, 0, 1)
        t = texture(linear, wrap=wrap, filter=filter, encoding="linear", name=name)
    field = "kd" if md.material.kind == "diffuse" else "ks"
    return md._replace(textures={field: t})
