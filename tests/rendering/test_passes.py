"""The compiled pass's sums: an error-free TwoSum chain per pixel, carried from pass to pass."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.passes import RenderPass, two_sum
from jaxrt.scene import builtin as scenes


def test_two_sum_keeps_the_rounding_error():
    """hi + lo is a + x exactly (float64 holds the sum of two float32 of these magnitudes), under
    jit: XLA does not simplify the error term away."""
    rng = np.random.default_rng(0)
    a = (rng.uniform(0, 1e3, 4096)).astype(np.float32)
    x = (rng.uniform(0, 1, 4096) * 10.0 ** rng.integers(-3, 3, 4096)).astype(np.float32)
    hi, lo = jax.jit(two_sum)(jnp.asarray(a), jnp.zeros_like(a), jnp.asarray(x))
    hi, lo = np.asarray(hi), np.asarray(lo)
    exact = a.astype(np.float64) + x.astype(np.float64)
    assert np.array_equal(hi, (a + x).astype(np.float32))  # hi is the float32 sum
    assert np.array_equal(hi.astype(np.float64) + lo.astype(np.float64), exact)
    assert np.mean(lo != 0) > 0.5


@pytest.fixture(scope="module")
def box_pass():
    est = make_estimator("mis")
    scene = prepare_scene(scenes.cornell_box(width=16, height=16), est)
    return RenderPass(scene, 7, jax.devices()[:1], 256, est=est, sampler="independent",
                      spp_total=1, batch_size=64)


def test_carried_pair_is_a_float64_sum(box_pass):
    """2 048 samples per pixel in 32 passes of 64, the sums carried: hi + lo equals the float64
    sum of the same samples (each taken alone, a pass of 1 from zero; summed exactly, then
    rounded: ``math.fsum``) to < 1e-12 relative (measured 5e-14 for Σ L, 3e-13 for Σ L²),
    where the float32 running sum (hi alone) is off by up to 8e-6."""
    run, n = box_pass, 2048
    sums = run.zeros()
    for start in range(0, n, 64):
        sums = run(sums, start, 64)
    s1, s2, bad = run.host(sums).totals()
    lo = run.host(sums).s1_lo
    x = np.stack([run.host(run(run.zeros(), k, 1)).s1 for k in range(n)])  # (n, pixels, 3)
    fsum = lambda v: np.array([math.fsum(c) for c in v.astype(np.float64).reshape(n, -1).T])
    ref1 = fsum(x).reshape(s1.shape)
    ref2 = fsum(x * x).reshape(s2.shape)  # L² rounded to float32, as the pass sums it
    lit = ref1 > 0
    assert np.all(bad == 0) and lit.mean() > 0.5
    err1 = np.abs(s1 - ref1)[lit] / ref1[lit]
    err2 = np.abs(s2 - ref2)[lit] / ref2[lit]
    hi_only = np.abs(run.host(sums).s1.astype(np.float64) - ref1)[lit] / ref1[lit]
    print(f"relative error: pair {err1.max():.2e} (Σx), {err2.max():.2e} (Σx²); "
          f"hi alone {hi_only.max():.2e}")
    assert err1.max() < 1e-12 and err2.max() < 1e-12
    assert hi_only.max() > 1e-7  # what float32 sums alone get: the bound has teeth
    assert np.mean(lo[lit] != 0) > 0.5


def test_where_passes_cut_the_chain_changes_no_bit(box_pass):
    """128 samples as 2 passes of 64, or as 5 passes of 1, one of 64 and 59 of 1: the same
    hi, lo and count, bit for bit (each pixel's sums are one chain over its sample indices).
    A chain restarted at every pass, its pair added to the carried one by TwoSum, rounds to
    the same float32 image almost always, but its lo differs: this test catches it."""
    run = box_pass
    two = run(run(run.zeros(), 0, 64), 64, 64)
    cut = run.zeros()
    for start, count in [(k, 1) for k in range(5)] + [(5, 64)] + [(k, 1) for k in range(69, 128)]:
        cut = run(cut, start, count)
    two, cut = run.host(two), run.host(cut)
    for name, a, b in zip(two._fields, two, cut, strict=True):
        assert np.array_equal(a, b), (name, np.mean(a != b))
    assert np.mean(two.s1_lo != 0) > 0.5


def test_compiler_options_keep_what_xla_accepts(monkeypatch):
    """An option the installed XLA does not know is left out (it would fail every compile);
    the known ones are kept."""
    import jaxrt.core.xla as E

    monkeypatch.setattr(E, "COMPILER_OPTIONS",
                        {"xla_cpu_prefer_vector_width": 512, "xla_no_such_option": 1})
    E.compiler_options.cache_clear()
    try:
        assert E.compiler_options() == {"xla_cpu_prefer_vector_width": 512}
    finally:
        E.compiler_options.cache_clear()


def test_the_option_probe_compiles_on_its_own_thread_while_the_pass_traces(
        compiles_in_fresh_process):
    """In a fresh process the compile-option probe's program compiles on a thread of its own,
    started before the pass is traced; the pass then compiles on the caller's thread with the
    options the probe found (``estimators.compiler_options_soon``)."""
    seen, options = compiles_in_fresh_process("""
        from jaxrt.scene import builtin as scenes
        from jaxrt.core.xla import compiler_options
        from jaxrt.rendering.driver import render
        render(scenes.cornell_box(16, 16), "mis", spp=1, progress=False)
        print(json.dumps([COMPILES, compiler_options()]))
    """)
    names = [name.split("_")[0] for name, _ in seen]  # the probe: one compile, or one per option
    assert len(seen) >= 2 and set(names[:-1]) == {"jaxrt-option-probe"}
    assert names[-1] == "MainThread" and options and seen[-1][1] == options


def test_pass_compiles_without_ynn_reductions():
    """The pass is compiled with jaxrt's options: no YNNPACK fusion is left in the program
    (each 3-vector dot would be one, ~9× slower than XLA's own loop:
    benchmarks/README.md#compiler-options). At 64² (4 096 lanes) XLA's default makes 15 of
    them; below ~1 000 lanes none, so a smaller pass would not tell."""
    from jaxrt.core.xla import compiler_options

    if "xla_cpu_experimental_ynn_fusion_type" not in compiler_options():
        pytest.skip("this XLA has no YNNPACK fusion option")
    est = make_estimator("mis")
    scene = prepare_scene(scenes.cornell_box(width=64, height=64), est)
    run = RenderPass(scene, 7, jax.devices()[:1], 256, est=est, sampler="independent",
                     spp_total=1, batch_size=64)
    run.compile(1)
    text = run.compiled[1].as_text()
    assert "fusion(" in text and "__ynn_fusion" not in text


@pytest.mark.parametrize("estimator", ["mis", "light_area"])
def test_pass_is_the_mean_of_camera_sample(estimator, camera_sample_mean):
    """The pass runs ``camera_sample`` as its two halves one sample apart (the camera hit of
    sample k + 1 found while sample k is shaded, ``lane_sums``); ``camera_sample`` (what
    ``estimate_at`` and ``image_vjp`` run) runs them together. The image is the mean of
    ``camera_sample`` over each pixel's samples to float32 rounding (rtol 1e-5: values are
    ~0.01–18, their float32 spacing ~1e-7 relative). A pass that shaded one sample's hit with
    another sample's numbers would still be unbiased, so only this can tell: it changes most
    pixels (checked: shading sample k + 1's numbers fails both cases)."""
    from jaxrt.rendering.driver import render

    scene = scenes.cornell_box(width=12, height=8)
    r = render(scene, estimator, spp=4, seed=6, progress=False)
    mean = camera_sample_mean(scene, estimator, 4, 6)
    assert mean.max() > 1 and np.mean(mean > 0) > 0.5
    np.testing.assert_allclose(r.image, mean, rtol=1e-5, atol=1e-7)
