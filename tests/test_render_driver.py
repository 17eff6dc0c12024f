"""The render driver: pass sizes, stopping rules without an spp cap, Ctrl-C, progress output.

Most tests here replace the compiled pass by a synthetic one (``FakePass``: per-pixel samples
from a numpy generator, a pure function of the sample index), so they test the loop without
compiling anything; the others render a 16×16 Cornell box.
"""

from __future__ import annotations

import os
import signal
import sys
from typing import NamedTuple

import numpy as np
import pytest

import jaxrt.render  # noqa: F401
from jaxrt import scenes
from jaxrt.passes import Sums

# the module (``jaxrt.render`` is the function: see test_first_hour.py)
RENDER = sys.modules["jaxrt.render"]


@pytest.fixture(scope="module")
def box16():
    return scenes.cornell_box(width=16, height=16)


class FakePass:
    """Stands for :class:`jaxrt.passes.RenderPass`: sample k of pixel p is
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
    """A budget without spp renders until the budget (it stopped at the default 16 spp)."""
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
    assert RENDER._relative_error(s1 / n, np.zeros_like(s1)) == 0.0  # what it used to see


@pytest.mark.parametrize("pixels, spp, expected", [
    (256 * 256, 64, 32), (256 * 256, 16, 16), (256 * 256, 67, 1), (256 * 256, 48, 24),
    (16 * 16, 64, 64), (16 * 16, None, 8192), (1920 * 1080, 64, 1), (256 * 256, None, 32),
])
def test_default_pass_size(pixels, spp, expected):
    assert RENDER.default_spp_per_pass(pixels, spp) == expected


def test_default_passes_are_sized_by_work_not_one_per_render(fake):
    """128 spp of a 256×256 image: 4 passes of 32 (it was one pass of 128, so the bar sat at
    0/1 for the whole render)."""
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
    """``render(scene, time_budget=...)`` on the real pass: more than the old default 16 spp."""
    r = RENDER.render(box16, "mis", time_budget=0.5, progress=False)
    assert r.stopped_by == "time_budget" and r.spp > 16
