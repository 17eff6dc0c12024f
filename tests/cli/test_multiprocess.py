"""``jaxrt render --processes 2``: two local CPU processes (JAX's multi-process runtime) render
the image of one process, bit for bit, whatever the split of the tiles (an uneven one
included), the pass size and whoever decides to stop (a time budget is decided by process 0)."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from jaxrt.scene.images import read_exr, read_exr_attributes

BASE = ["render", "--width", "16", "--height", "12", "--spp-per-pass", "2", "-q",
        "--no-compile-cache"]


def _run(args) -> str:
    proc = subprocess.run([sys.executable, "-m", "jaxrt", *BASE, *args],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def _free_port() -> str:
    """A port on localhost that is free now (for a coordinator)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return str(sock.getsockname()[1])


@pytest.mark.slow  # ~30 s: four compiles in subprocesses
def test_two_processes_equal_one_bit_for_bit(tmp_path):
    # 24 × 24 pixels = 3 tiles of 256: process 0 renders tiles 0 and 1, process 1 tile 2 and
    # a tile past the image; in passes of 4 and 2 spp, against one process in one pass of 6
    size = ["--width", "24", "--height", "24"]
    _run([*size, "--spp", "6", "--spp-per-pass", "4", "--processes", "2",
          "-o", str(tmp_path / "two.exr")])
    _run([*size, "--spp", "6", "--spp-per-pass", "6", "-o", str(tmp_path / "one.exr")])
    two, two_extra = read_exr(tmp_path / "two.exr")
    one, one_extra = read_exr(tmp_path / "one.exr")
    assert np.array_equal(two, one) and np.array_equal(two_extra["stderr"], one_extra["stderr"])
    assert read_exr_attributes(tmp_path / "two.exr")["spp"] == 6
    assert one.mean() > 0


@pytest.mark.slow  # ~25 s
def test_two_processes_stop_together_on_a_time_budget(tmp_path):
    out = _run(["--time-budget", "1", "--processes", "2", "-o", str(tmp_path / "two.exr")])
    spp = int(re.search(r"^(\d+) spp in", out, re.M).group(1))
    assert "stopped by time_budget" in out and spp % 2 == 0 and spp > 2
    _run(["--spp", str(spp), "-o", str(tmp_path / "one.exr")])
    assert np.array_equal(read_exr(tmp_path / "two.exr")[0], read_exr(tmp_path / "one.exr")[0])


def test_multi_host_options_are_checked(capsys):
    from jaxrt.cli.command import main

    code = main(["render", "--num-processes", "2", "--process-id", "2", "-q", "-o",
                 "/tmp/x.exr"])
    assert code == 2 and "--process-id must lie in [0, 2)" in capsys.readouterr().err


AGREE = """
import sys, threading
import jax
rank, port = int(sys.argv[1]), sys.argv[2]
jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=2, process_id=rank)
from jaxrt import RenderInterrupted
from jaxrt.scene import builtin as scenes
from jaxrt.rendering.driver import render
stop = threading.Event()
if rank == 0:
    stop.set()  # Ctrl-C on process 0 before a pass begins; process 1 knows nothing of it
try:
    render(scenes.cornell_box(16, 12), "mis", spp=8, spp_per_pass=2, stop=stop, progress=False)
    print("finished")
except RenderInterrupted as e:
    print("interrupted", e.result.spp)
"""


@pytest.mark.slow  # ~15 s: two processes compile
def test_a_stop_flag_set_between_passes_stops_every_process_together():
    """Process 0's Ctrl-C flag, set between passes, ends the loop only through the agreed
    decision: leaving on its own, it waited in the final gather while process 1 waited for
    it in the next pass's agreement (a deadlock that hung CI's Ctrl-C test)."""
    port = _free_port()
    procs = [subprocess.Popen([sys.executable, "-c", AGREE, str(rank), port],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for rank in range(2)]
    try:
        outs = [p.communicate(timeout=180) for p in procs]
    finally:
        for p in procs:
            p.kill()
    last = [(out.strip().splitlines() or [""])[-1] for out, _ in outs]
    assert last == ["interrupted 2"] * 2, [(out, err[-1500:]) for out, err in outs]


def test_launcher_kills_a_process_that_ignores_sigterm(monkeypatch, tmp_path):
    """Once process 0 is done, a process still running gets SIGTERM and, if it ignores it
    (JAX's distributed runtime catches it as a preemption notice while the process waits in a
    collective for one that has left), SIGKILL: the launcher always returns."""
    import os
    import time

    from jaxrt.cli import command as cli
    from jaxrt.cli import processes as launcher
    ready = tmp_path / "ready"
    # rank 1 ignores SIGTERM and says so; rank 0 exits as soon as it has
    codes = {0: f"import os, time\nwhile not os.path.exists({str(ready)!r}): time.sleep(0.01)",
             1: "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
                f"open({str(ready)!r}, 'w').close()\ntime.sleep(120)"}
    started = []
    real = subprocess.Popen

    def popen(cmd, **kwargs):
        rank = int(cmd[cmd.index("--process-id") + 1])
        started.append(real([sys.executable, "-c", codes[rank]], **kwargs))
        return started[-1]

    monkeypatch.setattr(subprocess, "Popen", popen)
    monkeypatch.setattr(launcher, "STOP_GRACE_S", 0.5)
    t0 = time.monotonic()
    code = cli.main(["render", "--processes", "2", "-q", "-o", str(tmp_path / "x.exr")])
    assert time.monotonic() - t0 < 30
    assert code == 0 and os.path.exists(ready)
    assert [p.returncode for p in started] == [0, -9]  # rank 1: killed, not terminated


def test_sigterm_to_the_launcher_kills_its_processes(monkeypatch, tmp_path):
    """The processes run with ``start_new_session``: SIGTERM to the launcher must not leave
    them running (it kills them and exits with 143)."""
    import os
    import signal
    import threading
    import time

    from jaxrt.cli import command as cli
    ready = [tmp_path / "ready0", tmp_path / "ready1"]
    started = []
    real = subprocess.Popen

    def popen(cmd, **kwargs):
        rank = int(cmd[cmd.index("--process-id") + 1])
        code = ("import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
                f"open({str(ready[rank])!r}, 'w').close()\ntime.sleep(120)")
        started.append(real([sys.executable, "-c", code], **kwargs))
        return started[-1]

    def sigterm_when_ready():
        while not all(r.exists() for r in ready):
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(subprocess, "Popen", popen)
    threading.Thread(target=sigterm_when_ready, daemon=True).start()
    t0 = time.monotonic()
    code = cli.main(["render", "--processes", "2", "-q", "-o", str(tmp_path / "x.exr")])
    assert time.monotonic() - t0 < 30
    assert code == 143
    assert [p.wait(timeout=10) for p in started] == [-9, -9]


@pytest.mark.slow  # ~20 s
def test_ctrl_c_stops_every_process_and_process_0_writes(tmp_path):
    """SIGINT to the launcher reaches each process once; process 0 decides, all stop after
    the pass, process 0 writes the image so far (its spp in the header), exit status 130.
    Passes of 200 spp, so that a loaded machine cannot push a pass past the time bound."""
    import os
    import signal
    import threading
    import time

    out = tmp_path / "out.exr"
    proc = subprocess.Popen([sys.executable, "-m", "jaxrt", "render", "--width", "32",
                             "--height", "32", "--spp", "100000", "--spp-per-pass", "200",
                             "--no-compile-cache", "--processes", "2", "-o", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = bytearray()

    def read():
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.extend(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    deadline = time.monotonic() + 180
    while b"200/100000" not in err:  # a first pass of 200 spp (each process half the tiles)
        assert time.monotonic() < deadline and proc.poll() is None, err.decode()[-2000:]
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    try:
        rc = proc.wait(timeout=60)
    finally:  # on a hang, SIGTERM makes the launcher kill its processes before it leaves
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=30)
    elapsed = time.monotonic() - t0
    reader.join(10)
    text = err.decode(errors="replace")
    assert rc == 130, text[-2000:]
    # a 200-spp pass (~0.1 s) and the write: 5 s is many passes, so load cannot fail it,
    # while a render that ignored the signal would (it has 100 000 spp to go)
    assert elapsed < 5, elapsed
    last = text.strip().splitlines()[-1]
    m = re.fullmatch(r"jaxrt: interrupted: wrote (\d+) spp to (\S+)", last)
    assert m, last
    assert int(m.group(1)) % 200 == 0 and read_exr_attributes(out)["spp"] == int(m.group(1))


@pytest.mark.slow  # ~10 s
def test_ctrl_c_during_compilation_stops_every_process_at_once(tmp_path):
    import signal
    import time

    proc = subprocess.Popen([sys.executable, "-m", "jaxrt", "render", "--width", "32",
                             "--height", "32", "--no-compile-cache", "--processes", "2",
                             "-o", str(tmp_path / "out.exr")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(4)  # the processes have started and are tracing or compiling
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    _, err = proc.communicate(timeout=60)
    elapsed = time.monotonic() - t0
    assert proc.returncode == 130, err[-2000:]
    assert "nothing written" in err.strip().splitlines()[-1]
    # process 0 quits at once and the launcher stops the other at once (0.2-0.5 s measured;
    # SIGKILL follows a SIGTERM it ignores after 5 s)
    assert elapsed < 7, elapsed
    assert not (tmp_path / "out.exr").exists()


INTERRUPTED_AFTER_JOINING = """
import pathlib, sys, time
from jaxrt.cli import command as cli
real = cli._load
def load_then_wait(args):
    scene = real(args)
    pathlib.Path(sys.argv[1]).touch()
    time.sleep(120)  # Ctrl-C comes here: JAX's distributed runtime has started
    return scene
cli._load = load_then_wait
sys.exit(cli.main(sys.argv[2:]))
"""


@pytest.mark.slow  # ~10 s: process 1 compiles
def test_ctrl_c_after_joining_the_runtime_exits_at_once(tmp_path):
    """Process 0 interrupted after it joined JAX's distributed runtime, while process 1
    compiles: it exits at once. Left to Python's KeyboardInterrupt, it printed "nothing
    written" and then waited in the runtime's exit handler, at a shutdown barrier, for
    process 1 (42 s in CI; up to the barrier's 300 s timeout)."""
    import signal
    import time

    port = _free_port()
    common = ["render", "--width", "32", "--height", "32", "--no-compile-cache", "-o",
              str(tmp_path / "out.exr"), "--coordinator", f"127.0.0.1:{port}",
              "--num-processes", "2"]
    ready = tmp_path / "ready"
    zero = subprocess.Popen([sys.executable, "-c", INTERRUPTED_AFTER_JOINING, str(ready),
                             *common, "--process-id", "0"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    one = subprocess.Popen([sys.executable, "-m", "jaxrt", *common, "--process-id", "1",
                            "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while not ready.exists():
            assert time.monotonic() < deadline and zero.poll() is None, zero.stderr.read()
            time.sleep(0.02)
        zero.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        try:
            _, err = zero.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            err = ""
        elapsed = time.monotonic() - t0
    finally:
        for p in (zero, one):
            p.kill()
            p.wait()
    assert elapsed < 3, elapsed
    assert zero.returncode == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == "jaxrt: interrupted; nothing written", err[-2000:]
    assert not (tmp_path / "out.exr").exists()
