"""The compiled render pass: running sums of camera samples over tiles of pixels.

One pass renders ``count`` samples (indices ``[start, start + count)``) of every pixel of a
contiguous range of tiles, and advances the per-pixel running sums (Σ L, Σ L², non-finite
count) that it takes as its initial loop carry and returns; :mod:`jaxrt.rendering.driver` forms the
image and its standard error from them. The per-sample program is
:func:`jaxrt.integrators.techniques.camera_sample`; this module decides only how the lanes are laid
out (tiles, steps of ``batch_size`` tiles, devices, processes) and how the sums accumulate.
Every sample is a pure function of (seed, pixel, sample index), and each pixel's sums are
one sequential chain over its sample indices whatever the passes, so neither the layout nor
the pass size changes the numbers.
"""

from __future__ import annotations

import math
import time
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array, lax

from jaxrt.core import xla
from jaxrt.core.vecmath import computed_once
from jaxrt.core.xla import compiler_options_soon
from jaxrt.integrators.config import Estimator
from jaxrt.integrators.path import compactions, pass_sums
from jaxrt.integrators.techniques import TECHNIQUES, camera_hit, camera_radiance
from jaxrt.integrators.terms import Stream
from jaxrt.rendering import program_cache
from jaxrt.sampling.sampler import pixel_key
from jaxrt.scene.container import Scene

#: Tiles are rounded up to a multiple of this many pixels (the widest CPU vector of float32).
LANES = 16


class Sums(NamedTuple):
    """Per-pixel running sums, carried from pass to pass.

    Σ L and Σ L² are each an unevaluated float32 pair ``hi + lo`` (a double-float32, ~48
    bits of significand) advanced by an error-free TwoSum per sample, so the host gets
    float64-grade sums without x64; ``bad`` counts the non-finite samples.
    """

    s1: jax.Array  # (P, 3) Σ L, high part
    s1_lo: jax.Array  # (P, 3) Σ L, low part
    s2: jax.Array  # (P, 3) Σ L², high part
    s2_lo: jax.Array  # (P, 3) Σ L², low part
    bad: jax.Array  # (P,) int32 non-finite samples

    def totals(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Σ L, Σ L², non-finite count) on the host: hi + lo in float64, the count int64."""
        wide = lambda hi, lo: np.asarray(hi, np.float64) + np.asarray(lo, np.float64)
        return (wide(self.s1, self.s1_lo), wide(self.s2, self.s2_lo),
                np.asarray(self.bad, np.int64))


def zero_sums(shape: tuple, dtype) -> Sums:
    """The sums before the first sample, for lanes of ``shape`` (numpy: built on the host,
    no program compiled)."""
    zero = np.zeros(shape + (3,), dtype)
    return Sums(zero, zero, zero, zero, np.zeros(shape, np.int32))


def two_sum(hi, lo, x):
    """``(hi, lo) + x``, the rounding error of ``hi + x`` kept in ``lo``.

    Knuth's TwoSum: s = hi + x rounds, and err = (hi − (s − b)) + (x − b) with b = s − hi is
    its exact error, for any magnitudes (Knuth, TAOCP vol. 2, 4.2.2). XLA does not
    reassociate floating point, so the error is not simplified away (tested: lo ≠ 0).
    """
    s = hi + x
    b = s - hi
    return s, lo + ((hi - (s - b)) + (x - b))


def lane_sums(scene: Scene, est: Estimator, sampler: str, spp_total: int, seed, pixels,
              start, count: int, sums: Sums) -> Sums:
    """``sums`` advanced by samples ``start … start+count−1`` of each pixel of ``pixels``.

    ``pixels``: (N,) int32 flat pixel indices (the lanes); ``sums`` has that shape (plus a
    channel axis of 3 for Σ L and Σ L²).

    One sequential chain per pixel over the sample indices: a pass takes the running sums
    as its initial carry, so where passes cut the chain never changes the result, bit for
    bit.

    A ``fori_loop`` over the samples whose body is the per-sample program vmapped over the
    lanes: ``camera_sample`` (as its two halves :func:`~jaxrt.integrators.techniques.camera_hit` and
    :func:`~jaxrt.integrators.techniques.camera_radiance`) is traced and batched once. (Vmapping a
    per-pixel loop instead makes JAX batch the loop body to a fixed point, once per vmap
    level, which takes most of the trace.)

    Software-pipelined in three stages: iteration k intersects the camera ray of sample
    k + 1, shades sample k (whose hit the previous iteration found) and folds sample k − 1.

    - The fold: the sample's only consumer is then the loop carry, so XLA:CPU materialises
      it once; folded directly, its last stage (the MIS combination) would be fused into
      each of the Σx, Σx² and non-finite kernels and computed three times.
    - The camera ray: its closest-hit loop and the shading's (shadow and BSDF rays) are then
      independent within an iteration, and XLA:CPU runs them side by side on its two
      threads; in sequence, the camera loop's kernels run on one thread while the other
      is mostly idle (the 256² MIS pass renders 1.10× as many samples per CPU-second
      pipelined, images bit-identical: benchmarks/README.md#pipelined-loop). The price:
      the first camera hit is found before the loop (a second copy of that part of the
      program, compile +0.2–0.3 s) and the last iteration's (sample start + count) is
      unused, 1/count of the camera rays.
    """
    if TECHNIQUES[est.name].regenerates:
        # paths of unequal length: lanes regenerate paths and are compacted (jaxrt.integrators.path)
        # (the key formed per stream: carried in the lanes, it slows the path pass)
        stream = lambda pixel, k: Stream.of(sampler, seed, pixel, start + k, spp_total)
        # L² stored before the fold reads it (as the loop carry stores it below), so that
        # LLVM cannot contract it into the TwoSum's adds: the same sums as `mis` at depth 2
        return pass_sums(scene, est, stream, pixels, count, sums,
                         lambda a, v: _fold(a, (v, computed_once(v * v))),
                         compactions(count, scene.width * scene.height * spp_total))

    # each lane's stream key once, outside the sample loop (jaxrt.sampling.sampler.pixel_key)
    keys = pixel_key(seed, pixels)
    stream = lambda key, index: Stream(sampler, key, index, spp_total)
    # jitted: the prologue and the loop body call it with the same types, so it is traced,
    # batched and lowered once (the same optimised program, traced in less time:
    # benchmarks/README.md#trace-once)
    first = jax.jit(jax.vmap(lambda pixel, key, index: camera_hit(scene, pixel,
                                                                  stream(key, index)),
                             (0, 0, None)))
    rest = jax.vmap(lambda key, index, hit, wo: camera_radiance(scene, est, hit, wo,
                                                                stream(key, index)),
                    (0, None, 0, 0))

    def body(k, carry):
        acc, previous, (hit, wo) = carry
        value = rest(keys, start + k, hit, wo)
        return _fold(acc, previous), _squared(value), first(pixels, keys, start + k + 1)

    zero = jnp.zeros(pixels.shape + (3,), sums.s1.dtype)
    # the first fold adds an exact zero (TwoSum of 0 leaves hi and lo as they are): the sums
    # are those of the unpipelined loop, bit for bit
    acc, last, _ = lax.fori_loop(0, count, body,
                                 (sums, (zero, zero), first(pixels, keys, start)))
    if count == 1:
        # XLA inlines a loop of one iteration, and the sample, no longer a loop carry, would
        # be fused into each of the fold's kernels and computed in each (the hazard the fold's
        # lag avoids): stored instead, which makes a 1-spp mis pass several times faster,
        # the sums bit-identical (benchmarks/README.md#pipelined-loop). Passes of 1
        # spp are render's default above 2^20 pixels (~1 megapixel)
        last = tuple(computed_once(x) for x in last)
    return _fold(acc, last)


def _squared(value: Array) -> tuple[Array, Array]:
    # L² is formed with the sample, not in the fold: there LLVM could contract it into the
    # TwoSum's adds (fma), differently in and after the loop
    return value, value * value


def _fold(acc: Sums, previous: tuple[Array, Array]) -> Sums:
    """``acc`` plus one sample ``(L, L²)`` (TwoSum; a non-finite sample counts in ``bad``)."""
    value, square = previous
    # per component, not jnp.all over the channel axis: that is a reduction over a minor
    # axis of 3, a kernel of its own in every sample step
    ok = (jnp.isfinite(value[..., 0]) & jnp.isfinite(value[..., 1])
          & jnp.isfinite(value[..., 2]))
    s1, s1_lo = two_sum(acc.s1, acc.s1_lo, jnp.where(ok[..., None], value, 0))
    s2, s2_lo = two_sum(acc.s2, acc.s2_lo, jnp.where(ok[..., None], square, 0))
    return Sums(s1, s1_lo, s2, s2_lo, acc.bad + (~ok).astype(jnp.int32))


def step_layout(num_tiles: int, batch_size: int) -> tuple[int, int]:
    """(tiles per step, steps) for ``num_tiles`` tiles run ``batch_size`` at a time."""
    per_step = min(batch_size, num_tiles)
    return per_step, -(-num_tiles // per_step)


#: the static arguments of a pass (:func:`render_tiles`; :func:`render_tiles_split` adds its mesh)
PASS_STATIC = ("est", "sampler", "spp_total", "count", "tile_size", "batch_size", "num_tiles")


@partial(jax.jit, static_argnames=PASS_STATIC)
def render_tiles(scene: Scene, seed, start, first_tile, sums: Sums, *, est: Estimator,
                 sampler: str, spp_total: int, count: int, tile_size: int, batch_size: int,
                 num_tiles: int) -> Sums:
    """``sums`` advanced by ``count`` samples for the pixels of tiles ``[first_tile,
    first_tile+num_tiles)``.

    The tiles run ``batch_size`` at a time (a ``lax.map`` over steps; the last step is
    padded), a step's pixels laid out flat as one axis of lanes, vmapped once: the BVH's
    batching rule then sees all of its rays and compacts the slow ones (tile by tile runs
    slower). Brute-force scenes use the same flat layout: vmapped twice, as (tiles, pixels),
    the 256² MIS pass traces longer and runs slower (benchmarks/README.md#step-lanes).

    ``sums`` and the result have a leading axis of ``steps · per_step · tile_size`` lanes
    (:func:`step_layout`: the padded last step included); lanes past the end of the image are
    computed as pixel 0 and must be discarded by the caller.
    """
    num_pixels = scene.width * scene.height
    per_step, steps = step_layout(num_tiles, batch_size)
    pixels = (first_tile * tile_size
              + jnp.arange(steps * per_step * tile_size, dtype=jnp.int32))

    def step(args):
        pix, acc = args
        return lane_sums(scene, est, sampler, spp_total, seed,
                         jnp.where(pix < num_pixels, pix, 0), start, count, acc)

    by_step = lambda a: a.reshape((steps, per_step * tile_size) + a.shape[1:])
    out = lax.map(step, (by_step(pixels), jax.tree.map(by_step, sums)))
    return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), out)


@partial(jax.jit, static_argnames=PASS_STATIC + ("mesh",))
def render_tiles_split(scene: Scene, seed, start, first_tiles, sums: Sums, *, est: Estimator,
                       sampler: str, spp_total: int, count: int, tile_size: int,
                       batch_size: int, num_tiles: int, mesh) -> Sums:
    """:func:`render_tiles` on every device of ``mesh`` (one axis, ``"tiles"``) as ONE program.

    Device k runs ``render_tiles`` for the ``num_tiles`` tiles from ``first_tiles[k]`` on its
    own slice of ``sums`` (their leading axis split over the devices); ``scene``, ``seed`` and
    ``start`` are replicated. One compile serves every device (a program per device would be
    compiled once each), and the devices' passes run side by side. On a 2-core CPU two
    devices run the 256² pass about as fast per CPU-second as one and compile ~1.2× as long,
    most of the extra in XLA's SPMD partitioner (benchmarks/README.md#devices). The
    numbers are one device's, bit for bit: each device's
    program is ``render_tiles``.
    """
    static = dict(est=est, sampler=sampler, spp_total=spp_total, count=count,
                  tile_size=tile_size, batch_size=batch_size, num_tiles=num_tiles)
    assert static.keys() == set(PASS_STATIC), "render_tiles' static arguments changed"

    def one_device(sc, sd, st, first, acc):
        return render_tiles(sc, sd, st, first[0], acc, **static)

    split, whole = jax.sharding.PartitionSpec("tiles"), jax.sharding.PartitionSpec()
    return _shard_map(one_device, mesh, (whole, whole, whole, split, split), split)(
        scene, seed, start, first_tiles, sums)


def _shard_map(f, mesh, in_specs, out_specs):
    """``jax.shard_map`` without its replication check (the loops' carries are per device)."""
    if hasattr(jax, "shard_map"):
        return jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs,
                             check_vma=False)
    from jax.experimental.shard_map import shard_map  # jax < 0.7

    return shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_rep=False)


class RenderPass:
    """One progressive pass, split over processes and devices: each device of each process
    runs the same program on its own contiguous range of tiles, and carries its pixels' sums
    from pass to pass (so the image depends on neither count).

    ``shard = (process index, process count)``: this process's devices take the tile ranges
    ``index · len(devices) …`` of ``count · len(devices)`` equal ranges. Several devices run
    as one SPMD program (:func:`render_tiles_split`), compiled once; the carry is then one
    array whose leading axis holds each device's lanes in turn.
    """

    def __init__(self, scene: Scene, seed: int, devices: list, tile_size: int,
                 shard: tuple[int, int] = (0, 1), **static):
        num_pixels = scene.width * scene.height
        total_tiles = math.ceil(num_pixels / tile_size)
        rank, num_shards = shard
        self.per_device = math.ceil(total_tiles / (num_shards * len(devices)))
        per_step, steps = step_layout(self.per_device, static["batch_size"])
        self.lanes = steps * per_step * tile_size  # carried per device (last step padded)
        self.tile_size = tile_size
        self.num_pixels = num_pixels
        self.dtype = scene.triangles.dtype
        self.devices = list(devices)
        self.static = dict(static, tile_size=tile_size, num_tiles=self.per_device)
        scene = scene.with_own_derived_state()  # a dataclasses.replace copy's may be stale
        firsts = np.asarray([(rank * len(devices) + k) * self.per_device
                             for k in range(len(devices))], np.int32)
        if len(devices) == 1:
            self.mesh = None
            self._whole = self._split = devices[0]
            firsts = firsts[0]
        else:
            self.mesh = jax.sharding.Mesh(np.asarray(devices), ("tiles",))
            self._whole = jax.sharding.NamedSharding(self.mesh, jax.sharding.PartitionSpec())
            self._split = jax.sharding.NamedSharding(self.mesh,
                                                     jax.sharding.PartitionSpec("tiles"))
        # the scene's arrays are copied to every device once, not once per pass
        self.scene = jax.device_put(scene, self._whole)
        self.seed = jax.device_put(np.uint32(seed), self._whole)
        self.firsts = jax.device_put(firsts, self._split)
        self.compiled: dict[int, object] = {}  # samples per pass -> the executable

    def zeros(self) -> Sums:
        """The carry before the first pass: zero sums of every device's lanes."""
        return jax.device_put(zero_sums((self.lanes * len(self.devices),), self.dtype),
                              self._split)

    def compile(self, count: int) -> float:
        """Compile the pass for ``count`` samples per pixel (one program for every device);
        returns seconds."""
        t0 = time.perf_counter()
        # read from jaxrt's program cache when the jaxrt command has set one up (no tracing,
        # no option probe); else the options' probe compiles on another thread while this
        # one traces (the first time in a process)
        self.compiled[count] = program_cache.compile_cached(*self.job(count),
                                                            resolve=compiler_options_soon)
        return time.perf_counter() - t0

    def job(self, count: int) -> tuple:
        """``(function, arguments, static arguments, compiler options, devices)`` of the
        program for ``count`` samples per pixel (the options jaxrt asks for,
        :data:`~jaxrt.core.xla.COMPILER_OPTIONS`, as the program cache's key names them;
        it compiles with those XLA accepts, :func:`~jaxrt.core.xla.compiler_options`)."""
        fn, static = render_tiles, dict(count=count, **self.static)
        if self.mesh is not None:
            fn, static = render_tiles_split, dict(static, mesh=self.mesh)
        return (fn, (self.scene, self.seed, self._start(0), self.firsts, self.zeros()),
                static, dict(xla.COMPILER_OPTIONS), self.devices)

    def _start(self, start: int):
        return jax.device_put(np.int32(start), self._whole)

    def __call__(self, sums: Sums, start: int, count: int) -> Sums:
        """The carry ``sums`` advanced by samples ``[start, start + count)`` (waits for it)."""
        if count not in self.compiled:
            self.compile(count)
        out = self.compiled[count](self.scene, self.seed, self._start(start), self.firsts,
                                   sums)
        return jax.block_until_ready(out)

    def host(self, sums: Sums) -> Sums:
        """The carry as numpy arrays over this process's tile range (pixels in order, padded
        past the image's end when the tiles do not fill the last range)."""
        keep = self.per_device * self.tile_size
        n = len(self.devices)
        return Sums(*(np.asarray(a).reshape((n, self.lanes) + a.shape[1:])[:, :keep]
                      .reshape((n * keep,) + a.shape[1:]) for a in sums))
