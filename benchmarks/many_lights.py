"""Many lights: the efficiency of light selection (power, light BVH) × light sampling, MIS and
RIS on the lamp-grid room.

Efficiency is ``1 / (MSE × CPU-seconds)`` of a render against a converged reference (MIS at
``--ref-spp``), MSE over every pixel and channel less the reference's own variance, CPU-seconds of
this process (``time.process_time``, every thread) and wall seconds of the render alone (compiled
before, by a warm-up render). Rounds interleave the estimators (A B C, C B A, …) and the
table reports each variant's median efficiency, relative to power-selected light sampling.
``--diffuse`` renders the room with its glossy floor and metal block made diffuse: what light
selection alone can gain where the BSDF does not decide which lamps matter.

Run (a few minutes on 2 cores)::

    python benchmarks/many_lights.py [--size 96] [--spp 16] [--rounds 3] [--ref-spp 1024]

``--split`` (median against SAOH splits, at the median tree's depth and free of it) or
``--branching`` (8 against 16 children) compares trees built differently, by light sampling
only, beside power selection.

With ``--mitsuba`` (same options, and ``--variant``) it compares jaxrt's ``mis`` with Mitsuba
3's ``direct`` integrator instead, on the room with Mitsuba-equal BSDFs (:func:`mitsuba_main`;
skipped with a message when Mitsuba does not import; benchmarks/MITSUBA.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import numpy as np

import jaxrt
from jaxrt.scene.builtin import lamp_grid

#: (label, light selection, estimator, parameters)
VARIANTS = tuple(
    (f"{sel} · {label}", sel, e, p)
    for sel in ("power", "bvh")
    for label, e, p in (("light_solid_angle", "light_solid_angle", {}), ("mis", "mis", {}),
                        ("ris M=4", "ris", {"ris_candidates": 4}),
                        ("ris M=8", "ris", {"ris_candidates": 8}),
                        ("ris M=16", "ris", {"ris_candidates": 16})))

#: ``--path``: the path tracer (3 segments) with next-event estimation by one light sample or
#: by RIS, against a path-traced reference
PATH_DEPTH = 3
PATH_VARIANTS = tuple(
    (f"{sel} · path nee={label}", sel, "path", {"max_depth": PATH_DEPTH, **p})
    for sel in ("power", "bvh")
    for label, p in (("light", {}), ("ris M=4", {"nee": "ris", "ris_candidates": 4}),
                     ("ris M=8", {"nee": "ris", "ris_candidates": 8})))


def tree_scene(scene, split="saoh", branch_bits=4):
    """``scene`` (light selection ``bvh``) with its light BVH rebuilt by ``split`` with
    ``2**branch_bits`` children per node."""
    from jaxrt.scene.lights import bvh_build
    from jaxrt.scene.lights.table import SELECTION_FLOOR, light_powers

    lights = scene.lights
    tree, depth = bvh_build.build_light_bvh(lights, light_powers(lights), SELECTION_FLOOR,
                                            branch_bits=branch_bits, split=split)
    lights = dataclasses.replace(lights, selection=tree, structure=dataclasses.replace(
        lights.structure, bvh_depth=depth))
    return scene.replace(lights=lights)


def _timed_render(scene, estimator, params, spp, seed):
    c0, w0 = time.process_time(), time.perf_counter()
    r = jaxrt.render(scene, estimator, spp=spp, seed=seed, progress=False, **params)
    return r, time.process_time() - c0, time.perf_counter() - w0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=96, help="image width (height 3/4 of it)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--path", action="store_true",
                    help=f"the path tracer at depth {PATH_DEPTH} (NEE by light sampling or RIS)")
    ap.add_argument("--diffuse", action="store_true",
                    help="the room with a diffuse floor and block (lamp_grid(glossy=False))")
    ap.add_argument("--split", action="store_true",
                    help="light sampling with trees of median, SAOH (at the median tree's depth) "
                    "and depth-free SAOH splits (16 children)")
    ap.add_argument("--branching", action="store_true",
                    help="light sampling with trees of 8 and of 16 children per node")
    ap.add_argument("--tree-split", default="saoh", choices=("saoh", "median"),
                    help="the splits of --branching's trees")
    args = ap.parse_args(argv)
    scenes = {sel: lamp_grid(args.size, args.size * 3 // 4, glossy=not args.diffuse,
                             light_selection=sel) for sel in ("power", "bvh")}
    print(scenes["bvh"].summary(), flush=True)
    variants = PATH_VARIANTS if args.path else VARIANTS
    if args.split or args.branching:
        trees = ({"bvh median": ("median", 4), "bvh saoh": ("saoh", 4),
                  "bvh saoh-free": ("saoh-free", 4)} if args.split else
                 {f"bvh 8 children ({args.tree_split})": (args.tree_split, 3),
                  f"bvh 16 children ({args.tree_split})": (args.tree_split, 4)})
        for sel, (split, bits) in trees.items():
            scenes[sel] = tree_scene(scenes["bvh"], split, bits)
            print(f"{sel}: depth {scenes[sel].lights.structure.bvh_depth}, "
                  f"{scenes[sel].lights.selection.node.shape[0]} nodes")
        variants = (variants[0],) + tuple((f"{sel} · light_solid_angle", sel,
                                           "light_solid_angle", {}) for sel in trees)
    load0 = os.getloadavg()
    ref_estimator, ref_params = ("path", {"max_depth": PATH_DEPTH}) if args.path else ("mis", {})
    ref = jaxrt.render(scenes["power"], ref_estimator, spp=args.ref_spp, seed=12345,
                       progress=False, **ref_params)
    ref_image = np.asarray(ref.image, np.float64)
    ref_mse = float(np.mean(np.asarray(ref.stderr, np.float64) ** 2))
    for _, sel, e, p in variants:  # compile outside the timed rounds
        jaxrt.render(scenes[sel], e, spp=args.spp, seed=0, progress=False, **p)
    eff = {v[0]: [] for v in variants}
    wall_eff = {v[0]: [] for v in variants}
    stats = {v[0]: [] for v in variants}
    for k in range(args.rounds):
        order = variants if k % 2 == 0 else variants[::-1]
        for label, sel, e, p in order:
            r, cpu, wall = _timed_render(scenes[sel], e, p, args.spp, seed=1 + k)
            # the reference's own variance, independent of the render's, comes off the MSE
            mse = float(np.mean((np.asarray(r.image, np.float64) - ref_image) ** 2)) - ref_mse
            eff[label].append(1 / (mse * cpu))
            wall_eff[label].append(1 / (mse * wall))
            stats[label].append((mse, cpu, wall))
    load1 = os.getloadavg()
    first = variants[0][0]
    base, base_w = statistics.median(eff[first]), statistics.median(wall_eff[first])
    print(f"\nreference: {ref_estimator} {args.ref_spp} spp, its own MSE (σ²) {ref_mse:.3g}; "
          f"load {load0[0]:.2f} -> {load1[0]:.2f}")
    print(f"{args.size}x{args.size * 3 // 4}, {args.spp} spp, {args.rounds} interleaved rounds"
          f"{', diffuse floor' if args.diffuse else ''}\n")
    print(f"| selection · estimator | efficiency per CPU-s (× {first}) | per wall s "
          "| MSE | CPU-s | wall s |")
    print("|---|---|---|---|---|---|")
    for label, *_ in variants:
        m, c, w = (statistics.median(x) for x in zip(*stats[label], strict=True))
        print(f"| {label} | {statistics.median(eff[label]) / base:.2f} | "
              f"{statistics.median(wall_eff[label]) / base_w:.2f} | {m:.3g} | {c:.3f} | "
              f"{w:.3f} |")
    return 0


# ---------------------------------------------------------------------------------------------
# Mitsuba 3 on the same room (optional): python benchmarks/many_lights.py --mitsuba
# ---------------------------------------------------------------------------------------------


def mitsuba_matched(scene):
    """``scene`` with the BSDFs Mitsuba 3 has no equal of replaced, in jaxrt's own tables.

    The Phong floor becomes ``diffuse(kd)`` (Mitsuba 3 has no Phong); a conductor becomes
    ``conductor(alpha, ks, fresnel="none", masking="separable")``, which is Mitsuba's GGX
    ``roughconductor`` with ``material="none"`` (its Fresnel term is ``specular_reflectance``).
    Geometry, lights and camera stay as they are.
    """
    from jaxrt.scene import materials as mt

    table = jax_to_np(scene.materials)
    new = []
    for i, kind in enumerate(table["kind"]):
        if kind in (mt.DIFFUSE, mt.PHONG):
            new.append(mt.diffuse(table["kd"][i]))
        elif kind == mt.CONDUCTOR:
            new.append(mt.conductor(float(table["alpha"][i]), table["ks"][i], fresnel="none",
                                    masking="separable"))
        else:
            raise ValueError(f"material {i}: kind {mt.KIND_NAMES[int(kind)]} not translated")
    materials, kinds = mt.material_table(new)
    return scene.replace(materials=materials, material_kinds=kinds)


def jax_to_np(tree) -> dict:
    return {k: np.asarray(v) for k, v in tree._asdict().items()}


def mitsuba_scene_dict(mi, scene) -> dict:
    """A ``mi.load_dict`` description of a (matched) jaxrt scene of triangles and triangle lights.

    Every emissive triangle is its own ``mi.Mesh`` with a one-sided ``area`` emitter (so that
    Mitsuba's uniform choice among emitters is jaxrt's uniform choice among light triangles);
    the other triangles are one mesh per material, ``twosided`` (jaxrt reflects on both sides);
    camera and fov (vertical) read back from jaxrt's camera; ``hdrfilm`` with a box filter;
    ``direct`` with one emitter and one BSDF sample (MIS, power heuristic), as jaxrt's ``mis``.
    """
    from jaxrt.scene import materials as mt

    st = scene.lights.structure
    if st.counts != (0, 0, 0, st.count("triangle"), 0, 0):
        raise ValueError("only triangle lights are translated")
    tris = np.asarray(scene.triangles, np.float64)
    mat = np.asarray(scene.prim_material)
    emissive = np.asarray(scene.prim_light) >= 0
    table = jax_to_np(scene.materials)

    def mesh(name, v, bsdf, radiance=None):
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "twosided", "material": bsdf})
        if radiance is not None:
            props["emitter"] = mi.load_dict({"type": "area", "radiance": {
                "type": "rgb", "value": [float(c) for c in radiance]}})
        v = np.asarray(v, np.float32).reshape(-1, 3)
        m = mi.Mesh(name, vertex_count=len(v), face_count=len(v) // 3, props=props,
                    has_vertex_normals=False, has_vertex_texcoords=False)
        params = mi.traverse(m)
        params["vertex_positions"] = mi.Float(v.ravel())
        params["faces"] = mi.UInt32(np.arange(len(v), dtype=np.uint32))
        params.update()
        return m

    def rgb(c):
        return {"type": "rgb", "value": [float(x) for x in c]}

    out = {"type": "scene"}
    for i in np.unique(mat[~emissive]):
        kind = int(table["kind"][i])
        if kind == mt.DIFFUSE:
            bsdf = {"type": "diffuse", "reflectance": rgb(table["kd"][i])}
        elif kind == mt.CONDUCTOR and not table["fresnel_schlick"][i] \
                and table["masking_separable"][i]:
            bsdf = {"type": "roughconductor", "distribution": "ggx",
                    "alpha": float(table["alpha"][i]), "material": "none",
                    "specular_reflectance": rgb(table["ks"][i])}
        else:
            raise ValueError(f"material {i} has no Mitsuba equal: use mitsuba_matched()")
        out[f"material{i}"] = mesh(f"material{i}", tris[(mat == i) & ~emissive], bsdf)
    lights = scene.lights.table("triangle")
    lv = np.asarray(lights.vertices, np.float64)
    n = np.cross(lv[:, 1] - lv[:, 0], lv[:, 2] - lv[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    if np.any(np.asarray(lights.two_sided)) or not np.allclose(n, np.asarray(lights.normal),
                                                                atol=1e-5):
        raise ValueError("a light triangle is two-sided or emits against its winding")
    black = {"type": "diffuse", "reflectance": rgb([0, 0, 0])}
    for k, (v, radiance) in enumerate(zip(lv, np.asarray(lights.radiance), strict=True)):
        out[f"lamp{k}"] = mesh(f"lamp{k}", v, black, radiance)
    cam = scene.camera
    eye, frame = np.asarray(cam.eye, np.float64), np.asarray(cam.frame, np.float64)
    out["sensor"] = {
        "type": "perspective", "fov_axis": "y",
        "fov": float(np.degrees(2 * np.arctan(float(cam.tan_half_fov)))),
        "to_world": mi.ScalarTransform4f().look_at(
            origin=eye.tolist(), target=(eye - frame[2]).tolist(), up=frame[1].tolist()),
        "film": {"type": "hdrfilm", "width": scene.width, "height": scene.height,
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": 1},
    }
    out["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1}
    return out


def mitsuba_main(argv=None) -> int:
    """jaxrt's ``mis`` (power and uniform light selection) and Mitsuba 3's ``direct`` on the
    matched lamp-grid room: MSE against jaxrt's converged reference, CPU-s, 1/(MSE·CPU-s)."""
    ap = argparse.ArgumentParser(description=mitsuba_main.__doc__.split("\n")[0])
    ap.add_argument("--mitsuba", action="store_true", required=True)
    ap.add_argument("--size", type=int, default=96, help="image width (height 3/4 of it)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args(argv)
    try:
        from mitsuba_cornell import import_mitsuba  # sets DRJIT_LIBLLVM_PATH when needed

        mi = import_mitsuba(args.variant)
    except ImportError as e:
        print(f"Mitsuba row skipped: {e} (benchmarks/MITSUBA.md)")
        return 0
    w, h = args.size, args.size * 3 // 4
    scenes = {f"jaxrt mis, {sel} selection": mitsuba_matched(lamp_grid(w, h, light_selection=sel))
              for sel in ("power", "uniform")}
    base = scenes["jaxrt mis, power selection"]
    load0 = os.getloadavg()
    ref = jaxrt.render(base, "mis", spp=args.ref_spp, seed=12345, progress=False)
    ref_image = np.asarray(ref.image, np.float64)
    ref_mse = float(np.mean(np.asarray(ref.stderr, np.float64) ** 2))
    t0 = time.perf_counter()
    mscene = mi.load_dict(mitsuba_scene_dict(mi, base))
    print(f"Mitsuba {mi.__version__} {args.variant}: {base.lights.structure.count('triangle')} "
          f"emitters, loaded in {time.perf_counter() - t0:.1f} s")

    def mitsuba_render(spp, seed):
        c0, w0 = time.process_time(), time.perf_counter()
        img = np.array(mi.render(mscene, spp=spp, seed=seed), np.float64)[..., :3]
        return img, time.process_time() - c0, time.perf_counter() - w0

    labels = list(scenes) + ["Mitsuba direct (uniform emitter choice)"]
    mitsuba_render(args.spp, 0)  # JIT-compile / warm up outside the timed rounds
    for sc in scenes.values():
        jaxrt.render(sc, "mis", spp=args.spp, seed=0, progress=False)
    mse = {k: [] for k in labels}
    cpu = {k: [] for k in labels}
    wall = {k: [] for k in labels}
    images = {k: [] for k in labels}
    for k in range(args.rounds):
        order = labels if k % 2 == 0 else labels[::-1]
        for label in order:
            if label in scenes:
                r, c, wl = _timed_render(scenes[label], "mis", {}, args.spp, seed=1 + k)
                img = np.asarray(r.image, np.float64)
            else:
                img, c, wl = mitsuba_render(args.spp, 1 + k)
            images[label].append(img)
            mse[label].append(float(np.mean((img - ref_image) ** 2)) - ref_mse)
            cpu[label].append(c)
            wall[label].append(wl)
    load1 = os.getloadavg()
    print(f"\nmatched lamp grid (Phong floor -> diffuse kd, conductor -> Fresnel-free, "
          f"separable GGX), {w}x{h}, {args.spp} spp, {args.rounds} interleaved rounds")
    print(f"reference: jaxrt mis {args.ref_spp} spp, mean {ref_image.mean():.4g}, its own MSE "
          f"{ref_mse:.3g}; load {load0[0]:.2f} -> {load1[0]:.2f}\n")
    print("| renderer | MSE | CPU-s | wall s | 1/(MSE·CPU-s) | × jaxrt power | mean / ref |"
          " bias² |")
    print("|---|---|---|---|---|---|---|---|")
    first = statistics.median(1 / (m * c) for m, c in zip(mse[labels[0]], cpu[labels[0]],
                                                           strict=True))
    for label in labels:
        e = statistics.median(1 / (m * c) for m, c in zip(mse[label], cpu[label], strict=True))
        imgs = np.asarray(images[label])
        # the render's own variance from the spread of its rounds: what the MSE has beyond it
        # is a squared bias against jaxrt's reference (≈ 0 when the two agree)
        own = float(np.mean(imgs.var(0, ddof=1))) if len(imgs) > 1 else float("nan")
        print(f"| {label} | {statistics.median(mse[label]):.4g} | "
              f"{statistics.median(cpu[label]):.2f} | {statistics.median(wall[label]):.2f} | "
              f"{e:.3g} | {e / first:.2f} | {imgs.mean() / ref_image.mean():.4f} | "
              f"{statistics.median(mse[label]) - own:+.2g} |")
    return 0


if __name__ == "__main__":
    import sys

    raise SystemExit(mitsuba_main() if "--mitsuba" in sys.argv[1:] else main())
