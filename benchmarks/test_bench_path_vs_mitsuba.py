"""jaxrt's path tracer against Mitsuba 3's ``path`` integrator on the same Cornell box.

Run: ``DRJIT_LIBLLVM_PATH=libLLVM-19.so pytest benchmarks/test_bench_path_vs_mitsuba.py -s``.

Both render the 32² box (:mod:`mitsuba_cornell` builds Mitsuba's scene from jaxrt's own
arrays) with unbounded paths and Russian roulette from depth 5 (``max_depth=-1,
rr_depth=5`` in both: jaxrt follows Mitsuba's depth convention; its roulette survives
with max β rather than min(max β, 0.95): the same expectation, another variance).
Mitsuba's image is a cached reference of 64 independent passes of 256 spp
(:func:`mitsuba_cornell.mitsuba_reference_with_error`); its standard error is the spread of
the passes over √64. jaxrt renders 2 048 spp and reports its own standard error.

Why so many samples per pixel: per-pixel z needs each pixel's mean to be near normal. Dark
pixels lit only by rare long paths are skewed: with few samples their mean is usually low
*and* their σ underestimated. At 64² × 128 spp jaxrt's dark pixels (values ~1e-3, e.g.
the blocks' sides in shadow) came out up to 10× below Mitsuba's with |z| up to 12.8 and
a mean z of −11, although the image means agreed to 0.1 % and the darkest 20 % of pixels
summed alike at 16² × 2 048 spp (jaxrt 0.839 ± 0.004 vs Mitsuba 0.833).

The statistic is the per-pixel z of the difference, ``(jaxrt − mitsuba) / √(σ_j² + σ_m²)``:
every pixel and channel within 5σ (3 072 values), and the mean z per channel,
``Σ z / √P`` (≈ N(0, 1)), within 5σ: it weighs every pixel alike, so it resolves a uniform
brightness error that per-pixel z cannot (teeth: jaxrt's image scaled by 1.01 and 1.02 must
fail it). Pixels where both standard errors vanish (inside the light, which both see at
every sample) are compared with a relative tolerance of 1e-5 instead. Skipped when Mitsuba
(or its LLVM backend) is unavailable.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (see benchmarks/MITSUBA.md)")

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba_cornell as mc  # noqa: E402

SIZE, JAXRT_SPP, MI_PASS_SPP, MI_PASSES = 32, 2048, 256, 64


@pytest.fixture(scope="module")
def images():
    try:
        mc.import_mitsuba(mc.DEFAULT_VARIANT)
    except ImportError as e:
        pytest.skip(f"Mitsuba's {mc.DEFAULT_VARIANT} variant is unusable: {e}")
    import jaxrt
    from jaxrt.scene.builtin import cornell_box

    m_img, m_se = mc.mitsuba_reference_with_error(MI_PASS_SPP, MI_PASSES, SIZE, SIZE,
                                                  integrator=mc.PATH_INTEGRATOR)
    t0 = time.perf_counter()
    r = jaxrt.render(cornell_box(SIZE, SIZE), "path", spp=JAXRT_SPP, seed=7, max_depth=-1,
                     rr_depth=5, progress=False)
    print(f"\n  jaxrt path {SIZE}² × {JAXRT_SPP} spp: {time.perf_counter() - t0:.1f} s")
    assert r.nonfinite == 0
    return r.image.astype(np.float64), r.stderr.astype(np.float64), \
        m_img.astype(np.float64), m_se.astype(np.float64)


def _statistics(j_img, j_se, m_img, m_se):
    se = np.sqrt(j_se**2 + m_se**2)
    # float rounding leaves σ ~1e-7 L where every sample was equal (inside the light)
    ok = se > 1e-5 * (np.abs(j_img) + np.abs(m_img))
    z = np.where(ok, (j_img - m_img) / np.where(ok, se, 1), 0)
    zbar = z.reshape(-1, 3).sum(0) / np.sqrt(ok.reshape(-1, 3).sum(0))
    return z, ok, zbar


def test_path_agrees_with_mitsuba(images):
    j_img, j_se, m_img, m_se = images
    z, ok, zbar = _statistics(j_img, j_se, m_img, m_se)
    print(f"\n  per-pixel |z| max {np.abs(z).max():.2f}, sd {z[ok].std():.3f}, "
          f"> 3: {100 * np.mean(np.abs(z[ok]) > 3):.2f} %, mean z per channel "
          f"{np.round(zbar, 2)}, {int((~ok).sum())} values with no error; image means "
          f"jaxrt {np.round(j_img.reshape(-1, 3).mean(0), 5)} mitsuba "
          f"{np.round(m_img.reshape(-1, 3).mean(0), 5)}")
    # inside the light both see L_e at every sample
    np.testing.assert_allclose(j_img[~ok], m_img[~ok], rtol=1e-5, atol=1e-7)
    assert np.abs(z).max() < 5.0
    assert np.all(np.abs(zbar) < 5.0)
    # pure noise has unit spread; a wrong standard error (either side) would move it
    assert 0.9 < z[ok].std() < 1.1


@pytest.mark.parametrize("scale", [1.01, 1.02])
def test_brightness_error_is_caught(images, scale):
    """Teeth: jaxrt's image (and its error) scaled by 1–2 % fails the same statistic."""
    j_img, j_se, m_img, m_se = images
    z, _, zbar = _statistics(scale * j_img, scale * j_se, m_img, m_se)
    print(f"\n  ×{scale}: per-pixel |z| max {np.abs(z).max():.2f}, mean z {np.round(zbar, 1)}")
    assert np.all(np.abs(zbar) > 5.0)
