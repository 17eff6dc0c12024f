"""The compiled render pass: running sums of camera samples over tiles of pixels.

One pass renders ``count`` samples (indices ``[start, start + count)``) of every pixel of a
contiguous range of tiles, and returns per-pixel running sums (Σ L, Σ L², non-finite count)
from which :mod:`jaxrt.render` forms the image and its standard error. The per-sample
program is :func:`jaxrt.estimators.camera_sample`; this module decides only how the lanes are
laid out (tiles, steps of ``batch_size`` tiles, devices) and how the sums accumulate. Every
sample is a pure function of (seed, pixel, sample index), so the layout never changes the
numbers.
"""

from __future__ import annotations

import math
import time
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxrt import program_cache
from jaxrt.bvh import BVH
from jaxrt.estimators import COMPILER_OPTIONS, Estimator, camera_sample
from jaxrt.scene import Scene

#: Tiles are rounded up to a multiple of this many pixels (the widest CPU vector of float32).
LANES = 16


class Sums(NamedTuple):
    s1: jax.Array  # (P, 3) Σ L
    s2: jax.Array  # (P, 3) Σ L²
    bad: jax.Array  # (P,) int32 non-finite samples


def lane_sums(scene: Scene, est: Estimator, sampler: str, spp_total: int, seed, pixels,
              start, count: int) -> Sums:
    """Sums of ``count`` samples ``start … start+count−1`` of each pixel of ``pixels``.

    ``pixels``: int32 flat pixel indices of any shape (the lanes); the sums have that shape
    (plus a channel axis of 3 for Σ L and Σ L²).

    A ``fori_loop`` over the samples whose body is the per-sample program vmapped over the
    lanes: ``camera_sample`` is traced and batched once. (Vmapping a per-pixel loop instead
    made JAX batch the loop body to a fixed point, once per vmap level: 3.5 s of a 4 s trace.)

    Software-pipelined: iteration k computes sample k and folds sample k − 1, carried from
    the previous iteration. The sample's only consumer is then the loop carry, so XLA:CPU
    materialises it once; folded directly, its last stage (the MIS combination) was fused
    into each of the Σx, Σx² and non-finite kernels and computed three times.
    """
    dtype = scene.triangles.dtype
    sample = lambda pixel, index: camera_sample(scene, est, pixel, index, seed, sampler,
                                                spp_total)
    for _ in range(pixels.ndim):
        sample = jax.vmap(sample, (0, None))

    def fold(acc, value):
        s1, s2, bad = acc
        # per component, not jnp.all over the channel axis: that is a reduction over a minor
        # axis of 3, a kernel of its own in every sample step
        ok = (jnp.isfinite(value[..., 0]) & jnp.isfinite(value[..., 1])
              & jnp.isfinite(value[..., 2]))
        value = jnp.where(ok[..., None], value, 0)
        return s1 + value, s2 + value * value, bad + (~ok).astype(jnp.int32)

    def body(k, carry):
        acc, previous = carry
        return fold(acc, previous), sample(pixels, start + k)

    zero = jnp.zeros(pixels.shape + (3,), dtype)
    # the first fold adds an exact zero: the sums are those of the unpipelined loop, bit for bit
    acc, last = lax.fori_loop(0, count, body,
                              ((zero, zero, jnp.zeros(pixels.shape, jnp.int32)), zero))
    return Sums(*fold(acc, last))


@partial(jax.jit, static_argnames=("est", "sampler", "spp_total", "count", "tile_size",
                                   "batch_size", "num_tiles"))
def render_tiles(scene: Scene, seed, start, first_tile, *, est: Estimator, sampler: str,
                  spp_total: int, count: int, tile_size: int, batch_size: int,
                  num_tiles: int) -> Sums:
    """Sums of ``count`` samples for the pixels of tiles ``[first_tile, first_tile+num_tiles)``.

    The tiles run ``batch_size`` at a time (a ``lax.map`` over steps; the last step is
    padded). BVH scenes lay a step's lanes out flat, so that the BVH's batching rule sees all
    of its rays and compacts the slow ones (tile by tile it was 1.74× slower on a 1 922-triangle
    box); brute-force scenes as (tiles, pixels), which ran 1.1× faster than flat (paired).

    Returns arrays with a leading axis of ``num_tiles · tile_size`` pixels; pixels past the
    end of the image are computed as pixel 0 and must be discarded by the caller.
    """
    num_pixels = scene.width * scene.height
    per_step = min(batch_size, num_tiles)
    steps = -(-num_tiles // per_step)
    lanes = per_step * tile_size
    pixels = (first_tile * tile_size
              + jnp.arange(steps * lanes, dtype=jnp.int32)).reshape(steps, lanes)

    if not isinstance(scene.geometry, BVH):
        # brute force: lanes as (tiles, pixels), vmapped twice (flat ran 0.90×, paired)
        pixels = pixels.reshape(steps, per_step, tile_size)

    def step(pix):
        return lane_sums(scene, est, sampler, spp_total, seed,
                         jnp.where(pix < num_pixels, pix, 0), start, count)

    sums = lax.map(step, pixels)
    return jax.tree.map(lambda a: a.reshape((steps * lanes,) + a.shape[pixels.ndim:])[
        : num_tiles * tile_size], sums)


class RenderPass:
    """One progressive pass, split over devices: each device runs the same compiled program
    on its own contiguous range of tiles (so the image cannot depend on the device count)."""

    def __init__(self, scene: Scene, seed: int, devices: list, tile_size: int, **static):
        num_pixels = scene.width * scene.height
        total_tiles = math.ceil(num_pixels / tile_size)
        self.per_device = math.ceil(total_tiles / len(devices))
        self.num_pixels = num_pixels
        self.devices = devices
        self.static = dict(static, tile_size=tile_size, num_tiles=self.per_device)
        # the scene's arrays are copied to every device once, not once per pass
        self.scenes = [jax.device_put(scene, d) for d in devices]
        self.seeds = [jax.device_put(np.uint32(seed), d) for d in devices]
        self.firsts = [jax.device_put(np.int32(k * self.per_device), d)
                       for k, d in enumerate(devices)]
        self.compiled: dict[int, list] = {}  # samples per pass -> one executable per device

    def compile(self, count: int) -> float:
        """Compile the pass for ``count`` samples per pixel on every device; returns seconds."""
        t0 = time.perf_counter()
        # read from jaxrt's program cache when the jaxrt command has set one up (no tracing)
        self.compiled[count] = [program_cache.compile_cached(*job) for job in self.jobs(count)]
        return time.perf_counter() - t0

    def jobs(self, count: int) -> list:
        """``(function, arguments, static arguments, compiler options, device)`` of the
        program each device runs for ``count`` samples per pixel."""
        return [(render_tiles, (sc, sd, jax.device_put(np.int32(0), d), f),
                 dict(count=count, **self.static), COMPILER_OPTIONS, d)
                for sc, sd, f, d in zip(self.scenes, self.seeds, self.firsts, self.devices,
                                        strict=True)]

    def __call__(self, start: int, count: int) -> Sums:
        if count not in self.compiled:
            self.compile(count)
        # dispatch to every device first (asynchronously), then gather on the host
        outs = [exe(sc, sd, jax.device_put(np.int32(start), d), f)
                for exe, sc, sd, f, d in zip(self.compiled[count], self.scenes, self.seeds,
                                             self.firsts, self.devices, strict=True)]
        host = [jax.tree.map(np.asarray, o) for o in outs]
        return jax.tree.map(lambda *xs: np.concatenate(xs)[: self.num_pixels], *host)
