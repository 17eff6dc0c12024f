"""Shared fixtures: an x64 switch so every kernel is also tested in double precision."""

import json
import subprocess
import sys
import textwrap

import jax
import pytest


@pytest.fixture(params=[False, True], ids=["f32", "x64"])
def x64(request):
    """Run the test body once in float32 (default) and once under ``jax_enable_x64``."""
    with jax.enable_x64(request.param):
        yield request.param


@pytest.fixture
def enable_x64():
    """Run the test body under ``jax_enable_x64`` only."""
    with jax.enable_x64(True):
        yield


@pytest.fixture
def camera_sample_mean():
    """``mean(scene, estimator, spp, seed, **params)``: each pixel's mean of
    :func:`jaxrt.integrators.techniques.camera_sample` over samples ``0 … spp−1`` (H, W, 3) float64,
    the per-sample program on its own (what ``estimate_at`` and ``image_vjp`` run), to compare
    with the render pass that lays the same samples out in lanes."""
    import jax.numpy as jnp
    import numpy as np

    from jaxrt.integrators.config import make_estimator, prepare_scene
    from jaxrt.integrators.techniques import camera_sample

    def mean(scene, estimator: str, spp: int, seed: int, **params):
        est = make_estimator(estimator, **params)
        prepared = prepare_scene(scene, est)
        one = lambda p, k: camera_sample(prepared, est, p, k, jnp.uint32(seed), "independent",
                                         spp)
        values = jax.jit(jax.vmap(jax.vmap(one, (None, 0)), (0, None)))(
            jnp.arange(scene.width * scene.height, dtype=jnp.int32),
            jnp.arange(spp, dtype=jnp.int32))  # (pixels, spp, 3)
        return np.asarray(values, np.float64).mean(axis=1).reshape(scene.height, scene.width, 3)

    return mean


@pytest.fixture
def compiles_in_fresh_process(tmp_path):
    """``run(body, *argv)``: ``body`` (Python source) run in a fresh interpreter (cwd
    ``tmp_path``, ``sys.argv[1:] = argv``) after every ``jax.stages.Lowered.compile`` is
    made to append ``(thread name, options)`` to a list ``COMPILES``; ``body``'s last printed
    line is JSON, which ``run`` returns. Only a fresh process shows what jaxrt compiles once
    per process (the compile-option probe)."""
    spy = """
        import json, sys, threading, jax
        COMPILES = []
        _compile = jax.stages.Lowered.compile
        def _spy(self, options=None):
            COMPILES.append((threading.current_thread().name, options))
            return _compile(self, options)
        jax.stages.Lowered.compile = _spy
    """

    def run(body: str, *argv: str):
        code = textwrap.dedent(spy) + textwrap.dedent(body)
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True,
                             text=True, check=True, cwd=tmp_path).stdout
        return json.loads(out.splitlines()[-1])

    return run


@pytest.fixture
def fresh_traces():
    """JAX's caches and jaxrt's programs in memory cleared before and after: for tests that
    patch what a pass traces (module constants, ``passes.compactions``, a shading function)
    under the same static arguments, which both caches would otherwise answer unpatched."""
    import jax

    from jaxrt.rendering import program_cache
    jax.clear_caches()
    program_cache.release_programs()
    yield
    jax.clear_caches()
    program_cache.release_programs()
