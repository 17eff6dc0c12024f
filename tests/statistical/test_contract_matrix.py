"""The contract matrix: every estimator on scenes composed the way users compose them.

Three factors span the configuration space:

- the lights (:data:`LIGHTS`): each kind alone (point, spot, directional, sphere, constant
  and map environment, emissive triangles) and all of them together, chosen by power and,
  once more, by the light BVH (``light_selection="bvh"``) with an emission-textured lamp;
- the geometry path (:data:`GEOMETRY`): a lone plane (nothing can block a shadow ray), an
  open mesh and a closed non-convex mesh tested triangle by triangle, a convex body tested
  by its face planes, and a BVH; every brute-force scene's camera rays take the shared-origin
  path (edge planes through the eye), the BVH's do not. Each scene asserts the path it takes;
- the material (:data:`MATERIALS`): diffuse, Phong, GGX conductor, mirror (a delta BSDF), and
  all four at once on the floor's tiles.

:data:`CELLS` crosses lights with geometry (every pair) and gives each cell a material such
that every (light, material) and (geometry, material) pair occurs too: 45 scenes, each
rendered by all 9 estimators (16 × 16 pixels, 512 spp). In every cell every estimator renders
without an exception and without a non-finite sample. The estimators unbiased for the cell
agree with MIS on the image mean within 5σ per channel (σ from the two renders' per-pixel
standard errors): one-sample MIS and ``path`` at ``max_depth=2`` always; light sampling and
RIS where no surface has a delta BSDF; BSDF sampling where no light is a delta light; hemisphere
sampling where neither is. Where every light is a delta light, BSDF and hemisphere sampling
see nothing: their image is exactly 0 (the README's estimator table says so).

Every comparison also resolves a bias of a stated size (:data:`RESOLUTION`): 5σ of the
difference, over the image mean, stays below 10 % for light sampling and ``path``, 15 % for
one-sample MIS, 20 % for BSDF and 35 % for hemisphere sampling in every cell: a relative
bias of that size moves z by 5 in expectation, whichever cell it is in. The fast subset
(:data:`FAST`, one cell per light and per geometry path) runs by default; the rest is marked
slow.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest

from jaxrt.geometry.bvh import BVH
from jaxrt.integrators.config import ESTIMATORS
from jaxrt.rendering.driver import render
from jaxrt.scene.camera import look_at
from jaxrt.scene.container import build_scene, mesh
from jaxrt.scene.lights import (
    constant_environment,
    directional_light,
    environment_map,
    point_light,
    sphere_light,
    spot_light,
)
from jaxrt.scene.materials import conductor, diffuse, mirror, phong
from jaxrt.scene.textures import texture

SPP = 512
SIZE = 16
DELTA_LIGHTS = {"point", "spot", "directional"}
OUTSIDE_LIGHTS = {"directional", "constant_env", "map_env", "mixed", "mixed_bvh"}
#: lights under which the floating box is tested triangle by triangle, not as a convex body
#: (no shadow-ray list is made). A point light in the plane of one of the box's faces (the
#: spot at z = 0.2 did) takes that face out of the list, since a segment to the light meets
#: it only at the light's end; the other ten triangles form an open box, which is not a
#: closed convex body. The spot sits off every face plane, so its cells take the convex path.
NOT_CONVEX_LIGHTS = OUTSIDE_LIGHTS


def _quad(x0, x1, z0, z1, y=0.0, down=False):
    """Axis-aligned quad at height ``y`` (vertices, faces), facing +y (or −y)."""
    v = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]], float)
    f = [[0, 2, 1], [0, 3, 2]]
    return v, (np.fliplr(f) if down else np.array(f))


def _box(lo, hi):
    """Closed axis-aligned box (8 vertices, 12 triangles)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[(hi if i & 1 else lo)[0], (hi if i & 2 else lo)[1], (hi if i & 4 else lo)[2]]
                  for i in range(8)])
    f = [[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
         [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]]
    return v, np.array(f)


def _tent():
    """Open mesh: two quads meeting at a ridge, no ends (non-convex, open)."""
    v = np.array([[-0.7, 0.25, 0.2], [-0.7, 0.25, 0.6], [-0.3, 0.55, 0.2], [-0.3, 0.55, 0.6],
                  [0.1, 0.25, 0.2], [0.1, 0.25, 0.6]], float)
    return v, np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]])


def _l_prism():
    """Closed non-convex mesh: an L-shaped profile in x–y extruded along z."""
    prof = np.array([[0.2, 0.1], [0.7, 0.1], [0.7, 0.25], [0.35, 0.25], [0.35, 0.6],
                     [0.2, 0.6]])
    z0, z1 = -0.6, -0.2
    v = np.array([[x, y, z] for z in (z0, z1) for x, y in prof])
    n = len(prof)
    caps = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]  # fan of the L (star-shaped from 0)
    f = [c[::-1] for c in caps] + [[i + n for i in c] for c in caps]
    for i in range(n):
        j = (i + 1) % n
        f += [[i, j, j + n], [i, j + n, i + n]]
    return v, np.array(f)


def _env_image():
    """An 8 × 16 lat-long map: a bright patch on a dim gradient."""
    h, w = 8, 16
    img = np.tile(np.linspace(0.1, 0.6, h)[:, None, None], (1, w, 3)) * [1.0, 0.8, 0.6]
    img[1:3, 3:6] = [6.0, 5.0, 4.0]
    return img


#: each light configuration: the extra lights, and whether an emissive quad is added
LIGHTS = {
    "point": lambda: [point_light([0.3, 1.6, 0.4], [3.0, 3.0, 3.0])],
    "spot": lambda: [spot_light([-0.3, 1.5, 0.3], [0.1, -1.0, 0.0], [4.0, 4.0, 4.0], 0.3, 0.7)],
    "directional": lambda: [directional_light([0.3, 1.0, 0.2], [1.0, 1.0, 1.0])],
    "sphere": lambda: [sphere_light([0.4, 2.7, -0.6], 0.5, [2.0, 2.0, 2.0])],
    "constant_env": lambda: [constant_environment([0.5, 0.5, 0.5])],
    "map_env": lambda: [environment_map(_env_image())],
    "triangles": lambda: [],
    "mixed": lambda: [point_light([0.3, 1.6, 0.4], [1.0, 1.0, 1.0]),
                      spot_light([-0.3, 1.5, 0.3], [0.1, -1.0, 0.0], [1.0, 1.0, 1.0], 0.3, 0.7),
                      directional_light([0.3, 1.0, 0.2], [0.3, 0.3, 0.3]),
                      sphere_light([0.4, 2.7, -0.6], 0.5, [0.8, 0.8, 0.8]),
                      environment_map(0.3 * _env_image())],
}
#: the mixed lights again, chosen by the light BVH (its pmf depends on the shading point and
#: normal: light sampling, MIS weights of BSDF hits and every path vertex use it), with the
#: lamp's radiance scaled by an emission texture (looked up at every light sample, BSDF hit
#: and camera hit of the lamp)
LIGHTS["mixed_bvh"] = LIGHTS["mixed"]
SELECTION = {"mixed_bvh": "bvh"}
EMISSIVE_QUAD = {"triangles", "mixed", "mixed_bvh"}
TEXTURED_LAMP = {"mixed_bvh"}
LAMP_TEXELS = np.random.default_rng(2).uniform(0.25, 1.75, (4, 4, 3))

#: the relative bias each comparison with MIS must resolve in every cell: 5σ of the image
#: means' difference, over the mean, at most this (a bias of that size moves z by 5).
#: Measured: light sampling and ``path`` ≤ 0.08 (``path`` through mirrors is BSDF sampling),
#: one-sample MIS ≤ 0.124, BSDF sampling ≤ 0.153, hemisphere sampling ≤ 0.28 (the emissive
#: quad and the sphere light are what they find least often).
RESOLUTION = {"light_area": 0.10, "light_solid_angle": 0.10, "ris": 0.10, "path": 0.10,
              "mis_one_sample": 0.15, "bsdf": 0.20,
              "uniform_hemisphere": 0.35, "cosine_hemisphere": 0.35}

GEOMETRY = ("plane", "open_mesh", "convex", "closed_nonconvex", "bvh")
MATERIALS = ("diffuse", "phong", "conductor", "mirror", "mixed")
_KINDS = {"diffuse": lambda: diffuse([0.7, 0.5, 0.3]),
          "phong": lambda: phong([0.4, 0.3, 0.2], 0.4, 20.0),
          "conductor": lambda: conductor(0.3, [0.9, 0.6, 0.4]),
          "mirror": lambda: mirror(0.8)}

#: (light, geometry, material): every light × geometry pair, material (l + g) mod 5, so that
#: every light × material and geometry × material pair occurs as well
CELLS = [(light, geom, MATERIALS[(i + j) % len(MATERIALS)])
         for (i, light), (j, geom) in itertools.product(enumerate(LIGHTS),
                                                        enumerate(GEOMETRY))]
#: the default subset: the diagonal l ≡ g (mod 5), every light and every geometry path once
FAST = {(light, GEOMETRY[i % len(GEOMETRY)], MATERIALS[(i + i % len(GEOMETRY)) % len(MATERIALS)])
        for i, light in enumerate(LIGHTS)}


def _floor(material: str):
    """The floor: four coplanar tiles, each its own mesh (one material each)."""
    kinds = list(_KINDS) if material == "mixed" else [material] * 4
    tiles = [_quad(x0, x0 + 1, z0, z0 + 1) for x0 in (-1.0, 0.0) for z0 in (-1.0, 0.0)]
    return [mesh(v, f, _KINDS[k](), name=f"tile {t}") for t, ((v, f), k) in
            enumerate(zip(tiles, kinds, strict=True))]


def _objects(geometry: str, material: str):
    kind = "phong" if material == "mixed" else material
    box = _box([-0.25, 0.2, -0.2], [0.25, 0.6, 0.2])
    parts = {"open_mesh": [_tent()], "convex": [box], "closed_nonconvex": [_l_prism()],
             "bvh": [_tent(), _l_prism(), box]}
    return [mesh(v, f, _KINDS[kind](), name=f"{geometry} {k}")
            for k, (v, f) in enumerate(parts.get(geometry, []))]


@functools.cache
def cell_scene(light: str, geometry: str, material: str):
    meshes = _floor(material) + _objects(geometry, material)
    if light in EMISSIVE_QUAD:
        v, f = _quad(-0.25, 0.25, -0.25, 0.25, y=1.5, down=True)
        glow = (dict(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                     textures={"emission": texture(LAMP_TEXELS)}) if light in TEXTURED_LAMP
                else {})
        meshes.append(mesh(v, f, diffuse(0.0), emission=[4.0, 4.0, 4.0], name="lamp", **glow))
    cam = look_at(eye=[0.0, 2.2, 2.2], target=[0.0, 0.1, -0.1], up=[0, 1, 0], fov_deg=40,
                  width=SIZE, height=SIZE)
    return build_scene(meshes, cam, LIGHTS[light](),
                       accel="bvh" if geometry == "bvh" else "brute",
                       light_selection=SELECTION.get(light, "power"))


def _assert_geometry_path(scene, light: str, geometry: str):
    """The scene takes the path its cell names (so the matrix cannot drift off it). Lights
    from outside the scene (directional, environments) make every triangle a possible
    occluder (:mod:`jaxrt.geometry.occluders`): then no shadow-ray list is made and a convex body is
    tested by its triangles."""
    if geometry == "bvh":
        assert isinstance(scene.geometry, BVH) and scene.eye_planes is None
        return
    assert not isinstance(scene.geometry, BVH) and scene.eye_planes is not None
    if geometry == "convex" and light not in NOT_CONVEX_LIGHTS:
        assert scene.convex is not None
    else:
        assert scene.convex is None
    if geometry == "plane":  # nothing to test, or (lights from outside) no list at all
        if light in OUTSIDE_LIGHTS:
            assert scene.occluders is None
        else:
            assert len(scene.occluders) == 0


def _unbiased(light: str, material: str) -> set[str]:
    """The estimators whose expectation is the cell's image (see the module docstring)."""
    delta_bsdf = material in ("mirror", "mixed")
    delta_light = light in DELTA_LIGHTS or light.startswith("mixed")
    ok = {"mis", "mis_one_sample", "path"}
    if not delta_bsdf:
        ok |= {"light_area", "light_solid_angle", "ris"}
    if not delta_light:
        ok.add("bsdf")
        if not delta_bsdf:
            ok |= {"uniform_hemisphere", "cosine_hemisphere"}
    return ok


def _render(scene, estimator: str):
    params = {"max_depth": 2} if estimator == "path" else {}
    return render(scene, estimator, spp=SPP, seed=ESTIMATORS.index(estimator) + 1,
                  progress=False, **params)


def _mean_and_sigma(r):
    """Image mean per channel (3,) and its standard error, pixels independent."""
    p = r.image.shape[0] * r.image.shape[1]
    mean = r.image.reshape(-1, 3).astype(np.float64).mean(0)
    sigma = np.sqrt((r.stderr.reshape(-1, 3).astype(np.float64) ** 2).sum(0)) / p
    return mean, sigma


def agreement(ref, other):
    """(z, resolution): per-channel z of the image means' difference, and 5σ of that
    difference relative to the reference mean."""
    (m0, s0), (m1, s1) = _mean_and_sigma(ref), _mean_and_sigma(other)
    sd, diff = np.hypot(s0, s1), m1 - m0
    # both renders without spread: only equal means agree
    z = np.where(sd > 0, diff / np.where(sd > 0, sd, 1.0), np.where(diff == 0, 0.0, np.inf))
    return z, 5 * sd / np.abs(m0)


def _params():
    for cell in CELLS:
        marks = () if cell in FAST else (pytest.mark.slow,)
        yield pytest.param(*cell, marks=marks, id="-".join(cell))


@pytest.mark.parametrize(("light", "geometry", "material"), list(_params()))
def test_cell(light, geometry, material):
    scene = cell_scene(light, geometry, material)
    _assert_geometry_path(scene, light, geometry)
    results = {e: _render(scene, e) for e in ESTIMATORS}
    for e, r in results.items():
        assert r.nonfinite == 0, f"{e}: {r.nonfinite} non-finite samples"
        assert np.all(np.isfinite(r.image)) and np.all(np.isfinite(r.stderr)), e
    ref = results["mis"]
    if light in DELTA_LIGHTS and material == "mirror":
        # a delta light seen through a delta BSDF only: no estimator can find it
        for e, r in results.items():
            assert np.all(r.image == 0), f"{e} found a delta light through a mirror"
        return
    assert ref.image.mean() > 0, "the cell's image is black: it tests nothing"
    for e in sorted(_unbiased(light, material) - {"mis"}):
        z, resolution = agreement(ref, results[e])
        assert np.all(np.abs(z) < 5), \
            f"{e} vs mis: z = {np.round(z, 2)} (5σ = {np.round(resolution, 3)} of the mean)"
        assert np.all(resolution <= RESOLUTION[e]), \
            f"{e} vs mis resolves only a bias of {np.round(resolution, 3)} of the mean"
    if light in DELTA_LIGHTS:
        for e in ("bsdf", "uniform_hemisphere", "cosine_hemisphere"):
            assert np.all(results[e].image == 0), f"{e} saw a delta light"


def test_the_cells_cover_every_pair():
    """Every pair of factor values occurs in some cell, and the fast subset names every
    light and every geometry path."""
    for (a, va), (b, vb) in itertools.combinations(
            enumerate((tuple(LIGHTS), GEOMETRY, MATERIALS)), 2):
        seen = {(c[a], c[b]) for c in CELLS}
        assert seen == set(itertools.product(va, vb))
    assert {c[0] for c in FAST} == set(LIGHTS) and {c[1] for c in FAST} == set(GEOMETRY)
