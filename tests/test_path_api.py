"""The path tracer's interface (issue 13): options, errors, the command line, derivatives.

The image-level validation of ``estimator="path"`` (furnaces, Cornell box vs ``mis`` and
Mitsuba 3, stability) lives in tests/test_path.py; here, what a user sets and gets, and one
closed form at a point with its derivatives.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxrt
from jaxrt import materials as mt
from jaxrt.camera import look_at
from jaxrt.cli import main
from jaxrt.differentiable import derivative_at
from jaxrt.estimators import estimate_at, make_estimator
from jaxrt.io import read_exr_attributes
from jaxrt.path import path_dims
from jaxrt.scene import build_scene, mesh
from jaxrt.scenes import cornell_box


@pytest.mark.parametrize("params, message", [
    (dict(max_depth=0), "max_depth must be -1"),
    (dict(max_depth=-2), "max_depth must be -1"),
    (dict(max_depth=2.5), "max_depth must be an integer"),
    (dict(rr_depth=0), "rr_depth must be >= 1"),
    (dict(light_samples=2), "one light and one BSDF sample"),
])
def test_path_options_are_checked(params, message):
    with pytest.raises(ValueError, match=message):
        make_estimator("path", **params)


def test_path_options_refused_by_direct_estimators():
    with pytest.raises(ValueError, match="max_depth applies to estimator='path' only"):
        make_estimator("mis", max_depth=3)
    assert make_estimator("mis", max_depth=-1).name == "mis"  # the default is no choice


def test_random_dimensions_per_depth():
    assert make_estimator("path", max_depth=2).num_dims == make_estimator("mis").num_dims
    assert path_dims(1) == 2 and path_dims(4) == 2 + 3 * 6 and path_dims(-1) is None


def test_reverse_mode_is_refused_before_any_work():
    scene = cornell_box(8, 8)
    with pytest.raises(ValueError, match="reverse-mode derivatives"):
        jaxrt.gradient(lambda im: (im * im).sum(), scene, "path", spp=1)


def test_cli_path_options_and_header(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("JAXRT_NO_COMPILE_CACHE", "1")
    out = tmp_path / "p.exr"
    code = main(["render", "cornell_box", "--estimator", "path", "--max-depth", "3",
                 "--rr-depth", "2", "--width", "8", "--height", "8", "--spp", "2",
                 "-o", str(out), "-q", "--no-compile-cache"])
    assert code == 0
    attrs = read_exr_attributes(out)
    assert (attrs["jaxrt.estimator"], attrs["jaxrt.max_depth"], attrs["jaxrt.rr_depth"]) == (
        "path", 3, 2)
    with pytest.raises(SystemExit):
        main(["render", "--estimator", "path", "--max-depth", "0", "-o", str(out)])
    assert "must be -1 (unbounded) or >= 1" in capsys.readouterr().err


def test_pass_chunking_changes_no_bit():
    """Each lane runs its pixel's samples one after the other, regenerating paths, and folds
    them in index order: 8 samples in one pass, in 4 passes of 2 or in 3, 3 and 2 give the
    same image and standard error, bit for bit."""
    scene = cornell_box(16, 12)
    one = jaxrt.render(scene, "path", spp=8, seed=2, progress=False)
    for per_pass in (2, 3):
        r = jaxrt.render(scene, "path", spp=8, seed=2, spp_per_pass=per_pass, progress=False)
        assert r.passes > 1
        assert np.array_equal(one.image, r.image) and np.array_equal(one.stderr, r.stderr)
    assert one.nonfinite == 0 and np.mean(one.stderr > 0) > 0.5  # noisy: the test can fail


def _path_pass(count: int, spp_total: int = 4):
    import jax

    from jaxrt.estimators import prepare_scene
    from jaxrt.passes import RenderPass

    est = make_estimator("path")
    scene = prepare_scene(cornell_box(32, 32), est)
    return RenderPass(scene, 3, jax.devices()[:1], 256, est=est, sampler="independent",
                      spp_total=spp_total, batch_size=64)


def _pass_with_compactions(monkeypatch, compact: int, count: int = 1):
    """A 32×32 path pass of ``count`` samples per lane compacting its lanes ``compact``
    times (down to 16 lanes: MIN_COMPACT_LANES lowered so that a small image compacts), its
    sums after two passes from zero, and the number of while loops of its program."""
    import jax

    import jaxrt.passes as ps
    import jaxrt.path as jp

    monkeypatch.setattr(jp, "MIN_COMPACT_LANES", 16)
    monkeypatch.setattr(ps, "compactions", lambda count, samples: compact)
    from jaxrt import program_cache

    # the same static arguments for every `compact`: trace afresh
    jax.clear_caches()
    program_cache.release_programs()
    run = _path_pass(count)
    sums = run(run(run.zeros(), 0, count), count, count)
    return [np.asarray(a) for a in sums], run.compiled[count].as_text().count(" while(")


@pytest.mark.parametrize("count", [1, 2])
def test_compactions_change_no_bit(monkeypatch, fresh_traces, count):
    """A pass's lanes are compacted 0 to 3 times (``path.compactions`` chooses by the
    samples per lane and the render's size): only the schedule changes, so the sums are
    the same bit for bit, while the program holds more while loops with each compaction
    (a stage is a copy of the step's loop)."""
    base, loops = _pass_with_compactions(monkeypatch, 0, count)
    assert np.mean(base[0] > 0) > 0.5
    for compact in (1, 2, 3):
        sums, more = _pass_with_compactions(monkeypatch, compact, count)
        assert more > loops
        loops = more
        for a, b in zip(base, sums, strict=True):
            assert np.array_equal(a, b)


def test_compactions_grow_with_the_render(monkeypatch, fresh_traces):
    """Passes of one or two samples per lane in long renders compact more (the measured
    break-even with the compile's cost, ``path.compactions``); the pass asks for them by
    its samples per lane and the render's pixels × spp."""
    import jaxrt.passes as ps
    from jaxrt.path import compactions

    hd = 1920 * 1080
    assert [compactions(1, hd * spp) for spp in (8, 16, 64)] == [1, 2, 3]
    assert [compactions(2, hd * spp) for spp in (16, 32, 64)] == [1, 2, 2]
    assert compactions(4, hd * 4096) == compactions(32, hd * 4096) == 1
    asked = []
    monkeypatch.setattr(ps, "compactions", lambda count, samples: asked.append(
        (count, samples)) or compactions(count, samples))
    fn, args, static, _, _ = _path_pass(2, spp_total=64).job(2)
    fn.trace(*args, **static)
    assert asked == [(2, 32 * 32 * 64)]


def test_time_budget_target_error_and_progress_hold_for_paths(capsys):
    """render's stopping rules drive the path tracer as they drive the direct estimators."""
    scene = cornell_box(16, 12)
    r = jaxrt.render(scene, "path", time_budget=0.5, spp_per_pass=1, progress=True)
    assert r.stopped_by == "time_budget" and r.spp >= 1 and r.passes == r.spp
    assert "spp" in capsys.readouterr().err  # the progress bar ran
    r = jaxrt.render(scene, "path", spp=256, target_error=0.2, spp_per_pass=4, progress=False)
    assert r.stopped_by == "target_error" and r.spp < 256 and r.relative_error <= 0.2


def test_max_depth_2_is_mis_from_the_same_random_numbers():
    """The first vertex uses mis's random dimensions, so the same seed gives mis's image up
    to float rounding (max |diff| measured 4.5e-8 at 32², values ~0.1–18)."""
    scene = cornell_box(32, 32)
    a = jaxrt.render(scene, "mis", spp=4, seed=9, progress=False).image
    b = jaxrt.render(scene, "path", spp=4, seed=9, max_depth=2, progress=False).image
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)
    c = jaxrt.render(scene, "path", spp=4, seed=9, max_depth=3, progress=False).image
    assert c.mean() > 1.05 * a.mean()  # the comparison can tell depth 3 from depth 2


# ---------------------------------------------------------------------------------------------
# A closed furnace at a point: value and derivatives
# ---------------------------------------------------------------------------------------------


def _emitting_box(rho, le) -> jaxrt.Scene:
    """The unit cube, every face diffuse(ρ) and emitting ``le`` inwards (normals flipped to
    the centre), 12 triangles: every point inside sees ``le`` after 0, 1, 2 … reflections."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            p = v[list(tri)]
            n = np.cross(p[1] - p[0], p[2] - p[0])
            inward = np.dot(n, 0.5 - p.mean(axis=0)) > 0
            faces.append(tri if inward else tri[::-1])
    box = mesh(v, np.array(faces), mt.diffuse(rho), emission=le, name="furnace")
    return build_scene([box], look_at([0.5, 0.5, 0.5], [0.5, 0.5, 0.0], [0, 1, 0],
                                       60.0, 4, 4), accel="brute")


P, N, WO = np.array([0.4, 0.55, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.6, 0.8])


@pytest.mark.slow  # ~15 s: four programs at 2^14 samples
@pytest.mark.parametrize("max_depth", [3, -1])
def test_furnace_point_value_and_derivatives(max_depth):
    """A floor point of the emitting box reflects ``Le Σ_{k=1}^{D−1} ρ^k`` towards the
    viewer (its own emission excluded; D = max_depth segments, ∞: ρ Le / (1 − ρ)); forward
    derivatives w.r.t. the albedo (R channel) and the radiance (G channel) match the closed
    form's within 5σ. With RR (unbounded) the roulette's 1/q is what keeps both unbiased:
    dropping it (``beta`` not divided by q) gives z = −324 for the value."""
    rho, le = 0.6, 1.5
    scene = _emitting_box(rho, le)
    k = np.arange(1, 200 if max_depth < 0 else max_depth)
    value = le * np.sum(rho ** k)
    d_rho, d_le = le * np.sum(k * rho ** (k - 1)), np.sum(rho ** k)
    est = estimate_at(scene, "path", P, N, WO, num_samples=1 << 14, seed=3,
                      max_depth=max_depth, rr_depth=2)
    z = (np.asarray(est.mean) - value) / np.asarray(est.stderr)
    assert np.all(np.abs(z) < 5), (est.mean, value, est.stderr)
    tangents = {"materials.kd": np.array([[1.0, 0.0, 0.0]]),
                "triangle.radiance": np.tile([0.0, 1.0, 0.0], (12, 1))}
    d = derivative_at(scene, tangents, "path", P, N, WO, num_samples=1 << 14, seed=4,
                      max_depth=max_depth, rr_depth=2)
    ref = np.array([d_rho, d_le, 0.0])
    z = (np.asarray(d.mean)[:2] - ref[:2]) / np.asarray(d.stderr)[:2]
    assert np.all(np.abs(z) < 5), (d.mean, ref, d.stderr)
    assert float(d.mean[2]) == 0.0
    assert np.all(ref[:2] > 20 * np.asarray(d.stderr)[:2])  # a 5 % error would show


def test_forward_derivative_of_a_path_traced_image():
    """``jax.jvp`` of ``estimate_image(..., "path")`` along the light's radiance itself is
    the image's emitted-light part: the image is linear in L_e with the sampling held fixed,
    and scaling every light alike leaves the light-selection pmf unchanged (Euler's
    identity), so the tangent equals the image exactly, up to float rounding."""
    import jax

    scene = cornell_box(12, 8)
    le = jaxrt.scene_params(scene)["triangle.radiance"]

    def image(radiance):
        box = jaxrt.with_params(scene, {"triangle.radiance": radiance})
        return jaxrt.estimate_image(box, "path", spp=4, seed=3)

    primal, tangent = jax.jvp(image, (le,), (le,))
    assert float(primal.mean()) > 0.05
    np.testing.assert_allclose(np.asarray(tangent), np.asarray(primal), rtol=2e-5, atol=1e-6)
    # along another direction it is not the image: the check can fail
    _, other = jax.jvp(image, (le,), (le * np.array([1.0, 0.5, 0.0]),))
    assert not np.allclose(np.asarray(other), np.asarray(primal), rtol=1e-2)


@pytest.mark.parametrize("max_depth", [-1, 3])
def test_render_pass_and_camera_sample_trace_the_same_paths(max_depth, camera_sample_mean):
    """The render pass runs paths in regenerating, compacted lanes (``path.pass_sums``);
    ``camera_sample`` (what ``estimate_at`` and ``image_vjp`` run) walks one path with
    ``path.trace_path``. Both are the same steps on the same random numbers: the image is
    the mean of ``camera_sample`` over the pixel's samples, to float32 rounding — but for
    rare decisions at a tie (a roulette draw u ≈ q) that the two differently fused programs
    round apart: unbounded, 2 of 288 values differed, by 1e-4 relative. A lane that folded a
    sample twice or drew its next path from the wrong index would change most pixels."""
    scene = cornell_box(12, 8)
    r = jaxrt.render(scene, "path", spp=4, seed=6, max_depth=max_depth, progress=False)
    mean = camera_sample_mean(scene, "path", 4, 6, max_depth=max_depth)
    assert mean.max() > 1 and np.mean(mean > 0) > 0.5
    close = np.isclose(r.image, mean, rtol=2e-5, atol=1e-6)
    assert close.mean() > 0.97, (close.mean(), np.abs(r.image - mean).max())
    np.testing.assert_allclose(r.image.mean(), mean.mean(), rtol=1e-4)
