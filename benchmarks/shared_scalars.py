"""Does XLA:CPU compute a value shared by several outputs once? A microbenchmark of one step.

    python benchmarks/shared_scalars.py [--lanes 16384] [--rounds 30]

The step a path tracer takes after a BSDF sample, for ``--lanes`` lanes under ``vmap``:
jaxrt's cosine-weighted warp of two hashed uniforms (``jaxrt.sampling.sampler``; ``sin``/``cos`` of
the concentric map), its frame change to world space (``jaxrt.core.vecmath``), the side of the
spawn offset (a dot product with the normal) and the select of the continuing segment
against a regenerated camera ray. Three ways to write the same step:

- ``aos``: (3,) vectors, as jaxrt's shading code is written (vmapped: (N, 3) arrays);
- ``soa``: every vector as three scalars (vmapped: three (N,) arrays);
- ``dot``: (3,) vectors with the frame change written as a matrix product ``[s t n] @ v``.

For each it prints the kernels of the compiled program, how many of them compute ``sin``
(XLA fuses a cheap elementwise producer into every consumer, so a shared value is computed
once per consumer kernel, and per element of an (N, 3) one) and the median time of a call.
benchmarks/README.md#vector-type quotes one run.
"""

from __future__ import annotations

import argparse
import re
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxrt.core.vecmath import coordinate_system, to_world
from jaxrt.core.xla import compiler_options
from jaxrt.sampling import sampler, warp


def _local_direction(i):
    """jaxrt's own cosine sample (``warp.square_to_cosine_hemisphere``) of the independent
    stream's dimensions 6-7 of sample ``i``, as its three components."""
    u = jnp.stack([sampler.independent_1d(0, i, 0, 6), sampler.independent_1d(0, i, 0, 7)])
    v = warp.square_to_cosine_hemisphere(u)
    return v[0], v[1], v[2]


def step(form: str):
    """The per-lane step in ``form`` (``aos``, ``soa`` or ``dot``)."""
    def aos(i, n, p, camera, ended):
        x, y, z = _local_direction(i)
        if form == "dot":
            s, t = coordinate_system(n)
            wi = jnp.stack([s, t, n], axis=1) @ jnp.stack([x, y, z])
        else:
            wi = to_world(jnp.stack([x, y, z]), n)  # jaxrt's frame change
        side = jnp.where(jnp.sum(wi * n) > 0, 1.0, -1.0)
        return (jnp.where(ended, camera, wi), jnp.where(ended, 0.0, p + side * 1e-4 * n), z)

    def soa(i, n, p, camera, ended):
        x, y, z = _local_direction(i)
        # jaxrt's tangents, taken apart into components (XLA folds the slices of the stack)
        s, t = (tuple(v[k] for k in range(3)) for v in coordinate_system(jnp.stack(n)))
        wi = tuple(s[k] * x + t[k] * y + n[k] * z for k in range(3))
        side = jnp.where(wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0, 1.0, -1.0)
        return (tuple(jnp.where(ended, camera[k], wi[k]) for k in range(3)),
                tuple(jnp.where(ended, 0.0, p[k] + side * 1e-4 * n[k]) for k in range(3)), z)

    return soa if form == "soa" else aos


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=16384)
    parser.add_argument("--rounds", type=int, default=30)
    a = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    n = rng.normal(size=(a.lanes, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p, camera = (rng.normal(size=(a.lanes, 3)).astype(np.float32) for _ in range(2))
    lanes = jnp.arange(a.lanes, dtype=jnp.int32)
    ended = jnp.asarray(rng.random(a.lanes) < 0.2)
    columns = lambda v: tuple(jnp.asarray(v[:, k]) for k in range(3))  # noqa: E731
    args = {"aos": (lanes, n, p, camera, ended), "dot": (lanes, n, p, camera, ended),
            "soa": (lanes, columns(n), columns(p), columns(camera), ended)}
    compiled = {f: jax.jit(jax.vmap(step(f))).lower(*args[f]).compile(compiler_options())
                for f in args}
    times = {f: [] for f in args}
    for _ in range(a.rounds):  # interleaved
        for f, exe in compiled.items():
            jax.block_until_ready(exe(*args[f]))
            t0 = time.perf_counter()
            for _ in range(20):
                out = exe(*args[f])
            jax.block_until_ready(out)
            times[f].append((time.perf_counter() - t0) / 20)
    for f, exe in compiled.items():
        text = exe.as_text()
        kernels = len(re.findall(r"= \S+ fusion\(", text)) + len(re.findall(r" dot\(", text))
        print(f"{f}: {kernels} kernels, sin in {len(re.findall(r' sine[(]', text))}, "
              f"{np.median(times[f]) * 1e6:.0f} µs per call")


if __name__ == "__main__":
    main()
