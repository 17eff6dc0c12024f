"""Warp throughput: samples/s of every registry warp (one parameter each) on 2^20 samples.

Run: ``pytest benchmarks/test_bench_warp.py --benchmark-enable -s``. Each case compiles
``jit(vmap(sample))`` separately (``.lower(u).compile()``, timed as ``compile_s``), warms up,
then times ``fn(u).block_until_ready()``; ``msamples_per_s`` (from the fastest round) and
``compile_s`` go to ``benchmark.extra_info``. The same is done for ``sample + pdf`` fused,
which is what a light or BSDF sampler pays. The machine is shared: compare ratios within a run.
"""

import time

import jax
import jax.numpy as jnp
import pytest

from jaxrt.sampling import warp as W
from jaxrt.validation.gallery import GALLERY_INDEX

N = 1 << 20
CASES = [pytest.param(spec, id=spec.name) for spec in W.REGISTRY]


def _kernel(spec, with_pdf):
    params = spec.params[GALLERY_INDEX.get(spec.name, 0)]
    args = tuple(jnp.asarray(p, jnp.float32) for p in params)

    def one(u):
        x = spec.sample(u[0] if spec.dim == 1 else u, *args)
        return (x, spec.pdf(x, *args)) if with_pdf else x

    return jax.vmap(one)


@pytest.mark.parametrize("with_pdf", [False, True], ids=["sample", "sample+pdf"])
@pytest.mark.parametrize("spec", CASES)
def test_warp_throughput(benchmark, spec, with_pdf):
    u = jax.random.uniform(jax.random.PRNGKey(0), (N, 2), jnp.float32)
    t0 = time.perf_counter()
    fn = jax.jit(_kernel(spec, with_pdf)).lower(u).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(fn(u))  # warm-up
    benchmark.pedantic(lambda: jax.block_until_ready(fn(u)), rounds=5, iterations=1)
    rate = N / benchmark.stats.stats.min / 1e6
    benchmark.extra_info.update(msamples_per_s=rate, compile_s=compile_s, samples=N)
    print(f"\n{spec.name:24} {'+pdf' if with_pdf else '    '} {rate:8.1f} Msamples/s  "
          f"compile {compile_s:5.3f}s")
