"""The Cornell box rendered by Mitsuba 3 from jaxrt's own arrays, for side-by-side benchmarks.

The scene is made from :func:`jaxrt.scene.builtin.cornell.cornell_meshes` (the very vertex and face
arrays jaxrt renders, so the geometry can never drift) and its camera constants:

- every mesh becomes an ``mi.Mesh`` whose ``vertex_positions``/``faces`` buffers are set from
  numpy; no vertex normals, so Mitsuba shades with the geometric normal
  ``(v1 − v0) × (v2 − v0)``, as jaxrt does;
- diffuse materials become ``twosided(diffuse(rgb kd))`` (jaxrt's triangles reflect on both
  sides; every visible face of the box faces the camera anyway);
- the light mesh gets a one-sided ``area`` emitter of the same RGB radiance (Mitsuba emits on
  the side of the geometric normal, which points down, as in jaxrt);
- ``perspective`` sensor, ``to_world = look_at(eye, target, up)``, vertical fov
  (``fov_axis="y"``), ``hdrfilm`` with a ``box`` reconstruction filter (one sample lands in
  one pixel, like jaxrt's box filter), ``independent`` sampler, ``direct`` integrator with
  one emitter and one BSDF sample combined by MIS (power heuristic) by default; any other
  integrator dict can be passed (``PATH_INTEGRATOR``: Mitsuba's ``path`` with unbounded depth
  and Russian roulette from depth 5, jaxrt's ``estimator="path"`` defaults).

Image orientation: Mitsuba's ``look_at`` puts camera +x on the world ``up × view`` side and
its film's column index grows towards camera −x, i.e. towards jaxrt's ``right = up × back``;
rows grow downwards in both. So the two images share the pixel grid: row 0 top, column 0 left
(the red wall is on the left). ``tests`` check it by ray casting jaxrt's camera
(:func:`cornell_region_masks`).

Mitsuba is optional (``pip install jaxrt[bench]``); importing this module does not import it.
Its ``llvm_ad_rgb`` variant needs libLLVM ≥ 16 (see ``benchmarks/MITSUBA.md``).
Reference: Jakob et al., "Mitsuba 3 renderer", https://mitsuba-renderer.org (v3.9.1).
"""

from __future__ import annotations

import functools
import glob
import json
import os
import re
import time
from pathlib import Path

import numpy as np

DEFAULT_VARIANT = "llvm_ad_rgb"
CACHE_DIR = Path(__file__).resolve().parent / ".cache"
# Seeds of the converged reference's passes start here, so that no benchmark render (small
# seeds) shares random numbers with the reference it is compared against.
REFERENCE_SEED = 1_000_000
_PASS_SPP = 256  # at most this many samples per pixel in one Mitsuba launch (bounds memory)
DIRECT_INTEGRATOR = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1}
#: Mitsuba's path tracer as jaxrt's ``render(scene, "path")`` defaults: unbounded, RR from 5
PATH_INTEGRATOR = {"type": "path", "max_depth": -1, "rr_depth": 5}


def _integrator_key(integrator: dict | None) -> str:
    """A hashable, canonical form of an integrator dict (None: the default ``direct``)."""
    return json.dumps(DIRECT_INTEGRATOR if integrator is None else integrator, sort_keys=True)


def _integrator_tag(integrator: dict | None) -> str:
    """'' for the default direct integrator (cache file names unchanged), else e.g.
    ``_path_max_depth-1_rr_depth5``."""
    if integrator is None or integrator == DIRECT_INTEGRATOR:
        return ""
    rest = "_".join(f"{k}{v}" for k, v in sorted(integrator.items()) if k != "type")
    return f"_{integrator['type']}" + (f"_{rest}" if rest else "")


def _find_libllvm() -> str | None:
    """Newest ``libLLVM`` ≥ 16 in the usual Debian/Ubuntu library folders, or None."""
    best = None
    for pattern in ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
                    "/usr/lib64/libLLVM*.so*"):
        for path in glob.glob(pattern):
            m = re.search(r"libLLVM(?:-|\.so\.)(\d+)", path)
            if m and int(m.group(1)) >= 16 and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), path)
    return best[1] if best else None


def import_mitsuba(variant: str = DEFAULT_VARIANT):
    """Import Mitsuba 3, select ``variant`` and return the ``mitsuba`` module.

    For LLVM variants, ``DRJIT_LIBLLVM_PATH`` is set to the newest libLLVM ≥ 16 found on the
    system when the user has not set it (Dr.Jit reads it when its LLVM backend starts).
    Raises ImportError when Mitsuba is not installed or the variant cannot be used (for
    example no usable libLLVM), with the reason in the message.
    """
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        path = _find_libllvm()
        if path is not None:
            os.environ["DRJIT_LIBLLVM_PATH"] = path
    try:
        import mitsuba as mi
    except ImportError as e:
        raise ImportError(f"mitsuba is not installed (pip install mitsuba): {e}") from e
    try:
        mi.set_variant(variant)
    except Exception as e:  # Mitsuba raises ImportError/RuntimeError/AttributeError here
        raise ImportError(f"mitsuba variant {variant!r} is unavailable: {e}") from e
    return mi


def _cornell():
    from jaxrt.scene.builtin import (
        cornell,  # lazy: the benchmark module imports without jaxrt's scene
    )

    return cornell


def _mi_mesh(mi, m):
    """One ``jaxrt.scene.container.Mesh`` (diffuse material, optional emission) as an
    ``mi.Mesh``."""
    kind = int(np.asarray(m.material.kind))
    if kind != 0:
        raise ValueError(f"mesh {m.name!r}: only diffuse materials (kind 0) are translated, "
                         f"got kind {kind}")
    props = mi.Properties()
    kd = np.broadcast_to(np.asarray(m.material.kd, np.float64), (3,))
    props["bsdf"] = mi.load_dict({"type": "twosided", "material": {
        "type": "diffuse", "reflectance": {"type": "rgb", "value": kd.tolist()}}})
    if m.emission is not None:
        if m.two_sided_emission:
            raise ValueError(f"mesh {m.name!r}: two-sided emission has no Mitsuba area analogue")
        radiance = np.broadcast_to(np.asarray(m.emission, np.float64), (3,))
        props["emitter"] = mi.load_dict({"type": "area", "radiance": {
            "type": "rgb", "value": radiance.tolist()}})
    v = np.asarray(m.vertices, np.float32)
    f = np.asarray(m.faces, np.uint32)
    mesh = mi.Mesh(m.name, vertex_count=len(v), face_count=len(f), props=props,
                   has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.ravel())
    params["faces"] = mi.UInt32(f.ravel())
    params.update()
    return mesh


def cornell_scene_dict(width: int = 256, height: int = 256, rfilter: str = "box",
                       light_scale: float = 1.0, variant: str = DEFAULT_VARIANT,
                       integrator: dict | None = None) -> dict:
    """The ``mi.load_dict`` description of jaxrt's Cornell box (shapes are live ``mi.Mesh``).

    ``rfilter``: ``"box"`` (matches jaxrt) or ``"gaussian"`` (Mitsuba's default, for the
    calibration figure). ``light_scale`` as in ``cornell_meshes`` (same power, smaller light).
    The sampler's ``sample_count`` is a placeholder: :func:`render_mitsuba` passes ``spp``.
    ``integrator``: a Mitsuba integrator dict (default :data:`DIRECT_INTEGRATOR`).
    """
    mi = import_mitsuba(variant)
    cb = _cornell()
    scene = {"type": "scene"}
    for m in cb.cornell_meshes(light_scale=light_scale):
        scene[m.name] = _mi_mesh(mi, m)
    # pose and fov read back from jaxrt's own camera, so they cannot drift either
    cam = cb.cornell_camera(int(width), int(height))
    eye = np.asarray(cam.eye, np.float64)
    frame = np.asarray(cam.frame, np.float64)  # rows: right, up, back
    fov = float(np.degrees(2 * np.arctan(float(cam.tan_half_fov))))
    scene["sensor"] = {
        "type": "perspective", "fov": fov, "fov_axis": "y",
        "to_world": mi.ScalarTransform4f().look_at(
            origin=eye.tolist(), target=(eye - frame[2]).tolist(), up=frame[1].tolist()),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height),
                 "rfilter": {"type": rfilter}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": 1},
    }
    scene["integrator"] = dict(DIRECT_INTEGRATOR if integrator is None else integrator)
    return scene


def load_cornell(width: int = 256, height: int = 256, rfilter: str = "box",
                 light_scale: float = 1.0, variant: str = DEFAULT_VARIANT,
                 integrator: dict | None = None):
    """The loaded ``mi.Scene`` (cached per arguments: loading is cheap, JIT kernels are reused)."""
    return _load_cornell(width, height, rfilter, light_scale, variant,
                         _integrator_key(integrator))


@functools.lru_cache(maxsize=8)
def _load_cornell(width, height, rfilter, light_scale, variant, integrator_key):
    mi = import_mitsuba(variant)
    return mi.load_dict(cornell_scene_dict(width, height, rfilter, light_scale, variant,
                                           json.loads(integrator_key)))


def _render_once(mi, scene, spp: int, seed: int) -> np.ndarray:
    img = mi.render(scene, spp=int(spp), seed=int(seed))
    return np.array(img, dtype=np.float32)  # forces evaluation (LLVM kernels run here)


def render_mitsuba(spp: int, seed: int = 0, width: int = 256, height: int = 256,
                   rfilter: str = "box", light_scale: float = 1.0,
                   variant: str = DEFAULT_VARIANT,
                   integrator: dict | None = None) -> tuple[np.ndarray, float]:
    """Render the Cornell box with Mitsuba 3: ``(image (H, W, 3) float32, seconds)``.

    Each pixel is the box-filtered mean of ``spp`` independent direct-lighting samples
    (radiance, W·sr⁻¹·m⁻², linear RGB). ``seconds`` is the wall time of ``mi.render`` until
    the image is on the host, scene loading excluded; the first call for a given variant and
    size also JIT-compiles Dr.Jit kernels (reused from ``~/.drjit`` across processes), so
    time a warm-up render first. The same ``seed`` gives the same image. ``integrator``: as in
    :func:`cornell_scene_dict` (each sample is then that integrator's estimate).
    """
    if int(spp) < 1:
        raise ValueError(f"spp must be ≥ 1, got {spp}")
    mi = import_mitsuba(variant)
    scene = load_cornell(int(width), int(height), rfilter, float(light_scale), variant,
                         integrator)
    t0 = time.perf_counter()
    img = _render_once(mi, scene, spp, seed)
    return img, time.perf_counter() - t0


def _timed_kernels(fn):
    """Run ``fn()`` with Dr.Jit's kernel history on: ``(result, dict)``.

    The dict sums over the JIT kernels launched: ``codegen_seconds`` (tracing to LLVM IR),
    ``compile_seconds`` (LLVM backend; 0 for kernels found in the ``~/.drjit`` cache),
    ``cache_hits`` / ``kernels`` (counts). Dr.Jit reports milliseconds.
    """
    import drjit as dr

    dr.kernel_history()  # drop older entries
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        out = fn()
        hist = [h for h in dr.kernel_history() if "codegen_time" in h]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return out, {"codegen_seconds": sum(h["codegen_time"] for h in hist) / 1e3,
                 "compile_seconds": sum(h.get("backend_time", 0.0) for h in hist) / 1e3,
                 "cache_hits": sum(int(h.get("cache_hit", 0)) for h in hist),
                 "kernels": len(hist)}


def mitsuba_samples_per_second(spp: int = 64, repeats: int = 5, width: int = 256,
                               height: int = 256, rfilter: str = "box",
                               variant: str = DEFAULT_VARIANT) -> dict:
    """Throughput of Mitsuba's ``direct`` integrator on the box, in camera samples per second.

    One warm-up render (seed 0) is timed separately — it includes Dr.Jit tracing and LLVM
    compilation unless the kernels are in the on-disk cache — then ``repeats`` renders with
    seeds 1..repeats. A sample is one camera ray's estimate (one emitter + one BSDF sample),
    so a render is ``width·height·spp`` samples. Returns a dict: ``samples_per_second``
    (best), ``median_samples_per_second``, ``seconds`` (list, per repetition),
    ``warmup_seconds``, ``warmup_compile_seconds`` (LLVM backend time of the warm-up's
    kernels per Dr.Jit's kernel history; 0 when they come from the ``~/.drjit`` disk cache),
    ``warmup_codegen_seconds``, ``warmup_cache_hits``, ``samples``, ``spp``, ``variant``,
    ``rfilter``, ``mitsuba_version``.
    """
    mi = import_mitsuba(variant)
    scene = load_cornell(int(width), int(height), rfilter, 1.0, variant)
    t0 = time.perf_counter()
    _, jit = _timed_kernels(lambda: _render_once(mi, scene, spp, 0))
    warmup = time.perf_counter() - t0
    seconds = []
    for k in range(int(repeats)):
        t0 = time.perf_counter()
        _render_once(mi, scene, spp, k + 1)
        seconds.append(time.perf_counter() - t0)
    n = int(width) * int(height) * int(spp)
    return {"samples_per_second": n / min(seconds),
            "median_samples_per_second": n / float(np.median(seconds)),
            "seconds": seconds, "warmup_seconds": warmup,
            "warmup_compile_seconds": jit["compile_seconds"],
            "warmup_codegen_seconds": jit["codegen_seconds"],
            "warmup_cache_hits": f"{jit['cache_hits']}/{jit['kernels']}",
            "samples": n, "spp": int(spp), "variant": variant, "rfilter": rfilter,
            "mitsuba_version": mi.__version__}


def render_mitsuba_passes(spp: int, seed: int, width: int = 256, height: int = 256,
                          variant: str = DEFAULT_VARIANT,
                          integrator: dict | None = None) -> tuple[np.ndarray, float]:
    """Like :func:`render_mitsuba` but in launches of at most 256 spp, averaged.

    Pass ``k`` uses seed ``seed + k``; with a box filter every sample has weight 1, so the
    mean of equal-spp passes is the mean of all samples (accumulated in float64).
    ``spp`` must be ≤ 256 or a multiple of 256. Returns ``(image float32, total seconds)``.
    """
    spp = int(spp)
    n_pass, per = (1, spp) if spp <= _PASS_SPP else (spp // _PASS_SPP, _PASS_SPP)
    if spp < 1 or per * n_pass != spp:
        raise ValueError(f"spp must be in [1, {_PASS_SPP}] or a multiple of it, got {spp}")
    acc = np.zeros((int(height), int(width), 3), np.float64)
    total = 0.0
    for k in range(n_pass):
        img, dt = render_mitsuba(per, seed + k, width, height, "box", 1.0, variant, integrator)
        acc += img
        total += dt
    return (acc / n_pass).astype(np.float32), total


def reference_path(spp: int, width: int, height: int, variant: str = DEFAULT_VARIANT,
                   integrator: dict | None = None, suffix: str = "") -> Path:
    """Where :func:`mitsuba_reference` caches its image (``benchmarks/.cache/…exr``)."""
    tag = _integrator_tag(integrator)
    return CACHE_DIR / f"mitsuba_cornell_{variant}{tag}_{width}x{height}_{spp}spp{suffix}.exr"


def mitsuba_reference_with_error(spp_per_pass: int = 64, passes: int = 64, width: int = 64,
                                 height: int = 64, variant: str = DEFAULT_VARIANT,
                                 integrator: dict | None = None,
                                 refresh: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's converged box and its per-pixel standard error: ``(image, stderr)`` (H, W, 3).

    ``passes`` independent renders of ``spp_per_pass`` spp (seeds ``REFERENCE_SEED + k``); the
    image is their mean and the standard error the standard deviation of the pass images over
    √passes (Mitsuba reports no error of its own). Cached as two EXRs under
    ``benchmarks/.cache/`` (``…_mean.exr``, ``…_stderr.exr``).
    """
    from jaxrt.scene.images import read_exr, write_exr

    spp = int(spp_per_pass) * int(passes)
    paths = [reference_path(spp, int(width), int(height), variant, integrator,
                            f"_{int(passes)}passes_{what}") for what in ("mean", "stderr")]
    if all(p.exists() for p in paths) and not refresh:
        return read_exr(paths[0])[0], read_exr(paths[1])[0]
    imgs = np.stack([render_mitsuba(spp_per_pass, REFERENCE_SEED + k, width, height, "box", 1.0,
                                    variant, integrator)[0].astype(np.float64)
                     for k in range(int(passes))])
    mean = imgs.mean(0).astype(np.float32)
    stderr = (imgs.std(0, ddof=1) / np.sqrt(len(imgs))).astype(np.float32)
    paths[0].parent.mkdir(parents=True, exist_ok=True)
    write_exr(paths[0], mean)
    write_exr(paths[1], stderr)
    return mean, stderr


def mitsuba_reference(spp: int = 4096, width: int = 256, height: int = 256,
                      variant: str = DEFAULT_VARIANT, refresh: bool = False) -> np.ndarray:
    """Mitsuba's converged image of the box, (H, W, 3) float32, cached as an EXR.

    Rendered once in passes of 256 spp with seeds ``REFERENCE_SEED + k`` (disjoint from the
    benchmark renders' seeds) and stored under ``benchmarks/.cache/`` (written atomically by
    :func:`jaxrt.scene.images.write_exr`); later calls read the file. Its own noise is that of
    ``spp`` samples: an image at n spp compared with it has
    ``MSE_measured ≈ MSE_true(n) · (1 + n/spp)``.
    """
    from jaxrt.scene.images import read_exr, write_exr

    path = reference_path(int(spp), int(width), int(height), variant)
    if path.exists() and not refresh:
        return read_exr(path)[0]
    img, _ = render_mitsuba_passes(spp, REFERENCE_SEED, width, height, variant)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, img)
    return img


def rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """Root-mean-square error over all pixels and channels, ``sqrt(mean((x − ref)²))``."""
    d = np.asarray(image, np.float64) - np.asarray(reference, np.float64)
    return float(np.sqrt(np.mean(d * d)))


def mitsuba_error_vs_time(spps=(1, 2, 4, 8, 16, 32, 64, 128, 256), reference=None,
                          reference_spp: int = 4096, seed: int = 100, width: int = 256,
                          height: int = 256, variant: str = DEFAULT_VARIANT) -> list[dict]:
    """Mitsuba's error/time trade on the box: one row per spp, for convergence plots.

    Each row renders at ``spp`` (seed ``seed + i``, after one untimed warm-up render) and
    compares with ``reference`` (default :func:`mitsuba_reference` at ``reference_spp``).
    Row keys: ``spp``, ``seconds`` (render wall time), ``rmse``, ``rel_rmse`` (rmse / mean
    reference radiance), ``efficiency`` = 1 / (rmse² · seconds), ``samples_per_second``.
    The reference's own noise inflates the measured MSE by a factor ≈ 1 + spp/reference_spp
    (≈ 6 % at 256 vs 4096 spp).
    """
    if reference is None:
        reference = mitsuba_reference(reference_spp, width, height, variant)
    render_mitsuba(int(min(spps)), seed, width, height, "box", 1.0, variant)  # warm-up
    mean_ref = float(np.mean(reference))
    rows = []
    for i, spp in enumerate(spps):
        img, dt = render_mitsuba(int(spp), seed + 1 + i, width, height, "box", 1.0, variant)
        e = rmse(img, reference)
        rows.append({"spp": int(spp), "seconds": dt, "rmse": e, "rel_rmse": e / mean_ref,
                     "efficiency": 1.0 / (e * e * dt),
                     "samples_per_second": width * height * int(spp) / dt})
    return rows


def time_to_rmse(rows: list[dict], target_rmse: float) -> float:
    """Seconds needed to reach ``target_rmse``, interpolated log-log in an error-vs-time table.

    Uses the rows of :func:`mitsuba_error_vs_time` (or any rows with ``seconds`` and
    ``rmse``); outside the table it extrapolates with the Monte Carlo rate
    ``rmse ∝ seconds^(-1/2)`` from the nearest row.
    """
    rows = sorted(rows, key=lambda r: r["seconds"])
    t = np.array([r["seconds"] for r in rows])
    e = np.array([r["rmse"] for r in rows])
    if target_rmse >= e[0]:
        return float(t[0] * (e[0] / target_rmse) ** 2)
    if target_rmse <= e[-1]:
        return float(t[-1] * (e[-1] / target_rmse) ** 2)
    # errors fall with time up to noise: interpolate on the first crossing
    i = int(np.argmax(e <= target_rmse))
    w = np.log(e[i - 1] / target_rmse) / np.log(e[i - 1] / e[i])
    return float(np.exp(np.log(t[i - 1]) + w * np.log(t[i] / t[i - 1])))


def _primary_hits(width: int, height: int):
    """Mesh index hit by the ray through each pixel centre (jaxrt's camera), −1 on a miss.

    Rays come from :func:`jaxrt.scene.camera.generate_ray` at ``u = (½, ½)``; intersection is a
    plain numpy Möller–Trumbore against all triangles of ``cornell_meshes()``. Returns
    ``(mesh_index (H, W) int32, hit points (H, W, 3), meshes)``.
    """
    import jax
    import jax.numpy as jnp

    from jaxrt.scene import camera as cm
    cb = _cornell()
    meshes = cb.cornell_meshes()
    cam = cb.cornell_camera(width, height)
    px = cm.pixel_coordinates(width, height)
    u = jnp.full(px.shape, 0.5, jnp.float32)
    o, d = jax.jit(jax.vmap(cm.generate_ray, in_axes=(None, 0, 0)))(cam, px, u)
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    tri = np.concatenate([m.vertices[m.faces] for m in meshes])  # (T, 3, 3)
    owner = np.concatenate([np.full(len(m.faces), i) for i, m in enumerate(meshes)])
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pvec = np.cross(d[:, None], e2[None])  # (N, T, 3)
    det = np.einsum("ntk,tk->nt", pvec, e1)
    inv = np.where(np.abs(det) > 1e-12, 1 / np.where(det == 0, 1, det), 0)
    tvec = o[:, None] - tri[None, :, 0]
    b1 = np.einsum("ntk,ntk->nt", tvec, pvec) * inv
    qvec = np.cross(tvec, e1[None])
    b2 = np.einsum("nk,ntk->nt", d, qvec) * inv
    t = np.einsum("tk,ntk->nt", e2, qvec) * inv
    ok = (inv != 0) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 1e-6)
    t = np.where(ok, t, np.inf)
    best = np.argmin(t, axis=1)
    hit = np.isfinite(t[np.arange(len(t)), best])
    index = np.where(hit, owner[best], -1).reshape(height, width).astype(np.int32)
    points = (o + d * np.where(hit, t[np.arange(len(t)), best], 0)[:, None])
    return index, points.reshape(height, width, 3), meshes


@functools.lru_cache(maxsize=4)
def cornell_region_masks(width: int = 256, height: int = 256) -> dict[str, np.ndarray]:
    """Boolean (H, W) pixel masks of named regions of the box, in jaxrt's pixel convention.

    One mask per mesh name (``floor``, ``back``, ``red_wall``, …): pixels whose whole 3×3
    neighbourhood sees that mesh through its centre (so no pixel straddles an edge), plus
    ``floor_under_light``: floor pixels whose visible point lies under the light, within
    twice its half-extent of the light's centre in x and z. Needs jax and jaxrt, not Mitsuba
    (use the same masks on jaxrt's and Mitsuba's images).
    """
    index, points, meshes = _primary_hits(int(width), int(height))
    pad = np.pad(index, 1, constant_values=-2)
    same = np.ones_like(index, bool)
    for dy in range(3):
        for dx in range(3):
            same &= pad[dy:dy + height, dx:dx + width] == index
    masks = {m.name: same & (index == i) for i, m in enumerate(meshes)}
    light = next(m for m in meshes if m.emission is not None)
    lo, hi = light.vertices.min(0), light.vertices.max(0)
    c, half = (lo + hi) / 2, (hi - lo) / 2
    near = (np.abs(points[..., 0] - c[0]) <= 2 * half[0]) & \
        (np.abs(points[..., 2] - c[2]) <= 2 * half[2])
    masks["floor_under_light"] = masks["floor"] & near
    return masks


def region_means(image: np.ndarray, masks: dict[str, np.ndarray] | None = None) -> dict:
    """Mean RGB radiance of ``image`` (H, W, 3) over each region mask, plus ``"image"``.

    ``masks`` default to :func:`cornell_region_masks` at the image's size. Returns
    name → (3,) float64 numpy (NaN for an empty mask).
    """
    image = np.asarray(image, np.float64)
    if masks is None:
        masks = cornell_region_masks(image.shape[1], image.shape[0])
    out = {"image": image.reshape(-1, 3).mean(0)}
    for name, m in masks.items():
        out[name] = image[m].mean(0) if m.any() else np.full(3, np.nan)
    return out
