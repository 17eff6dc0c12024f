"""Image files: EXR and PNG round trips, sRGB values, atomic writes, clear errors."""

import os
import struct
import warnings
import zlib

import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.scene import images as io


def _image(height=5, width=7, seed=0):
    rng = np.random.default_rng(seed)
    # HDR content: values above 1, tiny values and exact zeros
    img = rng.exponential(1.0, (height, width, 3)).astype(np.float32)
    img[0, 0] = [0.0, 1e-30, 65504.0 * 4]
    return img


def _listing(directory):
    return sorted(os.listdir(directory))


# ---------------------------------------------------------------------------------------------
# EXR
# ---------------------------------------------------------------------------------------------


def test_exr_round_trip_is_bit_exact_with_extra_channels(tmp_path):
    img = _image()
    err = _image(seed=1) * 0.01
    spp = np.full(img.shape[:2], 64.0, np.float32)
    path = tmp_path / "out.exr"
    io.write_exr(path, img, {"stderr": err, "spp": spp, "depth.Z": spp * 2})
    image, extra = io.read_exr(path)
    # float32 EXR channels store the exact bits: equality, not closeness
    assert image.dtype == np.float32 and image.shape == img.shape
    np.testing.assert_array_equal(image, img)
    assert set(extra) == {"stderr", "spp", "depth.Z"}
    np.testing.assert_array_equal(extra["stderr"], err)
    np.testing.assert_array_equal(extra["spp"], spp)
    np.testing.assert_array_equal(extra["depth.Z"], spp * 2)
    # no temporary file left beside the target
    assert _listing(tmp_path) == ["out.exr"]


def test_exr_accepts_jax_and_float64_and_keeps_nan(tmp_path):
    img64 = _image().astype(np.float64)
    img64[1, 1, 1] = np.nan
    io.write_exr(tmp_path / "a.exr", img64)
    image, extra = io.read_exr(tmp_path / "a.exr")
    # stored as float32: equal to the float32 rounding of the input, NaN kept (faithful format)
    np.testing.assert_array_equal(image, img64.astype(np.float32))
    assert extra == {}
    io.write_exr(tmp_path / "b.exr", jnp.asarray(_image()))
    np.testing.assert_array_equal(io.read_exr(tmp_path / "b.exr")[0], _image())


def test_exr_channel_names_as_in_the_file(tmp_path):
    import OpenEXR

    io.write_exr(tmp_path / "a.exr", _image(), {"stderr": _image(seed=2)})
    names = set(OpenEXR.File(str(tmp_path / "a.exr"), separate_channels=True).channels())
    # the standard-error layer follows the EXR "layer.channel" convention
    assert names == {"R", "G", "B", "stderr.R", "stderr.G", "stderr.B"}


def test_exr_reads_half_float_and_alpha_written_by_others(tmp_path):
    import OpenEXR

    rng = np.random.default_rng(3)
    planes = {c: rng.random((3, 4)).astype(np.float16) for c in "RGBA"}
    # OpenEXR.File wraps the dict values in place: hand it a copy
    OpenEXR.File({}, dict(planes)).write(str(tmp_path / "h.exr"))
    image, extra = io.read_exr(tmp_path / "h.exr")
    assert image.dtype == np.float32
    # half → float32 widening is exact
    np.testing.assert_array_equal(image[..., 1], planes["G"].astype(np.float32))
    np.testing.assert_array_equal(extra["A"], planes["A"].astype(np.float32))


@pytest.mark.parametrize(
    "bad, extra",
    [
        (np.zeros((4, 4)), None),
        (np.zeros((4, 4, 4)), None),
        (np.zeros((0, 4, 3)), None),
        (np.zeros((4, 4, 3)), {"stderr": np.zeros((4, 5, 3))}),
        (np.zeros((4, 4, 3)), {"R": np.zeros((4, 4))}),
        (np.zeros((4, 4, 3)), {"": np.zeros((4, 4))}),
        (np.zeros((4, 4, 3)), {"n": np.zeros((4, 4, 3)), "n.G": np.zeros((4, 4))}),
    ],
    ids=["2d", "4ch", "empty", "extra-shape", "collide-R", "empty-name", "collide-layer"],
)
def test_exr_write_rejects_bad_shapes_and_names(tmp_path, bad, extra):
    with pytest.raises(ValueError):
        io.write_exr(tmp_path / "x.exr", bad, extra)
    # nothing written, no temporary left
    assert _listing(tmp_path) == []


def _malformed(tmp_path, kind):
    path = tmp_path / f"{kind}.exr"
    if kind == "text":
        path.write_text("this is not an image\n")
    elif kind == "random":
        path.write_bytes(np.random.default_rng(0).bytes(4096))
    elif kind == "empty":
        path.write_bytes(b"")
    else:  # truncated at a fraction of a valid file's length
        good = tmp_path / "good.exr"
        io.write_exr(good, _image(64, 64))
        data = good.read_bytes()
        path.write_bytes(data[: int(len(data) * float(kind.split("-")[1]))])
    return path


@pytest.mark.parametrize("kind", ["text", "random", "empty", "trunc-0.1", "trunc-0.5", "trunc-0.9"])
def test_exr_read_malformed_raises_named_error(tmp_path, kind):
    path = _malformed(tmp_path, kind)
    with pytest.raises(io.FileFormatError, match=str(path.name)):
        io.read_exr(path)


def test_exr_missing_file_and_missing_rgb(tmp_path):
    import OpenEXR

    with pytest.raises(FileNotFoundError, match="nope.exr"):
        io.read_exr(tmp_path / "nope.exr")
    OpenEXR.File({}, {"Y": np.ones((2, 2), np.float32)}).write(str(tmp_path / "lum.exr"))
    with pytest.raises(io.FileFormatError, match=r"lum\.exr: missing channel\(s\) R, G, B"):
        io.read_exr(tmp_path / "lum.exr")


# ---------------------------------------------------------------------------------------------
# PNG
# ---------------------------------------------------------------------------------------------


def test_srgb_oetf_reference_values():
    # IEC 61966-2-1 values: both branches at the breakpoint agree to 1e-7 (the curve is continuous)
    x = np.array([0.0, 0.0031308, 0.5, 1.0])
    v = io.srgb_oetf(x)
    np.testing.assert_allclose(v, [0.0, 0.04045, 0.735356983, 1.0], rtol=0, atol=2e-6)
    lo = 12.92 * 0.0031308
    hi = 1.055 * 0.0031308 ** (1 / 2.4) - 0.055
    assert abs(lo - hi) < 1e-7


def test_png_sRGB_values_and_pixels_round_trip(tmp_path):
    # one pixel row with the four reference values in the red channel, others mixed
    img = np.zeros((2, 4, 3), np.float32)
    img[0, :, 0] = [0.0, 0.0031308, 0.5, 1.0]
    img[1] = _image(1, 4)[0]
    path = tmp_path / "p.png"
    written = io.write_png(path, img)
    # round(255 · V): 0 → 0, 0.0031308 → 10.31 → 10, 0.5 → 187.52 → 188, 1 → 255
    assert written[0, :, 0].tolist() == [0, 10, 188, 255]
    decoded = io.read_png(path)
    assert decoded.dtype == np.uint8 and decoded.shape == (2, 4, 3)
    np.testing.assert_array_equal(decoded, written)
    # expected bytes recomputed independently of the module's curve function
    ref = np.clip(img.astype(np.float64), 0, 1)
    ref = np.where(ref <= 0.0031308, 12.92 * ref, 1.055 * ref ** (1 / 2.4) - 0.055)
    np.testing.assert_array_equal(decoded, np.floor(ref * 255 + 0.5).astype(np.uint8))
    assert _listing(tmp_path) == ["p.png"]


def test_png_decodes_with_pillow(tmp_path):
    image_mod = pytest.importorskip("PIL.Image")
    img = _image(6, 11)
    written = io.write_png(tmp_path / "p.png", img, exposure=-1.0)
    with image_mod.open(tmp_path / "p.png") as im:
        assert im.mode == "RGB" and im.size == (11, 6)
        np.testing.assert_array_equal(np.asarray(im), written)


def test_png_exposure_and_tonemaps(tmp_path):
    img = np.full((1, 1, 3), 0.25, np.float32)
    # +1 stop doubles 0.25 to 0.5 → 188 under the sRGB curve
    assert io.write_png(tmp_path / "a.png", img, exposure=1.0)[0, 0, 0] == 188
    # clamp: linear storage, 0.25 · 255 = 63.75 → 64; 4.0 clamps to 255
    assert io.write_png(tmp_path / "b.png", img, tonemap="clamp")[0, 0, 0] == 64
    assert io.write_png(tmp_path / "c.png", img * 16, tonemap="clamp")[0, 0, 0] == 255
    # reinhard: 1 → 1/2 → 188; huge values stay below saturation
    assert io.write_png(tmp_path / "d.png", img * 4, tonemap="reinhard")[0, 0, 0] == 188
    assert io.write_png(tmp_path / "e.png", img * 4000, tonemap="reinhard")[0, 0, 0] == 255
    assert io.write_png(tmp_path / "f.png", -img)[0, 0, 0] == 0
    with pytest.raises(ValueError, match="tonemap"):
        io.write_png(tmp_path / "g.png", img, tonemap="aces")
    with pytest.raises(ValueError, match="exposure"):
        io.write_png(tmp_path / "g.png", img, exposure=float("nan"))


def test_png_nonfinite_values_warn_with_count(tmp_path):
    img = np.full((2, 2, 3), 0.5, np.float32)
    img[0, 0, 0], img[1, 1, 2], img[0, 1, 1] = np.nan, np.inf, -np.inf
    with pytest.warns(RuntimeWarning, match="3 non-finite"):
        out = io.write_png(tmp_path / "n.png", img)
    # mapped to black, the rest untouched
    assert out[0, 0, 0] == 0 and out[1, 1, 2] == 0 and out[0, 1, 1] == 0 and out[0, 0, 1] == 188
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        io.write_png(tmp_path / "ok.png", np.full((2, 2, 3), 0.5))  # finite input: no warning


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (0, 3, 3), (3, 0, 3), (2, 2, 2, 3)])
def test_png_rejects_bad_shapes(tmp_path, shape):
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        io.write_png(tmp_path / "x.png", np.zeros(shape))
    assert _listing(tmp_path) == []


def _png_with_filters(pixels, filters):
    """Reference encoder: apply the given PNG filter type to each row (PNG spec §9)."""
    height, width, bpp = pixels.shape
    rows = pixels.reshape(height, width * bpp).astype(np.int64)
    out = []
    for y, kind in enumerate(filters):
        cur, up = rows[y], rows[y - 1] if y else np.zeros_like(rows[0])
        left = np.concatenate([np.zeros(bpp, np.int64), cur[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, np.int64), up[:-bpp]])
        p = left + up - upleft
        pa, pb, pc = abs(p - left), abs(p - up), abs(p - upleft)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
        pred = [0 * cur, left, up, (left + up) // 2, paeth][kind]
        out.append(bytes([kind]) + ((cur - pred) % 256).astype(np.uint8).tobytes())
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2 if bpp == 3 else 6, 0, 0, 0)

    def chunk(kind, data):
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    idat = zlib.compress(b"".join(out))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


@pytest.mark.parametrize("bpp", [3, 4])
def test_read_png_undoes_every_filter_type(tmp_path, bpp):
    rng = np.random.default_rng(5)
    # full-range noise (wrap-around mod 256) and four small levels (Paeth ties)
    noise = rng.integers(0, 256, (10, 6, bpp), dtype=np.uint8)
    levels = rng.integers(0, 4, (10, 6, bpp)).astype(np.uint8)
    pixels = np.concatenate([noise, levels])
    filters = [0, 1, 2, 3, 4, 4, 3, 2, 1, 0] + [4] * 10
    (tmp_path / "f.png").write_bytes(_png_with_filters(pixels, filters))
    np.testing.assert_array_equal(io.read_png(tmp_path / "f.png"), pixels)


def test_read_png_malformed(tmp_path):
    good = tmp_path / "good.png"
    io.write_png(good, _image())
    data = good.read_bytes()
    cases = {
        "text.png": b"hello",
        "trunc.png": data[: len(data) // 2],
        "crc.png": data[:40] + bytes([data[40] ^ 0xFF]) + data[41:],
    }
    for name, payload in cases.items():
        (tmp_path / name).write_bytes(payload)
        with pytest.raises(io.FileFormatError, match=name):
            io.read_png(tmp_path / name)


# ---------------------------------------------------------------------------------------------
# Atomic writes
# ---------------------------------------------------------------------------------------------


def _boom_after_partial_write(f, *args, **kwargs):
    f.write(b"partial garbage")
    f.flush()
    raise OSError("disk full (simulated)")


def test_png_failure_mid_write_leaves_target_intact(tmp_path, monkeypatch):
    path = tmp_path / "keep.png"
    first = io.write_png(path, _image())
    before = path.read_bytes()

    real_atomic = io.write_atomically

    def failing_atomic(p, write):
        # the real machinery, with a writer that dies half-way through the bytes
        real_atomic(p, lambda f: (write(f), _boom_after_partial_write(f)))

    monkeypatch.setattr(io, "write_atomically", failing_atomic)
    with pytest.raises(OSError, match="simulated"):
        io.write_png(path, _image(seed=9))
    assert path.read_bytes() == before  # old file intact
    assert _listing(tmp_path) == ["keep.png"]  # no temporary left
    np.testing.assert_array_equal(io.read_png(path), first)


def test_png_encoder_failure_leaves_no_file(tmp_path, monkeypatch):
    def broken_encoder(*args, **kwargs):
        raise RuntimeError("encoder exploded")

    monkeypatch.setattr(io, "_encode_png", broken_encoder)
    with pytest.raises(RuntimeError, match="exploded"):
        io.write_png(tmp_path / "new.png", _image())
    assert _listing(tmp_path) == []


def test_exr_failure_mid_write_leaves_target_intact(tmp_path, monkeypatch):
    path = tmp_path / "keep.exr"
    io.write_exr(path, _image())
    before = path.read_bytes()

    class HalfWriter:
        def __init__(self, header, channels):
            pass

        write = staticmethod(_boom_after_partial_write)

    monkeypatch.setattr(io, "_exr_file", HalfWriter)
    with pytest.raises(OSError, match="simulated"):
        io.write_exr(path, _image(seed=4))
    assert path.read_bytes() == before
    assert _listing(tmp_path) == ["keep.exr"]
    # a new target is not created either
    with pytest.raises(OSError, match="simulated"):
        io.write_exr(tmp_path / "new.exr", _image())
    assert _listing(tmp_path) == ["keep.exr"]


def test_interrupt_mid_write_cleans_up(tmp_path):
    def interrupted(f):
        f.write(b"abc")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        io.write_atomically(tmp_path / "x.bin", interrupted)
    assert _listing(tmp_path) == []


def test_atomic_write_replaces_and_keeps_mode(tmp_path):
    path = tmp_path / "x.bin"
    io.write_atomically(path, lambda f: f.write(b"one"))
    # a new file is not left with mkstemp's private 0600 mode
    assert os.stat(path).st_mode & 0o777 == 0o644
    os.chmod(path, 0o640)
    io.write_atomically(path, lambda f: f.write(b"two"))
    assert path.read_bytes() == b"two" and os.stat(path).st_mode & 0o777 == 0o640


@pytest.mark.parametrize("kind", ["trunc-0.1", "trunc-0.5", "trunc-0.9"])
def test_exr_truncated_says_truncated_not_unable_to_open(tmp_path, kind):
    """A cut-off EXR read like a missing file ("Unable to open ... for read")."""
    path = _malformed(tmp_path, kind)
    with pytest.raises(io.FileFormatError, match=r"truncated or corrupt OpenEXR file"):
        io.read_exr(path)


@pytest.mark.parametrize("kind", ["text", "random", "empty"])
def test_exr_non_exr_says_not_an_exr(tmp_path, kind):
    with pytest.raises(io.FileFormatError, match=r"not an OpenEXR file \(bad magic number\)"):
        io.read_exr(_malformed(tmp_path, kind))


def test_exr_attributes_round_trip(tmp_path):
    path = tmp_path / "a.exr"
    io.write_exr(path, _image(4, 5), attributes={"spp": 12, "jaxrt.estimator": "mis",
                                                 "scale": np.float32(1.5)})
    assert io.read_exr_attributes(path) == {"spp": 12, "jaxrt.estimator": "mis", "scale": 1.5}
    assert io.read_exr_attributes(tmp_path / "a.exr")["spp"] == 12
    for bad in ({"compression": 1}, {"spp": [1, 2]}, {"": 1}, {"ok": True}):
        with pytest.raises(ValueError, match="attribute"):
            io.write_exr(tmp_path / "b.exr", _image(4, 5), attributes=bad)
    assert not (tmp_path / "b.exr").exists()
