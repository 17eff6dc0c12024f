"""The ``jaxrt`` command: render to EXR + PNG, scene listing, errors as exit code 2, console script.

One tiny render (8×8, 2 spp) is shared by the tests that look at its outputs.

The second part meets the command as a careless user does: arguments, output paths, Ctrl-C, the
compile cache, help and messages. Tests that render use 8×8 or 16×16 images.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from jaxrt.cli import command as cli
from jaxrt.cli.command import main
from jaxrt.scene import builtin as scenes
from jaxrt.scene.images import read_exr, read_exr_attributes, read_png, write_exr


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


# ---------------------------------------------------------------------------------------------
# The command as a careless user meets it: arguments, output paths, Ctrl-C, the compile cache
# ---------------------------------------------------------------------------------------------


DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
TINY = ["--width", "8", "--height", "8", "-q", "--no-compile-cache"]


def _run(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _cli(args, env=None, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "jaxrt", *args], stdout=subprocess.DEVNULL
                            if kw.pop("quiet_stdout", False) else subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, **(env or {})), **kw)


@pytest.fixture()
def no_render(monkeypatch):
    """Fail the test if the command gets as far as loading a scene."""
    def loaded(args):
        raise AssertionError("the scene was loaded before the output check")
    monkeypatch.setattr(cli, "_load", loaded)


def test_choices_equal_the_library_lists():
    from jaxrt.integrators.config import ESTIMATORS
    from jaxrt.sampling.sampler import SAMPLERS

    assert tuple(cli.ESTIMATOR_NAMES) == tuple(ESTIMATORS)
    assert tuple(cli.SAMPLER_NAMES) == tuple(SAMPLERS)


def test_cli_import_and_output_errors_need_no_jax(tmp_path):
    """Output checks come before JAX is imported: a bad path fails in well under a second."""
    code = ("import sys, jaxrt.cli.command; assert 'jax' not in sys.modules, 'jax imported'; "
            f"sys.exit(jaxrt.cli.command.main(['render', '-o', "
            f"{str(tmp_path / 'no' / 'x.exr')!r}]))")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 2, proc.stderr
    assert "does not exist" in proc.stderr and str(tmp_path / "no" / "x.exr") in proc.stderr
    assert elapsed < 1.0, elapsed


@pytest.mark.parametrize("option", ["--width", "--height", "--spp", "--time-budget",
                                    "--target-error"])
def test_zero_sizes_and_budgets_are_usage_errors(option, capsys):
    """--width 0 rendered 256 wide (``if args.width:`` took 0 for 'not given')."""
    with pytest.raises(SystemExit) as info:
        main(["render", option, "0"])
    assert info.value.code == 2
    assert "must be > 0, got 0" in capsys.readouterr().err


def _readonly_dir(tmp_path, monkeypatch):
    d = tmp_path / "ro"
    d.mkdir()
    real = os.access
    # root may write anywhere, so the test also stands in for os.access
    monkeypatch.setattr(cli.os, "access", lambda p, m: False if Path(p) == d else real(p, m))
    d.chmod(0o555)
    return d / "x.exr"


@pytest.mark.parametrize("case", ["missing-dir", "is-dir", "wrong-ext", "png-ext", "ro-dir",
                                  "ro-file"])
def test_outputs_are_checked_before_rendering(case, tmp_path, monkeypatch, no_render):
    target = tmp_path / "out.exr"
    args = ["render", "-o", str(target)]
    expect = ""
    if case == "missing-dir":
        target = tmp_path / "nope" / "out.exr"
        args, expect = ["render", "-o", str(target)], "does not exist"
    elif case == "is-dir":
        target = tmp_path / "d.exr"
        target.mkdir()
        args, expect = ["render", "-o", str(target)], "is a directory"
    elif case == "wrong-ext":
        target = tmp_path / "image.png"
        args, expect = ["render", "-o", str(target)], "must end in .exr"
    elif case == "png-ext":
        target = tmp_path / "preview.exr"
        args, expect = ["render", "--png", str(target)], "must end in .png"
    elif case == "ro-dir":
        target = _readonly_dir(tmp_path, monkeypatch)
        args, expect = ["render", "-o", str(target)], "is not writable"
    else:  # ro-file
        target.write_bytes(b"old")
        target.chmod(0o444)
        expect = "read-only; use --force"
    code, _, err = _run(args)
    assert code == 2
    assert str(target) in err and expect in err, err
    assert len(err.strip().splitlines()) == 1


def test_force_replaces_a_read_only_output_and_header_has_spp(tmp_path):
    target = tmp_path / "out.exr"
    target.write_bytes(b"old")
    target.chmod(0o444)
    code, out, err = _run(["render", "--spp", "2", *TINY, "-o", str(target), "--force"])
    assert code == 0, err
    image, _ = read_exr(target)
    assert image.shape == (8, 8, 3)
    attrs = read_exr_attributes(target)
    assert attrs["spp"] == 2 and attrs["jaxrt.stopped_by"] == "spp"
    assert attrs["jaxrt.estimator"] == "mis" and attrs["jaxrt.seed"] == 0


def test_existing_output_survives_a_failed_run(tmp_path):
    target = tmp_path / "out.exr"
    write_exr(target, np.full((2, 2, 3), 7.0))
    before = target.read_bytes()
    bad = tmp_path / "bad.json"
    bad.write_text('{"camera": {"eye": [0, 0, 1], "target": [0, 0, 0]}, "meshes": []}')
    code, _, err = _run(["render", str(bad), *TINY, "-o", str(target)])
    assert code == 2 and str(bad) in err
    assert target.read_bytes() == before


def test_time_budget_is_not_capped_by_the_default_spp(tmp_path):
    """With a budget and no --spp, ``jaxrt render scene.json --time-budget`` has no spp
    limit: it does not stop at the default --spp 64 ("stopped by spp")."""
    code, out, err = _run(["render", str(DATA / "scene.json"), "--time-budget", "1.5",
                           "--width", "16", "--height", "16", "-q", "--no-compile-cache",
                           "-o", str(tmp_path / "budget.exr")])
    assert code == 0, err
    spp = int(re.search(r"^(\d+) spp in", out, re.M).group(1))
    assert "stopped by time_budget" in out and spp > 64


def test_mesh_file_gets_a_scene_file_message(tmp_path, capsys):
    code = main(["render", str(DATA / "room.obj"), "-q", "-o", str(tmp_path / "x.exr")])
    err = capsys.readouterr().err
    assert code == 2
    assert "room.obj: a mesh file, not a scene" in err and '"file": "room.obj"' in err
    assert "JSON" not in err  # it said "not valid JSON"


def test_gallery_without_matplotlib_names_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    code = main(["gallery", "-o", str(tmp_path / "g.png")])
    assert code == 2
    assert "pip install 'jaxrt[plot]'" in capsys.readouterr().err


def test_help_has_description_defaults_examples_and_version(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    top = capsys.readouterr().out
    assert "Monte Carlo direct illumination" in top and "examples:" in top
    assert "jaxrt render cornell_box" in top
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    sub = capsys.readouterr().out
    assert "(default: mis)" in sub and "(default: out.exr)" in sub
    assert "default: 64; no limit with" in " ".join(sub.split())
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    from jaxrt import __version__
    assert capsys.readouterr().out.strip() == f"jaxrt {__version__}"


def test_scenes_prints_no_restructuredtext(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    assert "``" not in out and ":func:" not in out and ":data:" not in out
    assert "LIGHT_RADIANCE" in out or "radiance" in out


def test_plain_text():
    assert cli.plain_text("a ``b`` :func:`c.d` :data:`~e.F` *g*") == "a b c.d e.F g"


class _Stderr:
    """Collects a child's stderr in a thread (tqdm writes lines without newlines)."""

    def __init__(self, proc):
        self.data = b""
        self.thread = threading.Thread(target=self._read, args=(proc.stderr.fileno(),),
                                       daemon=True)
        self.thread.start()

    def _read(self, fd):
        while chunk := os.read(fd, 4096):
            self.data += chunk

    def wait_for(self, text: str, timeout: float):
        deadline = time.monotonic() + timeout
        while text not in self.text():
            assert time.monotonic() < deadline, f"{text!r} not seen: {self.text()[-2000:]}"
            time.sleep(0.02)

    def text(self) -> str:
        return self.data.decode(errors="replace")


def _interrupt(proc, stderr) -> tuple[int, float, str]:
    """Send SIGINT to the CLI process: (exit code, seconds until it exited, its stderr)."""
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    rc = proc.wait(timeout=60)
    elapsed = time.monotonic() - t0
    stderr.thread.join(10)
    return rc, elapsed, stderr.text()


def test_ctrl_c_writes_the_partial_image_and_exits_130(tmp_path):
    """SIGINT one second into the render: the pass finishes, the image so far is written
    with its spp in the EXR header, one line says so, exit status 130 (it took 120 s and
    printed a traceback). Passes of 100 spp (~0.1 s): the 3 s bound is 30 passes, so a
    loaded machine cannot fail it, while a render that ignored the signal would (it has
    100 000 spp to go)."""
    out = tmp_path / "out.exr"
    proc = _cli(["render", "--width", "32", "--height", "32", "--spp", "100000",
                 "--spp-per-pass", "100", "--no-compile-cache", "-o", str(out),
                 "--png", str(tmp_path / "out.png")], quiet_stdout=True)
    stderr = _Stderr(proc)
    stderr.wait_for("compiled in", 120)
    time.sleep(1.5)
    rc, elapsed, err = _interrupt(proc, stderr)
    assert rc == 130, err
    assert elapsed < 3.0, elapsed  # one pass of 100 spp × 32², ~0.1 s
    last = err.strip().splitlines()[-1]
    m = re.fullmatch(r"jaxrt: interrupted: wrote (\d+) spp to (\S+) and (\S+)", last)
    assert m and m.group(2) == str(out), last
    assert "Traceback" not in err
    spp = int(m.group(1))
    assert spp > 0 and spp % 100 == 0  # whole passes
    assert read_exr_attributes(out)["spp"] == spp
    assert read_exr_attributes(out)["jaxrt.stopped_by"] == "interrupted"
    assert read_exr(out)[0].mean() > 0


def test_ctrl_c_during_compilation_exits_at_once_and_keeps_the_old_file(tmp_path):
    out = tmp_path / "out.exr"
    write_exr(out, np.full((2, 2, 3), 7.0))
    before = out.read_bytes()
    proc = _cli(["render", "--width", "32", "--height", "32", "--no-compile-cache",
                 "-o", str(out)], quiet_stdout=True)
    stderr = _Stderr(proc)
    stderr.wait_for("compiling", 120)
    rc, elapsed, err = _interrupt(proc, stderr)
    assert rc == 130 and "nothing written" in err.strip().splitlines()[-1], err
    assert elapsed < 1.0, elapsed
    assert out.read_bytes() == before


def test_ctrl_c_handler_acts_by_stage(monkeypatch, capsys):
    """jaxrt/cli/ctrl_c.py's table: quit at once while nothing can be saved or the second time,
    stop after the pass once a pass is done, never quit while the files are written."""
    from jaxrt.cli import ctrl_c
    quits = []
    monkeypatch.setattr(ctrl_c, "quit_now", quits.append)
    handler = ctrl_c.CtrlC()
    handler(signal.SIGINT, None)
    assert quits == ["jaxrt: interrupted; nothing written"]
    handler.stage = "rendering"
    handler(signal.SIGINT, None)
    assert quits[1:] == ["jaxrt: interrupted before the first pass finished; nothing written"]
    handler.passes_done.append(4)
    handler(signal.SIGINT, None)
    assert len(quits) == 2 and handler.stop.is_set()
    assert "stopping after the pass running" in capsys.readouterr().err
    handler(signal.SIGINT, None)
    assert quits[2:] == ["jaxrt: interrupted twice; nothing written"]
    writing = ctrl_c.CtrlC()
    writing.stage = "finishing"
    writing(signal.SIGINT, None)
    writing(signal.SIGINT, None)
    assert len(quits) == 3 and writing.stop.is_set()


@pytest.mark.slow  # ~20 s
def test_a_second_ctrl_c_during_a_pass_quits_at_once(tmp_path):
    """Passes of ~3 s: the first Ctrl-C after a pass says the render stops after the pass
    running, a second one quits at once, writing nothing (the old file kept)."""
    out = tmp_path / "out.exr"
    write_exr(out, np.full((2, 2, 3), 7.0))
    before = out.read_bytes()
    proc = _cli(["render", "--width", "64", "--height", "64", "--spp", "100000",
                 "--spp-per-pass", "1000", "--no-compile-cache", "-o", str(out)],
                quiet_stdout=True)
    stderr = _Stderr(proc)
    stderr.wait_for("1000/100000", 180)
    proc.send_signal(signal.SIGINT)
    stderr.wait_for("stopping after the pass running", 10)
    rc, elapsed, err = _interrupt(proc, stderr)
    assert rc == 130 and err.strip().splitlines()[-1] == \
        "jaxrt: interrupted twice; nothing written", err[-2000:]
    assert elapsed < 1.0, elapsed  # a pass takes ~3 s
    assert out.read_bytes() == before


@pytest.mark.slow  # ~25 s: 25 short-lived processes
def test_ctrl_c_at_any_moment_of_start_up_exits_at_once(tmp_path):
    """SIGINT at 24 moments spread over start-up (imports, JAX, the scene, tracing, past the
    compilation's first line) after Python's own (the interpreter and this module, ~0.1 s of
    ~1.3 s, where a KeyboardInterrupt is Python's as in any program): each exits at once
    with status 130, one line, no traceback, and the old file kept. Python's own
    KeyboardInterrupt loses some (jaxrt/cli/ctrl_c.py): raised inside jaxlib's garbage-collector
    callback it is printed as "ignored" and the render runs to the end (4 of 27 moments 50 ms
    apart), inside an extension's start-up the process aborts."""
    out = tmp_path / "out.exr"
    write_exr(out, np.full((2, 2, 3), 7.0))
    before = out.read_bytes()
    args = ["render", "--width", "32", "--height", "32", "--no-compile-cache", "-o", str(out)]
    t0 = time.monotonic()  # how long start-up takes on this machine, now
    proc = _cli(args, quiet_stdout=True)
    _Stderr(proc).wait_for("compiling", 120)
    startup = time.monotonic() - t0
    proc.kill()
    proc.wait()
    failures = []
    for k in range(24):
        proc = _cli(args, quiet_stdout=True)
        stderr = _Stderr(proc)
        time.sleep(startup * (0.15 + k / 24))
        rc, elapsed, err = _interrupt(proc, stderr)
        last = (err.strip().splitlines() or [""])[-1]
        # at once: 0.01-0.03 s measured; a lost Ctrl-C renders for seconds
        if rc != 130 or "nothing written" not in last or "Traceback" in err or elapsed > 2:
            failures.append((k, rc, round(elapsed, 2), err[-800:]))
    assert not failures, failures
    assert out.read_bytes() == before


def test_compile_cache_second_run_reads_it(tmp_path):
    """Two runs of the same 16×16 render with the cache in $XDG_CACHE_HOME: the first
    compiles and keeps its pass, the second reads it (no tracing, no XLA) and reports a
    smaller compile time and the same image, bit for bit."""
    env = {"XDG_CACHE_HOME": str(tmp_path / "cache"), "JAXRT_NO_COMPILE_CACHE": ""}
    times, outs, images = [], [], []
    for k in range(2):
        out = tmp_path / f"x{k}.exr"
        proc = _cli(["render", "--width", "16", "--height", "16", "--spp", "4", "-q",
                     "-o", str(out)], env=env)
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, stderr
        assert "warning" not in stderr, stderr
        times.append(float(re.search(r"\+([\d.]+) s compile", stdout).group(1)))
        outs.append(stdout)
        images.append(read_exr(out)[0])
        cache = tmp_path / "cache" / "jaxrt" / "programs"
        assert cache.is_dir() and len(list(cache.iterdir())) == 1
    assert "program cache" not in outs[0]
    assert "1 program(s) read from the program cache" in outs[1]
    assert times[1] < 0.5 * times[0], times
    assert np.array_equal(images[0], images[1])


def test_compile_cache_can_be_turned_off(tmp_path):
    env = {"XDG_CACHE_HOME": str(tmp_path / "cache"), "JAXRT_NO_COMPILE_CACHE": "1"}
    proc = _cli(["render", "--width", "8", "--height", "8", "--spp", "1", "-q",
                 "-o", str(tmp_path / "x.exr")], env=env)
    proc.communicate(timeout=300)
    assert proc.returncode == 0
    assert not (tmp_path / "cache").exists()


def test_scene_warnings_are_one_line_without_source(tmp_path):
    """A zero-area emissive triangle warns (docs/scenes.md) in one line naming the file,
    not with Python's "file:line: UserWarning" and a line of jaxrt's source."""
    doc = {"camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
           "materials": {"white": {"type": "diffuse", "albedo": 0.5}},
           "meshes": [{"vertices": [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [0, 1, 0], [0, 1, 0],
                                    [1, 1, 0]],
                       "faces": [[0, 2, 1], [3, 4, 5]], "material": "white",
                       "emission": 1, "name": "lamp"}],
           "lights": [{"type": "point", "position": [0, 2, 0], "intensity": 5}]}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    code, _, err = _run(["render", str(path), "--spp", "1", *TINY, "-o",
                         str(tmp_path / "x.exr")])
    assert code == 0, err
    lines = err.strip().splitlines()
    assert lines == [f"jaxrt: warning: {path}: mesh 'lamp': 1 zero-area emissive triangles "
                     "do not emit (they have no area to sample)"], err
