"""Each example's ``main`` runs tiny and writes what it promises.

The examples live in ``examples/`` (not a package): they are imported by path. Every new
(estimator, scene) pair costs a 5–20 s compile, so the multi-estimator examples are slow.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from jaxrt.scene.images import read_exr, read_png

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _png_pixels(path: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(str(path))


def test_load_obj(tmp_path, capsys):
    exr, png = tmp_path / "room.exr", tmp_path / "room.png"
    # light_area: a smaller program to compile than the default mis (one light strategy)
    result = _load("load_obj").main(["--size", "12", "--spp", "2", "--estimator", "light_area",
                                     "-o", str(exr), "--png", str(png)])
    out = capsys.readouterr().out
    assert "Scene: 12x12 camera" in out and "2 triangle" in out  # the Ke lamp became lights
    assert "[[12. 11.  9.]]" in out  # its radiance, from room.mtl
    image, extra = read_exr(exr)
    assert image.shape == (12, 12, 3) and np.isfinite(image).all()
    np.testing.assert_array_equal(image, result.image)  # the EXR holds the render, exactly
    np.testing.assert_array_equal(extra["stderr"], result.stderr)  # and its stderr layer
    assert image.max() > 0  # the lamp and the sphere light the room
    assert read_png(png).shape == (12, 12, 3)


@pytest.mark.slow
def test_estimators_equal_time(tmp_path, capsys):
    out_png = tmp_path / "eq.png"
    chosen = ["light_area", "mis"]  # two estimators: each one more compile
    res = _load("estimators_equal_time").main(
        ["--size", "16", "--time", "0.5", "--reference-factor", "4", "--estimators", *chosen,
         "-o", str(out_png)])
    rows = res["rows"]
    assert [r["estimator"] for r in rows] == chosen
    ref = res["reference"]
    for r in rows:
        # the budget is spent before stopping: render() stops when the elapsed time plus the
        # last pass's time passes 0.5 s (a loaded machine can make that pass several times the
        # mean pass, so the mean is no bound)
        assert r["spp"] > 0 and r["seconds"] + r["last_pass"] > 0.5, r
        assert r["seconds"] <= 0.75, r
        # unbiased estimators of the same image: the error is far below that of a black image
        # (RMSE of black = RMS of the reference); half of it already needs ≳ 4 spp per pixel
        assert r["rmse"] < 0.5 * np.sqrt(np.mean(ref**2)), r
    assert _png_pixels(out_png).shape[0] > 100  # a real figure, not a 16-pixel image
    table = capsys.readouterr().out
    for name in chosen:
        assert name in table


@pytest.mark.slow
def test_mis_scene(tmp_path):
    out_png = tmp_path / "mis.png"
    results = _load("mis_scene").main(["--width", "24", "--height", "16", "--spp", "2",
                                       "-o", str(out_png)])
    assert set(results) == {"light_solid_angle", "bsdf", "mis"}
    for r in results.values():
        assert r.image.shape == (16, 24, 3) and r.spp == 2
        assert np.isfinite(r.image).all() and r.image.max() > 0  # the plates reflect light
    assert out_png.exists() and _png_pixels(out_png).shape[0] > 50


@pytest.mark.slow
def test_inverse_rendering_recovers_the_box(tmp_path):
    """The example at 16², 150 steps (~30 s): the loss falls, the light's radiance and the
    bright albedos come within a few percent, every fitted albedo moves most of the way from
    its start, and the ceiling (never directly lit) is reported as not identifiable."""
    pytest.importorskip("optax")
    out = tmp_path / "fit.png"
    res = _load("inverse_rendering").main(["--size", "16", "--steps", "150", "-q",
                                           "-o", str(out)])
    loss = np.asarray(res["history"]["loss"])
    assert loss[-20:].mean() < loss[0] / 10  # the rest is the 64-spp image's noise
    kd, le = "materials.kd", "triangle.radiance"
    assert res["initial_rel_error"][le].max() > 0.3 and res["rel_error"][le].max() < 0.05
    vis = res["visible"]
    np.testing.assert_array_equal(np.flatnonzero(~vis), [1, 7])  # ceiling, lamp
    bright = res["true"][kd][vis] > 0.3
    assert res["rel_error"][kd][bright].max() < 0.05
    assert np.all(res["rel_error"][kd] < res["initial_rel_error"][kd] / 4)
    assert _png_pixels(out).shape[0] > 100


@pytest.mark.slow
def test_inverse_texture_recovers_the_back_wall(tmp_path):
    """The texture example at 100 steps: the seen texels' median error falls from ~54 % to a
    few percent, unseen texels (behind the tall block) are left alone, both PNGs written."""
    pytest.importorskip("optax")
    res = _load("inverse_texture").main(["--steps", "100", "--target-spp", "256", "-q",
                                         "-o", str(tmp_path / "fit")])
    assert np.median(res["initial_rel_error"]) > 0.4
    assert np.median(res["rel_error"]) < 0.08
    assert 0 < (~res["seen"]).sum() < res["seen"].size / 2
    np.testing.assert_array_equal(res["fitted"][~res["seen"]], res["start"][~res["seen"]])
    for name in ("before", "after"):
        assert read_png(tmp_path / f"fit_{name}.png").shape == (32, 64, 3)


def test_emission_texture(tmp_path, capsys):
    out = tmp_path / "stripes"
    res = _load("emission_texture").main(["--size", "12", "--spp", "2", "--estimator",
                                          "light_area", "-o", str(out)])
    assert "2 triangle (selection power, triangles by area, 2 with 1 emission textures)" \
        in capsys.readouterr().out
    image, extra = read_exr(f"{out}.exr")
    np.testing.assert_array_equal(image, res["result"].image)
    np.testing.assert_array_equal(extra["stderr"], res["result"].stderr)
    assert np.isfinite(image).all() and image.max() > 0
    assert read_png(f"{out}.png").shape == (12, 12, 3)
    stripes = _load("emission_texture").stripes()
    np.testing.assert_allclose(stripes.mean(axis=(0, 1)), 1.0)  # the lamp keeps its power
