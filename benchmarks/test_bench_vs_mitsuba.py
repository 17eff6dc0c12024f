"""jaxrt vs Mitsuba 3 on the same 256² Cornell box, MIS with 1 light + 1 BSDF sample.

Run (several minutes on a loaded machine; one run measures everything)::

    pytest benchmarks/test_bench_vs_mitsuba.py --benchmark-enable -s

The whole comparison is :func:`convergence.mitsuba_comparison` (run once per module; its
dict is saved to ``benchmarks/.cache/vs_mitsuba.json`` and ``python benchmarks/convergence.py
--mitsuba-only --cached`` turns it into a markdown table). The tests report samples/s
and time-to-equal-RMSE ratios in ``benchmark.extra_info``, check that the two converged
images agree within their noise, and state the targets: the firm ones (≥ 0.45× Mitsuba's
samples per CPU-second, Sobol at ≤ 0.5× its time to RMSE 0.03) as tests, the stretch ones
(≥ 0.6× its samples/s, ≤ 1.0× its time to every RMSE) as expected failures, since they sit at
the edge (see the markers' reasons).
Skipped when Mitsuba (or its LLVM backend) is unavailable.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (see benchmarks/MITSUBA.md)")

sys.path.insert(0, str(Path(__file__).resolve().parent))
import convergence as cv  # noqa: E402
import mitsuba_cornell as mc  # noqa: E402


@pytest.fixture(scope="module")
def comparison():
    try:
        mc.import_mitsuba(mc.DEFAULT_VARIANT)
    except ImportError as e:
        pytest.skip(f"Mitsuba's {mc.DEFAULT_VARIANT} variant is unusable: {e}")
    return cv.mitsuba_comparison(log=print)


def test_bench_samples_per_second(benchmark, comparison):
    r, m = comparison["ratios"], comparison["mitsuba"]
    info = {"mitsuba_samples_per_s_best": m["samples_per_second"],
            "mitsuba_samples_per_s_median": m["median_samples_per_second"],
            **{f"jaxrt_{s}_samples_per_s": v["samples_per_s"]
               for s, v in comparison["jaxrt"].items()},
            "ratio_vs_best": r["samples_per_s_vs_best"],
            "ratio_vs_median": r["samples_per_s_vs_median"]}
    benchmark.extra_info.update(info)
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)  # figures come from the fixture
    print(f"\n  samples/s: Mitsuba {info['mitsuba_samples_per_s_best'] / 1e6:.3f} (best), "
          f"jaxrt {info['jaxrt_independent_samples_per_s'] / 1e6:.3f}: "
          f"ratio {info['ratio_vs_best']:.3f}")
    # both renderers actually rendered: positive, finite throughput
    assert all(np.isfinite(v) and v > 0 for v in info.values())


def test_bench_time_to_equal_error(benchmark, comparison):
    ttr = comparison["ratios"]["time_to_rmse"]
    for target, e in ttr.items():
        for k, v in e.items():
            benchmark.extra_info[f"rmse_{target}_{k}"] = v
        print(f"\n  RMSE {target}: Mitsuba {e['mitsuba_s']:.3f} s, jaxrt independent "
              f"{e['jaxrt_independent_s']:.3f} s (×{e['ratio_independent']:.2f}), sobol "
              f"{e['jaxrt_sobol_s']:.3f} s (×{e['ratio_sobol']:.2f})")
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)
    # each renderer's error must fall with spp at the Monte Carlo rate (RMSE ∝ spp^-1/2 for
    # independent samples): from 1 to 16 spp it drops ×4; allow ×2.5 (noise of one image)
    for name, rows in [("mitsuba", comparison["mitsuba"]["rows"]),
                       ("jaxrt", comparison["jaxrt"]["independent"]["rows"])]:
        e = {r["spp"]: r["rmse"] for r in rows}
        assert e[1] / e[16] > 2.5, f"{name}: RMSE 1 spp {e[1]:.4f} vs 16 spp {e[16]:.4f}"


def test_converged_images_agree(comparison):
    a = comparison["agreement"]
    print(f"\n  block z: max {a['max_abs_z']:.2f}, >3: {100 * a['frac_abs_z_gt_3']:.2f} %, "
          f"mean {a['mean_z']:.3f}, sd {a['std_z']:.3f}; 2 % brighter: "
          f"{a['max_abs_z_light_2pct_brighter']:.1f}")
    # ~700 block z-scores of independent noise: |z| ≤ 5 for all has family-wise false-alarm
    # probability < 1e-3; a systematic 2 % difference must break it (teeth, same statistic)
    assert a["max_abs_z"] < 5.0
    assert a["max_abs_z_light_2pct_brighter"] > 5.0
    # z-scores of pure noise have unit spread: a much larger sd means the noise model is off
    # (e.g. a wrong stderr), a much smaller one a stderr that is too large; ±30 % for ~700 z
    assert 0.7 < a["std_z"] < 1.3
    for name, v in a["regions"].items():
        # per-region means: 5 σ of the jaxrt reference (Mitsuba's 4096 spp add ~3 % to σ)
        assert np.all(np.abs(v["z"]) < 5.0), (name, v)


def test_profile_explains_the_gap(comparison):
    p = comparison["profile"]
    whole = p["whole MIS camera sample"]["ns_per_ray"]
    for name, v in p.items():
        if isinstance(v, dict):
            print(f"\n  {name:28s} {v['ns_per_ray']:8.0f} ns/ray "
                  f"({100 * v['share_of_whole']:.0f} %)")
    # a camera sample traces 3 rays (camera, shadow, BSDF): each stage alone is cheaper than
    # the whole, or the profile measured something else
    assert all(v["ns_per_ray"] <= 1.5 * whole for v in p.values() if isinstance(v, dict))


@pytest.mark.xfail(reason="stretch target at the edge: ~0.60x Mitsuba's median samples/s on an "
                   "AMD family-25 VM (independent sampler, whole renders)",
                   strict=False)
def test_target_samples_per_second(comparison):
    # stretch target: jaxrt ≥ 0.6 × Mitsuba's samples/s (against Mitsuba's median: same load)
    assert comparison["ratios"]["samples_per_s_vs_median"] >= 0.6


@pytest.mark.xfail(reason="stretch target at the edge at RMSE 0.1 (renders of ~30 ms: Sobol "
                   "~0.9x Mitsuba's time); ~0.64x at 0.05, ~0.22x at 0.03",
                   strict=False)
def test_target_time_to_equal_error(comparison):
    # stretch target: time to equal error ≤ 1.0 × Mitsuba's, with the better of jaxrt's samplers
    for e in comparison["ratios"]["time_to_rmse"].values():
        assert min(e["ratio_independent"], e["ratio_sobol"]) <= 1.0


def test_bench_paired_per_cpu_second(benchmark):
    """jaxrt ÷ Mitsuba per CPU-second and per wall second, interleaved rounds in one process,
    with jaxrt's compile time, kernel count and first frame."""
    import paired_vs_mitsuba as pvm

    try:
        mc.import_mitsuba(mc.DEFAULT_VARIANT)
    except ImportError as e:
        pytest.skip(f"Mitsuba's {mc.DEFAULT_VARIANT} variant is unusable: {e}")
    res = pvm.paired(spp=32, rounds=4)
    total, compile_s = pvm.first_frame_seconds()
    benchmark.extra_info.update({
        "ratio_per_cpu_s": res["ratio_per_cpu_s"], "ratio_per_wall_s": res["ratio_per_wall_s"],
        "jaxrt_cores": res["jaxrt"]["cores"], "mitsuba_cores": res["mitsuba"]["cores"],
        "jaxrt_compile_s": res["jaxrt_compile_s"], "first_frame_s": total,
        "first_frame_compile_s": compile_s, **res["jaxrt_kernels"]})
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)  # figures come from paired()
    print(f"\n  first frame {total:.2f} s (compile {compile_s:.2f} s)")
    assert res["ratio_per_cpu_s"] > 0 and np.isfinite(res["ratio_per_cpu_s"])


def test_target_per_cpu_second():
    """The target: jaxrt's pass renders ≥ 0.45× Mitsuba's samples per CPU-second, paired in
    one process (0.60–0.70× on an AMD family-25 VM and 0.74–0.79× on a family-23 one:
    benchmarks/README.md#results-mitsuba).

    A run inside one of the shared VM's slow episodes, where jaxrt's pass runs ~2.4× slower
    for seconds at a time while Mitsuba keeps its speed, reads 0.32–0.40×
    (benchmarks/README.md#method); a run below the target is repeated once, and the test
    fails when the repeat is below it too (a pass that lost half its speed fails both).
    """
    import paired_vs_mitsuba as pvm

    try:
        mc.import_mitsuba(mc.DEFAULT_VARIANT)
    except ImportError as e:
        pytest.skip(f"Mitsuba's {mc.DEFAULT_VARIANT} variant is unusable: {e}")
    ratios = [pvm.paired(spp=32, rounds=4)["ratio_per_cpu_s"]]
    if ratios[0] < 0.45:
        ratios.append(pvm.paired(spp=32, rounds=4)["ratio_per_cpu_s"])
    print(f"\n  jaxrt ÷ Mitsuba per CPU-s: {', '.join(f'{r:.3f}' for r in ratios)}")
    assert ratios[-1] >= 0.45


def test_target_sobol_time_to_equal_error(comparison):
    """The target: with the Sobol stream, jaxrt reaches RMSE 0.03 in ≤ 0.5× Mitsuba's time (both
    timed as renders of each spp from scratch in the same interleaved rounds)."""
    e = comparison["ratios"]["time_to_rmse"]["0.03"]
    print(f"\n  RMSE 0.03: jaxrt sobol ÷ Mitsuba {e['ratio_sobol']:.2f} per wall s, "
          f"{e['ratio_sobol_cpu']:.2f} per CPU-s")
    assert e["ratio_sobol"] <= 0.5 and e["ratio_sobol_cpu"] <= 0.5
