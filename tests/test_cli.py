"""The ``jaxrt`` command: render to EXR + PNG, scene listing, errors as exit code 2, console script.

One tiny render (8×8, 2 spp) is shared by the tests that look at its outputs.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxrt import scenes
from jaxrt.cli import main
from jaxrt.io import read_exr, read_png


@pytest.fixture(autouse=True)
def _no_compile_cache(monkeypatch):
    """main() would turn JAX's persistent cache on for this whole test process (and write to
    ~/.cache); tests that want it set the variable back in a subprocess's environment."""
    monkeypatch.setenv("JAXRT_NO_COMPILE_CACHE", "1")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Run ``jaxrt render --width 8 --height 8 --spp 2`` once; return (exit code, out, dir)."""
    out = tmp_path_factory.mktemp("cli")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["render", "--width", "8", "--height", "8", "--spp", "2", "-q",
                     "--no-compile-cache", "-o", str(out / "box.exr"), "--png",
                     str(out / "box.png")])
    return code, buf.getvalue(), out


def test_render_writes_exr_and_png(rendered):
    code, stdout, out = rendered
    assert code == 0, stdout
    image, extra = read_exr(out / "box.exr")
    assert image.shape == (8, 8, 3)  # --width/--height reach the camera
    assert np.isfinite(image).all()
    # the box is lit: the default scene is the Cornell box, which is not black at 2 spp
    assert image.mean() > 0
    assert "stderr" in extra and extra["stderr"].shape == (8, 8, 3)  # stderr layer written
    assert (extra["stderr"] >= 0).all() and np.isfinite(extra["stderr"]).all()
    png = read_png(out / "box.png")
    assert png.shape == (8, 8, 3) and png.max() > 0
    # the summary line and the spp reached are printed
    assert "Scene: 8x8 camera" in stdout and "2 spp" in stdout


def test_unknown_scene_name_exits_2(capsys):
    code = main(["render", "no_such_scene", "--spp", "1", "-q"])
    assert code == 2  # usage error, not a crash
    err = capsys.readouterr().err
    assert "no_such_scene" in err and "cornell_box" in err  # names it and lists the built-ins


def test_malformed_scene_file_exits_2_with_file_and_entry(tmp_path, capsys):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"camera": {"eye": [0, 0, 1], "target": [0, 0, 0]},
                                "meshes": [{"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                                            "faces": [[0, 1, 2]], "material": "gold"}]}))
    code = main(["render", str(path), "--spp", "1", "-q", "-o", str(tmp_path / "x.exr")])
    assert code == 2
    err = capsys.readouterr().err
    assert str(path) in err and "meshes[0].material" in err
    assert not (tmp_path / "x.exr").exists()  # nothing written on failure


def test_scenes_lists_builtins(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in scenes.BUILTIN:
        assert name in out
    assert len(out.strip().splitlines()) == len(scenes.BUILTIN)  # one line per scene


def test_bad_estimator_is_argparse_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["render", "--estimator", "magic"])
    assert info.value.code == 2  # argparse's usage-error code
    assert "magic" in capsys.readouterr().err


def _console_script() -> str:
    exe = Path(sys.executable).parent / "jaxrt"
    return str(exe) if exe.exists() else shutil.which("jaxrt")


def test_console_script_help():
    exe = _console_script()
    assert exe, "the jaxrt console script is not installed next to the interpreter or on PATH"
    proc = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for command in ("render", "scenes", "gallery"):
        assert command in proc.stdout
    proc = subprocess.run([exe, "render", "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "--time-budget" in proc.stdout


def _summary_line(args, capsys):
    assert main(["render", "--width", "8", "--height", "8", "--spp", "1", "-q",
                 "--no-compile-cache", *args]) == 0
    return next(line for line in capsys.readouterr().out.splitlines() if "Scene:" in line)


def test_triangle_sampling_option_reaches_the_scene(tmp_path, capsys):
    """``--triangle-sampling`` is honoured (Scene.summary names it); without it the scene's
    own mode stands: area for the built-in box, the file's option for a scene file, whose
    ``accel`` option is not overridden by a default on the command line either."""
    out = str(tmp_path / "x.exr")
    assert "triangles by area" in _summary_line(["-o", out], capsys)
    assert "triangles by solid_angle" in _summary_line(
        ["--triangle-sampling", "solid_angle", "-o", out], capsys)
    scene = tmp_path / "quad.json"
    scene.write_text(json.dumps({
        "camera": {"eye": [0, -3, 2], "target": [0, 0, 0], "up": [0, 0, 1], "fov": 40,
                   "width": 8, "height": 8},
        "materials": {"white": {"type": "diffuse", "albedo": 0.5}},
        "meshes": [{"vertices": [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                    "faces": [[0, 1, 2], [0, 2, 3]], "material": "white"},
                   {"vertices": [[-0.2, -0.2, 1], [0.2, -0.2, 1], [0.2, 0.2, 1]],
                    "faces": [[0, 2, 1]], "material": "white", "emission": [5, 5, 5]}],
        "options": {"accel": "bvh", "triangle_sampling": "solid_angle"}}))
    line = _summary_line([str(scene), "-o", out], capsys)
    assert "triangles by solid_angle" in line and "(BVH)" in line, line
    line = _summary_line([str(scene), "--triangle-sampling", "area", "--accel", "brute",
                          "-o", out], capsys)
    assert "triangles by area" in line and "(TriangleSet)" in line, line
