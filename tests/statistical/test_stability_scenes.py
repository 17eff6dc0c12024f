"""Numerical stability of whole renders: the Cornell box scaled, translated far, and unlit.

Radiance is invariant under a similarity transform of the scene and camera, so the Cornell box
scaled by 1e-3 and 1e4, or translated 1e5 from the origin, must render the same image as the
box at its own size. The geometry is first snapped to a grid of 2^-7 m (and the light lowered by
one grid step below the ceiling): such coordinates stay exact in float32 after translating by
1e5 (where the float32 spacing is 2^-7), so both renders see the SAME triangles and any
difference comes from the arithmetic (intersection, spawn offsets), not from the model.
Translation is the hard case: the hit points carry a rounding error of ~γ₇·1e5 ≈ 4 cm, so shadow
rays that are not pushed past it self-intersect and the image darkens.

All renders use one seed and share the scene structure, so each estimator compiles once. The
translated box is rendered with light sampling alone (default suite) and with MIS (slow).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrt.integrators.point import estimate_at
from jaxrt.rendering.driver import render
from jaxrt.scene import camera as cm
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene.builtin import cornell
from jaxrt.scene.container import build_scene, mesh
from jaxrt.validation import analytic

SIZE = 12
SPP = 64
GRID = 2.0**-7  # float32 spacing in [65536, 131072): coordinates on it survive + 1e5 exactly
SHIFT = np.array([1e5, 1e5, 1e5])


def _snap(v):
    return np.round(np.asarray(v, np.float64) / GRID) * GRID


def _base_meshes():
    """Cornell meshes on the 2^-7 grid; the light sits one grid step below the ceiling."""
    out = []
    for m in cornell.cornell_meshes():
        v = _snap(m.vertices)
        if m.name == "light":
            ceiling = _snap(cornell.CEILING[0][1] * 1e-3)
            v[:, 1] = ceiling - GRID
        out.append(m._replace(vertices=v))
    return out


def _scene(scale=1.0, shift=(0.0, 0.0, 0.0)):
    """The box with every vertex and the camera mapped by ``x -> scale·x + shift``."""
    shift = np.asarray(shift, np.float64)
    meshes = [m._replace(vertices=m.vertices * scale + shift) for m in _base_meshes()]
    eye = _snap([0.278, 0.273, -0.8]) * scale + shift
    target = _snap([0.278, 0.273, 0.0]) * scale + shift
    cam = cm.look_at(eye=eye, target=target, up=[0, 1, 0], fov_deg=cornell.FOV_DEG,
                     width=SIZE, height=SIZE)
    return build_scene(meshes, cam, accel="brute")


_renders = {}


def _render(key, est, scale=1.0, shift=(0.0, 0.0, 0.0)):
    if (key, est) not in _renders:
        _renders[key, est] = render(_scene(scale, shift), est, spp=SPP, seed=3, progress=False)
    return _renders[key, est]


def _check_same(ref, r, what, pixel_floor, mean_floor):
    """Per pixel: |Δ| ≤ 5 joint σ + pixel_floor·ref; means: 5 joint σ + mean_floor·mean."""
    # no NaN/Inf anywhere: neither dropped samples nor non-finite pixels or errors
    assert r.nonfinite == 0, (what, r.nonfinite)
    assert np.all(np.isfinite(r.image)) and np.all(np.isfinite(r.stderr)), what
    a, b = ref.image.astype(np.float64), r.image.astype(np.float64)
    sa, sb = ref.stderr.astype(np.float64), r.stderr.astype(np.float64)
    # 432 pixel-channels: |z| > 5 has probability < 432·6e-7 for a correct renderer (and much
    # less here, where both renders use the same seed so most of the noise is common)
    excess = np.abs(b - a) - 5 * np.hypot(sa, sb) - pixel_floor * np.abs(a)
    assert np.all(excess <= 0), (what, np.argwhere(excess > 0)[:5].tolist(),
                                 float(excess.max()))
    # the mean over pixels that do not see the emitter (whose σ would swamp everything else)
    keep = np.all(sa < 0.05, axis=-1)
    assert keep.sum() > 100, keep.sum()
    m_a, m_b = a[keep].mean(), b[keep].mean()
    se = np.sqrt((sa[keep] ** 2).sum() + (sb[keep] ** 2).sum()) / a[keep].size
    assert abs(m_b - m_a) <= 5 * se + mean_floor * m_a, (what, m_b, m_a, se)


def _reference(est):
    r = _render("ref", est)
    assert r.nonfinite == 0 and np.all(np.isfinite(r.image))
    # the lit box: the mean radiance is far from 0 (so "darker" is measurable)
    assert r.image.mean() > 0.05, r.image.mean()
    return r


# scaling by 1e-3 / 1e4 changes only the last bits (measured |z| ≤ 2e-4): 1e-4 relative
SCALE_FLOOR = 1e-4
# 1e5 away, float32 hit points are off by up to 2^-8 m and rays start ~γ₇·1e5 ≈ 4 cm off the
# surface (pbrt's bound), which moves the contact shadows of the blocks: measured beyond 5σ,
# at most 31% of a (dark) pixel and −1.0% on the mean of the pixels not seeing the light. A
# self-shadowed box loses the direct light of every lit pixel (−100%); a pdf_li of zero near
# the light's edges gives +92%.
SHIFT_PIXEL_FLOOR = 0.4
SHIFT_MEAN_FLOOR = 0.02


@pytest.mark.slow
@pytest.mark.parametrize("scale", [1e-3, 1e4], ids=["scale-1e-3", "scale-1e4"])
def test_scaled_box_renders_the_same(scale):
    ref = _reference("mis")
    _check_same(ref, _render(f"s{scale}", "mis", scale=scale), f"scale {scale}", SCALE_FLOOR,
                SCALE_FLOOR)


def test_translated_box_renders_the_same():
    """1e5 from the origin in float32: shadow rays must not re-hit their own surface."""
    ref = _reference("light_solid_angle")
    r = _render("t1e5", "light_solid_angle", shift=SHIFT)
    _check_same(ref, r, "translated 1e5", SHIFT_PIXEL_FLOOR, SHIFT_MEAN_FLOOR)


# a floor point with the whole light in view
FLOOR_POINT = np.array([0.15, 0.0, 0.45])
UP = np.array([0.0, 1.0, 0.0])
WO = np.array([0.0, 0.6, -0.8])


def _rotation(axis, deg):
    k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


@pytest.mark.parametrize("shift", [0.0, 1e3, 1e4, pytest.param(1e5, marks=pytest.mark.xfail(
    strict=True, reason="1e5 away, 2.2% of the floor point's shadow rays are falsely occluded by "
    "the tall block: pbrt-style offsets move both ends of each shadow ray off their surfaces by "
    "the float32 error bound, γ₇·1e5·|n|₁ ≈ 6 cm, and sightlines that pass within that of the "
    "block's top edge now cut it (removing the block gives 1.00003× the oracle; a float64 "
    "model of the offsets alone occludes 0.9%). A limit of error-bound offsets, not fixed"))],
    ids=["origin", "shift-1e3", "shift-1e4", "shift-1e5"])
def test_box_floor_point_against_lambert(shift):
    """Light sampling at a floor point of the rotated box, near and 1e5 from the origin.

    The box is rotated (so no surface is axis-aligned and the float32 shading point lies off
    its plane by up to an ulp of 1e5 ≈ 8 mm) and then translated. Unlike the image
    comparison, this has an absolute reference: Lambert's formula in float64 on the SAME
    float32-rounded light vertices and point. A shadow ray that re-hits the floor darkens the
    estimate; the oracle does not move.
    """
    rot, t = _rotation([1.0, 2.0, 3.0], 30.0), np.full(3, shift)
    # without the ceiling: rotated and rounded at 1e5 (±4 mm per vertex) it would cut through
    # the light 7.8 mm below it; it never lies between the floor and the light
    meshes = [m._replace(vertices=m.vertices @ rot.T + t) for m in _base_meshes()
              if m.name != "ceiling"]
    eye, target = rot @ [0.278, 0.273, -0.8] + t, rot @ [0.278, 0.273, 0.0] + t
    cam = cm.look_at(eye=eye, target=target, up=rot @ UP, fov_deg=cornell.FOV_DEG, width=4,
                     height=4)
    scene = build_scene(meshes, cam, accel="brute")
    p = (rot @ FLOOR_POINT + t).astype(np.float32)  # rounded like a computed hit point
    n = (rot @ UP).astype(np.float32)
    lamp = [m for m in meshes if m.name == "light"][0].vertices.astype(np.float32)
    with jax.enable_x64(True):
        phi = float(analytic.polygon_projected_solid_angle(
            jnp.asarray(lamp, jnp.float64), jnp.asarray(p, jnp.float64),
            jnp.asarray(n, jnp.float64) / np.linalg.norm(n)))
    exact = np.asarray(cornell.WHITE) * np.asarray(cornell.LIGHT_RADIANCE) * phi / np.pi
    r = estimate_at(scene, "light_solid_angle", p, n, rot @ WO, material=0,
                    num_samples=1 << 13, seed=2)
    mean, se = np.asarray(r.mean, np.float64), np.asarray(r.stderr, np.float64)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(se))
    # 5σ (σ ≈ 0.03% here) + 1% for float32 at 1e5: light vertices relative to p carry ~1e-2
    # relative rounding (8 mm on 0.5 m) that the renderer's float32 spherical triangle sees
    # and the oracle does not. Self-shadowing loses about half of the samples.
    assert np.all(np.abs(mean - exact) <= 5 * se + 1e-2 * exact), (mean, se, exact)


@pytest.mark.slow
def test_translated_box_renders_the_same_mis():
    """MIS 1e5 from the origin matches the box at the origin. A pdf_li that re-tests whether
    the BSDF ray passes through the light from the un-offset point returns 0 near the
    light's edges (MIS weight 1, +92% off the light): this catches it."""
    ref = _reference("mis")
    _check_same(ref, _render("t1e5", "mis", shift=SHIFT), "translated 1e5, MIS",
                SHIFT_PIXEL_FLOOR, SHIFT_MEAN_FLOOR)


@pytest.mark.slow
def test_zero_radiance_light_gives_black_image():
    """A light of radiance 0 is the only light: every pixel is exactly 0 (0/0 never appears)."""
    meshes = [m for m in _base_meshes() if m.name != "light"]
    light = [m for m in _base_meshes() if m.name == "light"][0]
    meshes.append(mesh(light.vertices, light.faces, mt.diffuse(0.0), emission=[0.0, 0.0, 0.0],
                       name="dark"))
    sphere = lt.sphere_light([0.278, 0.4, 0.28], 0.05, [0.0, 0.0, 0.0])
    cam = cornell.cornell_camera(8, 8)
    scene = build_scene(meshes, cam, [sphere], accel="brute")
    for est in ("mis", "light_area"):
        r = render(scene, est, spp=4, seed=1, progress=False)
        # exactly zero, not merely small: nothing emits, and a 0/0 would give NaN instead
        assert r.nonfinite == 0, (est, r.nonfinite)
        assert np.all(r.image == 0) and np.all(r.stderr == 0), (est, np.abs(r.image).max())
