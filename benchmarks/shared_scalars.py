"""Does XLA:CPU compute a value shared by several outputs once? A microbenchmark of one step.

    python benchmarks/shared_scalars.py [--lanes 16384] [--rounds 30]

The step a path tracer takes after a BSDF sample, for ``--lanes`` lanes under ``vmap``: a
hashed cosine-weighted direction (``sin``/``cos`` of the hash), its frame change to world
space, the side of the spawn offset (a dot product with the normal) and the select of the
continuing segment against a regenerated camera ray. Three ways to write the same step:

- ``aos``: (3,) vectors, as jaxrt's shading code is written (vmapped: (N, 3) arrays);
- ``soa``: every vector as three scalars (vmapped: three (N,) arrays);
- ``dot``: (3,) vectors with the frame change written as a matrix product ``[s t n] @ v``.

For each it prints the kernels of the compiled program, how many of them compute ``sin``
(XLA fuses a cheap elementwise producer into every consumer, so a shared value is computed
once per consumer kernel, and per element of an (N, 3) one) and the median time of a call.
benchmarks/README.md quotes one run.
"""

from __future__ import annotations

import argparse
import re
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxrt.estimators import compiler_options


def _uniform(i, dim):
    x = (i * jnp.uint32(0x9E3779B9)) ^ (jnp.uint32(dim) * jnp.uint32(0x85EBCA6B))
    for _ in range(3):
        x = (x ^ (x >> 16)) * jnp.uint32(0x7FEB352D)
        x = (x ^ (x >> 15)) * jnp.uint32(0x846CA68B)
    return (x >> 8).astype(jnp.float32) * (2.0 ** -24)


def _local_direction(i):
    u1, u2 = _uniform(i, 6), _uniform(i, 7)
    r, phi = jnp.sqrt(u1), 2 * jnp.pi * u2
    return r * jnp.cos(phi), r * jnp.sin(phi), jnp.sqrt(jnp.maximum(0.0, 1 - u1))


def _frame(n):
    """Duff et al.'s branchless tangents of unit ``n`` (3 scalars each)."""
    nx, ny, nz = n
    sign = jnp.where(nz >= 0, 1.0, -1.0)
    a = -1 / (sign + nz)
    b = nx * ny * a
    return (1 + sign * nx * nx * a, sign * b, -sign * nx), (b, sign + ny * ny * a, -ny)


def step(form: str):
    """The per-lane step in ``form`` (``aos``, ``soa`` or ``dot``)."""
    def aos(i, n, p, camera, ended):
        x, y, z = _local_direction(i)
        s, t = (jnp.stack(v) for v in _frame(tuple(n)))
        if form == "dot":
            wi = jnp.stack([s, t, n], axis=1) @ jnp.stack([x, y, z])
        else:
            wi = s * x + t * y + n * z
        side = jnp.where(jnp.sum(wi * n) > 0, 1.0, -1.0)
        return (jnp.where(ended, camera, wi), jnp.where(ended, 0.0, p + side * 1e-4 * n), z)

    def soa(i, n, p, camera, ended):
        x, y, z = _local_direction(i)
        s, t = _frame(n)
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
    lanes = jnp.arange(a.lanes, dtype=jnp.uint32)
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
