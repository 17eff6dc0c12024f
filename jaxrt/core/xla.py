"""XLA:CPU options for jaxrt's own programs, set per compilation and probed once.

:data:`COMPILER_OPTIONS` are what every per-sample program (render passes, ``estimate_at``,
gradient passes) is compiled with; :func:`compiler_options` keeps those the installed XLA
accepts; :func:`jit_with_options` is ``jax.jit`` with them. A user's own programs are
untouched: nothing is set process-wide.
"""

from __future__ import annotations

import concurrent.futures
import functools

import jax
import numpy as np

#: XLA:CPU options wanted for every program of the per-sample code (render passes,
#: ``estimate_at``, gradient passes): set per compilation, never process-wide, so a user's own
#: programs are untouched; :func:`compiler_options` keeps those the installed XLA knows.
#: Measured on the 256² Cornell box (benchmarks/README.md#compiler-options):
#:
#: - ``xla_cpu_prefer_vector_width=512``: MIS 1.5× per CPU-second on a CPU with AVX-512. On a
#:   CPU without it XLA uses what exists: on AVX2 the option changes neither the compile time
#:   nor the speed nor the images (benchmarks/README.md#compiler-options).
#: - ``xla_cpu_experimental_ynn_fusion_type=""`` (no YNNPACK fusions): XLA:CPU hands every
#:   reduction to YNNPACK, whose reduction over the minor axis of an (N, 3) array (each
#:   ``vecmath.dot`` under ``vmap``) takes ~9× as long as XLA's own loop; without them MIS
#:   runs 1.28× and the path tracer 1.32× faster per CPU-second, and the MIS pass compiles
#:   in two thirds of the time.
#: - ``xla_cpu_enable_fast_min_max=True``: ``min``/``max`` as a compare and a select, as C's
#:   ``a < b ? b : a`` (pbrt's and Mitsuba's ``std::max``), not IEEE's NaN-propagating
#:   ``llvm.maximum`` (several x86 instructions around ``vmaxps``): the watertight test takes
#:   eight maxima per triangle. MIS ~1.1× and path 1.06× per CPU-second, images
#:   bit-identical. The price: a NaN met by a min or max inside a
#:   sample may come out as the other operand (and ``max(−0, +0)`` as −0), so a NaN that
#:   would have reached the pixel's sums (and been counted, ``RenderResult.nonfinite``) can
#:   be clamped instead; none of jaxrt's validated scenes produces one.
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": "",
                    "xla_cpu_enable_fast_min_max": True}


@functools.cache
def compiler_options() -> dict:
    """The :data:`COMPILER_OPTIONS` that this jaxlib's XLA:CPU accepts, found once per process.

    An option unknown to the installed version (they are experimental and come and go) would
    fail every compilation, so they are tried on a trivial program first: all at once (one
    probe compile, ~20 ms, in every process that compiles or reads a program), and only if
    that fails one by one, leaving out each one refused. Called when the first program is
    compiled, not at import: compiling starts JAX's backend, after which a user can no longer
    choose its devices.
    """
    probe = jax.jit(lambda x: x + 1).lower(np.float32(0))

    def accepts(options: dict) -> bool:
        try:
            probe.compile(options)
        except Exception:  # noqa: BLE001 — XLA raises INVALID_ARGUMENT for an unknown option
            return False
        return True

    if accepts(COMPILER_OPTIONS):
        return dict(COMPILER_OPTIONS)
    accepted = {}
    for key, value in COMPILER_OPTIONS.items():
        if accepts({**accepted, key: value}):
            accepted[key] = value
    return accepted


def compiler_options_soon() -> concurrent.futures.Future:
    """:func:`compiler_options` as a future, its probe compiled on a thread of its own.

    The probe's trivial program (most of its time the process's first-compile set-up) then
    compiles while the caller traces its program, which needs the options only when it
    compiles (:meth:`jaxrt.rendering.passes.RenderPass.compile`): part of the probe's time
    comes off a first frame, the rest shares the GIL with the trace
    (benchmarks/README.md#second-run).
    Already resolved once :func:`compiler_options` has run in this process.
    """
    if compiler_options.cache_info().currsize:
        done: concurrent.futures.Future = concurrent.futures.Future()
        done.set_result(compiler_options())
        return done
    if not _PROBING or _PROBING[0].done():
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxrt-option-probe")
        _PROBING[:] = [pool.submit(compiler_options)]
        pool.shutdown(wait=False)  # its one thread ends when the probe does
    return _PROBING[0]


_PROBING: list[concurrent.futures.Future] = []  # the probe under way, if any


def jit_with_options(**jit_kwargs):
    """``jax.jit(fn, **jit_kwargs)`` with :func:`compiler_options`, resolved at the first call.

    Used as a decorator for jaxrt's own programs; ``fn.program()`` is the jitted function
    itself (for ``.lower``).
    """
    def wrap(fn):
        @functools.cache
        def program():
            return jax.jit(fn, compiler_options=compiler_options(), **jit_kwargs)

        @functools.wraps(fn)
        def call(*args, **kwargs):
            return program()(*args, **kwargs)

        call.program = program
        return call

    return wrap
