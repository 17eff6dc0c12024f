"""``jaxrt render --processes N``: N local processes that render one image together.

The launcher starts N copies of the command, each joining JAX's multi-process runtime with a
coordinator on localhost (``--coordinator``, ``--num-processes``, ``--process-id``), and
waits for them. Process 0 prints and writes the files and decides when all stop; the
launcher forwards Ctrl-C to it alone, and cleans up after it: a process that fails stops the
others, as does process 0's exit on Ctrl-C, and processes still running once process 0 is
done are stopped after a grace period (SIGTERM, then SIGKILL: JAX's distributed runtime
catches SIGTERM).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

from jaxrt.cli.ctrl_c import EXIT_INTERRUPTED

#: Seconds a process gets to exit on its own (after process 0, or after SIGTERM).
STOP_GRACE_S = 5


def launch(argv: list[str], processes: int) -> int:
    """``--processes N``: run N local processes of this command that render together (JAX's
    multi-process runtime, coordinator on localhost); process 0 prints and writes the files.
    Ctrl-C is forwarded to process 0, which stops all after the pass (or at once during
    start-up and compilation); the first failure, or process 0's exit on Ctrl-C, stops the
    others at once (SIGTERM, then SIGKILL after :data:`STOP_GRACE_S`), and once process 0 is
    done the others get :data:`STOP_GRACE_S` to exit, then SIGTERM, then SIGKILL.

    ``argv``: the command's arguments (without ``--processes``), given to every process with
    its ``--coordinator``, ``--num-processes`` and ``--process-id``. Returns the exit status:
    process 0's, or that of the first other process that failed (143 when the launcher itself
    got SIGTERM, after killing the processes).
    """
    with socket.socket() as sock:  # a free port for the coordinator
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    children, logs = [], []
    codes: dict[int, int] = {}
    # terminated by us, or ended after process 0: their exit code says nothing
    stopped: set[int] = set()
    terminated_at: dict[int, float] = {}
    zero_done = None

    def forward(signum, frame):
        # Ctrl-C goes to process 0 only: it decides for all. A handler that forwards, not a
        # KeyboardInterrupt: raised inside Popen.poll, that can leave its waitpid lock held,
        # and poll then reports the child running for ever. returncode is None until this
        # loop reaps the child, so its pid cannot have been reused.
        if children and children[0].returncode is None:
            os.kill(children[0].pid, signal.SIGINT)

    leaving: list[int] = []

    def leave(signum, frame):
        # SIGTERM to the launcher: the loop below leaves through its finally, which kills
        # the processes (started with start_new_session, they would outlive it otherwise); a flag,
        # not an exception, for the same reason as in forward
        leaving.append(signum)

    previous = signal.signal(signal.SIGINT, forward), signal.signal(signal.SIGTERM, leave)
    try:
        for rank in range(processes):
            log = tempfile.TemporaryFile() if rank else None
            logs.append(log)
            children.append(subprocess.Popen(
                [sys.executable, "-m", "jaxrt", *argv, "--coordinator",
                 f"127.0.0.1:{port}", "--num-processes", str(processes), "--process-id",
                 str(rank)] + ([] if rank == 0 else ["-q"]),
                stdout=subprocess.DEVNULL if rank else None, stderr=log,
                start_new_session=True))  # Ctrl-C reaches them once, through this process
        while len(codes) < len(children) and not leaving:
            for rank, child in enumerate(children):
                if rank not in codes and child.poll() is not None:
                    codes[rank] = child.returncode
                    if rank == 0:
                        zero_done = time.monotonic()
                    elif zero_done:  # e.g. aborted when process 0 left: not a failure
                        stopped.add(rank)
                    # a failure stops the others at once; so does process 0's Ctrl-C (it
                    # wrote what there was: the others have nothing left to do)
                    if (child.returncode not in (0, EXIT_INTERRUPTED)
                            or (rank == 0 and child.returncode == EXIT_INTERRUPTED)):
                        stopped |= _terminate(children, codes, terminated_at)
            # once process 0 is done (written, or quit during compilation) the others have
            # nothing left to do: a few seconds to exit, then they are stopped
            if zero_done and time.monotonic() - zero_done > STOP_GRACE_S:
                stopped |= _terminate(children, codes, terminated_at)
            # SIGTERM may be caught (JAX's distributed runtime listens for it, as a notice
            # of preemption) by a process waiting in a collective for one that has left
            for rank, t in terminated_at.items():
                if rank not in codes and time.monotonic() - t > STOP_GRACE_S:
                    children[rank].kill()
            time.sleep(0.05)
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
        for child in children:
            if child.poll() is None:
                child.kill()
    if leaving:
        return 128 + leaving[0]
    failed = [r for r in range(1, len(children))
              if r not in stopped and codes.get(r) not in (0, EXIT_INTERRUPTED)]
    for rank in failed:  # process 0 printed its own errors
        logs[rank].seek(0)
        tail = logs[rank].read().decode(errors="replace").strip().splitlines()[-5:]
        print(f"jaxrt: process {rank} exited with {codes[rank]}: " + " | ".join(tail),
              file=sys.stderr)
    code0 = None if 0 in stopped else codes.get(0)
    if code0:
        return code0 if code0 > 0 else 1  # < 0: killed by a signal
    return max(1, codes[failed[0]]) if failed else 0


def _terminate(children, codes, terminated_at: dict) -> set[int]:
    """SIGTERM to the children still running (once each; ``terminated_at`` records when, so
    that the caller can kill those that ignore it); returns their ranks."""
    ranks = {r for r, c in enumerate(children) if r not in codes and c.poll() is None}
    for r in ranks - terminated_at.keys():
        children[r].terminate()
        terminated_at[r] = time.monotonic()
    return ranks
