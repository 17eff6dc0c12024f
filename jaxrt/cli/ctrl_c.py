"""What Ctrl-C (SIGINT) does in the ``jaxrt`` command, stage by stage.

Python turns SIGINT into a ``KeyboardInterrupt`` raised wherever the main thread happens to
be. During a command's first second or two that is often a place that loses it:

- inside a garbage-collector callback (jaxlib registers one): the exception is printed as
  "ignored" and the command renders on to the end (4 of 27 start-up moments tried, one per
  50 ms);
- inside an extension module's initialisation: the import fails with an ``ImportError``
  (exit status 1, a traceback) or the process aborts (status -6);
- in process 0 of a multi-process render, after JAX's distributed runtime has started: the
  exception unwinds normally, and the runtime's exit handler then waits at a shutdown barrier
  for processes still compiling (38 s and 300 s measured; the barrier's timeout).

So the command handles SIGINT with a handler that raises nothing: it decides from the stage
the command has reached and either quits at once (``os._exit``: nothing to save, no exit
handler to wait for) or asks the render to stop after its pass.

==============================  ===========================================================
stage                           Ctrl-C
==============================  ===========================================================
starting (imports, scene, JAX)  quit at once, nothing written
rendering, no pass finished     quit at once, nothing written (compilation cannot be
                                interrupted, and there is nothing to save)
rendering, a pass finished      stop after the pass running; the command writes the image
a second time                   quit at once, nothing written
finishing (writing the files)   noted, not acted on: the writes are atomic and short
==============================  ===========================================================
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

#: Exit status of a process stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130


def quit_now(message: str):
    """Print ``message`` on its own line and exit with :data:`EXIT_INTERRUPTED` at once:
    without waiting for a worker thread (XLA cannot be interrupted) or for exit handlers
    (JAX's distributed runtime waits for the other processes in one)."""
    # the handler may run while the main thread is inside a write to one of these streams:
    # a flush may then fail ("reentrant call"), and the message goes to the descriptor itself
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(OSError):
        os.write(2, f"\n{message}\n".encode())
    os._exit(EXIT_INTERRUPTED)


class CtrlC:
    """The command's SIGINT handler (see the module's table): ``stage`` is ``"starting"``,
    ``"rendering"`` or ``"finishing"``; while rendering, ``passes_done`` (a list the render
    appends to after each pass) says whether there is an image to save and ``stop`` is the
    flag the render checks between passes."""

    def __init__(self):
        self.stage = "starting"
        self.passes_done: list = []
        self.stop = threading.Event()
        self._previous = None

    def __call__(self, signum, frame):
        if self.stage == "finishing":
            self.stop.set()
        elif self.stage == "starting":
            quit_now("jaxrt: interrupted; nothing written")
        elif not self.passes_done:
            quit_now("jaxrt: interrupted before the first pass finished; nothing written")
        elif self.stop.is_set():
            quit_now("jaxrt: interrupted twice; nothing written")
        else:
            self.stop.set()
            print("\njaxrt: stopping after the pass running (Ctrl-C again quits without "
                  "writing)", file=sys.stderr, flush=True)

    def __enter__(self):
        # signals reach only the main thread; a command run from another thread keeps
        # Python's KeyboardInterrupt (and cannot be interrupted there anyway)
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self)
        return self

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None
        return False
