"""Image files: HDR EXR (through OpenEXR) and 8-bit PNG previews (a small encoder of our own).

- ``write_exr`` / ``read_exr``: linear float32 RGB plus any extra channels (for example the
  per-pixel standard error as ``stderr.R``, ``stderr.G``, ``stderr.B``), bit-exact round trip.
- ``write_png``: a display preview of a linear HDR image: exposure scale ``2^exposure``, a tone
  curve (the piecewise sRGB OETF by default), clamp to [0, 1], 8 bits. The PNG is encoded by hand
  with ``zlib`` + ``struct`` (PNG spec, ISO/IEC 15948) so the runtime needs no imaging library.
  ``read_png`` decodes 8-bit RGB/RGBA PNGs (used by the tests; any filter type).

Every write is atomic: the bytes go to a temporary file in the target's directory, which is
fsynced and then renamed over the target with ``os.replace``; on any exception the temporary file
is removed and an existing target is left untouched. Readers never execute code (no pickle): a
missing file raises ``FileNotFoundError``, anything unreadable or malformed raises
``FileFormatError`` (a ``ValueError``) naming the file and the problem.

This module runs on the host (numpy), outside traced code: convert JAX arrays with ``np.asarray``
(done for you) after ``block_until_ready``.
"""

from __future__ import annotations

import contextlib
import os
import struct
import tempfile
import warnings
import zlib
from collections.abc import Callable, Mapping
from typing import BinaryIO

import numpy as np
import OpenEXR

__all__ = ["FileFormatError", "read_exr", "read_exr_attributes", "read_png", "srgb_oetf",
           "write_atomically", "write_exr", "write_png"]

_RGB = ("R", "G", "B")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_TONEMAPS = ("srgb", "clamp", "reinhard")
# header attributes every EXR file has (OpenEXR 3: ImfHeader.h), not user attributes
_STANDARD_ATTRIBUTES = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
    "screenWindowCenter", "screenWindowWidth", "type", "tiles", "name", "version",
    "chunkCount", "view"})


class FileFormatError(ValueError):
    """A file exists but cannot be decoded: its message names the file and what is wrong."""


# ---------------------------------------------------------------------------------------------
# Atomic writes
# ---------------------------------------------------------------------------------------------


def write_atomically(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """Call ``write(f)`` on a temporary file beside ``path``, fsync it, then rename it to ``path``.

    The rename is atomic on POSIX and Windows (``os.replace``), so readers see either the old
    file or the complete new one. On any exception (including KeyboardInterrupt) the temporary
    file is deleted and the exception propagates; an existing ``path`` is untouched. A file
    replaced keeps its permission bits; a new one gets rw-r--r--. Every writer of jaxrt uses
    it (EXR, PNG, the gallery's figure); for your own files::

        write_atomically("plot.png", lambda f: fig.savefig(f, format="png"))
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    # keep the mode of a file we replace; a new file gets rw-r--r-- (mkstemp makes it 0600)
    mode = os.stat(path).st_mode & 0o777 if os.path.exists(path) else 0o644
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    # make the rename itself durable; not every platform/filesystem allows fsync on a directory
    with contextlib.suppress(OSError):
        dir_fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def _check_image(image, what: str = "image") -> np.ndarray:
    """``image`` as a numpy float array of shape (H, W, 3), H, W ≥ 1, or a ValueError."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{what} must have shape (H, W, 3) with H, W >= 1, got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"{what} must hold real numbers, got dtype {arr.dtype}")
    return arr


# ---------------------------------------------------------------------------------------------
# EXR
# ---------------------------------------------------------------------------------------------


def _exr_file(header: dict, channels: dict) -> OpenEXR.File:
    """Build the OpenEXR file object (a seam so tests can simulate a failing encoder)."""
    return OpenEXR.File(header, channels)


def write_exr(
    path: str | os.PathLike,
    image,
    extra_channels: Mapping[str, object] | None = None,
    attributes: Mapping[str, int | float | str] | None = None,
) -> None:
    """Write a linear RGB image, and optional extra channels, as a float32 OpenEXR file, atomically.

    Args:
      path: target file; replaced atomically (see the module docstring).
      image: (H, W, 3) linear radiance, any real dtype; stored as 32-bit float channels
        ``R``, ``G``, ``B`` (values are kept as they are, NaN and inf included: EXR is a faithful
        format, the preview writer is the one that complains).
      extra_channels: name → (H, W) array, stored as one channel ``name``, or name → (H, W, 3),
        stored as the layer ``name.R``, ``name.G``, ``name.B`` (the EXR layer convention, e.g.
        ``{"stderr": err}``). Names must be non-empty, must not collide with each other or with
        ``R``, ``G``, ``B``.
      attributes: extra header attributes (name → int, float or str), e.g. ``{"spp": 64}``;
        read back with :func:`read_exr_attributes`. Names must not be standard EXR attributes.

    Raises:
      ValueError: wrong shapes, bad or colliding channel names, bad attributes.

    ZIP compression (lossless). Reference: OpenEXR 3 Python API, ``OpenEXR.File(header, channels)``.
    """
    rgb = _check_image(image).astype(np.float32)
    height, width = rgb.shape[:2]
    channels = {c: np.ascontiguousarray(rgb[..., k]) for k, c in enumerate(_RGB)}
    for name, value in (extra_channels or {}).items():
        if not isinstance(name, str) or not name or name.startswith(".") or name.endswith("."):
            raise ValueError(f"extra channel name must be a non-empty layer name, got {name!r}")
        arr = np.asarray(value)
        if arr.shape == (height, width):
            planes = {name: arr}
        elif arr.shape == (height, width, 3):
            planes = {f"{name}.{c}": arr[..., k] for k, c in enumerate(_RGB)}
        else:
            raise ValueError(
                f"extra channel {name!r} must have shape {(height, width)} or "
                f"{(height, width, 3)}, got {arr.shape}"
            )
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"extra channel {name!r} must hold real numbers, got {arr.dtype}")
        for full_name, plane in planes.items():
            if full_name in channels:
                raise ValueError(f"extra channel {full_name!r} collides with another channel")
            channels[full_name] = np.ascontiguousarray(plane, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for name, value in (attributes or {}).items():
        if not isinstance(name, str) or not name or name in _STANDARD_ATTRIBUTES:
            raise ValueError(f"EXR attribute name must be a non-standard name, got {name!r}")
        if isinstance(value, bool) or not isinstance(value, int | float | str | np.integer
                                                         | np.floating):
            raise ValueError(f"EXR attribute {name!r} must be an int, float or str, got "
                             f"{type(value).__name__}")
        header[name] = value.item() if isinstance(value, np.generic) else value
    exr = _exr_file(header, channels)
    write_atomically(path, exr.write)


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read an OpenEXR file into a float32 (H, W, 3) RGB image and a dict of the other channels.

    Extra channels come back grouped the way ``write_exr`` takes them: a layer with exactly the
    channels ``name.R``, ``name.G``, ``name.B`` becomes ``extra[name]`` of shape (H, W, 3); any
    other channel (``A``, ``Z``, ``spp``, a lone ``foo.R``) is ``extra[full_name]`` of shape (H, W).
    Half-float and uint channels are converted to float32. Only the first part of a multi-part
    file is read.

    Raises:
      FileNotFoundError: no such file.
      FileFormatError: not an OpenEXR file, truncated or corrupt, no ``R``/``G``/``B`` channels,
        or subsampled channels (message names the file and the problem).
    """
    path = os.fspath(path)
    exr = _open_exr(path)
    try:
        raw = {name: channel.pixels for name, channel in exr.channels().items()}
    except Exception as err:  # OpenEXR raises RuntimeError or ValueError on bad bytes
        raise FileFormatError(f"{path}: truncated or corrupt OpenEXR file ({err})") from err
    missing = [c for c in _RGB if c not in raw]
    if missing:
        raise FileFormatError(
            f"{path}: missing channel(s) {', '.join(missing)} (found: {', '.join(sorted(raw))})"
        )
    shape = raw["R"].shape
    for name, pixels in raw.items():
        if pixels is None or pixels.shape != shape or len(shape) != 2:
            got = None if pixels is None else pixels.shape
            raise FileFormatError(f"{path}: channel {name!r} has shape {got}, expected {shape}")
    planes = {name: np.asarray(pixels, dtype=np.float32) for name, pixels in raw.items()}
    image = np.stack([planes.pop(c) for c in _RGB], axis=-1)
    # regroup complete name.R/G/B layers into (H, W, 3) arrays
    layers = {name.rsplit(".", 1)[0] for name in planes if "." in name}
    extra: dict[str, np.ndarray] = {}
    for layer in sorted(layers):
        members = {n for n in planes if n.rsplit(".", 1)[0] == layer and "." in n}
        if members == {f"{layer}.{c}" for c in _RGB}:
            extra[layer] = np.stack([planes.pop(f"{layer}.{c}") for c in _RGB], axis=-1)
    extra.update(planes)
    return image, extra


def _open_exr(path: str) -> OpenEXR.File:
    """Open an EXR file (pixels are read by the caller), with errors that say what is wrong.

    OpenEXR reports a file it cannot read as "Unable to open ... for read", which reads like
    a missing file: check the magic number first, then call anything else truncated or corrupt.
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such EXR file")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != b"\x76\x2f\x31\x01":
        raise FileFormatError(f"{path}: not an OpenEXR file (bad magic number)")
    try:
        return OpenEXR.File(path, separate_channels=True)
    except Exception as err:  # OpenEXR raises RuntimeError or ValueError on bad bytes
        size = os.path.getsize(path)
        raise FileFormatError(f"{path}: truncated or corrupt OpenEXR file ({size} bytes; "
                              f"OpenEXR: {err})") from err


def read_exr_attributes(path: str | os.PathLike) -> dict:
    """The non-standard header attributes of an EXR file (e.g. ``{"spp": 64}`` written by
    ``jaxrt render``), as Python ints, floats and strings."""
    path = os.fspath(path)
    header = _open_exr(path).header()
    return {k: v for k, v in header.items() if k not in _STANDARD_ATTRIBUTES}


# ---------------------------------------------------------------------------------------------
# PNG
# ---------------------------------------------------------------------------------------------


def srgb_oetf(x: np.ndarray) -> np.ndarray:
    """The sRGB opto-electronic transfer function (IEC 61966-2-1), for x in [0, 1].

        V = 12.92 x                     for x ≤ 0.0031308
        V = 1.055 x^(1/2.4) − 0.055     otherwise

    Host-side numpy; the two branches meet at x = 0.0031308 (V ≈ 0.04045).
    """
    x = np.asarray(x)
    # max() keeps the power's argument positive in the branch that np.where discards
    return np.where(
        x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055
    )


def _tonemap_to_8bit(image: np.ndarray, exposure: float, tonemap: str) -> np.ndarray:
    """Linear HDR (H, W, 3) → display uint8 (H, W, 3): 2^exposure, tone curve, clamp, round."""
    x = image.astype(np.float64) * 2.0**exposure
    if tonemap == "srgb":
        v = srgb_oetf(np.clip(x, 0.0, 1.0))
    elif tonemap == "clamp":
        v = np.clip(x, 0.0, 1.0)
    else:  # reinhard: x / (1 + x) compresses [0, inf) into [0, 1) before the sRGB curve
        x = np.maximum(x, 0.0)
        v = srgb_oetf(x / (1.0 + x))
    # round half up to the nearest of the 256 levels
    return np.floor(np.clip(v, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: big-endian length, type, data, CRC-32 of type + data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _encode_png(rgb8: np.ndarray, srgb: bool) -> bytes:
    """Encode (H, W, 3) uint8 as a non-interlaced 8-bit truecolour PNG (filter type 0 per row)."""
    height, width = rgb8.shape[:2]
    # bit depth 8, colour type 2 (RGB), deflate, adaptive filtering, no interlace
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    # each scanline is preceded by its filter-type byte (0 = None)
    rows = np.concatenate([np.zeros((height, 1), np.uint8), rgb8.reshape(height, 3 * width)], 1)
    # sRGB chunk (perceptual intent) for curve-encoded data, else gAMA = 1.0 for linear values
    colour = (
        _png_chunk(b"sRGB", b"\x00") if srgb else _png_chunk(b"gAMA", struct.pack(">I", 100000))
    )
    return (
        _PNG_SIGNATURE
        + _png_chunk(b"IHDR", ihdr)
        + colour
        + _png_chunk(b"IDAT", zlib.compress(rows.tobytes(), 6))
        + _png_chunk(b"IEND", b"")
    )


def write_png(
    path: str | os.PathLike, image, exposure: float = 0.0, tonemap: str = "srgb"
) -> np.ndarray:
    """Write an 8-bit sRGB PNG preview of a linear HDR image, atomically.

    Per channel, with x the linear value:
      - scale by 2^exposure (exposure in photographic stops);
      - ``tonemap="srgb"`` (default): clamp to [0, 1], then the sRGB OETF (see ``srgb_oetf``);
        ``"clamp"``: clamp to [0, 1] and store linearly (data images: masks, normals);
        ``"reinhard"``: x / (1 + x) (negatives clamped to 0), then the sRGB OETF;
      - quantise to 8 bits: floor(255 V + 1/2).

    Non-finite values (NaN, ±inf) cannot be displayed: they become 0 (black) and a
    ``RuntimeWarning`` gives their count. Negative values clamp to 0 without a warning.

    Args:
      path: target file; replaced atomically.
      image: (H, W, 3) linear RGB, any real dtype.
      exposure: finite number of stops.
      tonemap: one of "srgb", "clamp", "reinhard".

    Returns:
      The (H, W, 3) uint8 pixels written.
    """
    arr = _check_image(image)
    if tonemap not in _TONEMAPS:
        raise ValueError(f"tonemap must be one of {_TONEMAPS}, got {tonemap!r}")
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure}")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        warnings.warn(
            f"{os.fspath(path)}: {int(bad.sum())} non-finite value(s) (NaN/inf) written as 0 "
            "in the PNG preview",
            RuntimeWarning,
            stacklevel=2,
        )
        arr = np.where(bad, 0.0, arr)
    rgb8 = _tonemap_to_8bit(arr, float(exposure), tonemap)
    data = _encode_png(rgb8, srgb=tonemap != "clamp")
    write_atomically(path, lambda f: f.write(data))
    return rgb8


def _unfilter(raw: np.ndarray, height: int, stride: int, bpp: int) -> np.ndarray:
    """Undo PNG scanline filters (types 0–4, PNG spec §9) on the inflated IDAT bytes."""
    rows = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), np.int32)
    prev = np.zeros(stride, np.int32)
    for y in range(height):  # host-side decoder: rows depend on the previous row
        kind, line = rows[y, 0], rows[y, 1:].astype(np.int32)
        if kind == 0:
            cur = line
        elif kind == 1:  # Sub: running sum over pixels, per byte lane, mod 256
            cur = np.cumsum(line.reshape(-1, bpp), axis=0).reshape(-1) % 256
        elif kind == 2:  # Up
            cur = (line + prev) % 256
        elif kind in (3, 4):  # Average, Paeth: sequential within the row
            cur = np.zeros(stride + bpp, np.int32)
            up = np.concatenate([np.zeros(bpp, np.int32), prev])
            for i in range(stride):
                a, b, c = cur[i], up[i + bpp], up[i]
                if kind == 3:
                    pred = (a + b) // 2
                else:
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i + bpp] = (line[i] + pred) % 256
            cur = cur[bpp:]
        else:
            raise FileFormatError(f"unknown PNG filter type {kind} in row {y}")
        out[y] = prev = cur
    return out.astype(np.uint8)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Decode an 8-bit, non-interlaced RGB or RGBA PNG into (H, W, 3) or (H, W, 4) uint8.

    Checks the signature and every chunk's CRC. Pixels are returned as stored (no gamma applied).

    Raises:
      FileNotFoundError: no such file.
      FileFormatError: not a PNG, truncated, bad CRC, or an unsupported variant (palette,
        greyscale, 16-bit, interlaced); the message names the file.
    """
    path = os.fspath(path)
    with open(path, "rb") as f:
        data = f.read()
    if not data.startswith(_PNG_SIGNATURE):
        raise FileFormatError(f"{path}: not a PNG file (bad signature)")
    pos, header, idat = len(_PNG_SIGNATURE), None, []
    while True:
        if pos + 8 > len(data):
            raise FileFormatError(f"{path}: truncated PNG (no IEND chunk)")
        (length,), kind = struct.unpack(">I", data[pos : pos + 4]), data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        crc = data[pos + 8 + length : pos + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise FileFormatError(f"{path}: truncated PNG chunk {kind!r}")
        if struct.unpack(">I", crc)[0] != zlib.crc32(kind + body):
            raise FileFormatError(f"{path}: CRC mismatch in PNG chunk {kind!r}")
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise FileFormatError(f"{path}: PNG without IHDR chunk")
    width, height, depth, colour_type, _, _, interlace = header
    if depth != 8 or colour_type not in (2, 6) or interlace != 0:
        raise FileFormatError(
            f"{path}: unsupported PNG variant (bit depth {depth}, colour type {colour_type}, "
            f"interlace {interlace}); only 8-bit non-interlaced RGB/RGBA is read"
        )
    channels = 3 if colour_type == 2 else 4
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8)
    except zlib.error as err:
        raise FileFormatError(f"{path}: corrupt PNG image data ({err})") from err
    if raw.size != height * (width * channels + 1):
        raise FileFormatError(
            f"{path}: PNG image data has {raw.size} bytes, expected "
            f"{height * (width * channels + 1)}"
        )
    try:
        pixels = _unfilter(raw, height, width * channels, channels)
    except FileFormatError as err:
        raise FileFormatError(f"{path}: {err}") from err
    return pixels.reshape(height, width, channels)
