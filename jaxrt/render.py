"""``render``: batching, chunking, progressive passes, error estimates and devices.

The image is the per-pixel Monte Carlo mean of :func:`jaxrt.estimators.camera_sample` over
``spp`` camera samples, with the standard error of that mean,

    I_p = 1/N Σ_k L_k,     σ_p = √( (Σ L_k² / N − I_p²) / (N − 1) ),

computed per channel from running sums. How the work is cut never changes the numbers:

- pixels are flattened (row-major, row 0 at the top) into tiles of ``tile_size`` pixels
  (rounded up to a multiple of 16, so every pixel runs the same vectorised code: XLA's
  scalar remainder loop can round differently from its vector body);
  ``lax.map`` walks the tiles (``batch_size`` tiles at a time, vmapped) so memory is bounded
  at any resolution; tiles are split over ``jax.devices()`` (each device runs the same
  program on its own range of tiles);
- the sample loop is a ``lax.fori_loop``; a *pass* renders ``spp_per_pass`` samples of every
  pixel with the sample indices ``[start, start + spp_per_pass)``;
- every sample is a pure function of (seed, pixel, sample index), so the same seed gives a
  bit-identical image whatever the tile size, batch size or device count.

Samples that are not finite (a NaN or Inf from a degenerate configuration) never reach the
image: they are replaced by zero, counted, and the count is reported. Long renders show a
progress bar (tqdm) and can stop at a time budget or at a target relative error.

Several devices: with ``devices=None`` all of ``jax.devices()`` are used. The same code runs
on several GPUs unchanged; on several hosts, call ``jax.distributed.initialize()`` first on
every host so that ``jax.devices()`` lists all of them (each host renders its share of tiles;
the image is gathered by the final ``np.asarray``).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import jax
import numpy as np

from jaxrt.estimators import Estimator, make_estimator
from jaxrt.passes import LANES, RenderPass
from jaxrt.sampler import SAMPLER_KINDS
from jaxrt.scene import Scene, with_triangle_sampling


class RenderResult(NamedTuple):
    """What :func:`render` returns.

    image: (H, W, 3) float32 mean radiance; stderr: (H, W, 3) float32 standard error of that
    mean; spp: samples per pixel taken; nonfinite: how many samples were NaN/Inf (dropped as
    zero); timings: dict of seconds (``compile``, ``render``, ``total``) and ``samples_per_s``;
    passes: number of progressive passes run; stopped_by: "spp", "time_budget" or
    "target_error".
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


def _relative_error(image: np.ndarray, stderr: np.ndarray) -> float:
    floor = max(1e-3 * float(np.mean(image)), 1e-12)
    return float(np.mean(stderr / np.maximum(image, floor)))


def render(scene: Scene, estimator: str | Estimator = "mis", spp: int = 16, seed: int = 0, *,
           sampler: str = "independent", spp_per_pass: int | None = None,
           time_budget: float | None = None, target_error: float | None = None,
           tile_size: int = 256, batch_size: int = 64, devices: int | None = None,
           progress: bool | None = None, **estimator_params) -> RenderResult:
    """Render ``scene`` with a direct-illumination estimator.

    Args:
        scene: a :class:`jaxrt.scene.Scene`.
        estimator: a name from :data:`jaxrt.estimators.ESTIMATORS` or an ``Estimator``;
            ``estimator_params`` (light_samples, bsdf_samples, heuristic, light_prob) refine it.
        spp: samples per pixel (the maximum when a time budget or target error is given).
        seed: the random seed; the same seed gives the same image, bit for bit.
        sampler: "independent" | "stratified" | "sobol" sample stream.
        spp_per_pass: samples per progressive pass (default: all of them in one pass, or
            about 1/16 of them when a time budget or target error is set).
        time_budget: stop after the pass during which this many seconds have elapsed.
        target_error: stop once the mean relative standard error falls below this.
        tile_size: pixels per tile (rounded up to a multiple of 16).
        batch_size: tiles evaluated at once (memory ∝ tile_size · batch_size). The default
            256 × 64 = 16 384 lanes per step renders the 256² Cornell box 1.4–1.6× faster
            than 1 024 lanes (XLA:CPU's fixed cost per kernel call is amortised over more
            lanes; benchmarks/RESULTS.md); a small image still runs as one step of its tiles.
        devices: how many of ``jax.devices()`` to split the tiles over (default: all).
        progress: show a tqdm bar (default: when more than one pass runs).

    Returns a :class:`RenderResult`.
    """
    est = make_estimator(estimator, **estimator_params)
    if not isinstance(spp, int | np.integer) or spp <= 0:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    if sampler not in SAMPLER_KINDS:
        raise ValueError(f"unknown sampler {sampler!r}; choose one of {SAMPLER_KINDS}")
    if time_budget is not None and not time_budget > 0:
        raise ValueError(f"time_budget must be > 0 seconds, got {time_budget}")
    if target_error is not None and not target_error > 0:
        raise ValueError(f"target_error must be > 0, got {target_error}")
    if tile_size <= 0 or batch_size <= 0:
        raise ValueError("tile_size and batch_size must be positive")
    num_devices = len(jax.devices()) if devices is None else int(devices)
    if not isinstance(num_devices, int) or not 1 <= num_devices <= len(jax.devices()):
        raise ValueError(f"devices must be between 1 and {len(jax.devices())}, got {devices}")
    # every pixel must take the same vectorised code path (XLA's remainder loop may round
    # differently), so tiles hold a whole number of 16-lane vectors
    tile_size = LANES * math.ceil(int(tile_size) / LANES)
    adaptive = time_budget is not None or target_error is not None
    if spp_per_pass is None:
        spp_per_pass = max(1, spp // 16) if adaptive else spp
    spp_per_pass = min(int(spp_per_pass), int(spp))
    # the estimator decides how triangle lights are sampled (a static property of the lights)
    scene = scene.replace(lights=with_triangle_sampling(scene.lights, est.triangle_sampling))

    run = RenderPass(scene, seed, jax.devices()[:num_devices], tile_size, est=est, sampler=sampler,
                spp_total=int(spp), batch_size=int(batch_size))
    t0 = time.perf_counter()
    t_compile = run.compile(spp_per_pass)

    num_passes = math.ceil(spp / spp_per_pass)
    show = progress if progress is not None else num_passes > 1
    bar = _progress_bar(num_passes, show)
    s1 = s2 = bad = None
    done, passes, stopped_by = 0, 0, "spp"
    t_start = time.perf_counter()
    while done < spp:
        # a shorter last pass compiles its own program (count is static)
        count = min(spp_per_pass, spp - done)
        sums = run(done, count)
        if s1 is None:
            s1, s2, bad = (sums.s1.astype(np.float64), sums.s2.astype(np.float64),
                           sums.bad.astype(np.int64))
        else:
            s1 += sums.s1
            s2 += sums.s2
            bad += sums.bad
        done += count
        passes += 1
        bar.update(1)
        elapsed = time.perf_counter() - t_start
        if done < spp and time_budget is not None and elapsed >= time_budget:
            stopped_by = "time_budget"
            break
        if done < spp and target_error is not None and done > 1:
            mean, err = _mean_and_error(s1, s2, done)
            rel = _relative_error(mean, err)
            bar.set_postfix(rel_err=f"{rel:.4f}")
            if rel <= target_error:
                stopped_by = "target_error"
                break
    bar.close()
    t_render = time.perf_counter() - t_start
    mean, err = _mean_and_error(s1, s2, done)
    h, w = scene.height, scene.width
    timings = {"compile": t_compile, "render": t_render, "total": time.perf_counter() - t0,
               "samples_per_s": done * h * w / max(t_render, 1e-12)}
    return RenderResult(image=mean.reshape(h, w, 3).astype(np.float32),
                        stderr=err.reshape(h, w, 3).astype(np.float32), spp=done,
                        nonfinite=int(bad.sum()), timings=timings, passes=passes,
                        stopped_by=stopped_by)


def _mean_and_error(s1: np.ndarray, s2: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error of the mean from Σx and Σx² over n samples (float64)."""
    mean = s1 / n
    if n < 2:
        return mean, np.full_like(mean, np.inf)
    var = np.maximum(s2 / n - mean * mean, 0) * n / (n - 1)
    return mean, np.sqrt(var / n)


class _NoBar:
    def update(self, n):
        pass

    def set_postfix(self, **kw):
        pass

    def close(self):
        pass


def _progress_bar(total: int, show: bool):
    if not show:
        return _NoBar()
    try:
        from tqdm.auto import tqdm
    except ImportError:  # tqdm is optional: render silently without it
        return _NoBar()
    return tqdm(total=total, unit="pass", desc="render")
