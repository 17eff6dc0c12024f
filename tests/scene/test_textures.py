"""Image textures: the lookup's laws, sRGB decoding, rendering against closed forms, texel
derivatives, texture-free scenes compiling no texture code, and the loaders' UVs and errors.

The rendering tests use one set-up whose answer is known per pixel: a diffuse quad seen
square-on by a camera whose image it exactly fills, under a constant environment ``L``. The
BSDF-sampling estimator then returns ``kd(uv) L`` for every sample (cosine sampling, weight
``kd``, the environment seen over the whole upper hemisphere), so a pixel's expectation is
``L`` times the mean of the bilinear reconstruction over the pixel's footprint in UV — which
:func:`_expected_pixels` integrates in closed form from the texels (hat functions), sharing
no code with :mod:`jaxrt.scene.textures`.
"""

from __future__ import annotations

import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import jaxrt
from jaxrt.rendering.differentiable import estimate_image, scene_params, with_params
from jaxrt.scene import camera as cm
from jaxrt.scene import container as sc
from jaxrt.scene import lights as lt
from jaxrt.scene import materials as mt
from jaxrt.scene import textures as tx
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import FileFormatError, write_exr
from jaxrt.scene.meshio import load_meshes

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)


# ------------------------------------------------------------------ lookup laws (bilinear)


@functools.partial(jax.jit, static_argnames=("wrap",))
def _lookup(texels, uv, wrap):
    return jax.vmap(lambda q: tx.bilinear(texels, q, wrap))(uv)


def _centre(i, j, h, w):
    """UV of the centre of texel (row i, column j)."""
    return np.array([(j + 0.5) / w, 1 - (i + 0.5) / h])


TEXELS = np.random.default_rng(7).uniform(0.0, 1.0, (3, 5, 3))


@pytest.mark.parametrize("wrap", tx.WRAPS)
def test_exact_at_texel_centres(wrap):
    h, w = TEXELS.shape[:2]
    uv = np.array([_centre(i, j, h, w) for i in range(h) for j in range(w)], np.float32)
    got = np.asarray(_lookup(jnp.asarray(TEXELS, jnp.float32), jnp.asarray(uv), wrap))
    np.testing.assert_allclose(got, TEXELS.reshape(-1, 3), rtol=0, atol=1e-6)


def test_wrap_and_clamp_at_the_borders():
    t = jnp.asarray(TEXELS, jnp.float32)
    h, w = TEXELS.shape[:2]
    u_edge = 0.0  # half a texel left of column 0's centre
    v_mid = 1 - 1.5 / h  # row 1's centre
    uv = jnp.asarray([[u_edge, v_mid], [1.0, v_mid], [-3.25, 0.5], [0.75, 0.5]], jnp.float32)
    rep, clamp = (np.asarray(_lookup(t, uv, wrap)) for wrap in ("repeat", "clamp"))
    # repeat: the border is half-way between the last and the first column
    np.testing.assert_allclose(rep[0], 0.5 * (TEXELS[1, 0] + TEXELS[1, w - 1]), atol=1e-6)
    np.testing.assert_allclose(rep[1], rep[0], atol=1e-6)
    np.testing.assert_allclose(rep[2], rep[3], atol=1e-5)  # u and u + 4 look up alike
    # clamp: the border texel itself, on both sides
    np.testing.assert_allclose(clamp[0], TEXELS[1, 0], atol=1e-6)
    np.testing.assert_allclose(clamp[1], TEXELS[1, w - 1], atol=1e-6)
    far_left = np.asarray(_lookup(t, jnp.asarray([[0.0, 0.5]], jnp.float32), "clamp"))[0]
    np.testing.assert_allclose(clamp[2], far_left, atol=1e-6)  # beyond the edge: the edge
    assert not np.allclose(rep[0], clamp[0], atol=1e-3)


uv_strategy = hnp.arrays(np.float32, 2, elements=st.floats(-3, 3, width=32))


@SETTINGS
@given(value=st.floats(0, 1, width=32, allow_subnormal=False), uv=uv_strategy,
       wrap=st.sampled_from(tx.WRAPS))
def test_a_constant_texture_gives_the_constant(value, uv, wrap):
    t = jnp.full((4, 6, 3), value, jnp.float32)
    got = np.asarray(_lookup(t, jnp.asarray(uv[None]), wrap))[0]
    np.testing.assert_array_equal(got, np.float32(value))  # bit for bit


@SETTINGS
@given(row=st.integers(0, 2), col=st.integers(0, 3), a=st.floats(0, 1, width=32),
       wrap=st.sampled_from(tx.WRAPS))
def test_linear_between_texel_centres(row, col, a, wrap):
    # along a row, between the centres of columns col and col + 1 (wrapped or clamped)
    h, w = TEXELS.shape[:2]
    c0, c1 = _centre(row, col, h, w), _centre(row, col + 1, h, w)
    q = (1 - a) * c0 + a * c1
    t = jnp.asarray(TEXELS, jnp.float32)
    got = np.asarray(_lookup(t, jnp.asarray(q[None], jnp.float32), wrap))[0]
    right = TEXELS[row, (col + 1) % w] if wrap == "repeat" else TEXELS[row, min(col + 1, w - 1)]
    np.testing.assert_allclose(got, (1 - a) * TEXELS[row, col] + a * right, atol=2e-6)


@SETTINGS
@given(uv=uv_strategy, s=st.floats(-2, 2, width=32), wrap=st.sampled_from(tx.WRAPS))
def test_lookup_is_linear_in_the_texels(uv, s, wrap):
    # T[a + s b] = T[a] + s T[b] at any point: the derivative w.r.t. texels is the weights
    rng = np.random.default_rng(3)
    a, b = (jnp.asarray(rng.uniform(0, 1, (3, 4, 3)), jnp.float32) for _ in range(2))
    q = jnp.asarray(uv[None])
    lhs = _lookup(a + s * b, q, wrap)
    rhs = _lookup(a, q, wrap) + s * _lookup(b, q, wrap)
    np.testing.assert_allclose(np.asarray(lhs), np.asarray(rhs), atol=1e-5)


def test_nearest_picks_the_texel_under_the_point():
    t = jnp.asarray(TEXELS, jnp.float32)
    h, w = TEXELS.shape[:2]
    q = _centre(2, 1, h, w) + np.array([0.49 / w, -0.49 / h])
    got = np.asarray(tx.nearest(t, jnp.asarray(q, jnp.float32), "clamp"))
    np.testing.assert_array_equal(got, TEXELS[2, 1].astype(np.float32))


# ----------------------------------------------------------------------------- sRGB


@pytest.mark.parametrize("c", [0.0, 0.02, 0.04045, 0.2, 0.5, 0.735, 1.0])
def test_srgb_decode_matches_the_standard(c):
    # IEC 61966-2-1: c/12.92 up to 0.04045 (the linear segment), ((c+0.055)/1.055)^2.4 above
    want = c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
    assert float(tx.srgb_to_linear(c, xp=np)) == pytest.approx(want, rel=1e-12)
    assert float(tx.srgb_to_linear(jnp.float32(c))) == pytest.approx(want, rel=2e-6, abs=1e-9)


def test_srgb_decode_is_continuous_and_8_bit_colour_maps_are_decoded():
    lo = tx.srgb_to_linear(np.nextafter(0.04045, 0), xp=np)
    hi = tx.srgb_to_linear(np.nextafter(0.04045, 1), xp=np)
    assert abs(hi - lo) < 1e-7
    image = np.full((2, 2, 3), 128, np.uint8)
    t = tx.texture(image)
    assert tx.decoded(t, "kd")[0, 0, 0] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4)
    assert tx.decoded(t, "alpha")[0, 0, 0] == pytest.approx(128 / 255)  # roughness: linear
    assert tx.decoded(tx.texture(image / 255.0), "kd")[0, 0, 0] == pytest.approx(128 / 255)


# ------------------------------------------------------------------- rendering set-up

QUAD = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float64)
FACES = [[0, 1, 2], [0, 2, 3]]
SIZE = 16  # pixels per side
ENV = 0.8


def _camera():
    h = 3.0  # the quad fills the square image exactly
    return cm.look_at(eye=[0, h, 0], target=[0, 0, 0], up=[0, 0, -1],
                      fov_deg=float(np.degrees(2 * np.arctan(1 / h))), width=SIZE, height=SIZE)


def _image_uv(camera) -> np.ndarray:
    """UVs that put (u, v) = (column / W, 1 − row / H) of the image on the quad's vertices."""
    raster = np.array([np.asarray(cm.project(camera, jnp.asarray(p, jnp.float32))[0])
                       for p in QUAD])
    uv = np.stack([raster[:, 0] / SIZE, 1 - raster[:, 1] / SIZE], axis=1)
    np.testing.assert_allclose(uv, np.round(uv), atol=1e-4)  # the corners are the image's
    return np.round(uv)


CAMERA = _camera()
UV = _image_uv(CAMERA)


def _quad_scene(material, textures=None, uv=UV):
    m = sc.mesh(QUAD, FACES, material, uv=uv, textures=textures)
    return sc.build_scene([m], CAMERA, [lt.constant_environment([ENV] * 3)])


def _hat_integrals(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """∫_a^b hat_j(s) ds for texels j < n, repeat wrap: (len(a), n).

    ``s`` in texel units (texel j spans [j, j + 1], centre j + ½); hat_j(s) = max(0, 1 − |s −
    c|) summed over the periodic copies c = j + ½ + k n.
    """
    def antiderivative(z):
        z = np.clip(z, -1, 1)
        return np.where(z < 0, (z + 1) ** 2 / 2, 1 - (1 - z) ** 2 / 2)

    out = np.zeros((len(a), n))
    for j in range(-1, n + 1):
        c = j + 0.5
        out[:, j % n] += antiderivative(b - c) - antiderivative(a - c)
    return out


def _expected_pixels(texels: np.ndarray, scale=ENV, swap_uv=False, offset=0.0) -> np.ndarray:
    """Per pixel: ``scale`` × the mean of the bilinear reconstruction (repeat) over the pixel.

    Pixel (r, c) spans u in [c/W, (c+1)/W] and, rows counted from the top, t = 1 − v in
    [r/H, (r+1)/H]; bilinear is separable, so the mean is Σ t_ij A_i B_j / (|A| |B|).
    ``swap_uv``/``offset`` make the expectation of a deliberately wrong lookup.
    """
    h, w = texels.shape[:2]
    edges = np.arange(SIZE + 1) / SIZE
    cols = _hat_integrals(w, edges[:-1] * w + offset, edges[1:] * w + offset) / (w / SIZE)
    rows = _hat_integrals(h, edges[:-1] * h + offset, edges[1:] * h + offset) / (h / SIZE)
    t = texels.transpose(1, 0, 2) if swap_uv else texels
    return scale * np.einsum("ri,ij k,cj->rck".replace(" ", ""), rows, t, cols)


CHECKER = np.where((np.add.outer(np.arange(4), np.arange(4)) % 2)[..., None] == 0,
                   np.array([0.9, 0.6, 0.3]), np.array([0.1, 0.25, 0.4]))
# an asymmetric pattern too: a u/v swap or a shift by half a texel changes its block means
PATTERN = np.random.default_rng(11).uniform(0.05, 0.95, (4, 4, 3))


def _block_means(image: np.ndarray, k: int = 4) -> np.ndarray:
    return image.reshape(k, SIZE // k, k, SIZE // k, 3).mean(axis=(1, 3))


def _render_mean_and_error(scene, spp, seed):
    r = jaxrt.render(scene, "bsdf", spp=spp, seed=seed, progress=False)
    return np.asarray(r.image, np.float64), np.asarray(r.stderr, np.float64)


def _within_sigma(image, stderr, expected) -> np.ndarray:
    """|block mean − expectation| / its standard error, per 4×4 block and channel."""
    n = (SIZE // 4) ** 2
    sigma = np.sqrt(_block_means(stderr**2)) / np.sqrt(n)
    return np.abs(_block_means(image) - _block_means(expected)) / np.maximum(sigma, 1e-12)


@pytest.mark.parametrize("estimator", ["mis", pytest.param("path", marks=pytest.mark.slow)])
def test_a_constant_texture_renders_bit_for_bit_as_the_untextured_material(estimator):
    kd = [0.725, 0.71, 0.68]  # not dyadic: a lookup that rounds would show
    plain = _quad_scene(mt.diffuse(kd))
    textured = _quad_scene(mt.diffuse(0.1), {"kd": tx.texture(np.broadcast_to(kd, (3, 5, 3)))})
    a = np.asarray(estimate_image(plain, estimator, spp=2, seed=3))
    b = np.asarray(estimate_image(textured, estimator, spp=2, seed=3))
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("texels", [CHECKER, PATTERN], ids=["checker", "pattern"])
def test_a_textured_quad_renders_its_area_weighted_albedo(texels):
    scene = _quad_scene(mt.diffuse(0.5), {"kd": tx.texture(texels)})
    image, stderr = _render_mean_and_error(scene, spp=16, seed=5)
    expected = _expected_pixels(texels)
    z = _within_sigma(image, stderr, expected)
    assert z.max() < 5, z.max()
    # the whole image's mean is the texels' (repeat: every hat integrates to one texel)
    assert abs(image.mean() - ENV * texels.mean()) < 5 * np.sqrt((stderr**2).sum()) / image.size
    # and a wrong lookup would fail it: u and v swapped, or texel centres off by half a texel
    for wrong in (dict(swap_uv=True), dict(offset=0.5)):
        if wrong.get("swap_uv") and np.allclose(texels, texels.transpose(1, 0, 2)):
            continue  # the checker is symmetric: a swap cannot show
        assert _within_sigma(image, stderr, _expected_pixels(texels, **wrong)).max() > 5, wrong


def test_textured_white_furnace_is_exact_under_bsdf_sampling():
    # kd = 1 everywhere: every sample of every pixel is L (cosine sampling, weight kd = 1)
    scene = _quad_scene(mt.diffuse(0.3), {"kd": tx.texture(np.ones((5, 3)))})
    image = np.asarray(estimate_image(scene, "bsdf", spp=2, seed=1))
    np.testing.assert_allclose(image, ENV, rtol=2e-6)


def test_textured_furnace_under_path_tracing():
    # kd = a everywhere, open plane: one bounce to the environment, E[L] = a·L per pixel
    a = 0.6
    scene = _quad_scene(mt.diffuse(0.3), {"kd": tx.texture(np.full((5, 3), a), wrap="clamp")})
    r = jaxrt.render(scene, "path", spp=8, seed=2, progress=False)
    image, stderr = np.asarray(r.image, np.float64), np.asarray(r.stderr, np.float64)
    sigma = np.sqrt((stderr**2).sum(axis=(0, 1))) / (SIZE * SIZE)
    z = np.abs(image.mean(axis=(0, 1)) - a * ENV) / sigma
    assert z.max() < 5, (image.mean(axis=(0, 1)), sigma)
    assert 0 < sigma.max() < 0.01 * a * ENV  # a noisy estimator, a tight bound


@pytest.mark.parametrize("estimator", ["bsdf", pytest.param("mis", marks=pytest.mark.slow)])
def test_texel_derivative_matches_central_differences(estimator):
    scene = _quad_scene(mt.diffuse(0.5), {"kd": tx.texture(PATTERN)})
    texels = scene_params(scene)["textures.0"]

    @jax.jit
    def loss(t):
        image = estimate_image(with_params(scene, {"textures.0": t}), estimator, spp=2, seed=4)
        return jnp.sum(image[..., 1] * jnp.linspace(0.5, 1.5, SIZE)[None, :])  # not flat

    g = np.asarray(jax.grad(loss)(texels))
    assert g.shape == PATTERN.shape
    assert np.all(g[..., 0] == 0) and np.all(g[..., 2] == 0)  # only green counts
    h = 0.05
    for i, j in [(0, 0), (1, 3), (3, 2)]:
        e = jnp.zeros_like(texels).at[i, j, 1].set(h)
        fd = (loss(texels + e) - loss(texels - e)) / (2 * h)
        assert float(g[i, j, 1]) == pytest.approx(float(fd), rel=2e-3)
        assert g[i, j, 1] > 0


def test_texture_coordinates_refuse_derivatives():
    # the UV maps are geometry (the hit's texel moves with them discontinuously)
    import dataclasses

    scene = _quad_scene(mt.diffuse(0.5), {"kd": tx.texture(PATTERN)})

    def image(uv_map):
        return jnp.sum(estimate_image(scene.replace(textures=dataclasses.replace(
            scene.textures, uv_map=uv_map)), "bsdf", spp=1))

    with pytest.raises(ValueError, match="texture coordinates"):
        jax.grad(image)(scene.textures.uv_map)


def test_texture_free_scenes_trace_no_texture_code(monkeypatch):
    plain = _quad_scene(mt.diffuse(0.5))
    textured = _quad_scene(mt.diffuse(0.5), {"kd": tx.texture(PATTERN)})
    assert plain.textures is None

    def jaxpr(scene):
        return str(jax.make_jaxpr(lambda s: estimate_image(s, "mis", spp=1))(scene))

    plain_text, textured_text = jaxpr(plain), jaxpr(textured)
    assert textured_text.count("gather") > plain_text.count("gather")
    # UVs alone (no texture bound) add nothing either
    assert jaxpr(_quad_scene(mt.diffuse(0.5), uv=UV)) == plain_text

    def no_textures(*args, **kwargs):
        raise AssertionError("texture code traced for a texture-free scene")

    monkeypatch.setattr(tx, "textured_material", no_textures)
    assert jaxpr(_quad_scene(mt.diffuse(0.25))) == plain_text  # traced anew: no texture code
    with pytest.raises(AssertionError, match="texture code traced"):  # the patch does bite
        jaxpr(_quad_scene(mt.diffuse(0.5), {"kd": tx.texture(PATTERN, wrap="clamp")}))


def test_textured_triangles_never_form_convex_faces():
    # a closest hit on a convex body's face knows one of the face's triangles, whose UV map
    # would be extrapolated over the others: textured triangles are tested as triangles
    from jaxrt.scene.builtin.cornell import cornell_camera

    def box(lo, hi):  # an axis-aligned box, outward faces (as tests/geometry/test_convex.py)
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
                 (1, 5, 7, 3)]
        return v, np.array([[q[0], q[k], q[k + 1]] for q in quads for k in (1, 2)], np.int32)

    def _scene(block):  # a closed room, a light quad under its ceiling, the block
        room = sc.mesh(*box((0, 0, 0), (1, 1, 1)), mt.diffuse(0.5), name="room")
        lv = np.array([[0.4, 0.99, 0.4], [0.6, 0.99, 0.4], [0.6, 0.99, 0.6], [0.4, 0.99, 0.6]])
        light = sc.mesh(lv, [[0, 2, 1], [0, 3, 2]], mt.diffuse(0.0), emission=[5.0] * 3)
        return sc.build_scene([room, block, light], cornell_camera(8, 8), accel="brute")

    v, f = box((0.3, 0, 0.3), (0.6, 0.4, 0.6))
    assert _scene(sc.mesh(v, f, mt.diffuse(0.5))).convex.count == 1
    uv = v[:, [0, 2]]
    assert _scene(sc.mesh(v, f, mt.diffuse(0.5), uv=uv)).convex.count == 1  # UVs alone
    textured = _scene(sc.mesh(v, f, mt.diffuse(0.5), uv=uv,
                              textures={"kd": tx.texture(PATTERN)}))
    assert textured.convex is None


# ------------------------------------------------------------------ loaders and errors


def test_uvs_from_obj_vt_lines_and_ply(tmp_path):
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                                    "vt 0 0\nvt 0.5 0\nvt 0.5 1\nvt 0 1\n"
                                    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    (md,) = load_meshes(tmp_path / "q.obj")
    by_position = {tuple(v): tuple(t) for v, t in zip(md.vertices, md.uv, strict=True)}
    assert by_position[(1.0, 1.0, 0.0)] == (0.5, 1.0)
    assert by_position[(1.0, 0.0, 0.0)] == (0.5, 0.0)
    import trimesh

    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], process=False,
                          visual=trimesh.visual.TextureVisuals(uv=[[0, 0], [0.25, 0], [1, 1]]))
    tri.export(tmp_path / "t.ply")
    (md,) = load_meshes(tmp_path / "t.ply")
    np.testing.assert_allclose(md.uv, [[0, 0], [0.25, 0], [1, 1]])
    (tmp_path / "n.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n")
    assert load_meshes(tmp_path / "n.obj")[0].uv is None


def _scene_doc(tmp_path, mesh_entry):
    doc = {"camera": {"eye": [0, 3, 0], "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30,
                      "width": 8, "height": 8},
           "materials": {"white": {"type": "diffuse", "albedo": 0.5}},
           "meshes": [mesh_entry], "lights": [{"type": "environment", "radiance": 1}]}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    return path


def test_scene_file_textures(tmp_path):
    write_exr(tmp_path / "albedo.exr", PATTERN.astype(np.float32))
    (tmp_path / "q.obj").write_text("v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n"
                                    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                                    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    scene = load_scene(_scene_doc(tmp_path, {"file": "q.obj", "material": "white", "textures": {
        "kd": {"file": "albedo.exr", "wrap": "clamp"}}}))
    (b,) = scene.textures.bindings
    assert (b.material, b.field, b.wrap, b.filter) == (0, "kd", "clamp", "bilinear")
    np.testing.assert_array_equal(np.asarray(scene.textures.texels[0]),
                                  PATTERN.astype(np.float32))  # EXR: linear, as stored
    inline = {"vertices": QUAD.tolist(), "faces": FACES, "uv": UV.tolist(),
              "material": "white", "textures": {"kd": "albedo.exr"}}
    assert load_scene(_scene_doc(tmp_path, inline)).textures.bindings[0].wrap == "repeat"


@pytest.mark.parametrize("case, message", [
    ("missing", r"meshes\[0\]\.textures\.kd: texture file not found: .*nope\.png"),
    ("wrap", r"meshes\[0\]\.textures\.kd: texture 'albedo\.exr': wrap must be one of "
             r"\('repeat', 'clamp'\), got 'mirror'"),
    ("no_uv", r"meshes\[0\]\.textures: a textured inline mesh needs 'uv'"),
    ("no_vt", r"meshes\[0\]\.textures: n\.obj \(mesh .*\) has no texture coordinates"),
    ("field", r"meshes\[0\]\.textures\.exponent: cannot texture 'exponent'"),
    ("kind", r"a diffuse material has no 'alpha' to texture"),
])
def test_scene_file_texture_errors(tmp_path, case, message):
    write_exr(tmp_path / "albedo.exr", PATTERN.astype(np.float32))
    (tmp_path / "n.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n")
    inline = {"vertices": QUAD.tolist(), "faces": FACES, "uv": UV.tolist(), "material": "white"}
    entry = {
        "missing": {**inline, "textures": {"kd": "nope.png"}},
        "wrap": {**inline, "textures": {"kd": {"file": "albedo.exr", "wrap": "mirror"}}},
        "no_uv": {k: v for k, v in inline.items() if k != "uv"} | {"textures": {
            "kd": "albedo.exr"}},
        "no_vt": {"file": "n.obj", "material": "white", "textures": {"kd": "albedo.exr"}},
        "field": {**inline, "textures": {"exponent": "albedo.exr"}},
        "kind": {**inline, "textures": {"alpha": "albedo.exr"}},
    }[case]
    with pytest.raises(FileFormatError, match=message) as err:
        load_scene(_scene_doc(tmp_path, entry))
    assert isinstance(err.value, ValueError)


def test_mesh_validation_errors():
    t = tx.texture(PATTERN)
    with pytest.raises(ValueError, match="is textured \\(kd\\) but has no UVs"):
        sc.mesh(QUAD, FACES, mt.diffuse(0.5), textures={"kd": t})
    with pytest.raises(ValueError, match="uv must be finite with shape \\(4, 2\\)"):
        sc.mesh(QUAD, FACES, mt.diffuse(0.5), uv=UV[:3], textures={"kd": t})
    with pytest.raises(ValueError, match="reaches 1.5 > 1"):
        sc.mesh(QUAD, FACES, mt.diffuse(0.5), uv=UV, textures={"kd": tx.texture(
            np.full((2, 2), 1.5))})
    with pytest.raises(ValueError, match="reaches 0.95 \\+ 0.3 > 1"):
        sc.mesh(QUAD, FACES, mt.phong(0.2, 0.3, 10), uv=UV, textures={"kd": tx.texture(
            np.full((2, 2), 0.95))})
    with pytest.raises(ValueError, match="filter must be one of"):
        tx.texture(PATTERN, filter="cubic")


def _mitsuba(tmp_path, texture_xml, shape="rectangle"):
    xml = f"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="30"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>
    </transform><film type="hdrfilm"><integer name="width" value="8"/>
    <integer name="height" value="8"/></film></sensor>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
  <shape type="{shape}"><bsdf type="diffuse">{texture_xml}</bsdf></shape>
</scene>"""
    (tmp_path / "s.xml").write_text(xml)
    return load_scene(tmp_path / "s.xml")


def test_mitsuba_bitmap_reflectance(tmp_path):
    from jaxrt.scene.images import write_png

    # an 8-bit PNG (sRGB unless raw) of two values
    rgb8 = np.zeros((2, 2, 3), np.uint8)
    rgb8[0], rgb8[1] = 200, 50
    write_png(tmp_path / "t.png", tx.srgb_to_linear(rgb8 / 255.0, xp=np), tonemap="srgb")
    from jaxrt.scene.images import read_png

    assert np.array_equal(read_png(tmp_path / "t.png"), rgb8)  # the sRGB round trip is exact
    bitmap = ('<texture type="bitmap" name="reflectance"><string name="filename" '
              'value="t.png"/><string name="wrap_mode" value="clamp"/>{}</texture>')
    scene = _mitsuba(tmp_path, bitmap.format(""))
    (b,) = scene.textures.bindings
    assert (b.field, b.wrap, b.filter) == ("kd", "clamp", "bilinear")
    texels = np.asarray(scene.textures.texels[0])
    np.testing.assert_allclose(texels[:, 0, 0], tx.srgb_to_linear(np.array([200, 50]) / 255,
                                                                  xp=np), rtol=1e-6)
    raw = _mitsuba(tmp_path, bitmap.format('<boolean name="raw" value="true"/>'))
    np.testing.assert_allclose(np.asarray(raw.textures.texels[0])[:, 0, 0], [200 / 255, 50 / 255],
                               rtol=1e-6)
    with pytest.raises(FileFormatError, match="wrap_mode 'mirror' is not modelled"):
        _mitsuba(tmp_path, bitmap.replace("clamp", "mirror").format(""))
    with pytest.raises(FileFormatError, match="textures on a cube are not modelled"):
        _mitsuba(tmp_path, bitmap.format(""), shape="cube")
    with pytest.raises(FileFormatError, match="texture file not found"):
        _mitsuba(tmp_path, bitmap.replace("t.png", "nope.png").format(""))
