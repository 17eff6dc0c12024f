"""Sample-stream throughput: independent, stratified, Sobol vs ``jax.random`` (threefry).

Run: ``pytest benchmarks/test_bench_sampler.py --benchmark-enable -s``. Each case draws 2^22
values of dimension pairs (2^21 calls of ``sample_2d`` over 256 pixels × 8192 indices) after
compiling separately (``.lower().compile()``), and records ``mvalues_per_s`` and
``compile_s`` in ``benchmark.extra_info``; ``jax.random.uniform`` on the same count is timed
in the same run for the ratio.
"""

import time

import jax
import jax.numpy as jnp
import pytest

from jaxrt.sampling.sampler import SAMPLERS, sample_2d

PIXELS, INDICES = 256, 8192  # 2^21 pairs = 2^22 values
SPP = 64


def _stream(kind):
    def fn(seed):
        p = jnp.arange(PIXELS, dtype=jnp.int32)[:, None]
        i = jnp.arange(INDICES, dtype=jnp.int32)[None, :]
        return sample_2d(kind, seed, p, i, 2, SPP)

    return fn


def _threefry(seed):
    return jax.random.uniform(jax.random.key(seed), (PIXELS, INDICES, 2), jnp.float32)


def _time(fn, seed, rounds=5):
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(seed))
        best = min(best, time.perf_counter() - t0)
    return best


@pytest.mark.parametrize("kind", SAMPLERS)
def test_sampler_throughput(benchmark, kind):
    seed = jnp.asarray(7, jnp.int32)
    t0 = time.perf_counter()
    fn = jax.jit(_stream(kind)).lower(seed).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(fn(seed))  # warm-up
    benchmark.pedantic(lambda: jax.block_until_ready(fn(seed)), rounds=5, iterations=1)
    n = 2 * PIXELS * INDICES
    rate = n / benchmark.stats.stats.min / 1e6
    ref = jax.jit(_threefry).lower(seed).compile()
    jax.block_until_ready(ref(seed))
    ref_rate = n / _time(ref, seed) / 1e6
    benchmark.extra_info.update(mvalues_per_s=rate, compile_s=compile_s, values=n,
                                threefry_mvalues_per_s=ref_rate, ratio_to_threefry=rate / ref_rate)
    print(f"\n{kind:12} {rate:8.1f} Mvalues/s  compile {compile_s:4.2f}s  "
          f"threefry {ref_rate:7.1f}  ratio {rate / ref_rate:5.2f}")
