"""``render``: batching, chunking, progressive passes, error estimates and devices.

The image is the per-pixel Monte Carlo mean of :func:`jaxrt.integrators.techniques.camera_sample`
over ``spp`` camera samples, with the standard error of that mean,

    I_p = 1/N Σ_k L_k,     σ_p = √( (Σ L_k² / N − I_p²) / (N − 1) ),

computed per channel from running sums. How the work is cut never changes the numbers:

- pixels are flattened (row-major, row 0 at the top) into tiles of ``tile_size`` pixels
  (rounded up to a multiple of 16, so every pixel runs the same vectorised code: XLA's
  scalar remainder loop can round differently from its vector body);
  ``lax.map`` walks the tiles (``batch_size`` tiles at a time, vmapped) so memory is bounded
  at any resolution; tiles are split over ``jax.devices()`` (each device runs the same
  program on its own range of tiles);
- the sample loop is a ``lax.fori_loop``; a *pass* renders ``spp_per_pass`` samples of every
  pixel with the sample indices ``[start, start + spp_per_pass)``, taking each pixel's
  running sums as its initial loop carry and returning them: a pixel's sums are one
  sequential chain over its sample indices 0, 1, 2, … wherever the passes cut it. Each sum
  is a float32 pair (hi, lo) advanced by an error-free TwoSum, and the host forms hi + lo in
  float64 (≤ 1e-12 relative to an exact sum of the same samples, tested; float32 alone is
  off by ~8e-6 at 2 048 spp). The pair costs ~1 % per CPU-second
  (benchmarks/README.md#carried-sums);
- every sample is a pure function of (seed, pixel, sample index), so the same seed gives a
  bit-identical image and standard error whatever the tile size, batch size, pass size,
  device count or process count.

Pass size. By default a pass holds about :data:`SAMPLES_PER_PASS` samples (1.0 s measured on
the 256² Cornell box, 2.1 M samples/s on one CPU core), so that the progress bar moves,
the time budget and Ctrl-C take effect within a pass, and the error can be checked. The pass
size is chosen from the image size and ``spp`` alone, never from a clock: it divides
``spp`` (one compiled program; a shorter last pass compiles a second one). An explicit
``spp_per_pass`` changes the pace, never the numbers: 12 spp in passes of 1, 3, 4, 5 or 12
give the same image and standard error, bit for bit (tested).

Stopping: after ``spp`` samples, or before a pass that would end past ``time_budget``
seconds of rendering, or once the error target is met, or at Ctrl-C (SIGINT): the pass
running finishes and :class:`RenderInterrupted` carries the image rendered so far (a second
Ctrl-C interrupts at once).

Samples that are not finite (a NaN or Inf from a degenerate configuration) never reach the
image: they are replaced by zero, counted, and the count is reported. Long renders show a
progress bar (tqdm) and can stop at a time budget or at a target relative error.

Several devices: with ``devices=None`` all of this process's devices are used (each runs
the same program on its own range of tiles). Several processes (``jax.distributed.initialize()``
first in every one, e.g. ``jaxrt render --processes N`` on one machine or one process per
host) split the tiles as devices do: the image's tiles are cut into N × devices contiguous
ranges, process q's devices take the q-th N-th of them, and every process renders every
pass of its own tiles, carrying its own pixels' sums. Where the error target is checked
and at the end, every process receives every process's sums (``process_allgather``), so the
image is bit for bit that of one process; process 0 decides when to stop and broadcasts it.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from typing import NamedTuple

import jax
import numpy as np

from jaxrt.integrators.config import Estimator, make_estimator, prepare_scene
from jaxrt.rendering.passes import LANES, RenderPass, Sums
from jaxrt.sampling.sampler import SAMPLERS
from jaxrt.scene.container import Scene


class RenderResult(NamedTuple):
    """What :func:`render` returns.

    image: (H, W, 3) float32 mean radiance; stderr: (H, W, 3) float32 standard error of that
    mean (the sample standard deviation over √spp; it is 0 where every sample of a pixel was
    equal, e.g. a penumbra whose rare lit samples were never drawn: an *estimate* from the
    samples taken, not a bound); spp: samples per pixel taken; nonfinite: how many samples
    were NaN/Inf (dropped as zero); timings: dict of seconds (``compile``, ``render``,
    ``total``, ``last_pass``: the seconds of the last pass, which the time-budget rule
    extrapolates) and ``samples_per_s``; passes: number of progressive passes run; stopped_by:
    "spp", "time_budget", "target_error" or "interrupted".
    """

    image: np.ndarray
    stderr: np.ndarray
    spp: int
    nonfinite: int
    timings: dict
    passes: int
    stopped_by: str

    @property
    def relative_error(self) -> float:
        """Mean over pixels of σ / max(I, 1e-3·mean(I)): the knob ``target_error`` refers to."""
        return _relative_error(self.image, self.stderr)


class RenderInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`render`: ``result`` is the image of the passes completed (a
    :class:`RenderResult` with ``stopped_by="interrupted"``), or None if none was."""

    def __init__(self, result: RenderResult | None):
        super().__init__("render interrupted"
                         + (f" after {result.spp} spp" if result is not None else ""))
        self.result = result


#: Samples (pixels × spp) per progressive pass by default: 1–2 s at 1–2 M samples/s.
SAMPLES_PER_PASS = 2**21


def default_spp_per_pass(num_pixels: int, spp: int | None,
                         samples_per_pass: int = SAMPLES_PER_PASS) -> int:
    """Samples per pixel per pass: the largest divisor of ``spp`` (any power of two when spp
    is unbounded) not above ``samples_per_pass / num_pixels`` (at least 1). A function of the
    image size and spp only, so the image never depends on the machine's speed."""
    target = max(1, samples_per_pass // max(1, num_pixels))
    if spp is None:
        return 1 << (target.bit_length() - 1)
    return max(d for d in range(1, min(spp, target) + 1) if spp % d == 0)


def _relative_error(image: np.ndarray, stderr: np.ndarray) -> float:
    floor = max(1e-3 * float(np.mean(image)), 1e-12)
    return float(np.mean(stderr / np.maximum(image, floor)))


def render(scene: Scene, estimator: str | Estimator = "mis", spp: int | None = None,
           seed: int = 0, *, sampler: str = "independent", spp_per_pass: int | None = None,
           time_budget: float | None = None, target_error: float | None = None,
           tile_size: int = 256, batch_size: int = 64, devices: int | None = None,
           progress: bool | None = None, stop: threading.Event | None = None,
           on_pass: Callable[[int], None] | None = None, **estimator_params) -> RenderResult:
    """Render ``scene`` with a direct-illumination estimator.

    Args:
        scene: a :class:`jaxrt.scene.container.Scene`.
        estimator: a name from :data:`jaxrt.integrators.config.ESTIMATORS` or an ``Estimator``;
            ``estimator_params`` (light_samples, bsdf_samples, heuristic, light_prob) refine it.
        spp: samples per pixel (the maximum when a time budget or target error is given).
            Default: 16, or unbounded when a time budget or target error is given.
        seed: the random seed; the same seed gives the same image, bit for bit (whatever
            the pass size, tiles, devices and processes).
        sampler: "independent" | "stratified" | "sobol" sample stream.
        spp_per_pass: samples per progressive pass (default: :func:`default_spp_per_pass`,
            about a second of work per pass); it never changes the image.
        time_budget: seconds of rendering (compilation excluded); no pass starts that would
            end past it, judged from the last pass's time (at least one pass runs).
        target_error: stop once the mean relative standard error falls below this (checked
            after each pass, from 16 spp on; see :func:`_error_for_stopping`).
        tile_size: pixels per tile (rounded up to a multiple of 16).
        batch_size: tiles evaluated at once (memory ∝ tile_size · batch_size). The default
            256 × 64 = 16 384 lanes per step renders the 256² Cornell box 1.4–1.6× faster
            than 1 024 lanes (XLA:CPU's fixed cost per kernel call is amortised over more
            lanes; benchmarks/README.md#step-lanes); a small image still runs as one step of
            its tiles.
        devices: how many of this process's devices (``jax.local_devices()``) to split the
            tiles over (default: all).
        progress: print what is compiled and show a tqdm bar on stderr (default: when more
            than one pass runs).
        stop: an event that, once set (from another thread), stops the render as Ctrl-C does.
        on_pass: called with the samples per pixel done after each pass.

    Returns a :class:`RenderResult`. Raises :class:`RenderInterrupted` (a KeyboardInterrupt
    carrying the partial result) on Ctrl-C, after the pass running; a second Ctrl-C raises a
    plain KeyboardInterrupt (at once, or after that pass if Python lost it in a
    garbage-collector callback).
    """
    est = make_estimator(estimator, **estimator_params)
    adaptive = time_budget is not None or target_error is not None
    if spp is None and not adaptive:
        spp = 16
    if spp is not None and (not isinstance(spp, int | np.integer) or isinstance(spp, bool)
                            or spp <= 0):
        raise ValueError(f"spp must be a positive integer (or None with a time budget or "
                         f"target error), got {spp!r}")
    if sampler not in SAMPLERS:
        raise ValueError(f"unknown sampler {sampler!r}; choose one of {SAMPLERS}")
    if time_budget is not None and not time_budget > 0:
        raise ValueError(f"time_budget must be > 0 seconds, got {time_budget}")
    if target_error is not None and not target_error > 0:
        raise ValueError(f"target_error must be > 0, got {target_error}")
    if tile_size <= 0 or batch_size <= 0:
        raise ValueError("tile_size and batch_size must be positive")
    if spp_per_pass is not None and not (isinstance(spp_per_pass, int | np.integer)
                                         and spp_per_pass > 0):
        raise ValueError(f"spp_per_pass must be a positive integer, got {spp_per_pass!r}")
    local = jax.local_devices()
    num_devices = len(local) if devices is None else int(devices)
    if not isinstance(num_devices, int) or not 1 <= num_devices <= len(local):
        raise ValueError(f"devices must be between 1 and {len(local)}, got {devices}")
    rank, num_procs = jax.process_index(), jax.process_count()
    # every pixel must take the same vectorised code path (XLA's remainder loop may round
    # differently), so tiles hold a whole number of 16-lane vectors
    tile_size = LANES * math.ceil(int(tile_size) / LANES)
    h, w = scene.height, scene.width
    if spp_per_pass is None:
        spp_per_pass = default_spp_per_pass(h * w, None if spp is None else int(spp))
    spp_per_pass = int(spp_per_pass) if spp is None else min(int(spp_per_pass), int(spp))
    # light_area / light_solid_angle fix the measure of triangle-light sampling; the other
    # estimators use the scene's own (a static property of the light table)
    scene = prepare_scene(scene, est)

    # a stratified stream needs its number of strata: one stratification per pass if unbounded
    spp_total = int(spp) if spp is not None else spp_per_pass
    run = RenderPass(scene, seed, local[:num_devices], tile_size, shard=(rank, num_procs),
                     est=est, sampler=sampler, spp_total=spp_total, batch_size=int(batch_size))
    num_passes = None if spp is None else math.ceil(spp / spp_per_pass)
    show = (progress if progress is not None else num_passes != 1) and rank == 0
    t0 = time.perf_counter()
    if show:
        procs = f" x {num_procs} processes" if num_procs > 1 else ""
        print(f"jaxrt: compiling {est.name} ({sampler}) for {w}x{h}, {spp_per_pass} spp per "
              f"pass on {num_devices} {local[0].platform.upper()} device(s){procs} ...",
              file=sys.stderr, flush=True)
    t_compile = run.compile(spp_per_pass)
    if show:
        print(f"jaxrt: compiled in {t_compile:.1f} s", file=sys.stderr, flush=True)

    bar = _progress_bar(spp, show)
    sums = run.zeros()  # the running sums of this process's tiles, carried through the passes
    done, passes, stopped_by, bar_done = 0, 0, None, 0
    t_start = time.perf_counter()
    last_pass = 0.0
    with _sigint_flag(stop) as (interrupted, repeated):
        # with several processes only the agreed decision ends the loop: a process that left
        # on its own flag (set between passes) would wait in the final gather while the others
        # wait for it in the next pass's agreement (a deadlock; tests/cli/test_multiprocess.py)
        while ((num_procs > 1 or not interrupted.is_set())
               and (spp is None or done < spp)):
            count = spp_per_pass if spp is None else min(spp_per_pass, spp - done)
            t_pass = time.perf_counter()
            # a shorter last pass compiles its own program (count is static)
            sums = run(sums, done, count)
            if repeated.is_set():  # a second Ctrl-C whose KeyboardInterrupt was lost
                raise KeyboardInterrupt
            done += count
            passes += 1
            if on_pass is not None:
                on_pass(done)
            # every process takes part in the gather, whatever its own clock says
            check_error = target_error is not None and done >= 16
            image_sums = _image_sums(run, sums, num_procs) if check_error else None
            now = time.perf_counter()
            last_pass, elapsed = now - t_pass, now - t_start
            rate = done * h * w / max(elapsed, 1e-12)
            left = None if spp is None else (spp - done) * h * w / rate
            reason = None
            if interrupted.is_set():
                reason = "interrupted"
            elif spp is not None and done >= spp:
                reason = "spp"
            if reason is None and time_budget is not None:
                if elapsed + last_pass > time_budget:
                    reason = "time_budget"
                left = min(math.inf if left is None else left, time_budget - elapsed)
            if reason is None and check_error:
                rel = _error_for_stopping(*image_sums[:2], done)
                bar.postfix(rel_err=f"{rel:.4f}")
                if rel <= target_error:
                    reason = "target_error"
                # σ ∝ 1/√n: the time the samples still needed take
                more = done * ((rel / target_error) ** 2 - 1) * h * w / rate
                left = more if left is None else min(left, more)
            # process 0's clock and Ctrl-C decide for every process
            reason = _agree(reason, num_procs)
            bar.advance(done - bar_done, rate, 0.0 if reason else left)
            bar_done = done
            if reason is not None:
                stopped_by = reason
                break
    bar.close()
    if stopped_by is None:  # the flag was set before the first pass (during compilation)
        stopped_by = "interrupted"
    t_render = time.perf_counter() - t_start
    result = None
    if done:  # every process gets here with the same done (process 0 decided)
        s1, s2, bad = _image_sums(run, sums, num_procs)
        mean, err = _mean_and_error(s1, s2, done)
        timings = {"compile": t_compile, "render": t_render, "total": time.perf_counter() - t0,
                   "last_pass": last_pass, "samples_per_s": done * h * w / max(t_render, 1e-12)}
        result = RenderResult(image=mean.reshape(h, w, 3).astype(np.float32),
                              stderr=err.reshape(h, w, 3).astype(np.float32), spp=done,
                              nonfinite=int(bad.sum()), timings=timings, passes=passes,
                              stopped_by=stopped_by)
    if stopped_by == "interrupted":
        raise RenderInterrupted(result)
    return result


_STOP_REASONS = (None, "spp", "time_budget", "target_error", "interrupted")


def _image_sums(run: RenderPass, sums, num_procs: int) -> tuple:
    """(Σ L, Σ L², non-finite count) of every pixel of the image (float64, int64), on every
    process: each process's tile range in process order (``process_allgather``)."""
    mine = run.host(sums)
    if num_procs > 1:
        from jax.experimental import multihost_utils

        every = multihost_utils.process_allgather(tuple(mine))  # (processes, pixels, ...)
        mine = Sums(*(a.reshape((-1,) + a.shape[2:]) for a in every))
    return Sums(*(a[: run.num_pixels] for a in mine)).totals()


def _agree(reason: str | None, num_procs: int) -> str | None:
    """Process 0's stopping decision, on every process."""
    if num_procs == 1:
        return reason
    from jax.experimental import multihost_utils

    code = multihost_utils.broadcast_one_to_all(np.int32(_STOP_REASONS.index(reason)))
    return _STOP_REASONS[int(code)]


def _mean_and_error(s1: np.ndarray, s2: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error of the mean from Σx and Σx² over n samples (float64)."""
    mean = s1 / n
    if n < 2:
        return mean, np.full_like(mean, np.inf)
    var = np.maximum(s2 / n - mean * mean, 0) * n / (n - 1)
    return mean, np.sqrt(var / n)


def _error_for_stopping(s1: np.ndarray, s2: np.ndarray, n: int) -> float:
    """The mean relative error that ``target_error`` is compared with.

    As :attr:`RenderResult.relative_error`, except that no lit pixel counts as exact: a pixel
    whose n samples were all equal has σ̂ = 0 (or float32 rounding noise), yet an outcome not
    drawn yet (a penumbra's rare lit sample) can still have probability 3/n (the rule of
    three). So every lit pixel counts with at least the relative standard error of a mean of
    n samples that differ with probability p = 3/n, √(p(1 − p)/n)/(1 − p) ≈ √3/n: a render
    whose pixels are mostly constant cannot stop early on their zeros, and the floor falls
    faster than any real error (1/n against 1/√n). Black pixels count as they are.
    """
    mean, err = _mean_and_error(s1, s2, n)
    p = min(3.0 / n, 0.5)
    floor = np.sqrt(p * (1 - p) / n) / (1 - p)
    err = np.where(mean > 0, np.maximum(err, floor * mean), err)
    return _relative_error(mean, err)


@contextmanager
def _sigint_flag(flag: threading.Event | None = None):
    """Turn the first Ctrl-C into a flag the pass loop checks (a second one interrupts at
    once). Yields ``(flag, repeated)``; ``repeated`` is set by the second Ctrl-C, whose
    KeyboardInterrupt is lost when it is raised inside a garbage-collector callback (jaxlib
    registers one: Python prints it as "ignored"), so the pass loop raises it again after the
    pass running. Only in the main thread, where Python delivers signals; elsewhere only
    ``flag``."""
    flag = threading.Event() if flag is None else flag
    repeated = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag, repeated
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum, frame):
        if flag.is_set():
            repeated.set()
            raise KeyboardInterrupt
        flag.set()

    signal.signal(signal.SIGINT, handler)
    try:
        yield flag, repeated
    finally:
        signal.signal(signal.SIGINT, previous)


class _Bar:
    """tqdm over samples per pixel, with samples/s and the time left (or nothing at all)."""

    def __init__(self, total: int | None, show: bool):
        self.tqdm = None
        if not show:
            return
        try:
            from tqdm.auto import tqdm
        except ImportError:  # tqdm is optional: render silently without it
            return
        self.tqdm = tqdm(total=total, unit="spp", desc="render", file=sys.stderr,
                         bar_format="{desc}: {percentage:3.0f}%|{bar}| {n}/{total} spp "
                         "[{elapsed}{postfix}]" if total else
                         "{desc}: {n} spp [{elapsed}{postfix}]")
        self.extra = {}

    def postfix(self, **kw):
        if self.tqdm is not None:
            self.extra.update(kw)

    def advance(self, n: int, rate: float, left: float | None):
        if self.tqdm is None:
            return
        post = {"Msamples/s": f"{rate / 1e6:.2f}"}
        if left is not None and math.isfinite(left):
            post["eta"] = f"{max(left, 0):.0f}s"
        self.tqdm.set_postfix(post | self.extra, refresh=False)
        self.tqdm.update(n)

    def close(self):
        if self.tqdm is not None:
            self.tqdm.close()


def _progress_bar(total: int | None, show: bool) -> _Bar:
    return _Bar(total, show)
