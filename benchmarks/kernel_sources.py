"""Where a render pass's kernel time goes, by source line, and which costly values XLA recomputes.

    python benchmarks/kernel_sources.py [--estimator path] [--spp 8] [--top 25]
    python benchmarks/kernel_sources.py --estimator mis --spp 32 --compile   # compile, by line

Compiles the real render pass (:class:`jaxrt.rendering.passes.RenderPass`, 256² Cornell box, the
independent sampler), runs it once under ``jax.profiler`` and charges every XLA:CPU kernel's time to
the source line of its root operation (the optimised HLO's ``stack_frame_id`` tables), innermost
frame first, beside the number of kernels of that line and how many of them are distinct (XLA:CPU
compiles a kernel once however many identical copies a program holds, and each distinct kernel costs
~20–40 ms of CPU to compile: benchmarks/README.md#xla-cpu). Then it lists the costly operations
(``sin``, ``cos``, ``rsqrt``, ``sqrt``, divisions, the sampler's hash) whose source line appears in
more than one kernel: XLA:CPU fuses a cheap elementwise producer into every consumer, so such a
value is computed once per kernel that reads it (and once per element of a (…, 3) output);
:func:`jaxrt.core.vecmath.computed_once` stores it. Each compaction stage of the path pass is a copy
of its step, so there every line shows up once per stage; and one line of the sampler's hash serves
every random dimension, so its count is mostly distinct values.

It shows where :func:`~jaxrt.core.vecmath.computed_once` pays (benchmarks/README.md#computed-once).

``--compile`` charges the *compile* instead: the pass is compiled in a fresh process with
XLA's log on (``TF_CPP_VMODULE``), and the MLIR and LLVM seconds XLA reports for each kernel
module go to the source line of the kernel's root operation, summed by file and by line
(benchmarks/README.md#first-frame).
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import sys
import tempfile

import jax
from profile_render import _trace_events  # this directory's profiler: one traced run

from jaxrt.integrators.config import make_estimator, prepare_scene
from jaxrt.rendering.passes import RenderPass
from jaxrt.scene.builtin import cornell_box

COSTLY = ("sine", "cosine", "rsqrt", "sqrt", "divide", "log", "exponential", "atan2", "xor")


def source_lines(text: str) -> tuple[dict, dict]:
    """(instruction → "file:line" of its innermost frame, fusion instruction → its
    computation's body) of an optimised HLO module's text."""
    tables = text.split("FileNames", 1)[1]
    files = dict(re.findall(r'^(\d+) "([^"]*)"$', tables.split("FunctionNames", 1)[0], re.M))
    locs = {i: f"{os.path.basename(files[f])}:{line}" for i, f, line in re.findall(
        r"^(\d+) \{file_name_id=(\d+) function_name_id=\d+ line=(\d+)", tables, re.M)}
    frames = dict(re.findall(r"^(\d+) \{file_location_id=(\d+) parent_frame_id=\d+\}", tables,
                             re.M))
    where = {name: locs.get(frames.get(sf), "?") for name, sf in re.findall(
        r"^\s*(?:ROOT )?%(\S+) = [^\n]*?stack_frame_id=(\d+)", text, re.M)}
    bodies = {m.group(1): m.group(2) for m in re.finditer(
        r"^%?(\S+) [^\n]*\{\n(.*?)\n\}", text, re.M | re.S)}
    calls = re.findall(r"^\s*(?:ROOT )?%(\S+) = \S+ fusion\([^\n]*calls=%(\S+?)[,\s]", text, re.M)
    return where, {kernel: bodies[comp] for kernel, comp in calls if comp in bodies}


def distinct(body: str) -> str:
    """A fused computation's text without its instruction names and metadata: two kernels
    with the same text are one kernel to XLA:CPU's compiler."""
    return "\n".join(re.sub(r"%[\w.\-]+", "%", re.sub(r", metadata=\{.*?\}", "", line)).strip()
                     for line in body.splitlines())


def kernel_times(exe, args) -> dict[str, float]:
    """Milliseconds per kernel (XLA:CPU thunk name) of one run of ``exe(*args)``."""
    ms = collections.defaultdict(float)
    for e in _trace_events(exe, args):
        if e.get("ph") == "X":
            ms[e.get("name", "").split(" ")[-1]] += e.get("dur", 0) / 1e3
    return ms


def module_seconds(log: str) -> dict[str, float]:
    """CPU seconds XLA:CPU's log reports per kernel module (MLIR and LLVM together), by the
    name of the fusion the module compiles."""
    unit = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
    out = collections.defaultdict(float)
    for name, v, u in re.findall(r"Compiled (?:MLIR|LLVM) module: (?:__compute_module_)*(\S+?)"
                                 r"(?:_kernel_module)? time: ([0-9.]+) (s|ms|us)", log):
        out[name] += float(v) * unit[u]
    return out


def compile_by_line(a) -> None:
    """Print the pass's compile seconds by source file and line (``--compile``)."""
    with tempfile.TemporaryDirectory() as tmp:
        hlo = os.path.join(tmp, "pass.hlo")
        env = dict(os.environ, TF_CPP_MIN_LOG_LEVEL="0", JAX_ENABLE_COMPILATION_CACHE="false",
                   TF_CPP_VMODULE="fusion_compiler=1,ir_compiler=1,cpu_compiler=1")
        out = subprocess.run([sys.executable, __file__, "--estimator", a.estimator, "--spp",
                              str(a.spp), "--write-hlo", hlo], env=env, text=True,
                             capture_output=True, check=True)
        with open(hlo) as f:
            text = f.read()
    seconds = module_seconds(out.stderr)
    hlo_passes = re.findall(r"Running HLO passes on \[jit_render_tiles\] for CPU time: "
                            r"([0-9.]+) (s|ms|us)", out.stderr)
    where, bodies = source_lines(text)

    def line_of(kernel: str) -> str:
        root = re.search(r"ROOT %(\S+) =", bodies[kernel]) if kernel in bodies else None
        return where.get(root.group(1), where.get(kernel, "?")) if root else where.get(kernel, "?")

    by_line, by_file, count = collections.Counter(), collections.Counter(), collections.Counter()
    for kernel, t in seconds.items():
        line = line_of(kernel)
        by_line[line] += t
        by_file[line.split(":")[0]] += t
        count[line] += 1
    total = sum(seconds.values())
    passes = f"{float(hlo_passes[-1][0]):.2f} {hlo_passes[-1][1]}" if hlo_passes else "?"
    print(f"{a.estimator}, 256², {a.spp} spp: HLO passes {passes} (one thread), then "
          f"{len(seconds)} kernel modules, {total:.2f} CPU-s of MLIR and LLVM; by file:")
    for name, t in by_file.most_common():
        print(f"  {t:7.3f} s {100 * t / total:5.1f} %  {name}")
    print("by source line (CPU-s, modules):")
    for line, t in by_line.most_common(a.top):
        print(f"  {t:7.3f} s {count[line]:4d}  {line}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estimator", default="path")
    parser.add_argument("--spp", type=int, default=8)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--compile", action="store_true",
                        help="charge the compile, not the run, to source lines")
    parser.add_argument("--write-hlo", default=None, help=argparse.SUPPRESS)
    a = parser.parse_args(argv)
    if a.compile:
        return compile_by_line(a)
    est = make_estimator(a.estimator)
    scene = prepare_scene(cornell_box(256, 256), est)
    run = RenderPass(scene, 0, jax.devices()[:1], 256, est=est, sampler="independent",
                     spp_total=a.spp, batch_size=64)
    run.compile(a.spp)
    text = run.compiled[a.spp].as_text()
    if a.write_hlo:  # the child of --compile: the optimised program, for its parent
        with open(a.write_hlo, "w") as f:
            f.write(text)
        return None
    where, bodies = source_lines(text)
    sums = jax.block_until_ready(run(run.zeros(), 0, a.spp))  # warm-up
    ms = kernel_times(lambda s: run(s, a.spp, a.spp), (sums,))
    def line_of(kernel: str) -> str:
        root = re.search(r"ROOT %(\S+) =", bodies[kernel]) if kernel in bodies else None
        return where.get(root.group(1), where.get(kernel, "?")) if root else where.get(kernel, "?")

    by_line, total = collections.defaultdict(float), 0.0
    for kernel, t in ms.items():
        if kernel in where and not kernel.startswith("while"):
            by_line[line_of(kernel)] += t
            total += t
    # each distinct fusion is compiled once (~20-40 ms of CPU, whatever its size), run or
    # not: the compile cost by line (benchmarks/README.md#xla-cpu)
    compiled = collections.Counter(line_of(kernel) for kernel in bodies)
    first = {}
    for kernel, body in bodies.items():
        first.setdefault(distinct(body), kernel)
    unique = collections.Counter(line_of(kernel) for kernel in first.values())
    print(f"{a.estimator}, 256², {a.spp} spp: {total:.0f} ms of kernels, {len(bodies)} kernels, "
          f"{len(first)} distinct; by source line (run time, share, kernels, distinct):")
    for line, t in sorted(by_line.items(), key=lambda r: -r[1])[:a.top]:
        share = 100 * t / total
        print(f"  {t:8.1f} ms {share:5.1f} % {compiled[line]:4d} {unique[line]:4d}  {line}")
    print("most distinct kernels compiled:",
          ", ".join(f"{line} {n}" for line, n in unique.most_common(8)))
    seen = collections.defaultdict(set)
    for kernel, body in bodies.items():
        for instr, op in re.findall(r"%(\S+) = \S+ (" + "|".join(COSTLY) + r")\(", body):
            seen[(op, where.get(instr, "?"))].add(kernel)
    print("costly operations of one source line computed in several kernels:")
    for (op, line), kernels in sorted(seen.items(), key=lambda r: -len(r[1])):
        if len(kernels) > 1 and line != "?":
            print(f"  {op:10s} {line:22s} {len(kernels)} kernels")


if __name__ == "__main__":
    main()
