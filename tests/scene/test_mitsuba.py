"""jaxrt.scene.mitsuba through jaxrt.load_scene("….xml"): the Cornell box written in Mitsuba 3's
XML builds what the file says, each transform kind matches numpy, ``<default>``/``$name``
substitution and overrides work, and every refused construct is a ValueError naming the
element and its line. Host-only apart from one 16×16 render, and, when Mitsuba 3 imports, a
pixel-by-pixel z-score comparison with Mitsuba's ``direct`` integrator.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import jaxrt
from jaxrt.scene.file import load_scene
from jaxrt.scene.images import FileFormatError, write_exr

DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
CORNELL = DATA / "cornell_mitsuba.xml"
SENSOR = """<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
</sensor>"""


LAMP = ('<emitter type="point"><point name="position" value="0, 0, 2"/>'
        '<rgb name="intensity" value="1"/></emitter>')


def _write(tmp_path: Path, body: str, sensor: str = SENSOR, name: str = "s.xml",
           lamp: bool = True) -> Path:
    path = tmp_path / name
    body = body + LAMP if lamp else body
    path.write_text(f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{sensor}\n{body}\n</scene>\n')
    return path


def _rect(transform: str = "", extra: str = "") -> str:
    return (f'<shape type="rectangle"><transform name="to_world">{transform}</transform>'
            f'{extra}</shape>')


def _tris(scene) -> np.ndarray:
    return np.asarray(scene.triangles, np.float64)


RECT = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)


def _rect_vertices(m: np.ndarray) -> np.ndarray:
    return RECT @ m[:3, :3].T + m[:3, 3]


def _rot(axis, deg) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k
    return m


def _line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


# ---------------------------------------------------------------------------------------------
# the Cornell box
# ---------------------------------------------------------------------------------------------


def test_cornell_loads_what_the_file_says():
    scene = load_scene(CORNELL, accel="brute")
    assert (scene.width, scene.height) == (64, 64)  # <default name="res" value="64"/>
    assert scene.num_triangles == 6 * 2 + 2 * 12
    np.testing.assert_allclose(np.asarray(scene.camera.eye), [0, 0, 4])
    np.testing.assert_allclose(np.asarray(scene.camera.frame),
                               [[1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-7)
    # fov 39.3 across x, square image
    np.testing.assert_allclose(float(scene.camera.tan_half_fov), np.tan(np.radians(39.3) / 2),
                               rtol=1e-6)
    # the floor: rotate x -90 then translate y -1 puts the square at y = -1, facing +y
    floor = _tris(scene)[np.asarray(scene.prim_material) == 0].reshape(-1, 3)
    np.testing.assert_allclose(floor[:, 1], -1, atol=1e-6)
    assert set(map(tuple, np.round(floor[:, [0, 2]]).astype(int))) == {(-1, -1), (1, -1),
                                                                         (1, 1), (-1, 1)}
    t = _tris(scene)[np.asarray(scene.prim_material) == 0][0]
    assert np.cross(t[1] - t[0], t[2] - t[0])[1] > 0
    # the light: 2 triangles, a 0.5 × 0.5 square at y = 0.99 facing down, radiance from $light
    assert scene.lights.structure.counts == (0, 0, 0, 2, 0, 0)
    tri = scene.lights.table("triangle")
    v = np.asarray(tri.vertices, np.float64).reshape(-1, 3)
    np.testing.assert_allclose(v[:, 1], 0.99, atol=1e-6)
    np.testing.assert_allclose(np.abs(v[:, [0, 2]]), 0.25, atol=1e-6)
    np.testing.assert_allclose(np.asarray(tri.normal), [[0, -1, 0]] * 2, atol=1e-6)
    np.testing.assert_allclose(np.asarray(tri.radiance), [[17, 12, 4]] * 2)
    # the red wall at x = -1 (a referenced BSDF), the twosided white one unwrapped
    albedo = np.asarray(scene.materials.kd)[np.asarray(scene.prim_material)]
    left = np.all(np.isclose(_tris(scene)[:, :, 0], -1, atol=1e-6), axis=1)
    np.testing.assert_allclose(albedo[left], [[0.63, 0.065, 0.05]] * 2, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(scene.materials.kd)[0], [0.725, 0.71, 0.68], rtol=1e-6)


def test_cornell_cubes_are_outward_and_placed():
    scene = load_scene(CORNELL, accel="brute")
    tall = _tris(scene)[np.asarray(scene.prim_material) == 5]  # the sixth shape
    m = np.diag([0.3, 0.6, 0.3, 1]) @ np.eye(4)
    m = _rot([0, 1, 0], 20) @ m
    m[:3, 3] += [-0.35, -0.4, -0.3]
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    want = corners @ m[:3, :3].T + m[:3, 3]
    dist = np.linalg.norm(tall.reshape(-1, 1, 3) - want[None], axis=-1)  # float32 vertices
    assert dist.min(1).max() < 1e-6 and dist.min(0).max() < 1e-6  # the same 8 corners
    centre = want.mean(0)
    for t in tall:
        n = np.cross(t[1] - t[0], t[2] - t[0])
        assert np.dot(n, t.mean(0) - centre) > 0  # outwards


def test_cornell_renders_finite_and_lit():
    scene = load_scene(CORNELL, params={"res": 16})
    assert (scene.width, scene.height) == (16, 16)
    image = np.asarray(jaxrt.render(scene, "mis", spp=4).image)
    assert image.shape == (16, 16, 3) and np.all(np.isfinite(image))
    assert image.mean() > 0.01
    # red wall on the left of the image, green on the right
    assert image[8, 1, 0] > image[8, 1, 1] and image[8, -2, 1] > image[8, -2, 0]


# ---------------------------------------------------------------------------------------------
# against Mitsuba 3, pixel by pixel (only where Mitsuba 3 imports)
# ---------------------------------------------------------------------------------------------

LIGHTS = DATA / "lights_mitsuba.xml"
PASSES, PASS_SPP, COMPARE_RES = 16, 256, 32  # K independent renders of n spp per renderer
SKY = re.compile(r'<emitter type="constant">\s*<rgb name="radiance" value="([^"]*)"/>\s*'
                 r"</emitter>")
# spot fall-off and envmap lookup differ by convention (docs/scenes.md): the spot's beam_width
# equals its cutoff_angle (a hard edge either way) and the envmap is uniform (nearest texel and
# bilinear agree), so neither difference shows
COMPARE_CASES = ("cornell", "lights", "lights_envmap")


def _comparison_scene(case: str, folder: Path) -> Path:
    """The case's XML, with Mitsuba's ``direct`` integrator (jaxrt's ``mis``), in ``folder``."""
    if case == "cornell":
        text = CORNELL.read_text().replace('<integrator type="path">',
                                           '<integrator type="direct">')
        text = text.replace('<integer name="max_depth" value="8"/>', "")
    else:
        text = LIGHTS.read_text()
    if case == "lights_envmap":  # the constant sky as a uniform 16 x 32 EXR at scale 2
        rgb = np.array([float(v) for v in SKY.search(text).group(1).split(",")])
        write_exr(folder / "sky.exr", np.broadcast_to(rgb / 2, (16, 32, 3)).astype(np.float32))
        text, count = SKY.subn('<emitter type="envmap"><string name="filename" value="sky.exr"/>'
                               '<float name="scale" value="2"/></emitter>', text)
        assert count == 1
    assert '<rfilter type="box"/>' in text and '<integrator type="direct"' in text
    path = folder / f"{case}.xml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def passes(tmp_path_factory):
    """``passes(case)``: (jaxrt, Mitsuba) arrays (K, H, W, 3) of K independent renders each."""
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed "
                             "(benchmarks/MITSUBA.md)")
    mi.set_variant("scalar_rgb")  # no LLVM needed; a few seconds per case here
    done = {}

    def get(case):
        if case not in done:
            path = _comparison_scene(case, tmp_path_factory.mktemp(case))
            theirs = mi.load_file(str(path), res=COMPARE_RES)
            m = [np.asarray(mi.render(theirs, spp=PASS_SPP, seed=k))[..., :3]
                 for k in range(PASSES)]
            ours = load_scene(path, params={"res": COMPARE_RES})
            j = [np.asarray(jaxrt.render(ours, "mis", spp=PASS_SPP, seed=1000 + k,
                                         progress=False).image) for k in range(PASSES)]
            done[case] = np.asarray(j, np.float64), np.asarray(m, np.float64)
        return done[case]

    return get


def _compare(ours: np.ndarray, theirs: np.ndarray) -> dict:
    """Per pixel and channel, z = (m_j − m_m) / √(se_j² + se_m²) from K passes a side.

    Under the null z is Student-t with Welch's ν (K−1 ≤ ν ≤ 2K−2), so the checks use t:
    the fraction of |z| > 3 against its expectation plus 4 standard deviations (bounded for
    the three channels of a pixel being correlated: Var ≤ 3 p / N), the smallest two-sided
    p-value against Bonferroni's 1e-3 / N, and the mean normal score against 4 √(3 / N)
    (a bias that no single pixel shows). Pixels that neither renderer varies in are compared
    for equality.
    """
    from scipy import stats

    k_o, k_t = len(ours), len(theirs)
    m_o, m_t = ours.mean(0), theirs.mean(0)
    v_o, v_t = ours.var(0, ddof=1) / k_o, theirs.var(0, ddof=1) / k_t
    v = v_o + v_t
    size = np.maximum(np.abs(m_o), np.abs(m_t))
    flat = np.sqrt(v) <= 1e-7 * size + 1e-12  # the passes agree to rounding on both sides
    noisy = ~flat
    z = (m_o - m_t)[noisy] / np.sqrt(v[noisy])
    nu = v[noisy] ** 2 / (v_o[noisy] ** 2 / (k_o - 1) + v_t[noisy] ** 2 / (k_t - 1))
    n = z.size
    p = 2 * stats.t.sf(np.abs(z), nu)
    q = np.sign(z) * np.minimum(stats.norm.isf(p / 2), 40.0)  # the normal score of each z
    expect3 = float(np.mean(2 * stats.t.sf(3.0, nu)))
    worst = int(np.argmin(p))
    flat_err = np.abs(m_o - m_t)[flat] - (1e-5 * size[flat] + 1e-7)
    where = np.argwhere(noisy)[worst]
    return {
        "pixels": int(m_o.size), "noisy": n, "flat": int(flat.sum()),
        "flat_unequal": int(np.sum(flat_err > 0)),
        "frac3": float(np.mean(np.abs(z) > 3)), "expect3": expect3,
        "frac3_bound": expect3 + 4 * np.sqrt(3 * expect3 / n),
        "max_z": float(abs(z[worst])) if n else 0.0,
        "max_z_bound": float(stats.t.isf(1e-3 / n / 2, nu[worst])) if n else 0.0,
        "min_p": float(p[worst]) if n else 1.0, "p_bound": 1e-3 / n,
        "worst": tuple(int(i) for i in where),
        "mean_q": float(q.mean()), "mean_q_bound": 4 * np.sqrt(3 / n),
    }


def _failures(c: dict) -> list[str]:
    out = []
    if c["flat_unequal"]:
        out.append(f"{c['flat_unequal']} of {c['flat']} noiseless pixel-channels differ")
    if c["frac3"] > c["frac3_bound"]:
        out.append(f"|z| > 3 in {c['frac3']:.2%} (bound {c['frac3_bound']:.2%})")
    if c["min_p"] < c["p_bound"]:
        out.append(f"max |z| {c['max_z']:.2f} at {c['worst']} (Bonferroni bound "
                   f"{c['max_z_bound']:.2f})")
    if abs(c["mean_q"]) > c["mean_q_bound"]:
        out.append(f"mean z-score {c['mean_q']:+.3f} (bound ±{c['mean_q_bound']:.3f})")
    return out


def _summary(c: dict) -> str:
    return (f"{c['noisy']} noisy + {c['flat']} noiseless of {c['pixels']} pixel-channels; "
            f"|z|>3 {c['frac3']:.2%} (expected {c['expect3']:.2%}, bound "
            f"{c['frac3_bound']:.2%}); max |z| {c['max_z']:.2f} (bound {c['max_z_bound']:.2f}); "
            f"mean z-score {c['mean_q']:+.3f} (bound ±{c['mean_q_bound']:.3f})")


@pytest.mark.slow
@pytest.mark.parametrize("case", COMPARE_CASES)
def test_against_mitsuba_pixel_by_pixel(passes, case):
    ours, theirs = passes(case)
    c = _compare(ours, theirs)
    print(f"{case}: {_summary(c)}")
    assert c["noisy"] > c["pixels"] // 2  # most of the image is compared statistically
    assert not _failures(c), f"{case}: {'; '.join(_failures(c))}\n{_summary(c)}"


@pytest.mark.slow
def test_mitsuba_comparison_has_teeth(passes):
    ours, theirs = passes("cornell")
    for label, broken in [("x1.03", ours * 1.03), ("x0.99", ours * 0.99),
                          ("one pixel right", np.roll(ours, 1, axis=2))]:
        c = _compare(broken, theirs)
        print(f"{label}: {_summary(c)}")
        # each one fails the statistical checks, not only the noiseless pixels' equality
        assert len(_failures(c)) - bool(c["flat_unequal"]) > 0, f"{label}: {_summary(c)}"


def test_rfilter_box_only(tmp_path):
    box = SENSOR.replace("</film>", '<rfilter type="box"/></film>')
    scene = load_scene(_write(tmp_path, _rect(), box), accel="brute")
    assert (scene.width, scene.height) == (8, 6)
    gauss = SENSOR.replace("</film>", '\n  <rfilter type="gaussian"/></film>')
    path = _write(tmp_path, _rect(), gauss)
    line = _line_of(path, "<rfilter")
    with pytest.raises(ValueError, match=rf"line {line}: <rfilter type=\"gaussian\">: only the "
                       "box reconstruction filter"):
        load_scene(path)
    radius = SENSOR.replace("</film>", '<rfilter type="box"><float name="radius" value="1"/>'
                            "</rfilter></film>")
    with pytest.raises(ValueError, match="'radius' is not supported"):
        load_scene(_write(tmp_path, _rect(), radius))


# ---------------------------------------------------------------------------------------------
# transforms, against numpy
# ---------------------------------------------------------------------------------------------

M16 = np.array([[0.0, 0, 2, 1], [0, 3, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]])


def _translate(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


@pytest.mark.parametrize("xml,want", [
    ('<translate x="1" y="-2" z="3"/>', _translate([1, -2, 3])),
    ('<translate value="1, -2, 3"/>', _translate([1, -2, 3])),
    ('<scale value="2"/>', np.diag([2.0, 2, 2, 1])),
    ('<scale x="2" z="3"/>', np.diag([2.0, 1, 3, 1])),
    ('<rotate x="1" y="1" angle="30"/>', _rot([1, 1, 0], 30)),
    ('<rotate value="0, 0, 1" angle="-45"/>', _rot([0, 0, 1], -45)),
    ('<matrix value="' + " ".join(map(str, M16.ravel())) + '"/>', M16),
    ('<matrix value="0 0 2  0 3 0  -1 0 0"/>', np.pad(M16[:3, :3], (0, 1)) + np.diag([0, 0, 0, 1])),
    # document order: each one left-multiplies: translate, then rotate, then scale
    ('<translate x="1"/><rotate y="1" angle="90"/><scale value="2"/>',
     np.diag([2.0, 2, 2, 1]) @ _rot([0, 1, 0], 90) @ _translate([1, 0, 0])),
])
def test_transforms_match_numpy(tmp_path, xml, want):
    scene = load_scene(_write(tmp_path, _rect(xml, '<emitter type="area"><rgb name="radiance" '
                                              'value="1"/></emitter>')), accel="brute")
    got = _tris(scene)
    want_v = _rect_vertices(want)
    faces = [[0, 1, 2], [0, 2, 3]] if np.linalg.det(want[:3, :3]) > 0 else [[2, 1, 0], [3, 2, 0]]
    np.testing.assert_allclose(got, want_v[np.array(faces)], atol=1e-6)


def test_lookat_transform(tmp_path):
    xml = '<lookat origin="1, 2, 3" target="1, 2, 0" up="0, 1, 0"/>'
    got = _tris(load_scene(_write(tmp_path, _rect(xml)), accel="brute")).reshape(-1, 3)
    # columns left, up, forward, origin: the square stands in z = 3, facing -z
    np.testing.assert_allclose(got[:, 2], 3, atol=1e-6)
    left = np.cross([0, 1, 0], [0, 0, -1])
    want = np.stack([left, [0, 1, 0], [0, 0, -1], [1, 2, 3]], 1)
    m = np.vstack([want, [0, 0, 0, 1]])
    np.testing.assert_allclose(got, _rect_vertices(m)[[0, 1, 2, 0, 2, 3]], atol=1e-6)


def test_flip_normals_turns_the_winding(tmp_path):
    flip = '<boolean name="flip_normals" value="true"/>'
    a = _tris(load_scene(_write(tmp_path, _rect()), accel="brute"))[0]
    b = _tris(load_scene(_write(tmp_path, _rect(extra=flip)), accel="brute"))[0]
    assert np.cross(a[1] - a[0], a[2] - a[0])[2] > 0 > np.cross(b[1] - b[0], b[2] - b[0])[2]


# ---------------------------------------------------------------------------------------------
# defaults and $name
# ---------------------------------------------------------------------------------------------


def test_defaults_and_overrides(tmp_path):
    body = ('<default name="h" value="1.5"/><default name="e" value="2, 3, 4"/>'
            + _rect('<translate y="$h"/>', '<emitter type="area"><rgb name="radiance" '
                    'value="$e"/></emitter>'))
    path = _write(tmp_path, body)
    scene = load_scene(path, accel="brute")
    np.testing.assert_allclose(_tris(scene)[..., 1].min(), 0.5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(scene.lights.table("triangle").radiance)[0], [2, 3, 4])
    over = load_scene(path, accel="brute", params={"h": 3, "e": "1"})
    np.testing.assert_allclose(_tris(over)[..., 1].min(), 2, atol=1e-6)
    np.testing.assert_allclose(np.asarray(over.lights.table("triangle").radiance)[0], [1, 1, 1])
    with pytest.raises(ValueError, match="parameter.*hh.*not used"):
        load_scene(path, params={"hh": 1})


# ---------------------------------------------------------------------------------------------
# refused: a ValueError naming the element and its line
# ---------------------------------------------------------------------------------------------

ERRORS = {
    "unknown plugin": ('<shape type="disk"/>', '<shape type="disk"', "unsupported shape"),
    "unknown tag": ("<shap type='rectangle'/>", "<shap", "unknown element"),
    "unknown property": (_rect(extra='<float name="radius" value="2"/>'), '<float name="radius"',
                         "not supported"),
    "missing file": ('<shape type="obj"><string name="filename" value="nope.obj"/></shape>',
                     '<string name="filename"', "not found"),
    "matrix of 15": (_rect('<matrix value="' + " ".join(["1"] * 15) + '"/>'), "<matrix",
                     "16 or 9 numbers"),
    "bad number": (_rect('<translate x="one"/>'), "<translate", "expected numbers"),
    "unresolved $": (_rect('<translate x="$dx"/>'), "<translate", r"\$dx"),
    "bad ref": (_rect(extra='<ref id="gold"/>'), '<ref id="gold"', "no BSDF with id 'gold'"),
    "plain sphere": ('<shape type="sphere"><float name="radius" value="1"/></shape>',
                     '<shape type="sphere"', "only a light"),
    "plastic": (_rect(extra='<bsdf type="plastic"/>'), '<bsdf type="plastic"',
                "unsupported BSDF"),
    "beckmann": (_rect(extra='<bsdf type="roughconductor"><float name="alpha" value="0.2"/>'
                       '</bsdf>'), '<bsdf type="roughconductor"', "ggx"),
    "complex ior": (_rect(extra='<bsdf type="conductor"><rgb name="eta" value="0.2"/></bsdf>'),
                    '<rgb name="eta"', "complex IOR"),
    "spectrum": (_rect(extra='<emitter type="area"><spectrum name="radiance" '
                       'value="400:1, 700:2"/></emitter>'), "<spectrum", "uniform spectrum"),
    "area at top": ('<emitter type="area"/>' + _rect(), '<emitter type="area"', "inside a shape"),
    "bad transform tag": (_rect('<shear value="1"/>'), "<shear", "unknown transform"),
    "top-level texture": ('<texture type="bitmap"/>' + _rect(), "<texture", "unsupported"),
    "ellipsoid": ('<shape type="sphere"><transform name="to_world"><scale x="2"/></transform>'
                  '<emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>',
                  '<shape type="sphere"', "uniformly"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_errors_name_the_element_and_line(tmp_path, case):
    body, marker, message = ERRORS[case]
    path = _write(tmp_path, body)
    line = _line_of(path, marker)
    tag = re.escape(re.match(r"<\w+", marker).group(0))
    with pytest.raises(ValueError, match=message) as info:
        load_scene(path)
    text = str(info.value)
    assert str(path) in text and f"line {line}" in text and re.search(tag, text), text


def test_fov_axis_and_sensor_errors(tmp_path):
    sensor = SENSOR.replace('<float name="fov" value="40"/>',
                            '<float name="fov" value="40"/><string name="fov_axis" value="y"/>')
    scene = load_scene(_write(tmp_path, _rect(), sensor), accel="brute")
    np.testing.assert_allclose(float(scene.camera.tan_half_fov), np.tan(np.radians(20)), rtol=1e-6)
    default = load_scene(_write(tmp_path, _rect()), accel="brute")  # Mitsuba's default is x
    np.testing.assert_allclose(float(default.camera.tan_half_fov),
                               np.tan(np.radians(20)) * 6 / 8, rtol=1e-6)
    bad = SENSOR.replace('type="perspective"', 'type="thinlens"')
    with pytest.raises(ValueError, match=r"line 3: <sensor type=\"thinlens\">"):
        load_scene(_write(tmp_path, _rect(), bad))
    with pytest.raises(ValueError, match="no <sensor>"):
        load_scene(_write(tmp_path, _rect(), ""))
    malformed = tmp_path / "m.xml"
    malformed.write_text("<scene>\n<shape>\n</scene>\n")
    with pytest.raises(FileFormatError, match="line 3: not well-formed"):
        load_scene(malformed)


# ---------------------------------------------------------------------------------------------
# emitters and other BSDFs
# ---------------------------------------------------------------------------------------------


def test_emitters(tmp_path):
    write_exr(tmp_path / "sky.exr", np.full((4, 8, 3), 0.5, np.float32))
    body = _rect() + """
<emitter type="point"><point name="position" x="0" y="2" z="1"/>
  <rgb name="intensity" value="5"/></emitter>
<emitter type="spot"><transform name="to_world">
  <lookat origin="0, 3, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
  <rgb name="intensity" value="7"/><float name="cutoff_angle" value="30"/>
  <float name="beam_width" value="10"/></emitter>
<emitter type="directional"><vector name="direction" x="0" y="-1" z="0"/>
  <rgb name="irradiance" value="2"/></emitter>
<shape type="sphere"><point name="center" value="1, 2, 3"/><float name="radius" value="0.5"/>
  <emitter type="area"><rgb name="radiance" value="9"/></emitter></shape>
<emitter type="envmap"><string name="filename" value="sky.exr"/>
  <float name="scale" value="2"/></emitter>"""
    s = load_scene(_write(tmp_path, body, lamp=False), accel="brute")
    assert s.lights.structure.counts == (1, 1, 1, 0, 1, 1)
    np.testing.assert_allclose(np.asarray(s.lights.table("point").position), [[0, 2, 1]])
    spot = s.lights.table("spot")
    np.testing.assert_allclose(np.asarray(spot.position), [[0, 3, 0]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(spot.axis), [[0, -1, 0]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(spot.cos_inner), np.cos(np.radians([10])), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(spot.cos_outer), np.cos(np.radians([30])), rtol=1e-6)
    # jaxrt's direction points towards the light; Mitsuba's is the way the light travels
    np.testing.assert_allclose(np.asarray(s.lights.table("directional").direction), [[0, 1, 0]])
    sphere = s.lights.table("sphere")
    np.testing.assert_allclose(np.asarray(sphere.center), [[1, 2, 3]])
    np.testing.assert_allclose(np.asarray(sphere.radius), [0.5])
    env = s.lights.table("environment")
    np.testing.assert_allclose(np.asarray(env.mean_radiance), [1, 1, 1], rtol=1e-5)
    # Mitsuba's +y (the map's top row) is the up direction of the jaxrt map's frame
    np.testing.assert_allclose(np.asarray(env.rotation) @ [0, 0, 1], [0, 1, 0], atol=1e-7)


def test_sphere_to_world_and_constant(tmp_path):
    body = _rect() + """
<shape type="sphere"><transform name="to_world"><scale value="0.2"/>
  <translate value="0, 1, 0"/></transform>
  <emitter type="area"><rgb name="radiance" value="3"/></emitter></shape>
<emitter type="constant"><rgb name="radiance" value="0.1, 0.2, 0.3"/></emitter>"""
    s = load_scene(_write(tmp_path, body))
    np.testing.assert_allclose(np.asarray(s.lights.table("sphere").center), [[0, 1, 0]])
    np.testing.assert_allclose(np.asarray(s.lights.table("sphere").radius), [0.2], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(s.lights.table("environment").radiance),
                               [0.1, 0.2, 0.3], rtol=1e-6)


def test_conductors(tmp_path):
    body = (_rect(extra='<bsdf type="conductor"><rgb name="specular_reflectance" value="0.9"/>'
                  '</bsdf>')
            + _rect('<translate z="-1"/>', '<bsdf type="roughconductor"><string '
                    'name="distribution" value="ggx"/><float name="alpha" value="0.3"/>'
                    '<rgb name="specular_reflectance" value="0.9, 0.6, 0.3"/></bsdf>'))
    s = load_scene(_write(tmp_path, body), accel="brute")
    from jaxrt.scene import materials as mt
    kinds = np.asarray(s.materials.kind)
    assert list(kinds) == [mt.MIRROR, mt.CONDUCTOR]
    np.testing.assert_allclose(np.asarray(s.materials.alpha)[1], 0.3, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(s.materials.ks)[1], [0.9, 0.6, 0.3], rtol=1e-6)
    assert float(np.asarray(s.materials.fresnel_schlick)[1]) == 0
    assert float(np.asarray(s.materials.masking_separable)[1]) == 1


def test_obj_shape_relative_path(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    body = ('<shape type="obj"><string name="filename" value="meshes/tri.obj"/>'
            '<transform name="to_world"><translate z="2"/></transform></shape>')
    s = load_scene(_write(tmp_path, body), accel="brute")
    np.testing.assert_allclose(np.sort(_tris(s)[0], axis=0)[:, 2], [2, 2, 2], atol=1e-6)
    assert np.asarray(s.materials.kd)[0].tolist() == pytest.approx([0.5] * 3)  # Mitsuba's default
