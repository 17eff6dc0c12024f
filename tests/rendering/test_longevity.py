"""A long-running process: rendering many scene structures, it keeps a bounded set of programs.

Each compiled program holds machine code in memory maps of its own; a process that kept every
one would die at the kernel's ``vm.max_map_count`` (LLVM: "Unable to allocate section memory",
then a segfault). :mod:`jaxrt.rendering.program_cache` keeps the last ``MAX_PROGRAMS`` and releases
the rest; here one process renders a few hundred distinct structures and its maps and RSS stop
growing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

SCENES = 200

_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    import jaxrt
    from jaxrt.rendering import program_cache
    from jaxrt.scene.camera import look_at
    from jaxrt.scene.lights import point_light
    from jaxrt.scene.materials import diffuse
    from jaxrt.scene.container import build_scene, mesh

    def maps():
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)

    def rss_mb():
        with open("/proc/self/status") as f:
            return next(int(ln.split()[1]) / 1024 for ln in f if ln.startswith("VmRSS"))

    v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    out = []
    for k in range(int(sys.argv[1])):
        # image width 4 + k: a structure (and a program) of its own per scene
        cam = look_at(eye=[0, 1, 5], target=[0, 0, 0], up=[0, 1, 0], fov_deg=30,
                      width=4 + k, height=4)
        s = build_scene([mesh(v, [[0, 2, 1], [0, 3, 2]], diffuse(0.5))], cam,
                        [point_light([0, 2, 1], [1, 1, 1])])
        r = jaxrt.render(s, "light_area", spp=1, progress=False)
        assert np.all(np.isfinite(r.image))
        out.append((maps(), rss_mb()))
    print(json.dumps({"kept": len(program_cache._IN_MEMORY),
                      "max": program_cache.MAX_PROGRAMS, "after": out}))
""")


@pytest.mark.slow
def test_many_scene_structures_keep_maps_and_memory_bounded():
    run = subprocess.run([sys.executable, "-c", _SCRIPT, str(SCENES)], capture_output=True,
                         text=True, timeout=1800)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.splitlines()[-1])
    assert report["kept"] == report["max"] < SCENES
    maps, rss = np.asarray(report["after"]).T
    settled = 2 * report["max"]  # the cache is full, and its first programs released
    # each program held ~150 maps in this scene: growth would be ~150 per scene past here
    assert maps[-1] - maps[settled] <= 100, maps[settled::20]
    # and resident memory stops growing: less than a few programs' worth over 160 scenes
    assert rss[-1] - rss[settled] < 40, rss[settled::20]
