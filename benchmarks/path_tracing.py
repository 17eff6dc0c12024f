"""Path tracing on the 256² Cornell box: error against time beside Mitsuba 3, and what the
indirect light adds.

    python benchmarks/path_tracing.py convergence   # ~6 min: RMSE vs time, both renderers
    python benchmarks/path_tracing.py indirect      # ~2 min: direct vs global illumination

``convergence``: jaxrt's ``path`` estimator and Mitsuba 3's ``path`` integrator (both
unbounded, Russian roulette from depth 5, box filter, independent sampler) render the box at
1, 2, 4, … 64 spp; each image's RMSE is taken against Mitsuba's converged image (2 048 spp,
seeds disjoint from the runs'; its own noise inflates the measured MSE by ≈ 1 + spp/2048).
Every level is one render of that many spp from scratch: for jaxrt one pass of the program
``render`` runs (compiled before the clock starts), for Mitsuba one ``mi.render`` call after a
warm-up; all levels of all three renderers are timed in the same 3 interleaved rounds
(medians, wall and CPU seconds). jaxrt's ``mis`` (direct light only) is run the same way against
Mitsuba's converged direct image, for the cost of the indirect light at equal relative error.
Writes ``benchmarks/plots/path_rmse_vs_time.png`` and prints the time each needs to reach RMSE
0.05 and 0.03 (log-log interpolation, ``time_to_rmse``).

``indirect``: ``mis`` (direct light, 1 + 1 samples) and ``path`` at 256 spp, their region
means (walls, floor, blocks) and what the indirect light adds, in numbers and in
``docs/images/cornell_direct_vs_path.png`` (direct | global | indirect = global − direct).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import mitsuba_cornell as mc  # noqa: E402

SIZE = 256
LEVELS = (1, 2, 4, 8, 16, 32, 64)
REFERENCE_SPP = 2048
PATH = {"type": "path", "max_depth": -1, "rr_depth": 5}


def mitsuba_path_scene(width: int = SIZE, height: int = SIZE):
    """Mitsuba's Cornell box (the very arrays jaxrt renders) with its ``path`` integrator."""
    mi = mc.import_mitsuba(mc.DEFAULT_VARIANT)
    desc = mc.cornell_scene_dict(width, height, "box", 1.0, mc.DEFAULT_VARIANT)
    desc["integrator"] = dict(PATH)
    return mi, mi.load_dict(desc)


def mitsuba_path_reference(spp: int = REFERENCE_SPP, width: int = SIZE,
                           height: int = SIZE) -> np.ndarray:
    """Mitsuba's converged path-traced box, cached under ``benchmarks/.cache`` as an EXR
    (passes of 256 spp, seeds from ``mc.REFERENCE_SEED``, averaged in float64)."""
    from jaxrt.scene.images import read_exr, write_exr

    path = mc.CACHE_DIR / f"mitsuba_cornell_path_{width}x{height}_{spp}spp.exr"
    if path.exists():
        return read_exr(path)[0]
    mi, scene = mitsuba_path_scene(width, height)
    per = min(spp, 256)
    acc = np.zeros((height, width, 3), np.float64)
    for k in range(spp // per):
        acc += np.array(mi.render(scene, spp=per, seed=mc.REFERENCE_SEED + k), np.float64)
    img = (acc / (spp // per)).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, img)
    return img


def paired_rows(reference: np.ndarray, direct_reference: np.ndarray, levels=LEVELS,
                rounds: int = 3, seed: int = 100) -> tuple[dict, float]:
    """(spp, seconds, cpu_seconds, rmse) rows of jaxrt ``path``, Mitsuba ``path`` and jaxrt
    ``mis``, every level one render from scratch, all timed in the same interleaved rounds
    (``convergence.paired_level_times``); and jaxrt's compile seconds (path)."""
    from convergence import level_renderer, paired_level_times

    from jaxrt.scene.builtin import cornell_box

    mi, scene = mitsuba_path_scene(reference.shape[1], reference.shape[0])
    box = cornell_box(reference.shape[1], reference.shape[0])
    path_fn, t_compile = level_renderer(box, "path", levels)
    mis_fn, _ = level_renderer(box, "mis", levels)
    images, times = paired_level_times({
        "jaxrt": (levels, lambda i, spp: path_fn(spp)[0]),
        "mitsuba": (levels, lambda i, spp: np.array(mi.render(scene, spp=int(spp),
                                                             seed=seed + 1 + i))),
        "jaxrt mis": (levels, lambda i, spp: mis_fn(spp)[0])}, rounds)
    refs = {"jaxrt": reference, "mitsuba": reference, "jaxrt mis": direct_reference}
    rows = {name: [{"spp": int(spp), **times[name][spp],
                    "rmse": mc.rmse(images[name][spp], refs[name]),
                    "rel_rmse": mc.rmse(images[name][spp], refs[name])
                    / float(np.mean(refs[name]))} for spp in levels] for name in refs}
    return rows, t_compile


def convergence(out: Path = HERE / "plots" / "path_rmse_vs_time.png") -> dict:
    """RMSE against time for both renderers; see the module docstring."""
    reference = mitsuba_path_reference()
    # direct light alone (mis), against Mitsuba's converged direct image: what the indirect
    # light costs in time for the same relative error
    direct_ref = mc.mitsuba_reference(4096, SIZE, SIZE)
    load = os.getloadavg()
    rows, t_compile = paired_rows(reference, direct_ref)
    jx, mt, jd = rows["jaxrt"], rows["mitsuba"], rows["jaxrt mis"]
    res = {"load": (load, os.getloadavg()), "jaxrt_compile_s": t_compile, "jaxrt": jx,
           "mitsuba": mt, "jaxrt_direct": jd}
    on_cpu = lambda rs: [dict(r, seconds=r["cpu_seconds"]) for r in rs]  # noqa: E731
    for target in (0.05, 0.03):
        tj, tm = mc.time_to_rmse(jx, target), mc.time_to_rmse(mt, target)
        cj, cm = mc.time_to_rmse(on_cpu(jx), target), mc.time_to_rmse(on_cpu(mt), target)
        res[f"time_to_{target}"] = {"jaxrt_s": tj, "mitsuba_s": tm, "ratio": tj / tm,
                                    "ratio_cpu": cj / cm}
        print(f"RMSE {target}: jaxrt {tj:.2f} s, Mitsuba {tm:.2f} s: jaxrt/Mitsuba {tj / tm:.2f}"
              f" per wall s, {cj / cm:.2f} per CPU-s")
    for name, rs in rows.items():
        print(name, " ".join(f"{r['spp']}:{r['seconds']:.2f}s/{r['rmse']:.4f}" for r in rs))
    print(f"load {res['load']}")
    _plot(jx, mt, jd, out)
    return res


def _plot(jx: list[dict], mt: list[dict], jd: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name, rows, style in (("jaxrt path", jx, "o-"), ("Mitsuba 3 path (llvm_ad_rgb)", mt,
                                                          "s-"),
                              ("jaxrt mis (direct light only)", jd, "^--")):
        ax.loglog([r["seconds"] for r in rows], [r["rel_rmse"] for r in rows], style,
                  label=name)
    ax.set_xlabel("render time (s, wall)")
    ax.set_ylabel("RMSE / mean radiance vs converged image")
    ax.set_title("Cornell box 256², box filter")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def indirect(spp: int = 256, out: Path = HERE.parent / "docs" / "images" /
             "cornell_direct_vs_path.png") -> dict:
    """Direct vs global illumination of the box: region means and a three-panel figure."""
    from jaxrt.rendering.driver import render
    from jaxrt.scene.builtin import cornell_box
    from jaxrt.scene.images import _tonemap_to_8bit

    scene = cornell_box(SIZE, SIZE)
    direct = render(scene, "mis", spp=spp, seed=1, progress=False)
    glob = render(scene, "path", spp=spp, seed=2, progress=False)
    masks = mc.cornell_region_masks(SIZE, SIZE)
    rd, rg = mc.region_means(direct.image, masks), mc.region_means(glob.image, masks)
    res = {"spp": spp, "seconds": {"mis": direct.timings["render"],
                                   "path": glob.timings["render"]}}
    print(f"{'region':14s} {'direct':>8s} {'global':>8s} {'indirect share':>15s}")
    for name in rd:
        d, g = np.asarray(rd[name]).mean(), np.asarray(rg[name]).mean()
        res[name] = {"direct": float(d), "global": float(g), "indirect_share": float(1 - d / g)}
        print(f"{name:14s} {d:8.4f} {g:8.4f} {1 - d / g:15.1%}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    diff = np.maximum(glob.image - direct.image, 0)
    fig, axes = plt.subplots(1, 3, figsize=(9, 3.3))
    for ax, img, title in zip(axes, (direct.image, glob.image, diff),
                              (f"direct (mis, {spp} spp)", f"global (path, {spp} spp)",
                               "indirect = global − direct"), strict=True):
        ax.imshow(_tonemap_to_8bit(img, 0.0, "srgb"))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")
    return res


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("convergence", "indirect"))
    a = parser.parse_args(argv)
    convergence() if a.what == "convergence" else indirect()
    return 0


if __name__ == "__main__":
    sys.exit(main())
