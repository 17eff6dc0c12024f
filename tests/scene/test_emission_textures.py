"""Emission textures on triangle lights: a lamp whose radiance is an image.

The closed form: a lamp quad with a nearest-filtered texture is a set of uniformly emitting
sub-squares, one per texel, so the reflection of a Lambertian point below it is the sum of
Lambert's formulas over them (:func:`jaxrt.validation.analytic.polygons_lambertian_radiance`).
The shading point lies off the lamp's axis, below a tilted normal, so that a transposed or
flipped texture has another answer (asserted: the test can tell them apart).
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrt.integrators.point import estimate_at
from jaxrt.rendering.differentiable import derivative_at, estimate_image, scene_params
from jaxrt.scene import camera as cm
from jaxrt.scene import container as sc
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import FileFormatError, write_exr
from jaxrt.scene.lights import area
from jaxrt.validation import analytic

ALBEDO = 0.6
HALF = 0.8  # the lamp's half-width, at height 1, facing down
LAMP = np.array([[-HALF, -HALF, 1.0], [HALF, -HALF, 1.0], [HALF, HALF, 1.0], [-HALF, HALF, 1.0]])
DOWN = [[0, 2, 1], [0, 3, 2]]  # normal −z
LAMP_UV = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
P = np.array([0.45, -0.25, 0.0])
N = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
WO = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
GLOW = np.random.default_rng(3).uniform(0.1, 2.0, (4, 4, 3))
SCALE = np.array([1.0, 0.5, 2.0])  # the mesh's emission, which the texture scales


def _sub_squares(texels: np.ndarray):
    """The lamp's texel sub-squares (H·W, 4, 3) and their radiance (H·W, 3), texel (i, j)
    covering u ∈ [j/W, (j+1)/W], v ∈ [1 − (i+1)/H, 1 − i/H]."""
    h, w = texels.shape[:2]

    def at(u, v):
        return LAMP[0] + u * (LAMP[1] - LAMP[0]) + v * (LAMP[3] - LAMP[0])

    quads, radiance = [], []
    for i in range(h):
        for j in range(w):
            u0, u1, v0, v1 = j / w, (j + 1) / w, 1 - (i + 1) / h, 1 - i / h
            quads.append([at(u0, v0), at(u0, v1), at(u1, v1), at(u1, v0)])
            radiance.append(texels[i, j] * SCALE)
    return np.asarray(quads), np.asarray(radiance)


def _lambert(texels: np.ndarray) -> np.ndarray:
    quads, radiance = _sub_squares(texels)
    return np.array([analytic.polygons_lambertian_radiance(quads, radiance[:, c], ALBEDO, P, N)
                     for c in range(3)])


def _lamp(texels=GLOW, filter="nearest", **texture):
    return sc.mesh(LAMP, DOWN, mt.diffuse(0.0), emission=SCALE, uv=LAMP_UV, name="lamp",
                   textures={"emission": tx.texture(texels, filter=filter, **texture)})


def _z(r, exact):
    return (np.asarray(r.mean, np.float64) - exact) / np.asarray(r.stderr, np.float64)


@pytest.mark.parametrize("estimator, selection", [
    ("light_area", "power"), ("light_solid_angle", "power"), ("mis", "power"),
    ("bsdf", "power"), ("ris", "power"), ("mis", "bvh")])
def test_lambert_per_texel(estimator, selection):
    """Every way of reaching the lamp (a light sample, a BSDF-sampled hit, RIS, the BVH)
    looks the texture up at the point it reaches: within 5σ of Σ Lambert, σ < 3 %."""
    scene = sc.shading_scene(mt.diffuse(ALBEDO), [], occluders=[_lamp()],
                             light_selection=selection)
    r = estimate_at(scene, estimator, P, N, WO, num_samples=1 << 14, seed=5)
    exact = _lambert(GLOW)
    assert np.all(np.abs(_z(r, exact)) < 5), (_z(r, exact), exact)
    assert np.all(np.asarray(r.stderr) < 0.03 * exact)


def test_a_wrong_texture_layout_is_told_apart():
    """The oracle discriminates: the same estimate is > 5σ from the answer of the texture
    transposed (u and v swapped) or flipped upside down (v = 0 taken as the top row)."""
    scene = sc.shading_scene(mt.diffuse(ALBEDO), [], occluders=[_lamp()])
    r = estimate_at(scene, "mis", P, N, WO, num_samples=1 << 14, seed=5)
    assert np.max(np.abs(_z(r, _lambert(GLOW)))) < 5
    for wrong in (GLOW.transpose(1, 0, 2), GLOW[::-1]):
        assert np.max(np.abs(_z(r, _lambert(wrong)))) > 5


def test_texel_derivatives():
    """d/dT_ij of the reflected radiance is ρ/π · L_c · Ω⊥ of texel (i, j)'s sub-square, for
    light sampling and MIS: the texels are differentiable parameters (``emission.0``)."""
    scene = sc.shading_scene(mt.diffuse(ALBEDO), [], occluders=[_lamp()])
    quads, _ = _sub_squares(GLOW)
    i, j, c = 1, 2, 1
    one = np.zeros(len(quads))
    one[i * GLOW.shape[1] + j] = SCALE[c]
    ref = analytic.polygons_lambertian_radiance(quads, one, ALBEDO, P, N)
    tangent = np.zeros_like(GLOW)
    tangent[i, j, c] = 1.0
    for estimator in ("light_area", "mis"):
        d = derivative_at(scene, {"emission.0": tangent}, estimator, P, N, WO,
                          num_samples=1 << 14, seed=8)
        mean, err = np.asarray(d.mean, np.float64), np.asarray(d.stderr, np.float64)
        assert abs(mean[c] - ref) < 5 * err[c] and ref > 10 * err[c], (estimator, mean, ref)
        assert np.all(mean[[0, 2]] == 0)  # channel c's texel drives channel c only


def _facing_camera(size=16):
    """A camera above the lamp (turned to face it, +z) whose image the lamp exactly fills,
    and the lamp's UVs that put (u, v) = (column / W, 1 − row / H) on it."""
    h = 3.0
    camera = cm.look_at(eye=[0, 0, 1 + h], target=[0, 0, 1], up=[0, 1, 0],
                        fov_deg=float(np.degrees(2 * np.arctan(HALF / h))), width=size,
                        height=size)
    raster = np.array([np.asarray(cm.project(camera, jnp.asarray(p, jnp.float32))[0])
                       for p in LAMP])
    uv = np.stack([raster[:, 0] / size, 1 - raster[:, 1] / size], axis=1)
    np.testing.assert_allclose(uv, np.round(uv), atol=1e-4)
    return camera, np.round(uv)


def test_the_camera_sees_the_texture():
    """Camera rays that hit the lamp find its texture: a 16 × 16 image of a 4 × 4
    nearest-filtered texture is each texel, ×SCALE, over a 4 × 4 block of pixels."""
    camera, uv = _facing_camera()
    lamp = sc.mesh(LAMP, [[0, 1, 2], [0, 2, 3]], mt.diffuse(0.0), emission=SCALE, uv=uv,
                   textures={"emission": tx.texture(GLOW, filter="nearest")})
    scene = sc.build_scene([lamp], camera)
    image = np.asarray(estimate_image(scene, "bsdf", spp=4, seed=1), np.float64)
    expected = np.repeat(np.repeat(GLOW * SCALE, 4, axis=0), 4, axis=1)
    np.testing.assert_allclose(image, expected, rtol=1e-5)


def _room(textured: bool):
    """A lamp over a floor, seen from above and to the side; the lamp's texture constant 1."""
    floor = sc.mesh(4 * LAMP - [0, 0, 4], [[0, 1, 2], [0, 2, 3]], mt.diffuse([0.7, 0.6, 0.5]))
    extra = dict(uv=LAMP_UV, textures={"emission": tx.texture(np.ones((2, 3)))}) if textured \
        else {}
    lamp = sc.mesh(LAMP, DOWN, mt.diffuse(0.3), emission=[3.1, 2.7, 1.3], **extra)
    camera = cm.look_at(eye=[2.5, -3, 2], target=[0, 0, 0.3], up=[0, 0, 1], fov_deg=60,
                        width=12, height=9)
    return sc.build_scene([floor, lamp], camera)


@pytest.mark.parametrize("estimator", ["mis", "light_solid_angle", "bsdf", "path"])
def test_a_constant_emission_texture_renders_bit_for_bit_as_none(estimator):
    plain, textured = _room(False), _room(True)
    assert plain.lights.triangle.emission is None and textured.lights.triangle.emission
    a = np.asarray(estimate_image(plain, estimator, spp=2, seed=3))
    b = np.asarray(estimate_image(textured, estimator, spp=2, seed=3))
    assert a.max() > 0
    np.testing.assert_array_equal(a, b)


def test_power_selection_uses_the_mean_over_each_triangle():
    """The lamp's two triangles: one over texels of 2, the other over texels of 0 but for
    halves of the diagonal's — power selection weighs them by those means."""
    texels = np.zeros((8, 8))
    texels[np.add.outer(np.arange(8), np.arange(8)) >= 7] = 2.0  # u ≥ v: one triangle's side
    scene = sc.shading_scene(mt.diffuse(ALBEDO), [], occluders=[_lamp(texels)])
    t = scene.lights.triangle
    mean = np.asarray(t.emission.mean)[:, 0]
    # the dark triangle holds half of each of the 8 diagonal texels: 4 of its 32 texels' area
    np.testing.assert_allclose(np.sort(mean), [0.25, 2.0], atol=0.005)
    power = area.triangle_power(t)
    plain = area.triangle_power(t._replace(emission=None))
    np.testing.assert_allclose(power / plain, mean, rtol=1e-6)
    # unbiased all the same, with the texture's sharp edge along the diagonal
    r = estimate_at(scene, "mis", P, N, WO, num_samples=1 << 14, seed=2)
    exact = _lambert(np.repeat(texels[..., None], 3, axis=2))
    assert np.all(np.abs(_z(r, exact)) < 5), _z(r, exact)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
def test_the_triangle_mean_is_exact_for_an_affine_texture(seed):
    """``emission_scale`` (the midpoint rule over sub-triangles) is exact where the lookup
    is affine in (u, v): texels ``α + β j + γ i``, bilinear, UVs between the texel centres.
    It then equals the lookup at the centroid. And a constant texture gives the constant
    under any wrap, filter and UVs."""
    rng = np.random.default_rng(seed)
    h, w = 3, 5
    i, j = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    coef = rng.uniform(0, 1, (3, 3))
    texels = coef[0] + coef[1] * j[..., None] + coef[2] * i[..., None]
    lo, hi = np.array([0.5 / w, 0.5 / h]), np.array([1 - 0.5 / w, 1 - 0.5 / h])
    uv = lo + (hi - lo) * rng.uniform(0, 1, (1, 3, 2))
    mean = area.emission_scale(texels, uv, "clamp", "bilinear")
    centroid = np.asarray(tx.bilinear(jnp.asarray(texels, jnp.float64 if jax.config.x64_enabled
                                                 else jnp.float32),
                                      jnp.asarray(uv[0].mean(axis=0)), "clamp"))
    np.testing.assert_allclose(mean[0], centroid, rtol=1e-5)
    wild = rng.uniform(-3, 3, (1, 3, 2))
    for wrap in tx.WRAPS:
        for filter in tx.FILTERS:
            flat = area.emission_scale(np.full((h, w, 3), 0.7), wild, wrap, filter)
            np.testing.assert_allclose(flat, 0.7, rtol=1e-12)


def test_emission_texture_errors():
    t = tx.texture(GLOW)
    with pytest.raises(ValueError, match="an emission texture needs an emissive mesh"):
        sc.mesh(LAMP, DOWN, mt.diffuse(0.5), uv=LAMP_UV, textures={"emission": t})
    with pytest.raises(ValueError, match="is textured \\(emission\\) but has no UVs"):
        sc.mesh(LAMP, DOWN, mt.diffuse(0.5), emission=1.0, textures={"emission": t})
    with pytest.raises(ValueError, match="needs finite uv of shape \\(2, 3, 2\\)"):
        lt.triangle_lights(LAMP[np.array(DOWN)], [1.0] * 3, [0, 1], texture=t)
    lights = lt.light_table([lt.triangle_lights(LAMP[np.array(DOWN)], [1.0] * 3, [0, 1],
                                                uv=LAMP_UV[np.array(DOWN)], texture=t)])
    with pytest.raises(ValueError, match="pass p_light"):
        lt.le_triangle(lights, jnp.int32(0), jnp.array([0.0, 0, -1]))


def test_textured_and_plain_triangle_tables_concatenate():
    """Two lamps, one textured: the plain one's lookups are 1 (its index −1)."""
    tris = LAMP[np.array(DOWN)]
    lights = lt.light_table([lt.triangle_lights(tris, [2.0] * 3, [0, 1]),
                             lt.triangle_lights(tris + [0, 0, 1], [1.0] * 3, [2, 3],
                                                uv=LAMP_UV[np.array(DOWN)],
                                                texture=tx.texture(GLOW, filter="nearest"))])
    e = lights.triangle.emission
    assert np.asarray(e.index).tolist() == [-1, -1, 0, 0]
    up = jnp.array([0.0, 0, -1])
    y = jnp.array([-0.7, 0.7, 1.0])  # over texel (0, 0)
    np.testing.assert_allclose(lt.le_triangle(lights, jnp.int32(0), up, y), [2.0] * 3)
    np.testing.assert_allclose(lt.le_triangle(lights, jnp.int32(3), up, y + jnp.array([0, 0, 1.])),
                               GLOW[0, 0], rtol=1e-6)


def test_scene_file_and_mitsuba_emission_textures(tmp_path):
    write_exr(tmp_path / "glow.exr", GLOW.astype(np.float32))
    lamp = {"vertices": LAMP.tolist(), "faces": DOWN, "uv": LAMP_UV.tolist(), "material": "m",
            "emission": SCALE.tolist(), "textures": {"emission": {"file": "glow.exr",
                                                                  "filter": "nearest"}}}
    doc = {"camera": {"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 30,
                      "width": 8, "height": 8},
           "materials": {"m": {"type": "diffuse", "albedo": 0.5}}, "meshes": [lamp]}
    (tmp_path / "s.json").write_text(json.dumps(doc))
    scene = load_scene(tmp_path / "s.json")
    e = scene.lights.triangle.emission
    np.testing.assert_array_equal(np.asarray(e.texels[0]), GLOW.astype(np.float32))
    assert e.modes == (("repeat", "nearest"),) and "emission.0" in scene_params(scene)
    assert scene.textures is None  # no material is textured
    assert "2 with 1 emission textures" in scene.summary()
    del lamp["emission"]
    (tmp_path / "s.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="an emission texture needs an emissive mesh"):
        load_scene(tmp_path / "s.json")

    xml = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="30"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>
    </transform><film type="hdrfilm"><integer name="width" value="8"/>
    <integer name="height" value="8"/></film></sensor>
  <shape type="{shape}"><emitter type="area"><texture type="bitmap" name="radiance">
    <string name="filename" value="glow.exr"/></texture></emitter></shape>
</scene>"""
    (tmp_path / "s.xml").write_text(xml.format(shape="rectangle"))
    scene = load_scene(tmp_path / "s.xml")
    e = scene.lights.triangle.emission
    np.testing.assert_array_equal(np.asarray(e.texels[0]), GLOW.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(scene.lights.triangle.radiance), 1.0)
    (tmp_path / "s.xml").write_text(xml.format(shape="sphere"))
    with pytest.raises(FileFormatError, match="a textured sphere light is not modelled"):
        load_scene(tmp_path / "s.xml")

