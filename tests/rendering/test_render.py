"""render(): reproducibility, chunking, devices, stopping rules, error estimates, agreement.

The second part tests the driver's loop: pass sizes, stopping rules without an spp cap,
Ctrl-C, progress output. Most of those replace the compiled pass by a synthetic one (``FakePass``:
per-pixel samples from a numpy generator, a pure function of the sample index), so they test the
loop without compiling anything; the others render a 16×16 Cornell box.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest

import jaxrt.rendering.driver  # noqa: F401
from jaxrt.integrators.config import DIRECT_ESTIMATORS
from jaxrt.rendering.driver import _mean_and_error, render
from jaxrt.rendering.passes import Sums
from jaxrt.sampling.sampler import pixel_key
from jaxrt.scene import builtin as scenes


@pytest.fixture(scope="module")
def box16():
    return scenes.cornell_box(width=16, height=16)


def test_result_shapes_and_dtypes(box16):
    r = render(box16, "mis", spp=4, progress=False)
    assert r.image.shape == (16, 16, 3) and r.image.dtype == np.float32
    assert r.stderr.shape == (16, 16, 3) and r.stderr.dtype == np.float32
    assert r.spp == 4 and r.nonfinite == 0 and r.passes == 1
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0)
    assert r.timings["samples_per_s"] > 0 and r.timings["compile"] > 0
    assert 0 < r.timings["last_pass"] <= r.timings["render"]
    # the light is visible from the camera: some pixels carry its radiance directly
    assert r.image.max() > 5


def test_same_seed_bit_identical_whatever_the_chunking(box16):
    a = render(box16, "mis", spp=4, seed=3, tile_size=256, batch_size=1, progress=False)
    b = render(box16, "mis", spp=4, seed=3, tile_size=7, batch_size=3, progress=False)
    c = render(box16, "mis", spp=4, seed=4, progress=False)
    assert np.array_equal(a.image, b.image)
    assert np.array_equal(a.stderr, b.stderr)
    assert not np.array_equal(a.image, c.image)


@pytest.mark.slow  # ~40 s: three compiles; CI runs it
def test_bvh_scene_renders_like_brute_force_whatever_the_chunking():
    """A BVH scene renders through a flat vmap per step (so ray compaction sees the whole
    step); 3 steps of one 256-pixel tile and 2 steps of 4 64-pixel tiles plus a remainder tile
    give the same image, and brute force the same image up to float32 ties."""
    bvh_box = scenes.cornell_box(width=24, height=24, accel="bvh")
    a = render(bvh_box, "light_area", spp=2, seed=3, tile_size=256, batch_size=1)
    b = render(bvh_box, "light_area", spp=2, seed=3, tile_size=64, batch_size=4)
    c = render(scenes.cornell_box(width=24, height=24, accel="brute"), "light_area", spp=2,
               seed=3, tile_size=256, batch_size=1)
    assert np.array_equal(a.image, b.image)
    # coplanar overlaps (block bottoms on the floor) may resolve to another triangle
    assert np.mean(np.any(np.abs(a.image - c.image) > 1e-5, axis=-1)) <= 0.01
    assert a.image.mean() > 0.01


@pytest.fixture(scope="module")
def spp12(box16):
    """12 spp in the default pass size (one pass of 12)."""
    r = render(box16, "mis", spp=12, seed=1, progress=False)
    assert r.passes == 1
    return r


# (each pass size compiles one or two programs, ~5 s each: 5 runs in the quick loop, CI all)
@pytest.mark.parametrize("spp_per_pass", [5] + [pytest.param(p, marks=pytest.mark.slow)
                                                for p in (1, 3, 4, 12)])
def test_pass_size_never_changes_a_bit(box16, spp12, spp_per_pass):
    """The same samples summed in one chain per pixel whatever the passes: 12 spp in passes
    of 1, 3, 4, 5 (5 + 5 + 2) or 12 give the default's image and stderr, bit for bit (with the
    chain restarted from zero in each pass, passes of 5 would change 65 % of the pixels of
    the image and 70 % of the stderr)."""
    r = render(box16, "mis", spp=12, seed=1, spp_per_pass=spp_per_pass, progress=False)
    assert r.spp == 12 and r.passes == -(-12 // spp_per_pass)
    assert np.array_equal(r.image, spp12.image)
    assert np.array_equal(r.stderr, spp12.stderr)


def test_time_budget_and_target_error_stop_early(box16):
    # 2^20 spp of 16² pixels take ~100 s at this box's 2.7 Msamples/s: the budget, not the
    # count, must stop it (4 096 spp, as this test had, render in 0.4 s, under the budget)
    r = render(box16, "mis", spp=1 << 20, spp_per_pass=4, time_budget=0.5, progress=False)
    assert r.stopped_by == "time_budget" and r.spp < 1 << 20
    r = render(box16, "mis", spp=4096, spp_per_pass=8, target_error=0.5, progress=False)
    assert r.stopped_by == "target_error" and r.relative_error <= 0.5 and r.spp < 4096


@pytest.mark.parametrize("kwargs, match", [
    (dict(spp=0), "spp"), (dict(spp=2.5), "spp"), (dict(sampler="halton"), "sampler"),
    (dict(time_budget=-1), "time_budget"), (dict(target_error=0), "target_error"),
    (dict(devices=99), "devices"), (dict(estimator="nope"), "unknown estimator"),
])
def test_bad_arguments(box16, kwargs, match):
    with pytest.raises(ValueError, match=match):
        render(box16, **{"estimator": "mis", "spp": 2, "progress": False, **kwargs})


def test_nonfinite_samples_are_counted_not_kept(box16, monkeypatch, fresh_traces):
    import jaxrt.rendering.passes as R

    real = R.camera_radiance  # what the pass shades each camera sample's hit with
    pixel_5 = pixel_key(0, 5)  # the stream key of pixel 5 at seed 0 (render's default)

    def poisoned(scene, est, hit, wo, s):
        v = real(scene, est, hit, wo, s)
        return jnp.where((s.key == pixel_5) & (s.index == 1), jnp.nan, v)

    monkeypatch.setattr(R, "camera_radiance", poisoned)
    r = render(box16, "mis", spp=4, progress=False)
    assert r.nonfinite == 1
    assert np.all(np.isfinite(r.image))


def test_mean_and_error_formula():
    x = np.random.default_rng(0).normal(2.0, 3.0, size=(1000, 1))
    mean, err = _mean_and_error(x.sum(0), (x * x).sum(0), 1000)
    assert mean[0] == pytest.approx(x.mean())
    assert err[0] == pytest.approx(x.std(ddof=1) / np.sqrt(1000), rel=1e-9)


@pytest.mark.slow  # ~30 s: a second compile (or a subprocess); CI runs it
def test_two_devices_identical_to_one(tmp_path):
    """Sharding tiles over two (host) devices changes nothing in the image (direct light and
    the path tracer, whose lanes regenerate paths)."""
    code = textwrap.dedent("""
        import numpy as np, jax
        from jaxrt.scene import builtin as scenes
        from jaxrt.rendering.driver import render
        assert len(jax.devices()) == 2, jax.devices()
        s = scenes.cornell_box(width=12, height=10)
        for est in ("mis", "path"):
            a = render(s, est, spp=2, seed=5, devices=1, progress=False)
            b = render(s, est, spp=2, seed=5, devices=2, progress=False)
            assert np.array_equal(a.image, b.image), (est, np.abs(a.image - b.image).max())
        print("OK")
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "OK" in out.stdout


def _blocks(img, k=4):
    h, w, c = img.shape
    return img[: h // k * k, : w // k * k].reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


@pytest.mark.slow
@pytest.mark.parametrize("triangle_sampling", ["area", "solid_angle"])
def test_estimators_agree_pixelwise_on_the_cornell_box(triangle_sampling):
    """Every estimator against MIS on the Cornell box: z-scores of 4×4-pixel block means.

    Run for both measures of triangle-light sampling the scene can ask for (MIS and one-sample
    MIS use the scene's; ``light_area`` / ``light_solid_angle`` force theirs).

    Blocks of 16 pixels make each mean close to Gaussian even for hemisphere sampling (whose
    per-pixel distribution is heavy-tailed). For unbiased estimators z ~ N(0, 1). Two checks
    per estimator and channel: the whole-image z (sum of differences over its standard error,
    ~10^5 samples or more, so Gaussian) within ±4 (false alarm 6e-5 each, 21 checks): scaling
    the light-area image by 0.99 moves its z by −0.8 (measured), so a global bias of ~5%
    fails; and fewer than 3 of 64 blocks beyond
    |z| = 3.5 (probability 5e-4 each), which catches a local one. (No bound on the mean of
    the block z-scores: |mean z| < 0.25 is only 2σ of that mean and would fail ~5% of the
    time per estimator with nothing wrong.)
    """
    s = scenes.cornell_box(width=32, height=32, triangle_sampling=triangle_sampling)
    ref = render(s, "mis", spp=256, seed=100, progress=False)
    r_mean, r_var = _blocks(ref.image), _blocks(ref.stderr**2) / 16
    for est in DIRECT_ESTIMATORS:  # the path tracer adds indirect light
        # hemisphere and BSDF sampling find the light by hitting it: in the darkest lit
        # blocks 1024 spp give ~5 hits per block (a block of 1 hit has a σ̂ that is itself
        # the mean: z = −3.8 seen), 4096 ~20, enough for the Gaussian model of z
        spp = 4096 if est in ("uniform_hemisphere", "cosine_hemisphere", "bsdf") else 128
        r = render(s, est, spp=spp, seed=1, progress=False)
        m, var = _blocks(r.image), _blocks(r.stderr**2) / 16
        z = (m - r_mean) / np.sqrt(var + r_var + 1e-12)
        z_all = (m - r_mean).sum(axis=(0, 1)) / np.sqrt((var + r_var).sum(axis=(0, 1)))
        assert np.all(np.abs(z_all) < 4), (est, z_all)
        assert np.sum(np.abs(z) > 3.5) < 3, (est, np.sort(np.abs(z).ravel())[-5:])


@pytest.mark.slow
def test_error_falls_as_one_over_sqrt_n():
    """RMSE against a 4096-spp reference: log-log slope −0.5 ± 0.1 over spp 4 … 256."""
    s = scenes.cornell_box(width=16, height=16)
    ref = render(s, "mis", spp=4096, seed=99, progress=False).image
    spps = [4, 16, 64, 256]
    rmse = []
    for n in spps:
        errs = [np.sqrt(np.mean((render(s, "mis", spp=n, seed=k, progress=False).image - ref)
                                ** 2)) for k in range(3)]
        rmse.append(np.mean(errs))
    slope = np.polyfit(np.log(spps), np.log(rmse), 1)[0]
    assert -0.6 < slope < -0.4, (slope, rmse)


# ---------------------------------------------------------------------------------------------
# The render driver: pass sizes, stopping rules without an spp cap, Ctrl-C, progress output.
# ---------------------------------------------------------------------------------------------


# the module (``jaxrt.render`` is the function: see test_first_hour.py)
RENDER = sys.modules["jaxrt.rendering.driver"]




class FakePass:
    """Stands for :class:`jaxrt.rendering.passes.RenderPass`: sample k of pixel p is
    ``values[p]`` + noise · ``noisy[p]``, with noise from a generator seeded by k; the carry
    is a :class:`Sums` of numpy arrays (float32 sums, their low parts zero)."""

    calls: list = []
    on_call = None

    def __init__(self, scene, seed, devices, tile_size, shard=(0, 1), **static):
        self.n = self.num_pixels = scene.width * scene.height
        self.values = np.linspace(0.5, 1.5, self.n)
        self.noisy = np.arange(self.n) % 10 == 0  # 10 % of the pixels vary, 90 % are constant

    def compile(self, count):
        return 0.0

    def zeros(self):
        zero = np.zeros((self.n, 3), np.float32)
        return Sums(zero, zero, zero, zero, np.zeros(self.n, np.int32))

    def host(self, sums):
        return sums

    def __call__(self, sums, start, count):
        FakePass.calls.append((start, count))
        if FakePass.on_call is not None:
            FakePass.on_call(len(FakePass.calls))
        s1, s2 = sums.s1.copy(), sums.s2.copy()
        for k in range(start, start + count):
            noise = np.random.default_rng(k).normal(size=self.n)
            v = (self.values + np.where(self.noisy, noise, 0.0)).astype(np.float32)[:, None]
            s1 += v
            s2 += v * v
        return sums._replace(s1=s1, s2=s2)


class TinyScene(NamedTuple):
    width: int = 16
    height: int = 16


@pytest.fixture()
def fake(monkeypatch):
    FakePass.calls, FakePass.on_call = [], None
    monkeypatch.setattr(RENDER, "RenderPass", FakePass)
    monkeypatch.setattr(RENDER, "prepare_scene", lambda scene, est: scene)
    return TinyScene()


def test_time_budget_alone_is_not_capped_by_a_default_spp(fake):
    """A budget without spp renders until the budget (not until the default 16 spp)."""
    r = RENDER.render(fake, "mis", time_budget=0.3, spp_per_pass=8, progress=False)
    assert r.stopped_by == "time_budget" and r.spp > 16
    assert r.spp == 8 * len(FakePass.calls)


def test_target_error_alone_is_not_capped_by_a_default_spp(fake):
    r = RENDER.render(fake, "mis", target_error=0.002, spp_per_pass=64, progress=False)
    assert r.stopped_by == "target_error" and r.spp > 16


def test_spp_default_without_a_budget_is_16(fake):
    r = RENDER.render(fake, "mis", progress=False)
    assert r.spp == 16 and r.stopped_by == "spp"


def test_target_error_is_not_met_by_constant_pixels(fake):
    """90 % of the pixels are constant (σ̂ = 0): averaged in as zeros they would let a 5 %
    target stop at 16 spp while the varying pixels are at ~13 % relative error."""
    r = RENDER.render(fake, "mis", target_error=0.05, spp_per_pass=16, progress=False)
    assert r.stopped_by == "target_error" and r.spp > 16
    n = r.spp
    p = 3 / n
    floor = np.sqrt(p * (1 - p) / n) / (1 - p)
    # the stopping rule's own value, recomputed: the constant pixels' floor, no zeros
    image, stderr = r.image.astype(np.float64), r.stderr.astype(np.float64)
    rel = np.mean(np.maximum(stderr, floor * image) / image)
    assert rel <= 0.05
    # and 16 spp fewer would not have met it
    assert 0.9 * np.sqrt(3 / (n - 16) * (1 - 3 / (n - 16)) / (n - 16)) / (1 - 3 / (n - 16)) \
        > 0.05 or n - 16 < 16


def _sums_of(r):
    n = r.spp
    s1 = r.image.reshape(-1, 3).astype(np.float64) * n
    var = (r.stderr.reshape(-1, 3).astype(np.float64) ** 2) * n
    s2 = (var * (n - 1) / n + (s1 / n) ** 2) * n
    return s1, s2


def test_error_for_stopping_formula():
    n = 100
    s1 = np.array([[100.0] * 3, [0.0] * 3])  # one constant lit pixel, one black pixel
    s2 = np.array([[100.0] * 3, [0.0] * 3])
    p = 3 / n
    expected = np.sqrt(p * (1 - p) / n) / (1 - p) / 2  # mean over the two pixels
    assert RENDER._error_for_stopping(s1, s2, n) == pytest.approx(expected, rel=1e-12)
    assert RENDER._relative_error(s1 / n, np.zeros_like(s1)) == 0.0  # blind to this case


@pytest.mark.parametrize("pixels, spp, expected", [
    (256 * 256, 64, 32), (256 * 256, 16, 16), (256 * 256, 67, 1), (256 * 256, 48, 24),
    (16 * 16, 64, 64), (16 * 16, None, 8192), (1920 * 1080, 64, 1), (256 * 256, None, 32),
])
def test_default_pass_size(pixels, spp, expected):
    assert RENDER.default_spp_per_pass(pixels, spp) == expected


def test_default_passes_are_sized_by_work_not_one_per_render(fake):
    """128 spp of a 256×256 image: 4 passes of 32 (not one pass of 128, with the bar at 0/1
    for the whole render)."""
    big = TinyScene(width=256, height=256)
    FakePass.__call__, saved = (lambda self, sums, start, count: (FakePass.calls.append(
        (start, count)), sums)[1]), FakePass.__call__
    try:
        r = RENDER.render(big, "mis", spp=128, progress=False)
    finally:
        FakePass.__call__ = saved
    assert r.passes == 4 and FakePass.calls == [(0, 32), (32, 32), (64, 32), (96, 32)]


@pytest.mark.parametrize("spp_per_pass", [1, 5, 7])
def test_the_driver_carries_the_sums_into_every_pass(fake, spp_per_pass):
    """Each pass gets the sums the previous one returned (FakePass adds in float32 in sample
    order, so only one chain over k = 0 … 11 gives the one-pass image bit for bit; sums
    restarted per pass and added on the host differ in the last bits)."""
    r = RENDER.render(fake, "mis", spp=12, spp_per_pass=spp_per_pass, progress=False)
    assert FakePass.calls == [(k, min(spp_per_pass, 12 - k)) for k in range(0, 12, spp_per_pass)]
    FakePass.calls = []
    one = RENDER.render(fake, "mis", spp=12, spp_per_pass=12, progress=False)
    assert np.array_equal(r.image, one.image) and np.array_equal(r.stderr, one.stderr)
    assert r.spp == 12 and r.stderr.max() > 0


def test_ctrl_c_stops_after_the_pass_and_returns_the_partial_image(fake):
    """SIGINT during the 3rd pass: that pass finishes, then RenderInterrupted carries the
    3 passes rendered, equal bit for bit to a 3-pass render."""
    FakePass.on_call = lambda k: os.kill(os.getpid(), signal.SIGINT) if k == 3 else None
    with pytest.raises(RENDER.RenderInterrupted) as info:
        RENDER.render(fake, "mis", spp=4096, spp_per_pass=4, progress=False)
    part = info.value.result
    assert part.stopped_by == "interrupted" and part.spp == 12 and part.passes == 3
    assert isinstance(info.value, KeyboardInterrupt)
    FakePass.on_call = None
    full = RENDER.render(fake, "mis", spp=12, spp_per_pass=4, progress=False)
    assert np.array_equal(part.image, full.image) and np.array_equal(part.stderr, full.stderr)
    # the handler is removed again
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_second_ctrl_c_whose_interrupt_is_lost_still_stops_the_render(fake):
    """Two Ctrl-C during the 3rd pass, the second's KeyboardInterrupt raised where Python
    loses it (inside a garbage-collector callback, as jaxlib's: here a caller that swallows
    it): the render still ends after that pass with a plain KeyboardInterrupt, as if it had
    landed, not with the partial image that one Ctrl-C asks for."""
    def twice(k):
        if k == 3:
            handler = signal.getsignal(signal.SIGINT)
            handler(signal.SIGINT, None)
            try:
                handler(signal.SIGINT, None)
            except KeyboardInterrupt:
                pass  # lost, as in a gc callback

    FakePass.on_call = twice
    try:
        with pytest.raises(KeyboardInterrupt) as info:
            RENDER.render(fake, "mis", spp=4096, spp_per_pass=4, progress=False)
    finally:
        FakePass.on_call = None
    assert not isinstance(info.value, RENDER.RenderInterrupted)
    assert len(FakePass.calls) == 3  # no pass after the one running
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_progress_says_what_compiles_and_shows_rate_and_eta(fake, capsys):
    RENDER.render(fake, "mis", spp=64, spp_per_pass=16, progress=True)
    err = capsys.readouterr().err
    assert "compiling mis (independent) for 16x16, 16 spp per pass" in err
    assert "compiled in" in err
    assert "Msamples/s" in err and "eta=" in err and "64/64 spp" in err


def test_time_budget_on_a_real_scene_is_not_capped(box16):
    """``render(scene, time_budget=...)`` on the real pass: more than the 16 spp of no budget."""
    r = RENDER.render(box16, "mis", time_budget=0.5, progress=False)
    assert r.stopped_by == "time_budget" and r.spp > 16
