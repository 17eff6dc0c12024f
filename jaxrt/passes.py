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

from jaxrt.bvh import BVH
from jaxrt.estimators import COMPILER_OPTIONS, Estimator, camera_sample
from jaxrt.scene import Scene

#: Tiles are rounded up to a multiple of this many pixels (the widest CPU vector of float32).
LANES = 16


class Sums(NamedTuple):
    s1: jax.Array  # (P, 3) Σ L
    s2: jax.Array  # (P, 3) Σ L²
    bad: jax.Array  # (P,) int32 non-finite samples


def pixel_sums(scene: Scene, est: Estimator, sampler: str, spp_total: int, seed, pixel,
                start, count: int) -> Sums:
    """Sums of ``count`` samples ``start … start+count−1`` of one pixel (a fori_loop).

    Software-pipelined: iteration k computes sample k and folds sample k − 1, carried from
    the previous iteration. The sample's only consumer is then the loop carry, so XLA:CPU
    materialises it once; folded directly, its last stage (the MIS combination) was fused
    into each of the Σx, Σx² and non-finite kernels and computed three times.
    """
    dtype = scene.triangles.dtype

    def fold(acc, value):
        s1, s2, bad = acc
        # per component, not jnp.all over the (3,) axis: under vmap that is a reduction over
        # a minor axis of 3, a kernel of its own in every sample step
        ok = jnp.isfinite(value[0]) & jnp.isfinite(value[1]) & jnp.isfinite(value[2])
        value = jnp.where(ok, value, 0)
        return s1 + value, s2 + value * value, bad + (~ok).astype(jnp.int32)

    def body(k, carry):
        acc, previous = carry
        value = camera_sample(scene, est, pixel, start + k, seed, sampler, spp_total)
        return fold(acc, previous), value

    zero = jnp.zeros(3, dtype)
    # the first fold adds an exact zero: the sums are those of the unpipelined loop, bit for bit
    acc, last = lax.fori_loop(0, count, body, ((zero, zero, jnp.int32(0)), zero))
    return Sums(*fold(acc, last))


@partial(jax.jit, static_argnames=("est", "sampler", "spp_total", "count", "tile_size",
                                   "batch_size", "num_tiles"))
def render_tiles(scene: Scene, seed, start, first_tile, *, est: Estimator, sampler: str,
                  spp_total: int, count: int, tile_size: int, batch_size: int,
                  num_tiles: int) -> Sums:
    """Sums of ``count`` samples for the pixels of tiles ``[first_tile, first_tile+num_tiles)``.

    Returns arrays with a leading axis of ``num_tiles · tile_size`` pixels; pixels past the
    end of the image are computed as pixel 0 and must be discarded by the caller.
    """
    num_pixels = scene.width * scene.height
    pixels = (first_tile * tile_size
              + jnp.arange(num_tiles * tile_size, dtype=jnp.int32)).reshape(num_tiles, tile_size)
    one_pixel = partial(pixel_sums, scene, est, sampler, spp_total, seed, start=start,
                        count=count)

    def block(pix):
        return jax.vmap(one_pixel)(jnp.where(pix < num_pixels, pix, 0))

    if not isinstance(scene.geometry, BVH):
        # brute force: lax.map's vmap of tiles over a vmap of pixels (a flat vmap of the same
        # lanes measured 0.93×, paired, on the Cornell box)
        sums = lax.map(block, pixels, batch_size=batch_size)
        return jax.tree.map(lambda a: a.reshape((num_tiles * tile_size,) + a.shape[2:]), sums)
    # BVH: batch_size tiles per step as ONE flat vmap of pixels, so that the BVH's batching
    # rule sees all batch_size · tile_size rays and can compact the slow ones (a nested vmap
    # shows it one tile at a time: 1.74× slower on a 1 922-triangle box at 128², same image)
    return lax.map(lambda p: one_pixel(jnp.where(p < num_pixels, p, 0)), pixels.reshape(-1),
                   batch_size=batch_size * tile_size)


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
        self.seeds = [jax.device_put(jnp.uint32(seed), d) for d in devices]
        self.firsts = [jax.device_put(jnp.int32(k * self.per_device), d)
                       for k, d in enumerate(devices)]
        self.compiled: dict[int, list] = {}  # samples per pass -> one executable per device

    def compile(self, count: int) -> float:
        """Compile the pass for ``count`` samples per pixel on every device; returns seconds."""
        t0 = time.perf_counter()
        self.compiled[count] = [
            render_tiles.lower(sc, sd, jax.device_put(jnp.int32(0), d), f, count=count,
                                **self.static).compile(COMPILER_OPTIONS)
            for sc, sd, f, d in zip(self.scenes, self.seeds, self.firsts, self.devices,
                                    strict=True)]
        return time.perf_counter() - t0

    def __call__(self, start: int, count: int) -> Sums:
        if count not in self.compiled:
            self.compile(count)
        # dispatch to every device first (asynchronously), then gather on the host
        outs = [exe(sc, sd, jax.device_put(jnp.int32(start), d), f)
                for exe, sc, sd, f, d in zip(self.compiled[count], self.scenes, self.seeds,
                                             self.firsts, self.devices, strict=True)]
        host = [jax.tree.map(np.asarray, o) for o in outs]
        return jax.tree.map(lambda *xs: np.concatenate(xs)[: self.num_pixels], *host)
